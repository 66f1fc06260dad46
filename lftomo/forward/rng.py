"""Counter-based random numbers for numba kernels.

Every Monte Carlo kernel in lftomo draws its random numbers from a stream
that depends only on ``(seed, stream)``, where ``stream`` is a stable index
such as the flat pixel index.  The result of a render therefore does not
depend on the number of threads or on the order in which ``prange``
schedules pixels.

The generator is SplitMix64 (Steele, Lea & Flood, "Fast splittable
pseudorandom number generators", OOPSLA 2014): the state is a 64-bit counter
advanced by the golden-ratio increment and each output is a bijective mix of
the counter.  It passes BigCrush and is more than adequate for Monte Carlo
transport.  Usage inside a kernel::

    state = rng_init(seed, pixel)
    state, u1 = rng_uniform(state)
    state, u2 = rng_uniform(state)
"""

from __future__ import annotations

import numpy as np
from numba import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV53 = 1.0 / 9007199254740992.0  # 2**-53


@njit(cache=True, inline="always")
def _mix64(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True, inline="always")
def rng_init(seed, stream):
    """Initial state (uint64) of the stream ``stream`` of generator ``seed``.

    Parameters
    ----------
    seed, stream : int
        Non-negative integers (seed < 2**63, stream < 2**63).
    """
    s = _mix64(np.uint64(seed) * _GOLDEN + np.uint64(0x632BE59BD9B4E019))
    return _mix64(s ^ _mix64(np.uint64(stream) + _GOLDEN))


@njit(cache=True, inline="always")
def rng_uniform(state):
    """Advance ``state``; return ``(new_state, u)`` with u uniform on [0, 1)."""
    state = state + _GOLDEN
    return state, float(_mix64(state) >> _S11) * _INV53


@njit(cache=True, inline="always")
def rng_uniform_open(state):
    """Like :func:`rng_uniform` but u is on the open interval (0, 1]."""
    state = state + _GOLDEN
    return state, (float(_mix64(state) >> _S11) + 1.0) * _INV53
