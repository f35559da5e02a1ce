"""A small random generator that lives in a block's record, for noise drawn inside compiled steps.

The sensors draw their white noise from NumPy generators in blocks (:class:`omnirotor.sim.sensors.NoiseStream`);
the disturbances (:mod:`omnirotor.sim.rotors`' thrust fluctuation and reversal, the IMU vibration phases and
the motion capture's latency jitter) need a few numbers per step inside the compiled step instead, without a
hand-back to Python. Each block keeps one ``uint64`` state field (``rng``) in its own record, seeded from the
simulator's seed through :class:`numpy.random.SeedSequence` (equal seeds, equal runs); :func:`next_uniform`
and :func:`next_normal` advance it in place.

The four draws are inlined into their compiled callers (:func:`omnirotor._jit.jit_inline`): each block's
record is another type, and as kernels of their own they were compiled once per block (14 compiles of a few
integer operations each on the first run), each with its own optimisation and machine code.

The generator is SplitMix64 (Steele, Lea and Flood, OOPSLA 2014): a Weyl sequence through a 64-bit finaliser,
statistically sound for simulation noise and a few integer operations per draw. Normals come from the
Box-Muller transform of two uniforms.
"""

from __future__ import annotations

import math

import numpy as np

from omnirotor._jit import jit_inline

__all__ = ["seed_state", "next_u64", "next_uniform", "next_normal", "gauss_markov_coefficients", "gauss_markov_next"]

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TWO_M53 = 1.0 / 9007199254740992.0  # 2**-53
_TWO_PI = 2.0 * math.pi


def seed_state(seed: int, stream: int) -> np.uint64:
    """The initial ``rng`` state of stream ``stream`` of a simulator seeded with ``seed`` (independent streams)."""
    return np.random.SeedSequence([int(seed), int(stream)]).generate_state(1, np.uint64)[0]


@jit_inline
def next_u64(rec):
    """The next 64-bit output of the generator whose state is ``rec["rng"]`` (advanced in place)."""
    z = rec["rng"] + _GOLDEN
    rec["rng"] = z
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@jit_inline
def next_uniform(rec) -> float:
    """A uniform draw in [0, 1) (53 random bits)."""
    return float(next_u64(rec) >> _S11) * _TWO_M53


@jit_inline
def next_normal(rec) -> float:
    """A standard normal draw (Box-Muller; two uniforms per draw)."""
    u1 = 1.0 - next_uniform(rec)  # (0, 1]: log is finite
    u2 = next_uniform(rec)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(_TWO_PI * u2)


def gauss_markov_coefficients(std: float, corner_hz: float, dt: float) -> tuple[float, float]:
    """``(decay, drive)`` of a first-order Gauss-Markov process sampled every ``dt`` [s].

    ``x = decay x + drive n`` (n standard normal) has the stationary standard deviation ``std`` and the
    first-order spectrum of corner frequency ``corner_hz`` [Hz]: ``decay = exp(-2 pi f_c dt)``,
    ``drive = std sqrt(1 - decay²)``.
    """
    decay = math.exp(-2.0 * math.pi * corner_hz * dt)
    return decay, std * math.sqrt(1.0 - decay * decay)


@jit_inline
def gauss_markov_next(x: float, decay: float, drive: float, rec) -> float:
    """The next sample ``decay x + drive n`` of a Gauss-Markov process, n drawn from ``rec["rng"]``."""
    return decay * x + drive * next_normal(rec)
