"""Denoised layer stacks that still add up: Intel Open Image Denoise (``pyoidn``, CPU) on the
beauty and on every colour layer, with the render's albedo and normal guides
(trace/guides.py), then made exact.

* One input scale for the whole stack: OIDN's HDR filter maps radiance to its network's
  range by an exposure it would estimate per image; each layer then would be denoised as a
  different picture. The scale is estimated once, from the beauty (:func:`input_scale`,
  OIDN's own autoexposure rule), and every image of the stack is filtered with it.
* Exactness: denoising is not linear, so the denoised layers do not add up to the denoised
  beauty (3–5 % L1 on the Cornell passes at 16 spp). The gap is redistributed over the
  layers in proportion to their denoised magnitude at each pixel and channel
  (:func:`redistributed`): a layer that holds no light there receives none, and the layers
  then add up to the denoised beauty exactly as the raw layers add up to the raw beauty
  (to float precision: both are a partition of it for a complete stack). The alternative,
  Octane's "denoised remainder", leaves the layers as the filter made them and adds a part
  holding the gap; it would change the product's parts, and benchmarks/bench_denoise.py
  measures that redistribution brings the layers as close to a high-spp reference or closer.
* Cryptomattes and data layers are never denoised (the caller passes colour layers only).

Every image is (h, w, 3) float32 linear radiance.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..scene import REC709_LUMINANCE

log = logging.getLogger(__name__)

AUTOEXPOSURE_KEY = 0.18
AUTOEXPOSURE_BLOCK = 16
AUTOEXPOSURE_EPSILON = 1e-8
"""OIDN's autoexposure (core/autoexposure.h): the key value over the geometric mean of the
luminance of 16×16-pixel block means, blocks darker than the epsilon left out."""


@dataclass(frozen=True)
class DenoisedStack:
    """beauty (h, w, 3) and layers (name → (h, w, 3)) float32, denoised and made exact;
    scale: the input scale every image was filtered with."""

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


def denoise_stack(beauty: np.ndarray, layers: Mapping[str, np.ndarray], albedo: np.ndarray,
                  normal: np.ndarray) -> DenoisedStack:
    """The beauty and `layers` denoised with one input scale (the beauty's) and the guides
    (albedo, normal: (h, w, 3)), the layers redistributed to add up to the denoised beauty
    as the raw ones add up to the raw beauty (module docstring)."""
    beauty = np.asarray(beauty[..., :3], np.float32)
    scale = input_scale(beauty)
    run = _Filter(albedo, normal, scale)
    try:
        denoised_beauty = run(beauty)
        # an empty layer stays empty (the filter would leave ~1e-7 in it)
        denoised = {name: run(image) if np.any(image[..., :3]) else np.zeros_like(image[..., :3], np.float32)
                    for name, image in layers.items()}
    finally:
        run.release()
    return DenoisedStack(denoised_beauty, redistributed(beauty, layers, denoised_beauty, denoised), scale)


def redistributed(beauty: np.ndarray, layers: Mapping[str, np.ndarray], denoised_beauty: np.ndarray,
                  denoised: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The denoised layers plus shares of the gap (denoised beauty − their sum) − (beauty −
    the raw layers' sum), each layer's share its denoised magnitude over all of theirs at
    that pixel and channel (where none holds any: its raw magnitude; where no raw layer
    does either, equal shares): afterwards their sum differs from the denoised beauty
    exactly as the raw layers' sum from the raw beauty."""
    if not denoised:
        return {}
    names = list(denoised)
    stack = np.stack([denoised[name] for name in names]).astype(np.float64)
    raw_gap = np.asarray(beauty[..., :3], np.float64) - sum(np.asarray(layers[name][..., :3], np.float64)
                                                            for name in names)
    gap = denoised_beauty.astype(np.float64) - stack.sum(axis=0) - raw_gap
    share = np.full(stack.shape, 1.0 / len(names))
    # by the denoised layers' magnitude; where none holds light, by the raw layers'
    for magnitude in (np.abs(np.stack([np.asarray(layers[name][..., :3], np.float64) for name in names])),
                      np.abs(stack)):
        total = magnitude.sum(axis=0)
        share = np.where(total > 0, magnitude / np.where(total > 0, total, 1.0), share)
    made = stack + share * gap
    return {name: made[k].astype(np.float32) for k, name in enumerate(names)}
