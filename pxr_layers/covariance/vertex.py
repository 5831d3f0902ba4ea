"""Per-vertex parameters of a covariance chain, as plain arrays (one lane per path).

Kept apart from the operators so that the scalar reference chain can read the same
record without importing any batched code.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np


def _no_texture() -> np.ndarray:
    return np.zeros((2, 2))


@dataclass(frozen=True)
class VertexParams:
    """What the covariance chain needs from one scattering vertex, for n paths at once.

    Every field is an (n,) array or a scalar for all lanes, except ``texture``
    ((n, 2, 2) or (2, 2)). Units and frames follow the package docstring.

    cos_in : cosine between the arriving ray and the surface normal (sign ignored).
    cos_out : cosine between the leaving ray ω_o and the normal (sign ignored).
    bandwidth_u, bandwidth_v : BRDF lobe bandwidth b in cycles²/rad² along t̂x, t̂y of the
        incoming plane of incidence; 0 = diffuse, inf = perfect mirror.
    distance : metres from this vertex to the next one (or to the eye / lens).
    rotation_in : radians turning the arriving frame so that ŷ is in the plane of incidence.
    rotation_out : radians turning the tangent frame so that t̂y is in the plane of ω_o.
    k1, k2 : principal curvatures, 1/m (positive: bowl facing the light).
    curvature_angle : radians from t̂x to the k1 principal direction.
    texture : T block, cycles²/m² in the tangent frame.
    """

    cos_in: np.ndarray
    cos_out: np.ndarray
    bandwidth_u: np.ndarray
    bandwidth_v: np.ndarray
    distance: np.ndarray
    rotation_in: np.ndarray = 0.0
    rotation_out: np.ndarray = 0.0
    k1: np.ndarray = 0.0
    k2: np.ndarray = 0.0
    curvature_angle: np.ndarray = 0.0
    texture: np.ndarray = field(default_factory=_no_texture)

    def lane(self, index: int) -> VertexParams:
        """The parameters of one path, every field a Python float (texture a (2, 2) array)."""
        picked = {}
        for item in fields(self):
            value = np.asarray(getattr(self, item.name), dtype=np.float64)
            per_lane_ndim = 3 if item.name == "texture" else 1
            if value.ndim == per_lane_ndim:
                value = value[index]
            picked[item.name] = value.copy() if item.name == "texture" else float(value)
        return VertexParams(**picked)
