"""A small, fast random number generator for the compiled hill climbers.

The searches draw millions of numbers per recording, inside numba kernels.
numba's ``np.random`` (Mersenne Twister, polar normals) costs about 34 ns a
normal; this xorshift64* generator with Box-Muller pairs costs a third of
that. The state is a ``uint64[1]`` array (seeded with :func:`new_state` from
the method's ``self.rng``), so a run is reproducible bit for bit and no
global state is shared between methods.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["new_state", "next_u64", "uniform", "randint", "normal_pair", "skip"]

_M = np.uint64(2685821657736338717)
_ONE = np.uint64(1)


def new_state(rng: np.random.Generator) -> np.ndarray:
    """A fresh generator state drawn from a numpy generator (never zero)."""
    return np.array([int(rng.integers(1, 2**63 - 1))], dtype=np.uint64)


@njit(cache=True, inline="always")
def next_u64(state):
    """Advance the xorshift64* state and return 64 random bits."""
    x = state[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    state[0] = x
    return x * _M


@njit(cache=True, inline="always")
def uniform(state):
    """Uniform float in [0, 1) with 53 random bits."""
    return float(next_u64(state) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def randint(state, n):
    """Uniform integer in [0, n) (n > 0); the top bits, so no modulo bias worth noting for small n."""
    return np.int64((next_u64(state) >> np.uint64(33)) * np.uint64(n) >> np.uint64(31))


@njit(cache=True, inline="always")
def normal_pair(state):
    """Two independent standard normal numbers (Box-Muller)."""
    u1 = 1.0 - uniform(state)  # (0, 1]: log is finite
    u2 = uniform(state)
    r = math.sqrt(-2.0 * math.log(u1))
    a = 2.0 * math.pi * u2
    return r * math.cos(a), r * math.sin(a)


# Skipping ahead. The xorshift step (the shifts and xors, before the output multiply) is linear over GF(2)^64, so
# n steps are one 64 x 64 bit matrix; _JUMPS[k] is the step matrix to the power 2^k, stored as the images of the
# 64 unit vectors. Why: a search that knows its remaining draws cannot change its result (rrhc) stops early and
# still leaves the state where drawing them would have, so the next scan's numbers, and every result, stay the same.


@njit(cache=True)
def _apply(columns, x):
    """The bit matrix ``columns`` (images of the unit vectors) times the state ``x``."""
    y = np.uint64(0)
    for i in range(64):
        if (x >> np.uint64(i)) & _ONE:
            y ^= columns[i]
    return y


@njit(cache=True)
def _jump_table(levels):
    table = np.empty((levels, 64), dtype=np.uint64)
    one = np.empty(1, dtype=np.uint64)
    for i in range(64):
        one[0] = _ONE << np.uint64(i)
        next_u64(one)
        table[0, i] = one[0]
    for k in range(1, levels):
        for i in range(64):
            table[k, i] = _apply(table[k - 1], table[k - 1, i])
    return table


_JUMPS = _jump_table(64)


@njit(cache=True)
def skip(state, steps):
    """Advance ``state`` as ``steps`` calls of :func:`next_u64` would (``steps`` >= 0), in at most 64 matrix products."""
    x = state[0]
    k = 0
    while steps > 0:
        if steps & 1:
            x = _apply(_JUMPS[k], x)
        steps >>= 1
        k += 1
    state[0] = x
