"""Stage 4: rays that hit a light's shape or an emissive surface receive its emission."""

from __future__ import annotations

import numpy as np

from ..bsdf import power_heuristic
from ...compiled import kernel, scratch
from ..light_kernels import LightArrays, emitted, emitter_pdf, found_by_hit, group_of
from .. import shading
from ..shading import MaterialArrays
from ..world import GeometryArrays
from .queues import Hits, PathQueue, Splats, trimmed


def emission(queue: PathQueue, hits: Hits, triangle_emits: np.ndarray, geometry: GeometryArrays,
             materials: MaterialArrays, lights: LightArrays) -> Splats:
    """The emission the hits of `queue` see, MIS-weighted against light sampling (light
    shapes emit on their front only), as far as camera visibility, light linking and the
    lights' multipliers let it through (lights.found_by_hit). Zero contributions are left
    out."""
    capacity = len(queue)
    splats = Splats(np.empty(capacity, np.int64), np.empty((capacity, 3), np.float32),
                    np.empty(capacity, np.int32), np.empty(capacity, np.int32))
    count = _emission_kernel(hits.triangle, hits.u, hits.v, hits.t, queue.travelled, queue.vertex_travelled,
                             triangle_emits, queue.direction, queue.throughput, queue.depth, queue.previous_pdf,
                             queue.previous_singular, queue.previous_triangle, queue.previous_lobe, geometry,
                             materials, lights, scratch(shading.REGISTERS, 4), scratch(shading.MATERIAL_FIELDS),
                             scratch(3), splats.lane, splats.rgb, splats.light, splats.triangle)
    return trimmed(splats, count)


@kernel
def _emission_kernel(triangle, bary_u, bary_v, t_hit, travelled, vertex_travelled, triangle_emits, direction,
                     throughput, depth, previous_pdf, previous_singular, previous_triangle, previous_lobe, geometry,
                     materials, lights, registers, inputs, radiance, lane_out, rgb_out, light_out, triangle_out):
    count = 0
    normal = geometry.geometric_normal
    for lane in range(len(triangle)):
        tri = triangle[lane]
        if tri < 0 or not triangle_emits[tri]:
            continue
        light = geometry.triangle_light[tri]
        found = found_by_hit(lights, light, depth[lane], previous_triangle[lane], previous_lobe[lane],
                             previous_singular[lane])
        if found == 0:
            continue
        dx, dy, dz = direction[lane, 0], direction[lane, 1], direction[lane, 2]
        cos_emitter = -(normal[tri, 0] * dx + normal[tri, 1] * dy + normal[tri, 2] * dz)
        emitted(tri, bary_u[lane], bary_v[lane], -dx, -dy, -dz, cos_emitter, geometry, lights.emission, materials,
                registers, inputs, radiance)
        if previous_singular[lane]:
            weight = 1.0
        else:
            # from the last scattering vertex, through any see-through surface crossed since
            distance = travelled[lane] + t_hit[lane] - vertex_travelled[lane]
            density = emitter_pdf(lights, geometry, group_of(lights, previous_triangle[lane]), tri, bary_u[lane],
                                  bary_v[lane], dx, dy, dz, distance, cos_emitter)
            weight = power_heuristic(previous_pdf[lane], density)
        weight *= found
        r = throughput[lane, 0] * radiance[0] * weight
        g = throughput[lane, 1] * radiance[1] * weight
        b = throughput[lane, 2] * radiance[2] * weight
        if r != 0 or g != 0 or b != 0:
            lane_out[count], light_out[count], triangle_out[count] = lane, light, tri
            rgb_out[count, 0], rgb_out[count, 1], rgb_out[count, 2] = r, g, b
            count += 1
    return count
