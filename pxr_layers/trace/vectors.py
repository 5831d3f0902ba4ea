"""Row-wise vector helpers for (n, 3) arrays.

numpy's axis=1 reductions over three columns are slow (a strided inner loop per row);
einsum and explicit column arithmetic are several times faster on the tracer's batches.
"""

from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product: (n, 3), (n, 3) -> (n,)."""
    return np.einsum("ij,ij->i", a, b)


def length(a: np.ndarray) -> np.ndarray:
    """Row-wise Euclidean norm: (n, 3) -> (n,)."""
    return np.sqrt(np.einsum("ij,ij->i", a, a))


def normalize(a: np.ndarray, floor: float = 1e-30) -> np.ndarray:
    """Rows scaled to unit length (rows shorter than `floor` stay ~0)."""
    return a / np.maximum(length(a), floor)[:, None]


def max3(a: np.ndarray) -> np.ndarray:
    """Largest of the three columns: (n, 3) -> (n,)."""
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])
