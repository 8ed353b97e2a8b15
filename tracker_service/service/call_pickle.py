"""The pickles of the calls the core sends the output process (``command.OutputProcess``).

Each radar batch's call carries three structured arrays (plots, local updates, system
rows), and pickle writes an array's dtype in full each time: a structured dtype of 20-36
fields costs 20-37 us to pickle, and as much to rebuild, which was most of the 70 us a
batch's call cost the fusion process. Here an array's dtype crosses once per output
process: its first array carries it with a number, the later ones the number only, and
the process keeps the dtypes it was given by number (``_known``). The arrays come out as
``pickle.loads`` made them before: the same dtype, shape and bytes, writable.

The numbers are a sender's (``CallPickler``) for one receiving process: a new output
process (a restart) needs a new ``CallPickler``, and a call pickled for a process that
died is pickled again for the next.
"""

from __future__ import annotations

import io
import pickle
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["MAX_DTYPES", "CallPickler"]

MAX_DTYPES = 256
"""Dtypes numbered at most: ever new ones (a dtype made per call) cost a full pickle each,
not memory."""

_known: dict[int, np.dtype[Any]] = {}
"""In the output process: the dtypes its sender numbered, by number."""


def _rebuild_new(
    number: int, dtype: np.dtype[Any], shape: tuple[int, ...], data: bytearray
) -> npt.NDArray[Any]:
    """An array whose dtype comes with it for the first time: kept under ``number``."""
    _known[number] = dtype
    return _rebuild(number, shape, data)


def _rebuild(number: int, shape: tuple[int, ...], data: bytearray) -> npt.NDArray[Any]:
    """An array of the dtype numbered ``number`` (C order)."""
    return np.frombuffer(data, dtype=np.uint8).view(_known[number]).reshape(shape)


class _NumberingPickler(pickle.Pickler):
    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.numbers: dict[int, tuple[int, np.dtype[Any]]] = {}
        """By ``id`` of a dtype (held here, so its id is not reused): its number."""

    def reducer_override(self, obj: object) -> Any:
        if type(obj) is not np.ndarray or obj.dtype.hasobject:
            return NotImplemented
        dtype = obj.dtype
        known = self.numbers.get(id(dtype))
        # In band as a bytearray (protocol 5): unpickled writable, as an array's own.
        raw = np.ascontiguousarray(obj).view(np.uint8).reshape(-1)
        data = pickle.PickleBuffer(raw)  # type: ignore[arg-type]  # numpy's buffer
        if known is not None:
            return _rebuild, (known[0], obj.shape, data)
        if len(self.numbers) >= MAX_DTYPES:
            return NotImplemented
        number = len(self.numbers)
        self.numbers[id(dtype)] = (number, dtype)
        return _rebuild_new, (number, dtype, obj.shape, data)


class CallPickler:
    """``pickle.dumps(call, HIGHEST_PROTOCOL)`` with each array's dtype numbered (see the
    module docstring). One pickler, its memo cleared at each call: made once."""

    def __init__(self) -> None:
        self._buffer = io.BytesIO()
        self._pickler = _NumberingPickler(self._buffer)

    def dumps(self, call: object) -> bytes:
        buffer = self._buffer
        buffer.seek(0)
        buffer.truncate()
        self._pickler.clear_memo()
        self._pickler.dump(call)
        return buffer.getvalue()
