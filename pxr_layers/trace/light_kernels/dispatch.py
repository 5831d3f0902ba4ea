"""One light sample per shading point (a source picked in proportion to its power, then that
light type's own sampling), and the density light sampling gives an emitter a ray hits, for
multiple importance sampling (after Cycles' kernel/light/light.h)."""

from __future__ import annotations

from ...compiled import inline
from .distant import distant_sample
from .distribution import pick
from .dome import dome_sample
from .point import point_sample
from .sphere import sphere_pdf, sphere_sample
from .table import AREA, DISTANT, POINT, SPHERE
from .triangle import triangle_pdf, triangle_point, triangle_sample


@inline
def sample(lights, geometry, materials, group, px, py, pz, u0, u1, u2, u3, registers, inputs, scratch):
    """One light sample toward point (px, py, pz) of link group `group` (group_of; its
    group must have lights: group_has_lights) from uniforms u0 (source), u1, u2
    (position), u3 (triangle). Returns (direction x, y, z unit toward the light; distance,
    metres, inf for distant and dome; radiance r, g, b arriving (irradiance at normal
    incidence for a delta light, point, line or distant, already divided by its
    probability); pdf, 1/sr, with the light's selection, inf for a delta; light index, −1
    for an emissive surface; triangle sampled, −1 for other lights). pdf 0: no sample.
    registers, inputs: scratch of shading.material_inputs; scratch (3,)."""
    source_cdf = lights.source_cdf[group]
    source = pick(source_cdf, 0, len(source_cdf), u0)
    kind, item = lights.source_kind[source], lights.source_item[source]
    if kind == AREA:
        return triangle_sample(lights, geometry, materials, group, px, py, pz, u1, u2, u3, registers, inputs, scratch)
    if kind == SPHERE:
        return sphere_sample(lights, group, item, px, py, pz, u1, u2)
    if kind == POINT:
        return point_sample(lights, group, item, px, py, pz, u1)
    if kind == DISTANT:
        return distant_sample(lights, group, item, u1, u2)
    return dome_sample(lights, group, item, u1, u2)


@inline
def emitter_pdf(lights, geometry, group, triangle, u, v, dx, dy, dz, distance, cos_light):
    """Solid-angle density (1/sr) with which light sampling from link group `group` picks the
    unit direction (dx, dy, dz) of a ray that hit emitting `triangle` at barycentrics (u, v),
    `distance` metres from the vertex it left, under cos_light: a sphere's cone density or
    the area source's."""
    light = geometry.triangle_light[triangle]
    sphere = lights.light_sphere[light] if light >= 0 else -1
    if sphere >= 0:
        hx, hy, hz = triangle_point(geometry, triangle, u, v)
        return sphere_pdf(lights, group, sphere, hx - dx * distance, hy - dy * distance, hz - dz * distance,
                          dx, dy, dz)
    return triangle_pdf(lights, group, triangle, distance, cos_light, geometry.area)
