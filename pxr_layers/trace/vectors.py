"""Component-major vectors: every per-lane vector or colour in trace/ is a (3, n) array.

Rows v[0], v[1], v[2] are contiguous, so arithmetic, broadcasting against per-lane
scalars (n,) and masking are plain 1-D loops. The (n, 3) layout numpy users reach for
first is several times slower here: its axis-1 reductions and (n, 1) broadcasts run a
strided three-element inner loop per lane.
"""

from __future__ import annotations

import numpy as np

from ..scene import FLOAT


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-lane dot product: (3, n), (3, n) -> (n,)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def length(a: np.ndarray) -> np.ndarray:
    """Per-lane Euclidean norm: (3, n) -> (n,)."""
    return np.sqrt(dot(a, a))


def normalize(a: np.ndarray, floor: float = 1e-30) -> np.ndarray:
    """Lanes scaled to unit length (lanes shorter than `floor` stay ~0)."""
    return a / np.maximum(length(a), floor)


def max3(a: np.ndarray) -> np.ndarray:
    """Largest component per lane: (3, n) -> (n,)."""
    return np.maximum(np.maximum(a[0], a[1]), a[2])


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance: (3, ...) -> (...)."""
    return rgb[0] * 0.2126 + rgb[1] * 0.7152 + rgb[2] * 0.0722


def to_lanes(a: np.ndarray) -> np.ndarray:
    """(3, n) -> contiguous (n, 3) float32, the layout Embree reads."""
    out = np.empty((a.shape[1], 3), FLOAT)
    out[:, 0], out[:, 1], out[:, 2] = a[0], a[1], a[2]
    return out


def transform_rows(matrix: np.ndarray, a: np.ndarray) -> np.ndarray:
    """matrix (3, 3) @ vectors (3, n) -> (3, n) float32."""
    return (matrix.astype(FLOAT) @ a).astype(FLOAT, copy=False)
