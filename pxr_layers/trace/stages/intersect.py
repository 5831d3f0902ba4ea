"""Stage 2: closest hits of a PathQueue's rays (Embree, through trace/embree.py)."""

from __future__ import annotations

from ..embree import RayCaster
from .queues import Hits, PathQueue


def intersect(caster: RayCaster, queue: PathQueue) -> Hits:
    triangle, u, v, t = caster.intersect(queue.origin, queue.direction, queue.t_max)
    return Hits(triangle, u, v, t)
