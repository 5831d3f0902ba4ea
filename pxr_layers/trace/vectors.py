"""Small vector helpers: numpy ones for set-up code, compiled per-lane ones for kernels.

Set-up code (camera, light tables) works on component-major (3, n) arrays: rows are
contiguous, so arithmetic and broadcasting are plain 1-D loops. Kernels work lane by lane
on scalars; their queues are lane-major (n, 3), the layout Embree reads.
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import inline
from ..scene import REC709_LUMINANCE

_LR, _LG, _LB = REC709_LUMINANCE


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-lane dot product: (3, n), (3, n) -> (n,)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance: (3, ...) -> (...)."""
    return rgb[0] * _LR + rgb[1] * _LG + rgb[2] * _LB


# -- per-lane helpers of kernels (scalars in, scalars out)

@inline
def luminance_of(r, g, b):
    return r * _LR + g * _LG + b * _LB


@inline
def normalized(x, y, z, floor):
    """(x, y, z) / max(|(x, y, z)|, floor)."""
    scale = 1.0 / max(math.sqrt(x * x + y * y + z * z), floor)
    return x * scale, y * scale, z * scale


@inline
def basis(x, y, z):
    """Tangent and bitangent completing the unit normal (x, y, z) (Duff et al. 2017):
    (tx, ty, tz, bx, by, bz)."""
    sign = 1.0 if z >= 0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    return 1.0 + sign * x * x * a, sign * b, -sign * x, b, sign + y * y * a, -y


@inline
def to_local(frame, lane, x, y, z):
    """World (x, y, z) in the shading frame ``frame[lane]`` (3 rows: tangent, bitangent,
    normal) -> local (x, y, z)."""
    return (frame[lane, 0, 0] * x + frame[lane, 0, 1] * y + frame[lane, 0, 2] * z,
            frame[lane, 1, 0] * x + frame[lane, 1, 1] * y + frame[lane, 1, 2] * z,
            frame[lane, 2, 0] * x + frame[lane, 2, 1] * y + frame[lane, 2, 2] * z)


@inline
def to_world(frame, lane, x, y, z):
    """Local (x, y, z) of the shading frame ``frame[lane]`` -> world (x, y, z)."""
    return (frame[lane, 0, 0] * x + frame[lane, 1, 0] * y + frame[lane, 2, 0] * z,
            frame[lane, 0, 1] * x + frame[lane, 1, 1] * y + frame[lane, 2, 1] * z,
            frame[lane, 0, 2] * x + frame[lane, 1, 2] * y + frame[lane, 2, 2] * z)


@inline
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric interface for the cosine cos_i of
    the incident direction; eta = n_transmitted / n_incident (surfaces' glass, hair)."""
    cos_i = min(max(cos_i, 0.0), 1.0)
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(max(1.0 - sin2_t, 0.0))
    r_parallel = (eta * cos_i - cos_t) / max(eta * cos_i + cos_t, 1e-12)
    r_perpendicular = (cos_i - eta * cos_t) / max(cos_i + eta * cos_t, 1e-12)
    return 0.5 * (r_parallel * r_parallel + r_perpendicular * r_perpendicular)
