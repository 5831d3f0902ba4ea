"""Stage 5: the surface a path reached — position, shading frame, material, cut-out, lobes."""

from __future__ import annotations


import numpy as np

from .. import bsdf, shading
from ...compiled import kernel, scratch
from ..shading import MaterialArrays
from ..vectors import basis, normalized
from ..world import GeometryArrays
from .queues import Hits, PathQueue, SurfaceQueue


def surface(queue: PathQueue, hits: Hits, alive: np.ndarray, geometry: GeometryArrays, materials: MaterialArrays,
            curvature: np.ndarray, max_depth: int) -> SurfaceQueue:
    """The shading points of `queue`'s hits, for the lanes `alive` (n,) bool marks: those
    that hit a surface that is not a light (lights absorb what reaches them).

    A hit whose material's opacity is below its opacityThreshold is cut out: the path
    passes straight through it. The shading normal is turned to the viewer's side of the
    geometric normal (and replaced by it where it would face away from the viewer).
    Paths at `max_depth` get no lobe. curvature: (t,) float32 C per triangle, or (0,) for
    none (C = 0). Also adds the hit distance to ``queue.travelled``.
    """
    n = len(queue)
    out = SurfaceQueue(
        position=np.empty((n, 3), np.float32), facing=np.empty((n, 3), np.float32),
        frame=np.empty((n, 3, 3), np.float32), wo=np.empty((n, 3), np.float32),
        lobes=bsdf.lobe_rows(n), cut=np.empty(n, bool), scatters=np.empty(n, bool), triangle=hits.triangle,
        st=np.empty((n, 2), np.float32), curvature=np.zeros(n, np.float32), texture=np.zeros(n, np.float32))
    _surface_kernel(alive, hits.triangle, hits.u, hits.v, hits.t, queue.direction, queue.depth, queue.travelled, max_depth,
                    geometry, materials, curvature, scratch(3), scratch(3), scratch(shading.MATERIAL_FIELDS),
                    out.position, out.facing, out.frame, out.wo, out.lobes, out.cut, out.scatters, out.st,
                    out.curvature)
    return out


@kernel
def _surface_kernel(alive, triangle, bary_u, bary_v, t_hit, direction, depth, travelled, max_depth, geometry, materials,
                    curvature, point, normal, inputs, position_out, facing_out, frame_out, wo_out, lobes_out, cut_out, scatters_out, st_out,
                    curvature_out):
    has_curvature = len(curvature) > 0
    for lane in range(len(triangle)):
        if not alive[lane]:
            cut_out[lane] = scatters_out[lane] = False
            wo_out[lane, 0] = wo_out[lane, 1] = wo_out[lane, 2] = 0.0
            continue
        tri = triangle[lane]
        u, v = bary_u[lane], bary_v[lane]
        travelled[lane] += t_hit[lane]
        shading.interpolate3(geometry.corner_positions, tri, u, v, point)
        shading.interpolate3(geometry.corner_normals, tri, u, v, normal)
        s, t = shading.interpolate_st(geometry.corner_uvs, tri, u, v)
        gx, gy, gz = geometry.geometric_normal[tri, 0], geometry.geometric_normal[tri, 1], geometry.geometric_normal[tri, 2]
        wx, wy, wz = -direction[lane, 0], -direction[lane, 1], -direction[lane, 2]
        cos_geometric = gx * wx + gy * wy + gz * wz
        material = geometry.triangle_material[tri]
        shading.material_inputs(materials.constants, materials.slot_input, materials.textured, materials.input_ints,
                                materials.input_floats, materials.texels, materials.texture_info, material, s, t,
                                inputs)
        threshold = inputs[shading.OPACITY_THRESHOLD]
        cut = threshold > 0 and inputs[shading.OPACITY] < threshold
        scatters = not cut and depth[lane] < max_depth
        if cos_geometric < 0:
            gx, gy, gz = -gx, -gy, -gz
        nx, ny, nz = normalized(normal[0], normal[1], normal[2], 1e-12)
        if nx * gx + ny * gy + nz * gz < 0:
            nx, ny, nz = -nx, -ny, -nz
        if nx * wx + ny * wy + nz * wz <= 1e-4:
            nx, ny, nz = gx, gy, gz
        tx, ty, tz, bx, by, bz = basis(nx, ny, nz)
        frame = frame_out[lane]
        frame[0, 0], frame[0, 1], frame[0, 2] = tx, ty, tz
        frame[1, 0], frame[1, 1], frame[1, 2] = bx, by, bz
        frame[2, 0], frame[2, 1], frame[2, 2] = nx, ny, nz
        ox, oy, oz = tx * wx + ty * wy + tz * wz, bx * wx + by * wy + bz * wz, nx * wx + ny * wy + nz * wz
        wo_out[lane, 0], wo_out[lane, 1], wo_out[lane, 2] = ox, oy, oz
        bsdf.prepare(lobes_out, lane, inputs[shading.DIFFUSE], inputs[shading.DIFFUSE + 1],
                     inputs[shading.DIFFUSE + 2], inputs[shading.SPECULAR], inputs[shading.SPECULAR + 1],
                     inputs[shading.SPECULAR + 2], inputs[shading.ROUGHNESS], inputs[shading.METALLIC],
                     inputs[shading.OPACITY], inputs[shading.CLEARCOAT], inputs[shading.CLEARCOAT_ROUGHNESS],
                     inputs[shading.USE_SPECULAR_WORKFLOW] > 0, inputs[shading.IOR], threshold, oz,
                     cos_geometric > 0, scatters)
        position_out[lane, 0], position_out[lane, 1], position_out[lane, 2] = point[0], point[1], point[2]
        facing_out[lane, 0], facing_out[lane, 1], facing_out[lane, 2] = gx, gy, gz
        cut_out[lane], scatters_out[lane] = cut, scatters
        st_out[lane, 0], st_out[lane, 1] = s, t
        if has_curvature:
            curvature_out[lane] = curvature[tri]
