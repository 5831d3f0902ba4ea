"""Distant lights: a delta direction (angle = 0), found by light sampling alone, or a cone of
directions sampled uniformly, which rays that escape inside it also find (stages/escaped.py)."""

from __future__ import annotations

import math

from ...compiled import inline
from .distribution import uniform_cone, uniform_cone_pdf


@inline
def distant_sample(lights, group, item, u1, u2):
    """Distant light `item`'s sample for link group `group` from uniforms (u1, u2). Returns
    sample()'s tuple: distance inf, triangle −1; a delta light's pdf is inf and its radiance
    the irradiance on a surface facing it, divided by the source's probability."""
    light = lights.distant_light[item]
    ax, ay, az = lights.distant_direction[item, 0], lights.distant_direction[item, 1], lights.distant_direction[item, 2]
    r, g, b = lights.distant_radiance[item, 0], lights.distant_radiance[item, 1], lights.distant_radiance[item, 2]
    probability = lights.distant_probability[group, item]
    cos_max = lights.distant_cos_max[item]
    if cos_max >= 1.0:
        return ax, ay, az, math.inf, r / probability, g / probability, b / probability, math.inf, light, -1
    dx, dy, dz = uniform_cone(ax, ay, az, 1.0 - cos_max, u1, u2)
    return dx, dy, dz, math.inf, r, g, b, cone_pdf(probability, cos_max), light, -1


@inline
def cone_pdf(probability, cos_max):
    """Solid-angle density (1/sr) of a distant light's cone (sampled uniformly, cos_max the
    cosine of its half angle), with its source probability."""
    return probability * uniform_cone_pdf(1.0 - cos_max)
