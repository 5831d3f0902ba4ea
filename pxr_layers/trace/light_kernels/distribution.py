"""Per-lane sampling primitives the lights share: a discrete distribution's inverse cdf and
the uniform cone (distant lights, spheres by solid angle, the host's power estimates)."""

from __future__ import annotations

import math

from ...compiled import inline
from ..vectors import basis


@inline
def pick(cdf, start, count, u):
    """The first index i in [0, count) with cdf[start + i] > u (the last if none)."""
    low, high = 0, count - 1
    while low < high:
        middle = (low + high) // 2
        if cdf[start + middle] > u:
            high = middle
        else:
            low = middle + 1
    return low


@inline
def uniform_cone(ax, ay, az, one_minus_cos_max, u1, u2):
    """A unit direction (x, y, z) uniform over the cone of half angle θmax about the unit
    axis (ax, ay, az), from uniforms u1 (cos θ = 1 − u1 (1 − cos θmax)) and u2 (φ = 2π u2).
    The cone is given by 1 − cos θmax (2 for the whole sphere), which keeps its precision for
    the tiny cones of far spheres and of the sun, where cos θmax rounds to 1."""
    one_minus_cos = u1 * one_minus_cos_max
    cos_theta = 1.0 - one_minus_cos
    sin_theta = math.sqrt(max(one_minus_cos * (2.0 - one_minus_cos), 0.0))
    phi = 2 * math.pi * u2
    tx, ty, tz, bx, by, bz = basis(ax, ay, az)
    cx, sx = sin_theta * math.cos(phi), sin_theta * math.sin(phi)
    return (tx * cx + bx * sx + ax * cos_theta, ty * cx + by * sx + ay * cos_theta,
            tz * cx + bz * sx + az * cos_theta)


@inline
def uniform_cone_pdf(one_minus_cos_max):
    """Solid-angle density (1/sr) of uniform_cone: one over the cone's solid angle."""
    return 1.0 / (2 * math.pi * one_minus_cos_max)
