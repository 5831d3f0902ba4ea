"""Sphere lights sampled by solid angle (after pbrt-v4's Sphere::Sample(ctx)): a direction
uniform over the cone the sphere subtends, instead of a point on its area, so that every
sample sees the sphere's front and none is wasted on its far side.

Rays hit the sphere's tessellation (world.py), a convex polyhedron between two balls about
the centre: one inside it (inner radius) and one around it (outer radius), each as close to
it as float32 rounding allows (trace/lights.py).
Sampling the inner ball's cone keeps light sampling and BSDF sampling on the same emitter:
every direction sampled reaches the polyhedron's front, whose radiance depends on the
direction alone (shaping, no colour map), and a BSDF ray that hits the polyhedron outside
that cone (a thin rim) has light-sampling density 0, so MIS gives it weight 1. The sample's
point is where the ray meets the outer ball, outside the polyhedron: the shadow ray ends
before the light's own shape. From a point inside the outer ball (inside the light, or
within its tessellation's sagitta of it) there is no sample: an outward emitter sends
nothing inside, and BSDF rays find whatever such a point sees, at weight 1.
"""

from __future__ import annotations

import math

from ...compiled import inline
from .distribution import uniform_cone, uniform_cone_pdf
from .shaping import light_emission


@inline
def _cone(lights, sphere, px, py, pz):
    """(axis x, y, z unit from (px, py, pz) toward the centre, distance to the centre,
    1 − cos θmax of the inner ball's cone); 1 − cos θmax = 0 from inside the outer ball."""
    ox = lights.sphere_center[sphere, 0] - px
    oy = lights.sphere_center[sphere, 1] - py
    oz = lights.sphere_center[sphere, 2] - pz
    squared = ox * ox + oy * oy + oz * oz
    outer = lights.sphere_outer_radius[sphere]
    if squared <= outer * outer:
        return 0.0, 0.0, 1.0, 0.0, 0.0
    distance = math.sqrt(squared)
    inner = lights.sphere_inner_radius[sphere]
    sin2_max = inner * inner / squared
    cos_max = math.sqrt(max(1.0 - sin2_max, 0.0))
    # 1 − cos θmax = sin² / (1 + cos): exact where cos θmax rounds to 1 (far, small spheres)
    return ox / distance, oy / distance, oz / distance, distance, sin2_max / (1.0 + cos_max)


@inline
def sphere_sample(lights, group, sphere, px, py, pz, u1, u2):
    """Sphere `sphere`'s sample toward point (px, py, pz) of link group `group` from uniforms
    (u1, u2). Returns sample()'s tuple (pdf with the source's probability, 0: no sample;
    triangle −1: the point is on the outer ball, not on a triangle)."""
    light = lights.sphere_light[sphere]
    ax, ay, az, distance, one_minus_cos_max = _cone(lights, sphere, px, py, pz)
    if one_minus_cos_max <= 0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, light, -1
    dx, dy, dz = uniform_cone(ax, ay, az, one_minus_cos_max, u1, u2)
    # where the ray meets the outer ball: the centre is `along` ahead, `across` off the ray
    along = distance * (dx * ax + dy * ay + dz * az)
    across2 = max(distance * distance - along * along, 0.0)
    outer = lights.sphere_outer_radius[sphere]
    to_ball = along - math.sqrt(max(outer * outer - across2, 0.0))
    r, g, b = light_emission(lights.emission, light, -dx, -dy, -dz)
    pdf = lights.sphere_probability[group, sphere] * uniform_cone_pdf(one_minus_cos_max)
    return dx, dy, dz, to_ball, r, g, b, pdf, light, -1


@inline
def sphere_pdf(lights, group, sphere, px, py, pz, dx, dy, dz):
    """Solid-angle density (1/sr) with which link group `group`'s light sampling picks the
    unit direction (dx, dy, dz) from point (px, py, pz) toward sphere `sphere`, with the
    source's probability: uniform inside the inner ball's cone, 0 outside it (and from
    inside the outer ball)."""
    ax, ay, az, distance, one_minus_cos_max = _cone(lights, sphere, px, py, pz)
    if one_minus_cos_max <= 0:
        return 0.0
    if dx * ax + dy * ay + dz * az <= 0:
        return 0.0
    # inside the cone: the ray passes within the inner radius of the centre (sin θ from the
    # cross product keeps its precision in tiny cones, where cos θ rounds to 1)
    cx, cy, cz = ay * dz - az * dy, az * dx - ax * dz, ax * dy - ay * dx
    inner = lights.sphere_inner_radius[sphere]
    if distance * distance * (cx * cx + cy * cy + cz * cz) > inner * inner:
        return 0.0
    return lights.sphere_probability[group, sphere] * uniform_cone_pdf(one_minus_cos_max)
