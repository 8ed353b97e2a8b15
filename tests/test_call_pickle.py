"""tracker_service.service.call_pickle against pickle: the same objects back."""

from __future__ import annotations

import pickle
from typing import Any

import numpy as np

from tracker_service.radar_stage import RAW_PLOT_DTYPE
from tracker_service.service.call_pickle import MAX_DTYPES, CallPickler


def _same(got: Any, expected: Any) -> None:
    assert type(got) is type(expected)
    assert got.dtype == expected.dtype
    assert got.shape == expected.shape
    assert got.tobytes() == expected.tobytes()
    assert got.flags.writeable


def test_arrays_come_back_as_pickle_gives_them() -> None:
    """Structured, plain, empty, 0-d, Fortran-ordered and strided arrays, each dtype
    sent twice (numbered the second time), beside other objects."""
    rng = np.random.default_rng(3)
    plots = np.zeros(5, dtype=RAW_PLOT_DTYPE)
    plots["x"] = rng.normal(size=5)
    plots["callsign"] = "ABC123"
    plots["R"] = rng.normal(size=(5, 2, 2))
    arrays = [
        plots,
        plots[:0],
        plots[::2],
        rng.normal(size=(4, 2, 4)),
        np.asfortranarray(rng.normal(size=(3, 5))),
        np.array(7.5),
        np.arange(6, dtype=np.int64).reshape(2, 3)[:, 1],
        np.array([True, False]),
    ]
    pickler = CallPickler()
    for _ in range(2):
        call = ("batch", (arrays, {"a": 1.5, "b": [None, "x"]}, 3))
        data = pickler.dumps(call)
        method, (got, extra, n) = pickle.loads(data)
        assert (method, extra, n) == ("batch", {"a": 1.5, "b": [None, "x"]}, 3)
        for g, e in zip(got, arrays, strict=True):
            _same(g, pickle.loads(pickle.dumps(e, protocol=pickle.HIGHEST_PROTOCOL)))


def test_a_dtype_crosses_once() -> None:
    """The second array of a structured dtype is its bytes and a number, no dtype."""
    pickler = CallPickler()
    plots = np.zeros(3, dtype=RAW_PLOT_DTYPE)
    first, second = pickler.dumps(plots), pickler.dumps(plots)
    assert b"callsign" in first and b"callsign" not in second
    assert len(second) < len(first) - 500
    _same(pickle.loads(second), plots)


def test_object_arrays_and_too_many_dtypes_pickle_as_ever() -> None:
    pickler = CallPickler()
    objects = np.array([1, "a", None], dtype=object)
    assert list(pickle.loads(pickler.dumps(objects))) == [1, "a", None]
    for k in range(MAX_DTYPES + 3):
        dtype = np.dtype([(f"f{k}", np.int64)])
        row = np.zeros(1, dtype=dtype)
        _same(pickle.loads(pickler.dumps(row)), row)
