"""Stage 3: rays that hit nothing see the dome lights and the cones of distant lights."""

from __future__ import annotations

import numpy as np

from ..bsdf import power_heuristic
from ...compiled import inline, kernel
from ..light_kernels import LightArrays, cone_pdf, dome_pdf, dome_radiance, found_by_hit, group_of
from .queues import Hits, PathQueue, Splats, trimmed


def escaped(queue: PathQueue, hits: Hits, lights: LightArrays) -> Splats:
    """What the missed rays of `queue` receive from every infinite light, MIS-weighted
    against the light sampling that could have found the same direction, as far as camera
    visibility, light linking and the lights' multipliers let it through
    (lights.found_by_hit). Zero contributions are left out."""
    capacity = len(queue) * (len(lights.dome_light) + len(lights.distant_light))
    splats = Splats(np.empty(capacity, np.int64), np.empty((capacity, 3), np.float32),
                    np.empty(capacity, np.int32), np.full(capacity, -1, np.int32))
    count = _escaped_kernel(hits.triangle, queue.direction, queue.throughput, queue.depth, queue.previous_pdf,
                            queue.previous_singular, queue.previous_triangle, queue.previous_lobe, lights, splats.lane,
                            splats.rgb, splats.light)
    return trimmed(splats, count)


@kernel
def _escaped_kernel(triangle, direction, throughput, depth, previous_pdf, previous_singular, previous_triangle,
                    previous_lobe, lights, lane_out, rgb_out, light_out):
    count = 0
    for lane in range(len(triangle)):
        if triangle[lane] >= 0:
            continue
        x, y, z = direction[lane, 0], direction[lane, 1], direction[lane, 2]
        group = group_of(lights, previous_triangle[lane])
        for dome in range(len(lights.dome_light)):
            found = found_by_hit(lights, lights.dome_light[dome], depth[lane], previous_triangle[lane],
                                 previous_lobe[lane], previous_singular[lane])
            if found == 0:
                continue
            r, g, b = dome_radiance(lights, dome, x, y, z)
            density = lights.dome_probability[group, dome] * dome_pdf(lights, dome, x, y, z)
            weight = found * (1.0 if previous_singular[lane] else power_heuristic(previous_pdf[lane], density))
            count = _splat(lane, lights.dome_light[dome], r * weight, g * weight, b * weight, throughput, count,
                           lane_out, rgb_out, light_out)
        for item in range(len(lights.distant_light)):
            cos_max = lights.distant_cos_max[item]
            if cos_max >= 1.0:
                continue  # a delta light is only found by light sampling
            axis = lights.distant_direction[item]
            if x * axis[0] + y * axis[1] + z * axis[2] < cos_max:
                continue
            found = found_by_hit(lights, lights.distant_light[item], depth[lane], previous_triangle[lane],
                                 previous_lobe[lane], previous_singular[lane])
            if found == 0:
                continue
            density = cone_pdf(lights.distant_probability[group, item], cos_max)
            weight = found * (1.0 if previous_singular[lane] else power_heuristic(previous_pdf[lane], density))
            radiance = lights.distant_radiance[item]
            count = _splat(lane, lights.distant_light[item], radiance[0] * weight, radiance[1] * weight,
                           radiance[2] * weight, throughput, count, lane_out, rgb_out, light_out)
    return count


@inline
def _splat(lane, light, r, g, b, throughput, count, lane_out, rgb_out, light_out):
    r, g, b = throughput[lane, 0] * r, throughput[lane, 1] * g, throughput[lane, 2] * b
    if r != 0 or g != 0 or b != 0:
        lane_out[count], light_out[count] = lane, light
        rgb_out[count, 0], rgb_out[count, 1], rgb_out[count, 2] = r, g, b
        count += 1
    return count
