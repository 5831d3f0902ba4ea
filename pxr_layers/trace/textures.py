"""Bilinear texture lookups with UsdUVTexture wrap modes, on batches of st coordinates."""

from __future__ import annotations

import numpy as np

from ..scene import FLOAT, WrapMode


def _wrap(index: np.ndarray, size: int, mode: WrapMode) -> tuple[np.ndarray, np.ndarray | None]:
    """Texel indices made valid for `mode`, and a (n,) bool mask of black texels (or None)."""
    if mode == "repeat":
        return np.mod(index, size), None
    if mode == "mirror":
        period = np.mod(index, 2 * size)
        return np.where(period < size, period, 2 * size - 1 - period), None
    clamped = np.clip(index, 0, size - 1)
    return clamped, ((index < 0) | (index >= size)) if mode == "black" else None


def sample_bilinear(
    pixels: np.ndarray, st: np.ndarray, wrap_s: WrapMode = "repeat", wrap_t: WrapMode = "repeat"
) -> np.ndarray:
    """Filtered texels at UsdUVTexture coordinates.

    pixels : (h, w, c) float32, row 0 = top of the image
    st     : (2, n) float32; (0, 0) is the lower-left corner of the image, (1, 1) upper-right
    Returns (c, n) float32.
    """
    height, width = pixels.shape[:2]
    x = st[0] * width - 0.5
    y = (1.0 - st[1]) * height - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0).astype(FLOAT)
    fy = (y - y0).astype(FLOAT)
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    xa, black_xa = _wrap(x0, width, wrap_s)
    xb, black_xb = _wrap(x0 + 1, width, wrap_s)
    ya, black_ya = _wrap(y0, height, wrap_t)
    yb, black_yb = _wrap(y0 + 1, height, wrap_t)

    def texel(yi, xi, black_y, black_x):
        value = pixels[yi, xi].T  # (c, n)
        black = black_y if black_x is None else black_x if black_y is None else black_y | black_x
        return value if black is None else np.where(black, 0.0, value)

    top = texel(ya, xa, black_ya, black_xa) * (1 - fx) + texel(ya, xb, black_ya, black_xb) * fx
    bottom = texel(yb, xa, black_yb, black_xa) * (1 - fx) + texel(yb, xb, black_yb, black_xb) * fx
    return (top * (1 - fy) + bottom * fy).astype(FLOAT)
