"""Stage 8: Russian roulette — which paths go on to the next bounce."""

from __future__ import annotations

import numpy as np

from .. import rng
from ...compiled import kernel
from .queues import PathQueue, SurfaceQueue
from .scatter import Scattering


def survivors(queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int,
              roulette_depth: int) -> np.ndarray:
    """Lanes (int64) that go on: cut-outs, and scattered paths with some throughput left
    that survive the roulette from bounce `roulette_depth` on (with probability
    max(throughput) clamped to [0.05, 1]; survivors' throughput is divided by it)."""
    survive = np.empty(len(queue), bool)
    _roulette_kernel(queue.key, queue.throughput, surfaces.cut, scattering.scattered, step + 1 >= roulette_depth,
                     rng.step_dimension(step) + rng.ROULETTE, survive)
    return np.flatnonzero(survive)


@kernel
def _roulette_kernel(key, throughput, cut, scattered, play, dimension, survive):
    for lane in range(len(key)):
        if cut[lane]:
            survive[lane] = max(throughput[lane, 0], throughput[lane, 1], throughput[lane, 2]) > 0
            continue
        alive = scattered[lane]
        if alive and play:
            probability = min(max(max(throughput[lane, 0], throughput[lane, 1], throughput[lane, 2]), 0.05), 1.0)
            alive = rng.uniform(key[lane], dimension) < probability
            for channel in range(3):
                throughput[lane, channel] /= probability
        survive[lane] = alive and max(throughput[lane, 0], throughput[lane, 1], throughput[lane, 2]) > 0
