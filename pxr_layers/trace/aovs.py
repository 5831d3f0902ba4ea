"""The Hydra data AOVs a recipe asks for as ``raw`` RenderVars: depth, normal, Neye, Peye,
primId, instanceId.

One unjittered primary ray goes through each pixel centre, film position
((x + 0.5) / w, (y + 0.5) / h); there is no anti-aliasing and no sample averaging. That is
what Hydra Storm and most production renderers do for id and depth AOVs: an id must stay an
exact integer (the average of ids 3 and 7 is not object 5) and a depth at a silhouette
must be the foreground's or the background's, never a blend of both. Surfaces cut out by
their material (opacity below opacityThreshold) are passed through, as the integrator
does, so the AOVs show what the beauty shows; a partly present one (opacity without a
threshold) is seen where it is at least half present, in every pixel alike.

Every array is float32 with row 0 the top row of the image, like FrameResult.rgba:

    depth      : (h, w)    metres along the camera's view axis (camera-space −Z, not the
                           ray length); +inf where the ray hits nothing
    normal     : (h, w, 3) world-space unit shading normal, on the side facing the camera;
                           0 where the ray hits nothing
    Neye       : (h, w, 3) the same normal in camera space (the camera looks along −Z,
                           +Y up, +X right); 0 where the ray hits nothing
    Peye       : (h, w, 3) hit position in camera space, metres (Peye.z = −depth);
                           0 where the ray hits nothing
    primId     : (h, w)    index of the hit object in World.object_paths (meshes, then
                           area-light shapes); −1 where the ray hits nothing
    instanceId : (h, w)    the hit object's instance number N within its innermost
                           PointInstancer (World.object_instance); −1 for an object that is
                           not point-instanced (native instances included) and where the
                           ray hits nothing

Ids are exact in float32 up to 2**24 objects / instances.

:func:`camera_surroundings` casts a small grid of such rays to tell what is around the
camera (a black picture's diagnosis: a camera inside closed geometry sees only back faces).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..cores import available_cores
from ..errors import RenderSettingsError
from ..scene import FLOAT
from .integrator import Integrator
from .stages.queues import MAX_PASS_THROUGH
from .stages.camera import camera_rays
from .stages.intersect import intersect
from .stages.queues import T_INFINITY
from .stages.surface import surface

log = logging.getLogger(__name__)

DATA_AOVS = ("depth", "normal", "Neye", "Peye", "primId", "instanceId")
_VECTOR_AOVS = frozenset({"normal", "Neye", "Peye"})
_BACKGROUND = {"depth": np.inf, "normal": 0.0, "Neye": 0.0, "Peye": 0.0, "primId": -1.0, "instanceId": -1.0}
BATCH_PIXELS = 1 << 16  # rays per batch: whole rows, memory bounded whatever the resolution


def render_data_aovs(
    integrator: Integrator, names: Iterable[str], *, threads: int | None = None
) -> dict[str, np.ndarray]:
    """The data AOVs `names` (a subset of DATA_AOVS) of the frame `integrator` was prepared
    for (trace.render.prepare), as {name: (h, w) or (h, w, 3) float32} (see the module
    docstring for units and background values).

    Rows are traced in batches of about BATCH_PIXELS rays on `threads` threads (default:
    one per CPU); the result does not depend on either.
    Raises RenderSettingsError for a name that is not a data AOV.
    """
    wanted = tuple(dict.fromkeys(names))
    unknown = [name for name in wanted if name not in DATA_AOVS]
    if unknown:
        raise RenderSettingsError(
            f"unknown data AOV {', '.join(map(repr, unknown))}: known ones are {', '.join(DATA_AOVS)}"
        )
    width, height = integrator.width, integrator.height
    out = {
        name: np.full((height, width, 3) if name in _VECTOR_AOVS else (height, width), _BACKGROUND[name], FLOAT)
        for name in wanted
    }
    if not wanted:
        return out
    tracer = _DataTracer(integrator)
    rows = max(1, BATCH_PIXELS // width)
    starts = range(0, height, rows)

    def run(first_row: int) -> None:
        tracer.trace_rows(first_row, min(first_row + rows, height), out)

    workers = min(threads or available_cores(), len(starts))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(run, starts))  # each batch writes its own rows: nothing to reduce
    log.debug("data AOVs %s: %d×%d", ", ".join(wanted), width, height)
    return out


class _DataTracer:
    """What every batch shares (read-only): camera frame, see-through materials."""

    def __init__(self, integrator: Integrator):
        self.integrator = integrator
        self.camera_from_world = np.asarray(integrator.camera.world_from_camera, np.float64).T  # a rotation

    def trace_rows(self, first_row: int, stop_row: int, out: dict[str, np.ndarray]) -> None:
        """Fill rows [first_row, stop_row) of every array in `out`."""
        with self.integrator.slot() as slot:
            self._trace_rows(first_row, stop_row, out, None if slot is None else slot.path_region(0))

    def _trace_rows(self, first_row: int, stop_row: int, out: dict[str, np.ndarray], region) -> None:
        integrator = self.integrator
        world = integrator.world
        width = integrator.width
        queue = camera_rays(integrator.camera, integrator.key, (width, integrator.height), 1, first_row * width,
                            stop_row * width, jitter=False)
        n = len(queue)
        view = queue.direction.astype(np.float64)  # (n, 3) unit rays through the pixel centres
        seen_object = np.full(n, -1, np.int32)  # what each pixel sees (a hit's row is reused by the next query)
        distance = np.zeros(n, np.float64)  # metres along the ray from the camera
        normal = np.zeros((n, 3), FLOAT)
        lanes = np.arange(n)
        # The closest surface that is not cut out: lanes crossing a cut-out go on from behind
        # it, as the integrator's paths do (stages.surface decides what is cut out).
        for step in range(MAX_PASS_THROUGH + 1):
            hits = intersect(integrator.caster, queue, integrator.geometry.triangle_light, integrator.hidden_lights,
                             integrator.epsilon, region)
            hit = np.flatnonzero(hits.triangle >= 0)
            queue, hits, lanes = queue.take(hit), hits.take(hit), lanes[hit]
            if not len(queue):
                break
            # a fixed presence choice (spp −1): one ray per pixel must not make the data noisy
            surfaces = surface(queue, hits, np.ones(len(queue), bool), step, integrator.geometry, integrator.materials.arrays,
                               np.zeros(0, FLOAT), max_depth=0, spp=-1, ray_cone=integrator.ray_cone)
            seen = np.flatnonzero(~surfaces.cut)
            seen_object[lanes[seen]] = np.take(world.triangle_object, hits.triangle[seen])
            distance[lanes[seen]] = queue.travelled[seen]
            normal[lanes[seen]] = surfaces.frame[seen, 2]  # the shading normal, on the camera's side
            crossing = np.flatnonzero(surfaces.cut)
            queue, lanes = queue.take(crossing), lanes[crossing]
            if not len(queue):
                break
            queue.origin = surfaces.position[crossing] - surfaces.facing[crossing] * np.float32(integrator.epsilon)
            queue.t_max = np.full(len(queue), T_INFINITY, FLOAT)
        # lanes still crossing cut-outs after MAX_PASS_THROUGH of them see nothing

        hits = np.flatnonzero(seen_object >= 0)
        rows = slice(first_row, stop_row)
        flat = {name: array[rows].reshape(n, -1) for name, array in out.items()}  # views
        if not len(hits):
            return
        if "primId" in flat or "instanceId" in flat:
            obj = seen_object[hits]
            if "primId" in flat:
                flat["primId"][hits, 0] = obj
            if "instanceId" in flat:
                flat["instanceId"][hits, 0] = np.take(world.object_instance, obj)
        if {"depth", "Peye"} & flat.keys():
            # Camera-space position from the ray itself (no world-space subtraction).
            position_eye = (view[hits] @ self.camera_from_world.T) * distance[hits, None]
            if "depth" in flat:
                flat["depth"][hits, 0] = -position_eye[:, 2]
            if "Peye" in flat:
                flat["Peye"][hits] = position_eye
        if "normal" in flat:
            flat["normal"][hits] = normal[hits]
        if "Neye" in flat:
            flat["Neye"][hits] = normal[hits].astype(np.float64) @ self.camera_from_world.T


# -- what the camera sees around it (the diagnosis of a black picture) ----------------------

PROBE_GRID = 16
"""Rays per side of the grid :func:`camera_surroundings` casts through the film (256 rays):
enough to tell "nearly all" from "most" and negligible beside any render."""


@dataclass(frozen=True)
class CameraSurroundings:
    """What unjittered rays through a PROBE_GRID × PROBE_GRID grid of the film first hit.

    rays       : rays cast; hits : those that hit a surface or light shape
    back_faces : those whose first hit is the back of a surface (its geometric normal, wound
                 as authored, turned away from the camera): the inside of a closed mesh
    enclosing  : the prim paths of the objects whose backs they hit, most hit first
    """

    rays: int
    hits: int
    back_faces: int
    enclosing: tuple[str, ...]


def camera_surroundings(integrator: Integrator, grid: int = PROBE_GRID) -> CameraSurroundings:
    """Cast a ``grid`` × ``grid`` grid of rays through the film of the frame ``integrator``
    was prepared for, as the camera casts them (lights hidden from the camera crossed), and
    say what they hit first: the signature of a camera inside closed geometry is that nearly
    every ray hits a back face. Host-side, from the compiled stages the render uses."""
    queue = camera_rays(integrator.camera, integrator.key, (grid, grid), 1, 0, grid * grid, jitter=False)
    geometry = integrator.geometry
    with integrator.slot() as slot:
        hits = intersect(integrator.caster, queue, geometry.triangle_light, integrator.hidden_lights,
                         integrator.epsilon, None if slot is None else slot.path_region(0))
        hit = np.flatnonzero(hits.triangle >= 0)
        triangles = hits.triangle[hit]
        facing = np.einsum("ij,ij->i", geometry.geometric_normal[triangles].astype(np.float64),
                           queue.direction[hit].astype(np.float64))
        back = triangles[facing > 0]
        objects, counts = np.unique(np.take(integrator.world.triangle_object, back), return_counts=True)
    paths = tuple(integrator.world.object_paths[int(obj)] for obj in objects[np.argsort(-counts, kind="stable")])
    return CameraSurroundings(len(queue), len(hit), len(back), paths)
