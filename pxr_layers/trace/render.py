"""Render a whole image: batches of paths over a thread pool, reduced in a fixed order."""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import RenderSettingsError
from ..paths.events import EventVocabulary
from ..progress import Progress
from ..scene import FLOAT, RenderSpec, SceneData
from .aovs import render_data_aovs
from .bounce_norms import BounceNorms
from .camera import PinholeCamera
from .embree import RayCaster
from .integrator import BatchResult, Integrator, TraceSettings
from .lights import LightSampler
from .shading import MaterialTable
from .world import build_world

log = logging.getLogger(__name__)

DEFAULT_BATCH_PATHS = 1 << 16


@dataclass(frozen=True)
class RenderResult:
    """rgba : (h, w, 4) float32, linear radiance (RGB) and camera-ray coverage (A).
    first_bounce_norms : (h, w, 3) float32 mean C (1/m), T (cycles/m), R (cycles/rad) of
        the first bounce over the samples whose first event scatters (NaN where none
        does); None unless settings.norm_bounces > 0.
    data : the data AOVs asked for (name → (h, w) or (h, w, 3) float32, see aovs.py)
    object_paths : the prim path of each object, indexed by the primId AOV
    """

    rgba: np.ndarray
    settings: TraceSettings
    resolution: tuple[int, int]
    frame: float
    rays: int
    seconds: float
    triangles: int
    vocabulary: EventVocabulary
    first_bounce_norms: np.ndarray | None = None
    data: dict[str, np.ndarray] = field(default_factory=dict)
    object_paths: tuple[str, ...] = ()


def prepare(scene: SceneData, spec: RenderSpec, settings: TraceSettings) -> Integrator:
    """Build the world, its Embree scene, material and light tables for one frame."""
    width, height = spec.resolution
    if width <= 0 or height <= 0:
        raise RenderSettingsError(f"resolution must be positive, got {width}×{height}")
    if settings.spp <= 0:
        raise RenderSettingsError(f"samples per pixel must be positive, got {settings.spp}")
    if settings.max_depth < 0:
        raise RenderSettingsError(f"max depth must be 0 or more, got {settings.max_depth}")
    world = build_world(scene)
    materials = MaterialTable(scene)
    lights = LightSampler(scene, world, materials)
    if not lights.has_lights:
        log.warning("%s: no light emits anything: the image will be black", scene.stage_path)
    camera = PinholeCamera.from_spec(spec)
    bounce_norms = BounceNorms(scene, world) if settings.norm_bounces > 0 else None
    # every distinct (object, material) pair of the triangles is one event subject
    pairs, triangle_subject = np.unique(np.stack([world.triangle_object, world.triangle_material], axis=1), axis=0,
                                        return_inverse=True)
    vocabulary = EventVocabulary(
        surface_objects=tuple(pairs[:, 0].tolist()), surface_materials=tuple(pairs[:, 1].tolist()),
        object_names=world.object_names, object_paths=world.object_paths,
        material_names=tuple(m.name for m in scene.materials), material_paths=tuple(m.path for m in scene.materials),
        light_names=tuple(light.name for light in scene.lights), light_paths=tuple(light.path for light in scene.lights),
    )
    return Integrator(world, materials, lights, camera, spec.resolution, settings, scene.frame, RayCaster(world),
                      vocabulary, triangle_subject.reshape(-1).astype(np.int64), bounce_norms)


def render(
    scene: SceneData,
    spec: RenderSpec,
    settings: TraceSettings,
    *,
    threads: int | None = None,
    batch_paths: int = DEFAULT_BATCH_PATHS,
    show_progress: bool = True,
    on_batch: Callable[[BatchResult], None] | None = None,
    data_aovs: Iterable[str] = (),
) -> RenderResult:
    """Path-trace `scene` as `spec` asks. The same inputs give the same bytes whatever
    `threads` and `batch_paths` are (each batch is reduced into the film in path order).

    on_batch, if given, receives every BatchResult in path order (with its records when
    settings.record_paths): the path index is written from there while rendering.
    data_aovs: names of data AOVs (aovs.DATA_AOVS) to render beside the beauty."""
    start = time.perf_counter()
    integrator = prepare(scene, spec, settings)
    width, height = spec.resolution
    total_paths = width * height * settings.spp
    # Batches never straddle a pixel, so each pixel's samples are summed in one order.
    batch_paths = max(settings.spp, batch_paths // settings.spp * settings.spp)
    starts = range(0, total_paths, batch_paths)
    film = _Film(width * height, settings.norm_bounces > 0)
    rays = 0
    progress = Progress(total_paths, "render", enabled=show_progress)
    workers = threads or os.cpu_count() or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        for first in starts:
            pending.append(pool.submit(integrator.trace, first, min(first + batch_paths, total_paths)))
            if len(pending) >= 2 * workers:
                rays += film.accumulate(pending.popleft().result(), progress, settings.spp, on_batch)
        while pending:
            rays += film.accumulate(pending.popleft().result(), progress, settings.spp, on_batch)
    rgba = np.empty((height, width, 4), FLOAT)
    rgba[..., :3] = (film.rgb / settings.spp).reshape(height, width, 3)
    rgba[..., 3] = (film.coverage / settings.spp).reshape(height, width)
    first_bounce_norms = None
    if film.norm_sums is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            means = film.norm_sums / film.norm_counts[:, None]
        first_bounce_norms = means.reshape(height, width, 3).astype(FLOAT)
    data = render_data_aovs(integrator, data_aovs, threads=threads)
    seconds = time.perf_counter() - start
    log.info("rendered %d×%d at %d spp in %.1fs (%.2f M rays/s)", width, height, settings.spp, seconds,
             rays / seconds / 1e6)
    return RenderResult(rgba, settings, (width, height), scene.frame, rays, seconds, integrator.world.triangle_count,
                        integrator.vocabulary, first_bounce_norms, data, integrator.world.object_paths)


class _Film:
    """Whole-image sums, filled batch by batch in path order."""

    def __init__(self, pixels: int, norms: bool):
        self.rgb = np.zeros((pixels, 3))
        self.coverage = np.zeros(pixels)
        self.norm_sums = np.zeros((pixels, 3)) if norms else None
        self.norm_counts = np.zeros(pixels) if norms else None

    def accumulate(self, batch: BatchResult, progress: Progress, spp: int, on_batch) -> int:
        span = slice(batch.first_pixel, batch.first_pixel + len(batch.rgb))
        self.rgb[span] += batch.rgb
        self.coverage[span] += batch.alpha
        if self.norm_sums is not None:
            self.norm_sums[span] += batch.first_bounce_norms
            self.norm_counts[span] += batch.first_bounce_count
        if on_batch is not None:
            on_batch(batch)
        progress.advance(len(batch.rgb) * spp)
        return batch.rays
