"""Matrix conversions between USD's Gf (row-vector) matrices and scene.py's column convention.

USD composes row vectors, ``p' = p @ M``, so a Gf.Matrix4d keeps its translation in the
last *row*. scene.py uses column vectors, ``p' = M @ p``: the transpose. Everything returned
here is a (4, 4) float64 numpy array in the column convention.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
from pxr import Gf, Tf, Usd

from pxr_layers.errors import StageError

from .opening import tf_error_summary

# Rotation of +90° about X: takes +Y to +Z and +Z to -Y. UsdLux (DomeLight_1 poleAxis) says a
# Z-up dome has latitude +pi/2 at +Z and (latitude 0, longitude 0) at -Y, where the OpenEXR
# Y-up convention has them at +Y and +Z: exactly this rotation.
Z_UP_FROM_Y_UP = np.array(
    [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def column_matrix(matrix: Gf.Matrix4d) -> np.ndarray:
    """A Gf.Matrix4d (row-vector convention) as a (4, 4) float64 column-vector matrix."""
    return np.array(matrix, dtype=np.float64).T


def to_metres(world_from_local: np.ndarray, meters_per_unit: float) -> np.ndarray:
    """Follow a stage-units transform by the units → metres scale (sizes and positions)."""
    metres_from_units = np.diag([meters_per_unit, meters_per_unit, meters_per_unit, 1.0])
    return metres_from_units @ world_from_local


def nearest_rotation(linear: np.ndarray) -> np.ndarray:
    """The rotation closest to a (3, 3) matrix (polar decomposition), removing scale and shear.

    A mirroring matrix (negative determinant) has no nearest rotation; its mirror is dropped
    by flipping the least significant singular direction so the result stays right-handed.
    """
    u, _, vt = np.linalg.svd(linear)
    if np.linalg.det(u @ vt) < 0.0:
        u[:, -1] = -u[:, -1]
    return u @ vt


def rigid_in_metres(world_from_local: np.ndarray, meters_per_unit: float) -> np.ndarray:
    """Keep only rotation and translation (in metres) of a stage-units transform."""
    rigid = np.eye(4)
    rigid[:3, :3] = nearest_rotation(world_from_local[:3, :3])
    rigid[:3, 3] = world_from_local[:3, 3] * meters_per_unit
    return rigid


def normal_matrix(linear: np.ndarray) -> np.ndarray:
    """A (3, 3) matrix taking object-space normals to world-space normal *directions*.

    This is the cofactor matrix ``det(A) · A⁻ᵀ`` with the sign of det(A) applied: it equals the
    inverse transpose up to a positive factor (normals are renormalised afterwards) and stays
    finite when the transform is singular (a flattened object still shades sensibly).
    """
    c0, c1, c2 = linear[:, 0], linear[:, 1], linear[:, 2]
    cofactor = np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=1)
    return cofactor if np.linalg.det(linear) >= 0.0 else -cofactor


@contextlib.contextmanager
def transform_errors_name(prim: Usd.Prim, file: str) -> Iterator[None]:
    """Turn a Tf error of the transform computations inside into a StageError naming
    ``prim``: USD raises one for an xformOp of the wrong type (``string xformOp:translate``)
    on the prim or an ancestor, which would otherwise name only the file."""
    try:
        yield
    except Tf.ErrorException as error:
        raise StageError(f"its transform cannot be computed: {tf_error_summary(error)}", file=file,
                         prim=str(prim.GetPath())) from None
