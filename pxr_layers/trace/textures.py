"""Bilinear texture lookups with UsdUVTexture wrap modes, lane by lane, from one atlas.

Every texture of a frame is packed into one flat float32 ``texels`` array; ``info`` (x, 4)
int64 holds each one's (offset, width, height, channels), its pixels row-major (h, w, c)
with row 0 the top of the image and the channels as stored (1 grey, 2 grey + alpha, 3 RGB,
4 RGBA: scene.TextureImage); :func:`rgba_channel` reads them as RGBA the way UsdUVTexture
expands them. st (0, 0) is the lower-left corner, (1, 1) upper-right.

The atlas of the last frame is kept in the process (:func:`packed`): the frames of a shot
share their decoded textures (stage/textures.py), so they share one atlas too instead of
copying gigabytes of texels per frame.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from ..compiled import inline

WRAP_MODES = ("repeat", "mirror", "clamp", "black")  # the codes kernels receive
OFFSET, WIDTH, HEIGHT, CHANNELS = range(4)


def pack(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(texels (N,) float32, info (x, 4) int64) of images (h, w, c) float32."""
    info = np.zeros((len(images), 4), np.int64)
    offset = 0
    for index, image in enumerate(images):
        height, width, channels = image.shape
        info[index] = offset, width, height, channels
        offset += image.size
    texels = np.empty(offset, np.float32)
    for index, image in enumerate(images):
        texels[info[index, OFFSET]:info[index, OFFSET] + image.size] = np.asarray(image, np.float32).reshape(-1)
    return texels, info


_PACKED: list = []  # [(ids of the images, weak references to them, (texels, info))], the last atlas


def packed(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pack` of `images`, the same arrays as the last call's when they are the same
    read-only images (the stage's decoded textures, which never change)."""
    frozen = all(not image.flags.writeable for image in images)
    key = tuple(id(image) for image in images)
    if frozen and _PACKED:
        ids, references, atlas = _PACKED[0]
        if ids == key and all(reference() is image for reference, image in zip(references, images)):
            return atlas
    atlas = pack(images)
    if frozen and images:  # a frame without textures leaves the last atlas for the next
        atlas[0].flags.writeable = atlas[1].flags.writeable = False
        _PACKED[:] = [(key, [weakref.ref(image) for image in images], atlas)]
        for image in images:  # the atlas goes with the first of its images
            weakref.finalize(image, _forget, key)
    return atlas


def _forget(key: tuple) -> None:
    if _PACKED and _PACKED[0][0] == key:
        _PACKED.clear()


def rgb_view(pixels: np.ndarray) -> np.ndarray:
    """(h, w, 3) RGB of an image stored with 1–4 channels (grey repeated, alpha dropped)."""
    return pixels[..., :3] if pixels.shape[2] >= 3 else np.repeat(pixels[..., :1], 3, axis=2)


def wrap_code(mode: str) -> int:
    return WRAP_MODES.index(mode)


@inline
def _wrap(index, size, mode):
    """A texel index made valid for `mode`, and whether the texel is black."""
    if mode == 0:
        return index % size, False
    if mode == 1:
        period = index % (2 * size)
        return (period if period < size else 2 * size - 1 - period), False
    black = mode == 3 and (index < 0 or index >= size)
    return min(max(index, 0), size - 1), black


@inline
def footprint(info, texture, s, t, wrap_s, wrap_t):
    """The four texels of a bilinear lookup: flat offsets of texels (x0, y0), (x1, y0),
    (x0, y1), (x1, y1) into the atlas (−1: black) and the fractions fx, fy."""
    offset, width, height, channels = info[texture, 0], info[texture, 1], info[texture, 2], info[texture, 3]
    x = s * width - 0.5
    y = (1.0 - t) * height - 0.5
    if not (math.isfinite(x) and math.isfinite(y)):
        x, y = 0.0, 0.0
    x0f, y0f = math.floor(x), math.floor(y)
    fx, fy = x - x0f, y - y0f
    x0, y0 = np.int64(x0f), np.int64(y0f)
    xa, black_xa = _wrap(x0, width, wrap_s)
    xb, black_xb = _wrap(x0 + 1, width, wrap_s)
    ya, black_ya = _wrap(y0, height, wrap_t)
    yb, black_yb = _wrap(y0 + 1, height, wrap_t)
    i00 = -1 if black_xa or black_ya else offset + (ya * width + xa) * channels
    i10 = -1 if black_xb or black_ya else offset + (ya * width + xb) * channels
    i01 = -1 if black_xa or black_yb else offset + (yb * width + xa) * channels
    i11 = -1 if black_xb or black_yb else offset + (yb * width + xb) * channels
    return i00, i10, i01, i11, fx, fy


@inline
def rgba_channel(channels, k):
    """The stored channel that is component k (RGBA) of an image of `channels` channels, or
    −1 where the component is 1 (the alpha of grey-only and RGB images)."""
    if channels >= 3:
        return k if k < channels else -1
    if k < 3:
        return 0
    return 1 if channels == 2 else -1


@inline
def _texel(texels, index, channel):
    return 0.0 if index < 0 else texels[index + channel]


@inline
def blend(texels, i00, i10, i01, i11, fx, fy, channel):
    """One stored channel of the lookup whose footprint is (i00, i10, i01, i11, fx, fy);
    channel −1 (see rgba_channel) is 1."""
    if channel < 0:
        return 1.0
    top = _texel(texels, i00, channel) * (1 - fx) + _texel(texels, i10, channel) * fx
    bottom = _texel(texels, i01, channel) * (1 - fx) + _texel(texels, i11, channel) * fx
    return top * (1 - fy) + bottom * fy
