"""Host-side values shared by content, for JAX callbacks with static handles.

:mod:`lftomo.inverse.hostsparse` (matrices) and
:mod:`lftomo.inverse.hostsegments` (ray-segment tables) hand JAX a small
pytree whose static field is an integer handle; the host callback looks the
value up by it.  The handle is a hash of the value's content, so equal values
share one handle and JAX's compilation cache hits across objects made from
equal inputs.  A hash collision with different content gets a fresh handle
(1, 2, …; content handles are ≥ 2³²).  An entry lives while an object that
holds its handle is alive (reference counted, released by a finaliser).
"""

from __future__ import annotations

import hashlib
import itertools
import threading
import weakref
from typing import Any, Callable, Iterable

import numpy as np

__all__ = ["ContentRegistry", "content_hash"]


def content_hash(arrays: Iterable[Any]) -> int:
    """A handle ≥ 2³² from arrays' dtypes, shapes and bytes (64-bit BLAKE2b)."""
    h = hashlib.blake2b(digest_size=8)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return int.from_bytes(h.digest(), "little") | (1 << 32)


class ContentRegistry:
    """Values by handle, kept while an object holding the handle lives.

    Attributes
    ----------
    values : dict
        handle → value (read it in the host callbacks).
    """

    def __init__(self) -> None:
        self.values: dict[int, Any] = {}
        self._live: dict[int, int] = {}  # handle -> live objects holding it
        self._fresh = itertools.count(1)
        self._lock = threading.RLock()  # re-entrant: a finaliser may run while register holds it

    def register(self, key: int, make: Callable[[], Any], same: Callable[[Any], bool]) -> int:
        """The handle for content hashed to ``key``.

        ``make()`` builds the value when the content is new; ``same(value)``
        tells whether a registered value under ``key`` has this content (a
        different one is a hash collision: a fresh handle is used).  Call
        :meth:`hold` with the object that carries the returned handle.
        """
        with self._lock:
            self._live[key] = self._live.get(key, 0) + 1  # counted first: a finaliser meanwhile keeps the entry
            entry = self.values.get(key)
            if entry is not None and not same(entry):  # hash collision with other content
                self._live[key] -= 1  # >= 1: the other content's objects are alive
                key, entry = next(self._fresh), None
                self._live[key] = 1
            if entry is None:
                self.values[key] = make()
        return key

    def hold(self, obj: Any, key: int) -> None:
        """Keep ``key``'s value while ``obj`` lives (one reference, counted by :meth:`register`)."""
        weakref.finalize(obj, self._release, key)

    def _release(self, key: int) -> None:
        with self._lock:
            n = self._live.get(key, 0) - 1
            if n > 0:
                self._live[key] = n
            else:
                self._live.pop(key, None)
                self.values.pop(key, None)
