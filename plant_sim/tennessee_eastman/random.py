"""The Downs & Vogel random-number generator (TESUB7/TESUB6 of ``teprob.f``).

The state is one double ``G``. Each draw is ``G <- mod(G * 9228907, 2**32)`` in
IEEE double arithmetic: the product exceeds 2**53 and is rounded before the
remainder, so the sequence is not the exact integer congruential one. Because
the modulus is a power of two, ``G - floor(G / 2**32) * 2**32`` is bit-identical
to the C library's ``fmod`` and about ten times faster; it is used here.

The generator state lives in element ``slot`` of a float64 array so that the
compiled model can keep it with the rest of its memory.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["ORIGINAL_SEED", "MULTIPLIER", "MODULUS", "next_g", "draw_unsigned", "draw_signed",
           "advance", "noise", "sequence"]

#: Seed of the original distribution (Downs & Vogel); the Braatz redistribution ships another.
ORIGINAL_SEED = 1431655765.0
MULTIPLIER = 9228907.0
MODULUS = 4294967296.0
_INV_MODULUS = 1.0 / MODULUS  # a power of two: multiplying is exact, like dividing


@njit(cache=True, inline="always")
def next_g(g):
    """One generator step on the value ``g`` (floor form of the original fmod)."""
    p = g * MULTIPLIER
    return p - np.floor(p * _INV_MODULUS) * MODULUS


@njit(cache=True, inline="always")
def draw_unsigned(mem, slot):
    """Advance ``mem[slot]`` and return a draw in [0, 1) (TESUB7 with I >= 0)."""
    g = next_g(mem[slot])
    mem[slot] = g
    return g / MODULUS


@njit(cache=True, inline="always")
def draw_signed(mem, slot):
    """Advance ``mem[slot]`` and return a draw in [-1, 1) (TESUB7 with I < 0)."""
    g = next_g(mem[slot])
    mem[slot] = g
    return 2.0 * g / MODULUS - 1.0


@njit(cache=True, inline="always")
def advance(mem, slot, n):
    """Advance the generator by ``n`` draws without using them."""
    g = mem[slot]
    for _ in range(n):
        g = next_g(g)
    mem[slot] = g


@njit(cache=True, inline="always")
def noise(mem, slot, std):
    """Gaussian-like noise of standard deviation ``std`` from 12 unsigned draws (TESUB6)."""
    g = mem[slot]
    x = 0.0
    for _ in range(12):
        g = next_g(g)
        x = x + g / MODULUS
    mem[slot] = g
    return (x - 6.0) * std


def sequence(seed: float = ORIGINAL_SEED, n: int = 5) -> np.ndarray:
    """The first ``n`` generator states after ``seed`` (float64 array), for checks."""
    mem = np.array([float(seed)])
    out = np.empty(n)
    for i in range(n):
        out[i] = next_g(mem[0])
        mem[0] = out[i]
    return out
