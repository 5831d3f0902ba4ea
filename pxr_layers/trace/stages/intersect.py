"""Stage 2: closest hits of a PathQueue's rays (Embree, through trace/embree.py)."""

from __future__ import annotations

import numpy as np

from ..embree import RayCaster
from ..instances import Region
from .queues import MAX_PASS_THROUGH, Hits, PathQueue


def intersect(caster: RayCaster, queue: PathQueue, triangle_light: np.ndarray, hidden_light: np.ndarray,
              epsilon: float, region: Region | None = None) -> Hits:
    """The closest hits of `queue`'s rays at their paths' times, hits through instances and
    on moving rows placed in `region`'s rows (instances.py; None: a world without either). Camera rays (depth 0) go on through the
    shapes of lights hidden from the camera (`hidden_light` (lights,) bool; triangle_light
    (t,) int32 as in World), up to MAX_PASS_THROUGH of them, so no later stage sees those
    lights: their hits' t is measured from the ray's origin as every hit's is."""
    triangle, instance, u, v, t = caster.intersect(queue.origin, queue.direction, queue.t_max, queue.time)
    if region is not None:
        region.place(triangle, instance, queue.time)
    if not hidden_light.any():
        return Hits(triangle, u, v, t)
    for _ in range(MAX_PASS_THROUGH):
        light = np.where(triangle >= 0, np.take(triangle_light, np.maximum(triangle, 0)), -1)
        lanes = np.flatnonzero((queue.depth == 0) & (light >= 0) & hidden_light[np.maximum(light, 0)])
        if not len(lanes):
            break
        past = t[lanes] + np.float32(epsilon)
        origin = queue.origin[lanes] + queue.direction[lanes] * past[:, None]
        crossed, instance, u[lanes], v[lanes], t_next = caster.intersect(origin, queue.direction[lanes],
                                                                         queue.t_max[lanes] - past, queue.time[lanes])
        if region is not None:
            region.place(crossed, instance, queue.time[lanes], lanes)
        triangle[lanes] = crossed
        t[lanes] = past + t_next
    return Hits(triangle, u, v, t)
