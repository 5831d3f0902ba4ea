"""Stage 5: the surface a path reached — position, shading frame, material, cut-out, lobes.

The shading frame is built here once per hit, and every consumer reads it (BSDF sampling
in scatter.py, BSDF evaluation for next-event estimation, the covariance and bounce-norm
records, the normal AOV), so all of them see one normal.

Shading normals and the geometric surface
-----------------------------------------
A shading normal n (interpolated, or bent further by a normal map) differs from the
triangle's geometric normal g. The path may only continue on g's side (scatter.py: a
direction below the real surface would leave from inside the object), so where the mirror
reflection of wo about n falls below the geometric surface, a smooth or glossy lobe
centred on it loses all or most of its samples: whole pixels go exactly black (strong
normal maps, bevels, interpolated normals at grazing views).

:func:`bent_normal` bends n toward g, per hit and per view direction, just enough that
the mirror reflection of wo about it rises SPECULAR_CLEARANCE (a cosine) above the
geometric surface, or 0.9·cos θo for a view that grazes more than that (a reflection may
always be as shallow as the incoming ray): the rule of Iray (Keller et al. 2017, "The
Iray light transport simulation and rendering system", appendix A.3) that Cycles
applies as ``ensure_valid_specular_reflection`` (kernel/closure/bsdf_util.h) and that
Arnold applies to its shading normals too. n is left alone wherever its reflection
already clears the surface. Cycles keeps n' in the plane of g and n and solves a quadratic
for it; here the reflection R is lifted to that height keeping its direction along the
surface, and n' is the half vector of wo and the lifted R' (the normal that mirrors wo
onto R'): one normalisation, no root to choose, continuous in n. The lobes of a hit share
one frame, so the bend applies to the diffuse lobe too (Cycles bends glossy closures
only): where it acts, the diffuse lobe's cosine turns toward g as well, and fewer of its
samples fall below the surface.

Energy: every lobe is still evaluated and sampled in the (bent) shading frame with
shading-frame cosines, so a hit reflects at most its shading-frame albedo (no energy is
created: tests/test_shading_normal.py, furnace); directions that still fall below the
geometric surface (the far tail of a lobe, part of a diffuse lobe about a tilted normal)
are still discarded, which is physically right. Schüssler et al. 2017 ("Microfacet-based
normal mapping for robust Monte Carlo path tracing") would keep energy exactly and stay
reciprocal, by replacing each lobe with a microsurface of two facets (n and a tangent
facet) and a random walk between them; it changes every lobe's sampling and evaluation
(bsdf.py), its pdf is no longer closed form for MIS, and it darkens and reshapes normal
maps relative to what artists authored for other renderers. The bend is local to the
frame, costs a few flops per hit, and matches Cycles/Arnold looks, so it is the one here.
"""

from __future__ import annotations

import math

import numpy as np

from .. import bsdf, rng, shading
from ...compiled import inline, kernel, scratch
from ..shading import MaterialArrays
from ..vectors import basis, normalized
from ..world import GeometryArrays
from .queues import Hits, PathQueue, SurfaceQueue

SPECULAR_CLEARANCE = 0.01
"""The height (a cosine above the geometric surface, ≈ 0.57°) to which the bend lifts the
mirror reflection of wo (module docstring): Iray's and Cycles' value."""


def surface(queue: PathQueue, hits: Hits, alive: np.ndarray, step: int, geometry: GeometryArrays,
            materials: MaterialArrays, curvature: np.ndarray, max_depth: int, frame_key: np.uint64 = np.uint64(0),
            spp: int = 0, ray_cone=None) -> SurfaceQueue:
    """The shading points of `queue`'s hits, for the lanes `alive` (n,) bool marks: those
    that hit a surface that is not a light (lights absorb what reaches them).

    Presence: a hit whose material's opacity is below its opacityThreshold is cut out, and
    with opacityThreshold 0 a fraction 1 − opacity of the paths is (chosen at random): the
    path passes straight through. At step 0 with `spp` > 0, that choice is stratified over
    each pixel's samples (rng.stratified, keyed by `frame_key`), so a half-present surface
    seen by the camera passes exactly half of them; later choices are independent. spp −1
    makes every choice fixed (what is less than half present passes), for data passes.

    The shading normal is the interpolated normal, perturbed by the material's tangent-space
    normal (mapped_normal), turned to the viewer's side of the geometric normal with the
    interpolated normal, then bent toward the geometric normal where the mirror reflection
    of the view direction would fall below the surface (bent_normal, module docstring).
    A hair material's frame is the fibre's instead (x along it, z its normal: hair.py), with
    neither normal map nor bend. Paths at `max_depth` get no lobe. curvature: (t,) float32 C
    per triangle, or (0,) for none (C = 0). Also adds the hit distance to
    ``queue.travelled``. Textures are looked up as wide as the camera sample's ray cone
    (``ray_cone``, a sigma.RayCone: its width at the distance travelled, over the cosine at
    the geometric surface), at their finest resident level without one.
    """
    cone = (0.0, 0.0, 0.0) if ray_cone is None else (ray_cone.pixel_angle, ray_cone.lens_radius,
                                                      ray_cone.focus_distance)
    n = len(queue)
    out = SurfaceQueue(
        position=np.empty((n, 3), np.float32), facing=np.empty((n, 3), np.float32),
        frame=np.empty((n, 3, 3), np.float32), wo=np.empty((n, 3), np.float32),
        lobes=bsdf.lobe_rows(n), cut=np.empty(n, bool), scatters=np.empty(n, bool), triangle=hits.triangle,
        st=np.empty((n, 2), np.float32), curvature=np.zeros(n, np.float32), texture=np.zeros(n, np.float32),
        through=np.zeros(n, np.float32))
    _surface_kernel(alive, queue.key, queue.pixel, queue.sample, frame_key, spp if step == 0 or spp < 0 else 0,
                    rng.step_dimension(step) + rng.PRESENCE, hits.triangle, hits.u, hits.v, hits.t,
                    queue.direction, queue.depth, queue.travelled, *cone, max_depth, geometry, materials, curvature,
                    scratch(3), scratch(3), scratch(shading.REGISTERS, 4), scratch(shading.MATERIAL_FIELDS),
                    out.position, out.facing, out.frame, out.wo, out.lobes, out.cut, out.scatters, out.st,
                    out.curvature, out.through)
    return out


@inline
def mapped_normal(geometry, triangle, inputs, nx, ny, nz):
    """The unit normal (nx, ny, nz) perturbed by the tangent-space normal inputs[NORMAL:+3]
    in the frame (∂P/∂u, ∂P/∂v, n) of `triangle`, (u, v) the coordinates the normal map is
    looked up at (inputs[NORMAL_UV:+4], through its uv transform), Gram–Schmidt
    orthonormalised (one tangent frame per triangle); unchanged where the uvs are
    degenerate."""
    e1x, e1y, e1z, e2x, e2y, e2z, ds1, dt1, ds2, dt2 = shading.triangle_edges(geometry, triangle)
    det = ds1 * dt2 - ds2 * dt1
    if not abs(det) > 1e-20:
        return nx, ny, nz
    sx, sy, sz = (e1x * dt2 - e2x * dt1) / det, (e1y * dt2 - e2y * dt1) / det, (e1z * dt2 - e2z * dt1) / det
    qx, qy, qz = (e2x * ds1 - e1x * ds2) / det, (e2y * ds1 - e1y * ds2) / det, (e2z * ds1 - e1z * ds2) / det
    # ∂P/∂(u, v) of the uv the normal map reads: ∂P/∂(s, t) · ∂(s, t)/∂(u, v)
    m00, m01 = inputs[shading.NORMAL_UV], inputs[shading.NORMAL_UV + 1]
    m10, m11 = inputs[shading.NORMAL_UV + 2], inputs[shading.NORMAL_UV + 3]
    tx, ty, tz = sx * m00 + qx * m10, sy * m00 + qy * m10, sz * m00 + qz * m10
    bx, by, bz = sx * m01 + qx * m11, sy * m01 + qy * m11, sz * m01 + qz * m11
    along = tx * nx + ty * ny + tz * nz
    tx, ty, tz = normalized(tx - along * nx, ty - along * ny, tz - along * nz, 1e-30)
    cx, cy, cz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx  # n × t
    if cx * bx + cy * by + cz * bz < 0:  # mirrored uvs: the bitangent runs the other way
        cx, cy, cz = -cx, -cy, -cz
    x, y, z = inputs[shading.NORMAL], inputs[shading.NORMAL + 1], inputs[shading.NORMAL + 2]
    mx, my, mz = normalized(x * tx + y * cx + z * nx, x * ty + y * cy + z * ny, x * tz + y * cz + z * nz, 1e-30)
    if not (mx * mx + my * my + mz * mz) > 0.5:
        return nx, ny, nz
    return mx, my, mz


@inline
def fibre_direction(geometry, triangle, nx, ny, nz):
    """The unit direction along a fibre at a hit on `triangle`, perpendicular to the unit
    normal n: a placed strand row's first corner lies along the curve's tangent from the hit
    (instances.py); on any other triangle this is the direction toward its first corner, a
    tangent of no meaning (a hair material on a mesh)."""
    corners = geometry.corner_positions
    ax, ay, az = (2.0 * corners[triangle, 0, 0] - corners[triangle, 1, 0] - corners[triangle, 2, 0],
                  2.0 * corners[triangle, 0, 1] - corners[triangle, 1, 1] - corners[triangle, 2, 1],
                  2.0 * corners[triangle, 0, 2] - corners[triangle, 1, 2] - corners[triangle, 2, 2])
    along = ax * nx + ay * ny + az * nz
    ax, ay, az = ax - along * nx, ay - along * ny, az - along * nz
    if not ax * ax + ay * ay + az * az > 1e-30:
        tx, ty, tz, _, _, _ = basis(nx, ny, nz)
        return tx, ty, tz
    return normalized(ax, ay, az, 1e-30)


@inline
def bent_normal(nx, ny, nz, gx, gy, gz, wx, wy, wz):
    """The unit shading normal n bent toward the unit geometric normal g (on the viewer's
    side) just enough that the mirror reflection of wo (unit, toward the viewer) about it
    is min(SPECULAR_CLEARANCE, 0.9·cos θo) above the geometric surface; n itself where its
    reflection already is, and it faces wo and g (module docstring). Returns (x, y, z)."""
    cos_o = wx * gx + wy * gy + wz * gz
    clearance = min(0.9 * cos_o, SPECULAR_CLEARANCE)
    cos_n = nx * wx + ny * wy + nz * wz
    rx, ry, rz = 2.0 * cos_n * nx - wx, 2.0 * cos_n * ny - wy, 2.0 * cos_n * nz - wz
    height = rx * gx + ry * gy + rz * gz
    if cos_n > 0 and nx * gx + ny * gy + nz * gz > 0 and height >= clearance:
        return nx, ny, nz
    # R's direction along the surface; straight down (n ⟂ g) it has none: take the mirror
    # of wo's own, the direction a flat surface reflects toward.
    px, py, pz = rx - height * gx, ry - height * gy, rz - height * gz
    length = math.sqrt(px * px + py * py + pz * pz)
    if not length > 1e-6:
        px, py, pz = cos_o * gx - wx, cos_o * gy - wy, cos_o * gz - wz
        length = math.sqrt(px * px + py * py + pz * pz)
        if not length > 1e-6:  # wo along g: the flat surface's own mirror
            return gx, gy, gz
    along = math.sqrt(max(1.0 - clearance * clearance, 0.0)) / length
    # n' = the half vector of wo and the lifted reflection R' = along·p + clearance·g
    hx, hy, hz = wx + px * along + clearance * gx, wy + py * along + clearance * gy, wz + pz * along + clearance * gz
    size = math.sqrt(hx * hx + hy * hy + hz * hz)
    if not size > 1e-6:  # R' opposite wo: only on a hit grazed exactly (cos θo = 0)
        return gx, gy, gz
    return hx / size, hy / size, hz / size


@kernel
def _surface_kernel(alive, key, pixel, sample, frame_key, spp, presence_dimension, triangle, bary_u, bary_v, t_hit,
                    direction, depth, travelled, pixel_angle, lens_radius, focus_distance, max_depth, geometry,
                    materials, curvature, point, normal, registers, inputs, position_out,
                    facing_out, frame_out, wo_out, lobes_out, cut_out, scatters_out, st_out, curvature_out,
                    through_out):
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
        gx, gy, gz = geometry.geometric_normal[tri, 0], geometry.geometric_normal[tri, 1], geometry.geometric_normal[tri, 2]
        wx, wy, wz = -direction[lane, 0], -direction[lane, 1], -direction[lane, 2]
        cos_geometric = gx * wx + gy * wy + gz * wz
        # the ray cone's width (sigma.RayCone.footprint's), over the geometric cosine: the
        # shading frame that RayCone divides by is not built before the material is read
        width = travelled[lane] * pixel_angle
        if lens_radius > 0.0:
            width += 2.0 * lens_radius * abs(1.0 - travelled[lane] / focus_distance)
        footprint = width / max(abs(cos_geometric), 0.05)
        s, t = shading.shade_point(materials, geometry, tri, u, v, registers, inputs, footprint)
        passing = shading.pass_fraction(inputs)
        cut = False
        if passing > 0:  # a random number only where there is a choice (most surfaces are opaque)
            if spp > 0:
                u_presence = rng.stratified(frame_key, pixel[lane], sample[lane], spp, presence_dimension)
            elif spp < 0:
                u_presence = 0.5
            else:
                u_presence = rng.uniform(key[lane], presence_dimension)
            cut = u_presence < passing
        scatters = not cut and depth[lane] < max_depth
        nx, ny, nz = normalized(normal[0], normal[1], normal[2], 1e-12)
        if cos_geometric < 0:
            gx, gy, gz = -gx, -gy, -gz
        # The side is the interpolated normal's: a normal map that tilts past the geometric
        # surface is bent back up below, not turned inside out.
        side = 1.0 if nx * gx + ny * gy + nz * gz >= 0 else -1.0
        hair = inputs[shading.HAIR] > 0
        if hair:  # a fibre: its own normal, and x along it (hair.py's frame)
            nx, ny, nz = side * nx, side * ny, side * nz
            tx, ty, tz = fibre_direction(geometry, tri, nx, ny, nz)
            bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx  # n × t
        else:
            if inputs[shading.HAS_NORMAL] > 0:
                nx, ny, nz = mapped_normal(geometry, tri, inputs, nx, ny, nz)
            nx, ny, nz = bent_normal(side * nx, side * ny, side * nz, gx, gy, gz, wx, wy, wz)
            tx, ty, tz, bx, by, bz = basis(nx, ny, nz)
        frame = frame_out[lane]
        frame[0, 0], frame[0, 1], frame[0, 2] = tx, ty, tz
        frame[1, 0], frame[1, 1], frame[1, 2] = bx, by, bz
        frame[2, 0], frame[2, 1], frame[2, 2] = nx, ny, nz
        ox, oy, oz = tx * wx + ty * wy + tz * wz, bx * wx + by * wy + bz * wz, nx * wx + ny * wy + nz * wz
        wo_out[lane, 0], wo_out[lane, 1], wo_out[lane, 2] = ox, oy, oz
        if hair:
            bsdf.prepare_hair(lobes_out, lane, inputs, ox, oy, oz, scatters)
        else:
            bsdf.prepare(lobes_out, lane, inputs, oz, cos_geometric > 0, scatters)
        position_out[lane, 0], position_out[lane, 1], position_out[lane, 2] = point[0], point[1], point[2]
        facing_out[lane, 0], facing_out[lane, 1], facing_out[lane, 2] = gx, gy, gz
        cut_out[lane], scatters_out[lane] = cut, scatters
        st_out[lane, 0], st_out[lane, 1] = s, t
        through_out[lane] = geometry.thickness[tri]
        if has_curvature:
            curvature_out[lane] = curvature[tri]
