"""Emitting triangles: the tessellated area lights (rect, disk, cylinder, and spheres too
squashed to sample by solid angle) and the triangles of emissive materials, all one "area"
source.

The source picks a triangle in proportion to its power (area × the emission averaged over
its points and cosine-weighted directions, so a narrow cone or an IES profile is sampled in
proportion to what it sends: trace/lights.py estimates it), then a point uniform over the
triangle; the density is turned to solid angle by distance² / |cos| at the light. Light
shapes emit on their front only (one-sided, or outward for closed shapes), emissive
surfaces on both sides. A RectLight's colour map multiplies its emission at each point (the
top-left corner of the image at local (+X, +Y)).
"""

from __future__ import annotations

import math

from ...compiled import inline
from .. import shading, textures
from ..vectors import normalized
from .distribution import pick
from .shaping import light_emission
from .table import SHAPE_HEIGHT, SHAPE_WIDTH


@inline
def triangle_point(geometry, triangle, u, v):
    """World point (x, y, z), metres, at barycentrics (u, v) of `triangle`
    (p = (1 − u − v) p0 + u p1 + v p2, Embree's convention)."""
    corners, w = geometry.corner_positions, 1.0 - u - v
    return (w * corners[triangle, 0, 0] + u * corners[triangle, 1, 0] + v * corners[triangle, 2, 0],
            w * corners[triangle, 0, 1] + u * corners[triangle, 1, 1] + v * corners[triangle, 2, 1],
            w * corners[triangle, 0, 2] + u * corners[triangle, 1, 2] + v * corners[triangle, 2, 2])


@inline
def emitted(triangle, u, v, ex, ey, ez, cos_toward_viewer, geometry, emission, materials, registers, inputs, out):
    """Radiance leaving an emitting `triangle` at barycentrics (u, v) in unit world direction
    (ex, ey, ez), under cos_toward_viewer from its geometric normal, into out (3,): light
    shapes emit on their front only, shaped (shaping.light_emission) and textured; emissive
    surfaces on both sides, in proportion to their presence (the fraction of paths that do
    not pass through them). emission: LightArrays.emission; registers, inputs: scratch of
    shading.material_inputs."""
    light = geometry.triangle_light[triangle]
    if light < 0:
        shading.shade_point(materials, geometry, triangle, u, v, registers, inputs, 0.0)
        present = 1.0 - shading.pass_fraction(inputs)  # what passes through does not emit
        out[0], out[1], out[2] = (inputs[shading.EMISSIVE] * present, inputs[shading.EMISSIVE + 1] * present,
                                  inputs[shading.EMISSIVE + 2] * present)
        return
    if not cos_toward_viewer > 0:
        out[0] = out[1] = out[2] = 0.0
        return
    r, g, b = light_emission(emission, light, ex, ey, ez)
    texture = emission.texture[light]
    if texture >= 0:
        qx, qy, qz = triangle_point(geometry, triangle, u, v)
        m = emission.light_from_world[light]
        x = m[0, 0] * qx + m[0, 1] * qy + m[0, 2] * qz + m[0, 3]
        y = m[1, 0] * qx + m[1, 1] * qy + m[1, 2] * qz + m[1, 3]
        # UsdLux: the image's top-left corner at (+X, +Y), bottom-right at (−X, −Y)
        s = 0.5 - x / emission.size[light, SHAPE_WIDTH]
        t = 0.5 + y / emission.size[light, SHAPE_HEIGHT]
        i00, i10, i01, i11, fx, fy = textures.footprint(emission.texture_info, texture, s, t, 2, 2)
        texels, channels = emission.texels, emission.texture_info[texture, textures.CHANNELS]
        r *= textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 0))
        g *= textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 1))
        b *= textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 2))
    out[0], out[1], out[2] = r, g, b


@inline
def triangle_sample(lights, geometry, materials, group, px, py, pz, u1, u2, u3, registers, inputs, out):
    """The area source's sample toward point (px, py, pz) of link group `group`: a triangle
    from u3, a point uniform over it from (u1, u2). Returns sample()'s tuple (pdf with the
    source's probability; the sampled triangle and its light, −1 for an emissive surface);
    out (3,): scratch for emitted."""
    triangle_cdf = lights.triangle_cdf[group]
    chosen = lights.emitter_triangles[pick(triangle_cdf, 0, len(triangle_cdf), u3)]
    root = math.sqrt(u1)
    bu, bv = u2 * root, 1.0 - root
    qx, qy, qz = triangle_point(geometry, chosen, bu, bv)
    ox, oy, oz = qx - px, qy - py, qz - pz
    distance = math.sqrt(ox * ox + oy * oy + oz * oz)
    dx, dy, dz = normalized(ox, oy, oz, 1e-12)
    normal = geometry.geometric_normal
    cos_light = -(normal[chosen, 0] * dx + normal[chosen, 1] * dy + normal[chosen, 2] * dz)
    emitted(chosen, bu, bv, -dx, -dy, -dz, cos_light, geometry, lights.emission, materials, registers, inputs, out)
    pdf = triangle_pdf(lights, group, chosen, distance, cos_light, geometry.area)
    return dx, dy, dz, distance, out[0], out[1], out[2], pdf, geometry.triangle_light[chosen], chosen


@inline
def triangle_pdf(lights, group, triangle, distance, cos_light, area):
    """Solid-angle density (1/sr) with which the area source of link group `group` picks a
    point seen at `distance` metres on `triangle` under |cos_light|, with the source's
    probability; area: (t,) m²."""
    area_probability = lights.area_probability[group]
    if area_probability == 0:
        return 0.0
    area_density = area_probability * lights.triangle_probability[group, triangle] / area[triangle]
    return area_density * distance * distance / max(abs(cos_light), 1e-8)
