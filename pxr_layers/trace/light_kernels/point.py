"""Positional delta lights: spheres with ``treatAsPoint`` (a point) and cylinders with
``treatAsLine`` (a segment, sampled uniformly along it), with the power of the shape they
stand for. Nothing but light sampling finds them (they have no shape to hit), so they have
no solid-angle density: sample() reports pdf = inf and returns the irradiance at normal
incidence, already divided by the source's probability."""

from __future__ import annotations

import math

from ...compiled import inline
from ..vectors import normalized
from .shaping import light_emission


@inline
def point_sample(lights, group, item, px, py, pz, u1):
    """Positional light `item`'s sample toward point (px, py, pz) of link group `group`, a
    line's point at u1 along its segment. Returns sample()'s tuple (pdf inf, triangle −1)."""
    light = lights.point_light[item]
    segment = lights.point_segment[item]
    qx = lights.point_center[item, 0] + segment[0] * (u1 - 0.5)
    qy = lights.point_center[item, 1] + segment[1] * (u1 - 0.5)
    qz = lights.point_center[item, 2] + segment[2] * (u1 - 0.5)
    ox, oy, oz = qx - px, qy - py, qz - pz
    distance = math.sqrt(ox * ox + oy * oy + oz * oz)
    dx, dy, dz = normalized(ox, oy, oz, 1e-12)
    r, g, b = light_emission(lights.emission, light, -dx, -dy, -dz)
    # irradiance at normal incidence: intensity / distance², by the light's probability
    scale = (lights.point_scale[item] * broadside(segment, dx, dy, dz) / max(distance * distance, 1e-12)
             / lights.point_probability[group, item])
    return dx, dy, dz, distance, r * scale, g * scale, b * scale, math.inf, light, -1


@inline
def broadside(segment, dx, dy, dz):
    """How much of a segment's silhouette unit direction (dx, dy, dz) sees: |sin| of its angle
    to the segment (3,) (a line's silhouette shrinks so), 1 for a point (a zero segment)."""
    length = math.sqrt(segment[0] * segment[0] + segment[1] * segment[1] + segment[2] * segment[2])
    if length == 0:
        return 1.0
    along = (dx * segment[0] + dy * segment[1] + dz * segment[2]) / length
    return math.sqrt(max(1.0 - along * along, 0.0))
