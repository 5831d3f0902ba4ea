"""Counter-based random numbers: every value is a pure function of its coordinates.

A path's stream is keyed by (seed, frame, pixel, sample) and each random number within it
by a *dimension* index, so results never depend on batch sizes, thread counts or the order
in which paths are traced. The mixer is SplitMix64's finaliser (Steele et al. 2014), a
bijection on 64-bit integers with full avalanche, which is all a counter-based generator
needs. Kernels call :func:`path_key` and :func:`uniform` per lane (uint64 arithmetic
wraps, as intended).
"""

from __future__ import annotations

import numpy as np

from ..compiled import inline

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_PIXEL_STEP = np.uint64(0xD1B54A32D192ED03)
_SAMPLE_STEP = np.uint64(0xAEF17502108EF2D9)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S40 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(40)
_ONE = np.uint64(1)
_TO_UNIT = np.float32(2.0**-24)

CAMERA_DIMENSIONS = 2  # film jitter x, y
STEP_DIMENSIONS = 9  # per bounce: lobe, direction ×2, light pick, light position ×3, roulette, presence
LOBE, DIRECTION, LIGHT_PICK, LIGHT_POSITION, ROULETTE, PRESENCE = 0, 1, 3, 4, 7, 8  # offsets within a step
LENS = 1 << 32  # lens position ×2: past every bounce's dimensions, so a pinhole render keeps its numbers
TIME = LENS + 2  # the camera sample's time in the shutter


@inline
def mix64(z):
    """SplitMix64 finaliser of one uint64."""
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return z ^ (z >> _S31)


def frame_key(seed: int, frame: float) -> np.uint64:
    """One 64-bit key for a (seed, frame) pair; a NaN frame (default time) is its own key."""
    frame_bits = np.array([frame], dtype=np.float64).view(np.uint64)[0]
    seed_bits = np.uint64(seed & 0xFFFFFFFFFFFFFFFF)
    return np.uint64(_mix64_scalar(_mix64_scalar(seed_bits) ^ frame_bits))


def _mix64_scalar(z: np.uint64) -> np.uint64:
    with np.errstate(over="ignore"):
        return mix64.py_func(np.uint64(z))


@inline
def path_key(key, pixel, sample):
    """The stream key of one path (uint64) from the frame key and its pixel and sample."""
    z = mix64(key + np.uint64(pixel) * _PIXEL_STEP)
    return mix64(z + np.uint64(sample) * _SAMPLE_STEP)


@inline
def uniform(key, dimension):
    """A float32 in [0, 1) (24 bits) for `dimension` of the stream `key`."""
    bits = mix64(key + (np.uint64(dimension) + _ONE) * _GOLDEN)
    return np.float32(bits >> _S40) * _TO_UNIT


@inline
def stratified(key, pixel, sample, spp, dimension):
    """A float32 in [0, 1) for `dimension` of a pixel's sample `sample` out of `spp`: in the
    sample's own stratum [sample, sample + 1)/spp, at one random offset per pixel shared by
    its strata. A pixel's spp values cover [0, 1) evenly, so a choice made with them splits
    its samples in exact proportion. Unbiased over a pixel's spp samples together, which is
    how they are always traced (batches and tiles hold whole pixels)."""
    offset = uniform(path_key(key, pixel, np.uint64(0xFFFFFFFF)), dimension)
    return np.float32(min((sample + offset) / spp, 1.0 - 2.0**-24))


@inline
def van_der_corput(key, pixel, sample, dimension):
    """A float32 in [0, 1) for `dimension` of a pixel's sample `sample`: the sample's number
    with its bits mirrored about the binary point (van der Corput's sequence), shifted by one
    random offset per pixel, modulo 1. Its first 2^k samples fall one in each of 2^k strata,
    and paired with :func:`stratified` (sample i in stratum i) they make a Hammersley set: two
    choices stratified together without the diagonal that pairing stratum i with stratum i
    would draw. Unbiased over a pixel's samples, as stratified is."""
    mirrored, weight, number = 0.0, 0.5, sample
    while number > 0:
        if number & 1:
            mirrored += weight
        number >>= 1
        weight *= 0.5
    value = mirrored + uniform(path_key(key, pixel, np.uint64(0xFFFFFFFF)), dimension)
    return np.float32(min(value - 1.0 if value >= 1.0 else value, 1.0 - 2.0**-24))


def step_dimension(step: int) -> int:
    """The first dimension of bounce `step` (after the camera's)."""
    return CAMERA_DIMENSIONS + step * STEP_DIMENSIONS
