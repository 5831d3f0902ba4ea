"""Render a whole image: batches of paths over a thread pool, reduced in a fixed order."""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..errors import RenderSettingsError
from ..progress import Progress
from ..scene import FLOAT, RenderSpec, SceneData
from .camera import PinholeCamera
from .embree import RayCaster
from .integrator import Integrator, TraceSettings
from .lights import LightSampler
from .shading import MaterialTable
from .world import build_world

log = logging.getLogger(__name__)

DEFAULT_BATCH_PATHS = 1 << 16


@dataclass(frozen=True)
class RenderResult:
    """rgba : (h, w, 4) float32, linear radiance (RGB) and camera-ray coverage (A)."""

    rgba: np.ndarray
    settings: TraceSettings
    resolution: tuple[int, int]
    frame: float
    rays: int
    seconds: float
    triangles: int


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
    return Integrator(world, materials, lights, camera, spec.resolution, settings, scene.frame, RayCaster(world))


def render(
    scene: SceneData,
    spec: RenderSpec,
    settings: TraceSettings,
    *,
    threads: int | None = None,
    batch_paths: int = DEFAULT_BATCH_PATHS,
    show_progress: bool = True,
) -> RenderResult:
    """Path-trace `scene` as `spec` asks. The same inputs give the same bytes whatever
    `threads` and `batch_paths` are (each batch is reduced into the film in path order)."""
    start = time.perf_counter()
    integrator = prepare(scene, spec, settings)
    width, height = spec.resolution
    total_paths = width * height * settings.spp
    # Batches never straddle a pixel, so each pixel's samples are summed in one order.
    batch_paths = max(settings.spp, batch_paths // settings.spp * settings.spp)
    starts = range(0, total_paths, batch_paths)
    rgb = np.zeros((width * height, 3))
    coverage = np.zeros(width * height)
    rays = 0
    progress = Progress(total_paths, "render", enabled=show_progress)
    workers = threads or os.cpu_count() or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        for first in starts:
            pending.append(pool.submit(integrator.trace, first, min(first + batch_paths, total_paths)))
            if len(pending) >= 2 * workers:
                rays += _accumulate(pending.popleft().result(), rgb, coverage, progress, settings.spp)
        while pending:
            rays += _accumulate(pending.popleft().result(), rgb, coverage, progress, settings.spp)
    rgba = np.empty((height, width, 4), FLOAT)
    rgba[..., :3] = (rgb / settings.spp).reshape(height, width, 3)
    rgba[..., 3] = (coverage / settings.spp).reshape(height, width)
    seconds = time.perf_counter() - start
    log.info("rendered %d×%d at %d spp in %.1fs (%.2f M rays/s)", width, height, settings.spp, seconds,
             rays / seconds / 1e6)
    return RenderResult(rgba, settings, (width, height), scene.frame, rays, seconds, integrator.world.triangle_count)


def _accumulate(batch, rgb, coverage, progress, spp) -> int:
    end = batch.first_pixel + len(batch.rgb)
    rgb[batch.first_pixel:end] += batch.rgb
    coverage[batch.first_pixel:end] += batch.alpha
    progress.advance(len(batch.rgb) * spp)
    return batch.rays
