"""The one place that talks to Embree (through embreex).

Embree's scene is built once per World; `intersect` and `occluded` take whole batches of
rays. Each call runs single-threaded inside Embree and releases the GIL, so the render
drives several batches from a thread pool.
"""

from __future__ import annotations

import numpy as np
from embreex import mesh_construction, rtcore_scene

from ..scene import FLOAT
from .world import World

MISS = -1


class RayCaster:
    """Closest-hit and any-hit queries against a World's triangles."""

    def __init__(self, world: World):
        # A world without triangles (a dome alone) has no Embree scene: every ray misses.
        self._scene = rtcore_scene.EmbreeScene() if world.triangle_count else None
        if self._scene is None:
            return
        mesh_construction.TriangleMesh(self._scene, world.vertices, world.triangles)
        # The first query commits the BVH without a lock: do it here, before any thread.
        probe = np.zeros((1, 3), FLOAT)
        self._scene.run(probe, np.array([[0, 0, 1]], FLOAT), output=1)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray):
        """Closest hits.

        origins, directions : (n, 3) float32 (directions need not be unit; t is in their units)
        t_max               : (n,) float32
        Returns (triangle (n,) int32 with MISS for no hit, u (n,), v (n,), t (n,) float32);
        u and v are Embree's barycentrics: p = (1 - u - v) p0 + u p1 + v p2.
        """
        if self._scene is None:
            n = len(t_max)
            return np.full(n, MISS, np.int32), np.zeros(n, FLOAT), np.zeros(n, FLOAT), np.asarray(t_max, FLOAT)
        # embreex writes the hit distances into `dists`: a copy keeps the caller's t_max
        result = self._scene.run(_rows(origins), _rows(directions), dists=np.array(t_max, FLOAT), output=1)
        return result["primID"], result["u"], result["v"], result["tfar"]

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """Any hit with t < t_max for origins, directions (n, 3): (n,) bool."""
        if self._scene is None:
            return np.zeros(len(t_max), bool)
        hit = self._scene.run(_rows(origins), _rows(directions), dists=np.array(t_max, FLOAT), query="OCCLUDED")
        return hit != MISS


def _rows(vectors: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(vectors, FLOAT)
