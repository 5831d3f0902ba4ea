"""Stage 6: next-event estimation — one light sample per shading point, its shadow ray,
and the tentative radiance each glossy lobe would receive through it."""

from __future__ import annotations

import math

import numpy as np

from .. import bsdf, light_kernels, rng, shading
from ...compiled import kernel, scratch
from ..embree import RayCaster
from ..instances import Region
from ..light_kernels import LightArrays
from ..shading import MaterialArrays
from ..vectors import normalized, to_local
from ..world import GeometryArrays
from .intersect import closest_placed
from .queues import MAX_PASS_THROUGH, T_INFINITY, PathQueue, ShadowQueue, SurfaceQueue, trimmed

SHADOW_SPAN = 1 - 1e-4  # a shadow ray's t_max over the span between its offset ends: stops short of the light


def light_samples(queue: PathQueue, surfaces: SurfaceQueue, step: int, epsilon: float, geometry: GeometryArrays,
                  materials: MaterialArrays, lights: LightArrays) -> ShadowQueue:
    """A light sample for every shading point that may scatter, with its shadow ray and
    each lobe's MIS-weighted contribution if the ray is unoccluded (times the light's
    diffuse or specular multiplier), picked among the lights linked to the surface (light
    linking). Samples that cannot contribute (no density, behind the surface, black light
    or lobes) are left out.

    The shadow ray runs between the two offset ends: from the shading point lifted off its
    surface to the light's point lifted off the light's surface toward it. Measuring t_max
    from the unlifted point instead lets a ray that meets the light at a grazing angle hit
    the light's own triangle before t_max (and lose the light)."""
    n = len(queue)
    shadows = ShadowQueue(lane=np.empty(n, np.int64), origin=np.empty((n, 3), np.float32),
                          direction=np.empty((n, 3), np.float32), t_max=np.empty(n, np.float32),
                          radiance=np.empty((n, 3, 3), np.float32), light=np.empty(n, np.int32),
                          triangle=np.empty(n, np.int32), visible=np.zeros(n, bool))
    count = _light_sample_kernel(queue.key, queue.throughput, surfaces.position, surfaces.facing, surfaces.frame,
                                 surfaces.wo, surfaces.lobes, surfaces.scatters, surfaces.triangle, surfaces.through,
                                 rng.step_dimension(step), epsilon,
                                 geometry, materials, lights, scratch(3, 3), scratch(3), scratch(3),
                                 scratch(shading.REGISTERS, 4), scratch(shading.MATERIAL_FIELDS), shadows.lane, shadows.origin, shadows.direction,
                                 shadows.t_max, shadows.radiance, shadows.light, shadows.triangle)
    return trimmed(shadows, count)


def cast_shadows(caster: RayCaster, shadows: ShadowQueue, time: np.ndarray, geometry: GeometryArrays,
                 materials: MaterialArrays, lights: LightArrays, see_through: bool, epsilon: float,
                 region: Region | None = None) -> None:
    """Set ``shadows.visible``: which shadow rays reach their light. With `see_through`
    materials in the scene, or lights whose shadows only some geometry casts, a blocked ray
    is followed through the surfaces it crosses (up to MAX_PASS_THROUGH of them): geometry
    outside the light's shadow link and cut-outs pass it whole, a partly present surface
    (opacity without threshold) passes a fraction 1 − opacity, which scales its radiance —
    the expected value of the camera paths' random choice, without its noise. The surfaces
    crossed through instances or on moving rows are placed in `region`'s rows (instances.py).
    time: (paths,) float32 the shutter fraction of each path (PathQueue.time): its shadow
    rays meet moving geometry where it is then."""
    if not len(shadows):
        return
    time = time[shadows.lane]
    blocked = caster.occluded(shadows.origin, shadows.direction, shadows.t_max, time)
    shadows.visible = ~blocked
    if not (see_through or lights.sampled_only.any()) or not blocked.any():
        return
    lanes = np.flatnonzero(blocked)
    origin, direction, time = shadows.origin[lanes], shadows.direction[lanes], time[lanes]
    t_left = shadows.t_max[lanes].copy()
    transmittance = np.ones(len(lanes), np.float32)
    for _ in range(MAX_PASS_THROUGH):
        triangle, u, v, t = closest_placed(caster, region, origin, direction, t_left, time)
        crossed = triangle < 0
        shadows.visible[lanes[crossed]] = True
        shadows.radiance[lanes[crossed]] *= transmittance[crossed, None, None]
        fraction = np.empty(len(lanes), np.float32)
        _presence_kernel(triangle, u, v, shadows.light[lanes], geometry, materials, lights,
                         scratch(shading.REGISTERS, 4), scratch(shading.MATERIAL_FIELDS), fraction)
        going = np.flatnonzero(~crossed & (fraction > 0))
        if not len(going):
            return
        step = t[going] + np.float32(epsilon)
        lanes, direction, transmittance = lanes[going], direction[going], transmittance[going] * fraction[going]
        time = time[going]
        origin = origin[going] + direction * step[:, None]
        t_left = t_left[going] - step


@kernel
def _presence_kernel(triangle, bary_u, bary_v, light, geometry, materials, lights, registers, inputs, fraction_out):
    """The fraction of `light`'s light each hit lets through (0 where there is no hit)."""
    for lane in range(len(triangle)):
        tri = triangle[lane]
        if tri < 0:
            fraction_out[lane] = 0.0
            continue
        if not light_kernels.blocks(lights, light[lane], tri):
            fraction_out[lane] = 1.0
            continue
        if geometry.triangle_light[tri] >= 0:  # a light's shape: opaque
            fraction_out[lane] = 0.0
            continue
        shading.shade_point(materials, geometry, tri, bary_u[lane], bary_v[lane], registers, inputs, 0.0)
        fraction_out[lane] = shading.pass_fraction(inputs)


@kernel
def _light_sample_kernel(key, throughput, position, facing, frame, wo, lobes, scatters, surface_triangle, through,
                         dimension, epsilon, geometry, materials, lights, f, lobe_pdf, radiance, registers, inputs, lane_out,
                         origin_out, direction_out, t_max_out, radiance_out, light_out, triangle_out):
    count = 0
    for lane in range(len(key)):
        if not scatters[lane]:
            continue
        stream = key[lane]
        u0 = rng.uniform(stream, dimension + rng.LIGHT_PICK)
        u1 = rng.uniform(stream, dimension + rng.LIGHT_POSITION)
        u2 = rng.uniform(stream, dimension + rng.LIGHT_POSITION + 1)
        u3 = rng.uniform(stream, dimension + rng.LIGHT_POSITION + 2)
        group = light_kernels.group_of(lights, surface_triangle[lane])
        if not lights.group_has_lights[group]:
            continue
        px, py, pz = position[lane, 0], position[lane, 1], position[lane, 2]
        dx, dy, dz, distance, r, g, b, pdf, light, triangle = light_kernels.sample(
            lights, geometry, materials, group, px, py, pz, u0, u1, u2, u3, registers, inputs, radiance)
        nx, ny, nz = facing[lane, 0], facing[lane, 1], facing[lane, 2]
        side = dx * nx + dy * ny + dz * nz
        hair = bsdf.is_hair(lobes[lane])  # a fibre is lit from all around (hair.py)
        if not pdf > 0 or not (side != 0 if hair else side > 0) or max(r, g, b) <= 0:
            continue
        ix, iy, iz = to_local(frame, lane, dx, dy, dz)
        bsdf.evaluate(lobes[lane], wo[lane, 0], wo[lane, 1], wo[lane, 2], ix, iy, iz, f, lobe_pdf)
        if max(f[0, 0], f[0, 1], f[0, 2], f[1, 0], f[1, 1], f[1, 2], f[2, 0], f[2, 1], f[2, 2]) <= 0:
            continue
        delta = math.isinf(pdf)
        scale = (1.0 if hair else abs(iz)) / (1.0 if delta else pdf)
        br, bg, bb = throughput[lane, 0] * r * scale, throughput[lane, 1] * g * scale, throughput[lane, 2] * b * scale
        alone = delta or (light >= 0 and lights.sampled_only[light])  # no BSDF sample finds it: no MIS
        for slot in range(3):
            weight = 1.0 if alone else bsdf.power_heuristic(pdf, lobe_pdf[slot])
            weight *= light_kernels.response(lights, light, bsdf.slot_lobe(lobes[lane], slot))
            radiance_out[count, slot, 0] = br * f[slot, 0] * weight
            radiance_out[count, slot, 1] = bg * f[slot, 1] * weight
            radiance_out[count, slot, 2] = bb * f[slot, 2] * weight
        lane_out[count], light_out[count], triangle_out[count] = lane, light, triangle
        lift = epsilon if side > 0 else -(through[lane] + epsilon)  # below a fibre: from past it
        ox, oy, oz = px + nx * lift, py + ny * lift, pz + nz * lift
        origin_out[count, 0], origin_out[count, 1], origin_out[count, 2] = ox, oy, oz
        if math.isfinite(distance):
            qx, qy, qz = px + dx * distance, py + dy * distance, pz + dz * distance
            if triangle >= 0:  # lifted off the light's surface, on the side the ray arrives from
                gx, gy, gz = (geometry.geometric_normal[triangle, 0], geometry.geometric_normal[triangle, 1],
                              geometry.geometric_normal[triangle, 2])
                side = epsilon if gx * dx + gy * dy + gz * dz < 0 else -epsilon
                qx, qy, qz = qx + gx * side, qy + gy * side, qz + gz * side
            sx, sy, sz = qx - ox, qy - oy, qz - oz
            span = math.sqrt(sx * sx + sy * sy + sz * sz)
            direction_out[count, 0], direction_out[count, 1], direction_out[count, 2] = normalized(sx, sy, sz, 1e-30)
            t_max_out[count] = span * SHADOW_SPAN
        else:
            direction_out[count, 0], direction_out[count, 1], direction_out[count, 2] = dx, dy, dz
            t_max_out[count] = T_INFINITY
        count += 1
    return count
