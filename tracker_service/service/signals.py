"""Stopping on SIGTERM and SIGINT without a lock in the signal handler.

A Python signal handler runs in the main thread between two bytecodes, wherever that
thread is, possibly inside ``threading.Event.wait`` holding the event's lock: a handler
that calls ``Event.set()`` then waits for a lock its own thread holds, and the process
hangs until SIGKILL (seen about once in 40 SIGTERMs). Here the handler only stores the
signal number in an attribute; the kernel-level wake-up is ``signal.set_wakeup_fd``,
which writes a byte into a non-blocking socket from the C handler itself, so that a
``wait`` blocked in ``select`` on it returns at once. ``set`` (another thread, a test)
writes a byte into the same socket.
"""

from __future__ import annotations

import contextlib
import select
import signal
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Protocol

__all__ = ["Stop", "StopSignal", "stop_on_signals"]

SIGNALS = (signal.SIGTERM, signal.SIGINT)


class Stop(Protocol):
    """What the daemon and the replay ask of a stop request (``threading.Event`` is one)."""

    def is_set(self) -> bool: ...
    def wait(self, timeout: float | None = None) -> bool: ...


class StopSignal:
    """A stop request: ``is_set()`` and ``wait(timeout)`` as ``threading.Event`` has them,
    set by a signal (see the module docstring) or by ``set()``."""

    def __init__(self) -> None:
        self._reader, self._writer = socket.socketpair()
        self._reader.setblocking(False)
        self._writer.setblocking(False)
        self.signal: int | None = None
        """The signal that asked to stop, if one did."""
        self._set = False

    def handler(self, signum: int, frame: FrameType | None) -> None:
        """The Python-level handler: two attribute stores, nothing that takes a lock."""
        self.signal = signum
        self._set = True

    def set(self) -> None:
        self._set = True
        with contextlib.suppress(BlockingIOError, OSError):
            self._writer.send(b"\0")

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout: float | None = None) -> bool:
        """True once stopping was asked for, else False after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._set:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                break
            select.select([self._reader], [], [], left)
            # The wake-up byte comes from the C handler before the Python handler has
            # run; that one runs as soon as this thread is back in Python code: here.
            self._drain()
        return self._set

    def _drain(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            while self._reader.recv(4096):
                pass

    @property
    def wakeup_fd(self) -> int:
        return self._writer.fileno()

    def close(self) -> None:
        self._reader.close()
        self._writer.close()


@contextmanager
def stop_on_signals() -> Iterator[StopSignal]:
    """A ``StopSignal`` set by SIGTERM or SIGINT, from the main thread (where Python runs
    signal handlers); the previous handlers and wake-up fd come back afterwards, unless
    a signal did stop: then the process is on its way out, and a repeated SIGTERM (an
    impatient operator, a service manager) must not kill it with the default action
    between here and its exit (the interpreter's finalisation resets Python handlers to
    the default), so both signals are ignored from here on. While the orderly stop runs
    (tracks ended, log closed), a repeated signal only sets the flag again: SIGKILL is
    what interrupts it."""
    stop = StopSignal()
    previous_fd = signal.set_wakeup_fd(stop.wakeup_fd, warn_on_full_buffer=False)
    previous = {s: signal.signal(s, stop.handler) for s in SIGNALS}
    try:
        yield stop
    finally:
        signal.set_wakeup_fd(previous_fd)
        for signum, handler in previous.items():
            signal.signal(signum, handler if stop.signal is None else signal.SIG_IGN)
        stop.close()
