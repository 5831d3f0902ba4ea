"""Stage 2: closest hits of a PathQueue's rays (Embree, through trace/embree.py)."""

from __future__ import annotations

import numpy as np

from ..embree import RayCaster
from ..instances import Region, StrandHits
from .queues import MAX_PASS_THROUGH, Hits, PathQueue


def intersect(caster: RayCaster, queue: PathQueue, triangle_light: np.ndarray, hidden_light: np.ndarray,
              epsilon: float, region: Region | None = None) -> Hits:
    """The closest hits of `queue`'s rays at their paths' times, placed (closest_placed). Camera rays (depth 0) go on through the
    shapes of lights hidden from the camera (`hidden_light` (lights,) bool; triangle_light
    (t,) int32 as in World), up to MAX_PASS_THROUGH of them, so no later stage sees those
    lights: their hits' t is measured from the ray's origin as every hit's is."""
    triangle, u, v, t = closest_placed(caster, region, queue.origin, queue.direction, queue.t_max, queue.time)
    if not hidden_light.any():
        return Hits(triangle, u, v, t)
    for _ in range(MAX_PASS_THROUGH):
        light = np.where(triangle >= 0, np.take(triangle_light, np.maximum(triangle, 0)), -1)
        lanes = np.flatnonzero((queue.depth == 0) & (light >= 0) & hidden_light[np.maximum(light, 0)])
        if not len(lanes):
            break
        past = t[lanes] + np.float32(epsilon)
        origin = queue.origin[lanes] + queue.direction[lanes] * past[:, None]
        crossed, u[lanes], v[lanes], t_next = closest_placed(caster, region, origin, queue.direction[lanes],
                                                             queue.t_max[lanes] - past, queue.time[lanes], lanes)
        triangle[lanes] = crossed
        t[lanes] = past + t_next
    return Hits(triangle, u, v, t)


def closest_placed(caster: RayCaster, region: Region | None, origin: np.ndarray, direction: np.ndarray,
                   t_max: np.ndarray, time: np.ndarray, lanes: np.ndarray | None = None):
    """caster.intersect at `time`, with the hits through instances, on moving rows and on
    strands placed in `region`'s rows (instances.py; None: a world with none of them), entry
    j as lane ``lanes[j]`` (None: lane j). Returns (triangle, u, v, t) as RayCaster.intersect."""
    normal = np.empty((len(t_max), 3), np.float32) if region is not None and caster.has_strands else None
    triangle, instance, u, v, t = caster.intersect(origin, direction, t_max, time, normal)
    if region is not None:
        strand_hits = None if normal is None else StrandHits(origin, direction, t, normal, u, v)
        region.place(triangle, instance, time, lanes, strand_hits)
    return triangle, u, v, t
