"""The Downs & Vogel random-number generator (TESUB7/TESUB6 of ``teprob.f``).

The state is one double ``G``. Each draw is ``G <- mod(G * 9228907, 2**32)`` in
IEEE double arithmetic: the product ``p`` exceeds 2**53 and is rounded before the
remainder, so the sequence is not the exact integer congruential one.

The original spends about 90 % of its run time in the C library's ``fmod``. Here
the remainder is computed as ``p - q * 2**32`` with ``q = floor(p / 2**32)``,
which is bit-identical: the modulus is a power of two, so ``q * 2**32`` is exact
and so is the difference (it is a multiple of the last place of ``p`` below
2**32). Two rearrangements shorten the serial chain from one draw to the next
without changing any bit: ``q`` is taken as ``floor(G * (9228907 / 2**32))``,
which equals ``floor(p / 2**32)`` because scaling by a power of two commutes with
rounding, so it is computed alongside ``p`` instead of after it; and the
difference is one fused multiply-add, whose single rounding of an exactly
representable result is exact.

The generator state lives in element ``slot`` of a float64 array so that the
compiled model can keep it with the rest of its memory.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic

__all__ = ["ORIGINAL_SEED", "MULTIPLIER", "MODULUS", "next_g", "draw_unsigned", "draw_signed",
           "advance", "noise", "sequence"]

#: Seed of the original distribution (Downs & Vogel); the Braatz redistribution ships another.
ORIGINAL_SEED = 1431655765.0
MULTIPLIER = 9228907.0
MODULUS = 4294967296.0
_SCALED_MULTIPLIER = MULTIPLIER / MODULUS  # exact: a 24-bit integer times a power of two


@intrinsic
def _fma(typingctx, a, b, c):
    """``a * b + c`` with one rounding (LLVM's fma); used only where the result is exact."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType()] * 3)
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.fma.f64")
        return builder.call(fn, args)

    return sig, codegen


@njit(cache=True, inline="always")
def next_g(g):
    """One generator step on the value ``g``, bit-identical to the original's DMOD form."""
    p = g * MULTIPLIER  # rounded to double, as in the original
    q = np.floor(g * _SCALED_MULTIPLIER)  # == floor(p / 2**32)
    return _fma(q, -MODULUS, p)  # == p - q * 2**32, exactly


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
