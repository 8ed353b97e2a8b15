"""``with`` support for the objects that hold a resource (a socket, a file, a session)."""

from __future__ import annotations

from types import TracebackType
from typing import Self


class Closing:
    """Mixin: ``with obj:`` calls ``obj.close()`` on the way out, on errors too, so that
    what was written until then remains readable and sockets are given back."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
