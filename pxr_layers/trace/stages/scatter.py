"""Stage 7: BSDF sampling — each path takes a lobe and a new direction (or passes straight
through a cut-out), its throughput and MIS state updated, its next ray set up."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import bsdf, rng
from ...compiled import kernel
from ...paths import events
from ..vectors import to_world
from .queues import T_INFINITY, PathQueue, SurfaceQueue


@dataclass
class Scattering:
    """What each lane of a SurfaceQueue did (n,): lobe, scatter (int8 codes, paths/events.py),
    transmit (bool, the new direction crosses the surface), scattered (bool: a valid
    direction on the lobe's side; cut-outs are not scattered, they pass)."""

    lobe: np.ndarray
    scatter: np.ndarray
    transmit: np.ndarray
    scattered: np.ndarray


def scatter(queue: PathQueue, surfaces: SurfaceQueue, step: int, epsilon: float) -> Scattering:
    """Sample every lane's continuation; updates `queue` in place (direction, origin,
    throughput, previous_pdf, previous_singular, previous_triangle, previous_lobe, depth,
    vertex_travelled; t_max to infinity)."""
    n = len(queue)
    out = Scattering(np.zeros(n, np.int8), np.zeros(n, np.int8), np.zeros(n, bool), np.zeros(n, bool))
    _scatter_kernel(queue.key, surfaces.position, surfaces.facing, surfaces.frame, surfaces.wo, surfaces.lobes,
                    surfaces.cut, surfaces.scatters, surfaces.triangle, surfaces.through, rng.step_dimension(step),
                    epsilon, queue.origin, queue.direction, queue.throughput, queue.previous_pdf, queue.previous_singular,
                    queue.previous_triangle, queue.previous_lobe, queue.depth, queue.t_max,
                    queue.travelled, queue.vertex_travelled, out.lobe, out.scatter, out.transmit, out.scattered)
    return out


@kernel
def _scatter_kernel(key, position, facing, frame, wo, lobes, cut, scatters, triangle, through, dimension, epsilon,
                    origin, direction, throughput, previous_pdf, previous_singular, previous_triangle, previous_lobe, depth, t_max,
                    travelled, vertex_travelled, lobe_out, scatter_out, transmit_out, scattered_out):
    for lane in range(len(key)):
        t_max[lane] = T_INFINITY
        nx, ny, nz = facing[lane, 0], facing[lane, 1], facing[lane, 2]
        if cut[lane]:  # straight on, from just behind the surface: not a bounce
            origin[lane, 0] = position[lane, 0] - nx * epsilon
            origin[lane, 1] = position[lane, 1] - ny * epsilon
            origin[lane, 2] = position[lane, 2] - nz * epsilon
            lobe_out[lane] = bsdf.GLASS
            scatter_out[lane] = events.SCATTER_STRAIGHT
            continue
        if not scatters[lane]:  # at max depth, or nothing hit: the path ends here
            continue
        depth[lane] += 1
        vertex_travelled[lane] = travelled[lane]
        stream = key[lane]
        u0 = rng.uniform(stream, dimension + rng.LOBE)
        u1 = rng.uniform(stream, dimension + rng.DIRECTION)
        u2 = rng.uniform(stream, dimension + rng.DIRECTION + 1)
        x, y, z, wr, wg, wb, pdf, lobe, code, transmit, valid = bsdf.sample(lobes[lane], wo[lane, 0], wo[lane, 1],
                                                                             wo[lane, 2], u0, u1, u2)
        dx, dy, dz = to_world(frame, lane, x, y, z)
        side = dx * nx + dy * ny + dz * nz
        # A direction on the wrong side of the geometric surface would leave from inside the
        # object: it ends the path. The shading normal was bent (surface.bent_normal) so that
        # a lobe's centre never falls there; only its tail can. A fibre scatters all around
        # (hair.py): what leaves below it starts past it.
        hair = bsdf.is_hair(lobes[lane])
        consistent = side != 0 if hair else (side < 0 if transmit else side > 0)
        scattered = valid and consistent
        lobe_out[lane], scatter_out[lane], transmit_out[lane], scattered_out[lane] = lobe, code, transmit, scattered
        throughput[lane, 0] *= wr
        throughput[lane, 1] *= wg
        throughput[lane, 2] *= wb
        previous_pdf[lane] = pdf
        previous_singular[lane] = pdf == 0
        previous_triangle[lane], previous_lobe[lane] = triangle[lane], lobe
        offset = -epsilon if transmit else epsilon
        if hair:
            offset = epsilon if side > 0 else -(through[lane] + epsilon)
        origin[lane, 0] = position[lane, 0] + nx * offset
        origin[lane, 1] = position[lane, 1] + ny * offset
        origin[lane, 2] = position[lane, 2] + nz * offset
        direction[lane, 0], direction[lane, 1], direction[lane, 2] = dx, dy, dz
