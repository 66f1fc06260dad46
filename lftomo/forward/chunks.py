"""Chunk sizes for long numba calls, so that Ctrl-C is honoured within about a second.

A numba kernel cannot be interrupted: Python sees SIGINT only when the kernel
returns.  The Python loops around the kernels (render rows, weight-matrix
rows) therefore take chunks sized from the measured time per row, aiming at
:data:`TARGET_SECONDS` per call; a pending KeyboardInterrupt is raised
between two chunks.

A SIGINT that arrives while a kernel calls back into Python (numba does so to
build some constants) surfaces as ``SystemError: ... returned a result with an
exception set`` caused by the KeyboardInterrupt; :func:`interruptible` turns it
back into a KeyboardInterrupt.
"""

from __future__ import annotations

import functools
import time
from typing import Callable, Iterator, TypeVar

__all__ = ["ChunkSizer", "TARGET_SECONDS", "interruptible"]

F = TypeVar("F", bound=Callable)

#: Aimed duration of one kernel call (s).
TARGET_SECONDS = 0.25


class ChunkSizer:
    """Row ranges whose kernel time stays near ``target`` seconds.

    Parameters
    ----------
    max_rows : int
        Upper bound of a chunk (e.g. from a scratch-memory budget), >= 1.
    start : int
        Rows of the first chunk (small: its time includes numba's start-up).
    target : float
        Aimed seconds per chunk.

    Examples
    --------
    >>> sizer = ChunkSizer(1000, start=4)
    >>> for r0, r1 in sizer.ranges(10):
    ...     pass  # run the kernel on rows r0:r1
    """

    def __init__(self, max_rows: int, *, start: int = 4, target: float = TARGET_SECONDS):
        self.max_rows = max(1, int(max_rows))
        self.rows = max(1, min(self.max_rows, int(start)))
        self.target = float(target)
        self.seconds_per_row: float | None = None

    def update(self, n_rows: int, seconds: float) -> None:
        """Record that ``n_rows`` took ``seconds``; size the next chunk (growth at most 4x)."""
        if n_rows <= 0:
            return
        per_row = max(seconds, 1e-9) / n_rows
        self.seconds_per_row = per_row
        want = int(self.target / per_row)
        self.rows = max(1, min(self.max_rows, want, 4 * self.rows))

    def ranges(self, n: int, start: int = 0) -> Iterator[tuple[int, int]]:
        """Yield ``(r0, r1)`` covering ``start .. n``, timing the caller's work between yields."""
        r0 = start
        while r0 < n:
            r1 = min(n, r0 + self.rows)
            t = time.perf_counter()
            yield r0, r1
            self.update(r1 - r0, time.perf_counter() - t)
            r0 = r1


def interruptible(func: F) -> F:
    """Decorate a function that calls numba kernels: Ctrl-C raises KeyboardInterrupt, never SystemError.

    Examples
    --------
    >>> @interruptible
    ... def build():
    ...     pass  # loops of kernel calls
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except SystemError as exc:
            if isinstance(exc.__cause__, KeyboardInterrupt) or isinstance(exc.__context__, KeyboardInterrupt):
                raise KeyboardInterrupt from None
            raise

    return wrapper  # type: ignore[return-value]
