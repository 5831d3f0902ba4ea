"""Denoised layer stacks that still add up: Intel Open Image Denoise (``pyoidn``, CPU) on
every colour layer, with the render's albedo and normal guides (trace/guides.py), and the
denoised beauty their sum.

* One input scale for the whole stack: OIDN's HDR filter maps radiance to its network's
  range by an exposure it would estimate per image, so each layer would be filtered as a
  different picture. The scale is estimated once, from the beauty (:func:`input_scale`,
  OIDN's own autoexposure rule), and every image is filtered with it.
* Exactness: denoising is not linear, so separately denoised layers do not add up to the
  separately denoised beauty (6 % L1 on the Cornell passes at 16 spp). Here the layers stay
  as the filter made them and the denoised beauty is their sum, plus the denoised rest of
  the raw beauty when the layers do not cover it all (a stack of some lights only): the
  layers add up to it by construction, to float precision. The two other ways were
  measured against 2048-spp references at 256², 16 spp (benchmarks/bench_denoise.py):
  redistributing the gap to a separately denoised beauty over the layers moves the Cornell
  passes further from the reference (diffuse indirect relMSE 2.6e-4 as filtered, 3.3e-4
  redistributed; diffuse direct 1.06e-4 against 1.21e-4) and leaves the showcase's within a
  few per cent either way; Octane's "denoised remainder" keeps the layers as filtered too,
  but adds a part holding the gap (6.3 % of the Cornell beauty's energy, L1, noise of both
  signs) and so changes the product's parts; the beauty as the layers' sum is as close to
  the reference as the separately denoised one, or closer (Cornell 5.5e-4 against 6.3e-4).
* An empty layer stays empty (the filter would leave ~1e-7 in it). Cryptomattes and data
  layers are never denoised (the caller passes colour layers only).

Every image is (h, w, 3) float32 linear radiance.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..colour import REC709_LUMINANCE

log = logging.getLogger(__name__)

AUTOEXPOSURE_KEY = 0.18
AUTOEXPOSURE_BLOCK = 16
AUTOEXPOSURE_EPSILON = 1e-8
"""OIDN's autoexposure (core/autoexposure.h): the key value over the geometric mean of the
luminance of 16×16-pixel block means, blocks darker than the epsilon left out."""


REST_TOLERANCE = 1e-4
"""Layers cover the beauty when the rest (beauty − their sum) is nowhere above this share of
the beauty's mean: a complete stack's rounding."""


@dataclass(frozen=True)
class DenoisedStack:
    """beauty (h, w, 3) and layers (name → (h, w, 3)) float32, denoised; the beauty their
    sum (with the denoised rest); scale: the input scale every image was filtered with."""

    beauty: np.ndarray
    layers: dict[str, np.ndarray]
    scale: float


def available() -> str | None:
    """Why denoising cannot run here (pyoidn missing), or None."""
    try:
        import pyoidn  # noqa: F401
    except ImportError as error:
        return f"denoising needs pyoidn (Intel Open Image Denoise): pip install pyoidn ({error})"
    return None


def input_scale(beauty: np.ndarray) -> float:
    """OIDN's autoexposure of `beauty` (h, w, 3): the multiplier that brings it to the
    filter's range; 1 for a black image."""
    height, width = beauty.shape[:2]
    rows, columns = -(-height // AUTOEXPOSURE_BLOCK), -(-width // AUTOEXPOSURE_BLOCK)
    luminance = np.asarray(beauty[..., :3], np.float64) @ np.asarray(REC709_LUMINANCE)
    padded = np.full((rows * AUTOEXPOSURE_BLOCK, columns * AUTOEXPOSURE_BLOCK), np.nan)
    padded[:height, :width] = luminance
    blocks = np.nanmean(padded.reshape(rows, AUTOEXPOSURE_BLOCK, columns, AUTOEXPOSURE_BLOCK), axis=(1, 3))
    lit = blocks[blocks > AUTOEXPOSURE_EPSILON]
    if not len(lit):
        return 1.0
    return float(AUTOEXPOSURE_KEY / np.exp2(np.mean(np.log2(lit))))


class _Filter:
    """One OIDN RT filter (HDR, high quality) with the guides and the stack's input scale."""

    def __init__(self, albedo: np.ndarray, normal: np.ndarray, scale: float):
        import pyoidn

        self._pyoidn = pyoidn
        self._device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
        self._device.commit()
        self._filter = pyoidn.Filter(self._device, pyoidn.OIDN_FILTER_TYPE_RT)
        self._albedo = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), np.float32)
        self._normal = np.ascontiguousarray(np.clip(normal, -1.0, 1.0), np.float32)
        self._filter.set_image(pyoidn.OIDN_IMAGE_ALBEDO, self._albedo, pyoidn.OIDN_FORMAT_FLOAT3)
        self._filter.set_image(pyoidn.OIDN_IMAGE_NORMAL, self._normal, pyoidn.OIDN_FORMAT_FLOAT3)
        self._filter.set_bool("hdr", True)
        self._filter.set_float("inputScale", scale)
        self._filter.set_quality(pyoidn.OIDN_QUALITY_HIGH)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        pyoidn = self._pyoidn
        color = np.ascontiguousarray(np.maximum(image[..., :3], 0.0), np.float32)  # HDR input is nonnegative
        output = np.empty_like(color)
        self._filter.set_image(pyoidn.OIDN_IMAGE_COLOR, color, pyoidn.OIDN_FORMAT_FLOAT3)
        self._filter.set_image(pyoidn.OIDN_IMAGE_OUTPUT, output, pyoidn.OIDN_FORMAT_FLOAT3)
        self._filter.commit()
        self._filter.execute()
        return output

    def release(self) -> None:
        self._filter.release()
        self._device.release()


def denoise_images(beauty: np.ndarray, images: Mapping[str, np.ndarray], albedo: np.ndarray,
                   normal: np.ndarray) -> dict[str, np.ndarray]:
    """`images` denoised as layers of the stack whose raw beauty is `beauty` (its input
    scale, the guides): a layer made later from the index joins a denoised stack so."""
    run = _Filter(albedo, normal, input_scale(np.asarray(beauty[..., :3], np.float32)))
    try:
        return {name: _filtered(run, image) for name, image in images.items()}
    finally:
        run.release()


def denoise_stack(beauty: np.ndarray, layers: Mapping[str, np.ndarray], albedo: np.ndarray,
                  normal: np.ndarray) -> DenoisedStack:
    """`layers` denoised with one input scale (the beauty's) and the guides (albedo,
    normal: (h, w, 3)), and the denoised beauty: their sum, plus the denoised rest of the raw
    beauty where they do not cover it (module docstring)."""
    beauty = np.asarray(beauty[..., :3], np.float32)
    scale = input_scale(beauty)
    run = _Filter(albedo, normal, scale)
    try:
        denoised = {name: _filtered(run, image) for name, image in layers.items()}
        rest = beauty.astype(np.float64) - sum((np.asarray(image[..., :3], np.float64) for image in layers.values()),
                                               np.zeros(beauty.shape))
        covered = np.abs(rest).max() <= REST_TOLERANCE * max(float(np.abs(beauty).mean()), 1e-30)
        total = sum((image.astype(np.float64) for image in denoised.values()), np.zeros(beauty.shape))
        if not covered:
            total += _filtered(run, rest.astype(np.float32))
    finally:
        run.release()
    return DenoisedStack(total.astype(np.float32), denoised, scale)


def _filtered(run: _Filter, image: np.ndarray) -> np.ndarray:
    """`image` (h, w, ≥3) denoised; an empty one stays empty."""
    return run(image) if np.any(image[..., :3]) else np.zeros(image.shape[:2] + (3,), np.float32)
