"""Counter-based random numbers: every value is a pure function of its coordinates.

A path's stream is keyed by (seed, frame, pixel, sample) and each random number within it
by a *dimension* index, so results never depend on batch sizes, thread counts or the order
in which paths are traced. The mixer is SplitMix64's finaliser (Steele et al. 2014), a
bijection on 64-bit integers with full avalanche, which is all a counter-based generator
needs.
"""

from __future__ import annotations

import numpy as np

_U64 = np.uint64
_GOLDEN = _U64(0x9E3779B97F4A7C15)
_PIXEL_STEP = _U64(0xD1B54A32D192ED03)
_SAMPLE_STEP = _U64(0xAEF17502108EF2D9)
_MUL1 = _U64(0xBF58476D1CE4E5B9)
_MUL2 = _U64(0x94D049BB133111EB)
_TO_UNIT = np.float32(2.0**-24)


def mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser. z : any shape, uint64 (wrapping arithmetic is intended)."""
    z = (z ^ (z >> _U64(30))) * _MUL1
    z = (z ^ (z >> _U64(27))) * _MUL2
    return z ^ (z >> _U64(31))


def frame_key(seed: int, frame: float) -> np.uint64:
    """One 64-bit key for a (seed, frame) pair; a NaN frame (default time) is its own key."""
    frame_bits = np.array([frame], dtype=np.float64).view(np.uint64)
    seed_bits = np.array([seed & 0xFFFFFFFFFFFFFFFF], dtype=np.uint64)
    with np.errstate(over="ignore"):
        return mix64(mix64(seed_bits) ^ frame_bits)[0]


def path_keys(key: np.uint64, pixel: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Per-path stream keys. pixel, sample : (n,) integer arrays -> (n,) uint64."""
    with np.errstate(over="ignore"):
        z = mix64(key + pixel.astype(np.uint64) * _PIXEL_STEP)
        return mix64(z + sample.astype(np.uint64) * _SAMPLE_STEP)


def uniforms(keys: np.ndarray, first_dimension: int, count: int) -> np.ndarray:
    """Uniform floats in [0, 1) for dimensions first_dimension .. +count of each stream.

    keys : (n,) uint64 path keys -> (count, n) float32 (one row per dimension), 24 bits.
    """
    dims = (np.arange(first_dimension, first_dimension + count, dtype=np.uint64) + _U64(1)) * _GOLDEN
    with np.errstate(over="ignore"):
        bits = mix64(keys[None, :] + dims[:, None])
    return (bits >> _U64(40)).astype(np.float32) * _TO_UNIT
