"""Unidirectional path tracing as a schedule of wavefront stages (after pbrt-v4's wavefront).

One batch of paths (a contiguous range of path ids, path = pixel · spp + sample) moves
through the stages together, as lane-major queues compacted after each bounce
(``stages/``, one module per stage, each a compiled kernel over its queue):

    camera rays → intersect → escaped (dome, distant cones) → emission (lights, emissive
    surfaces) → surface (cut-out, shading frame, lobes) → next event (light sample, shadow
    ray, tentative radiance) → scatter (BSDF sampling) → roulette → next bounce

and every stage's results go to the batch's observers (stages/observer.py): its film,
and with covariance or an index the first-bounce pictures and the path recorder. With
``clamp_indirect``, each stage's indirect contributions are clamped first (stages/film.py),
so every observer sees the same, clamped light.

Emission found by BSDF sampling and by light sampling is combined with the power
heuristic, per lobe (see bsdf.py). ``max_depth`` counts scattering events: with
max_depth = 1 only direct lighting is computed. Straight pass-through at cut-out
surfaces (opacityThreshold) does not count.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ..request import DEFAULT_MAX_DEPTH, DEFAULT_SEED, DEFAULT_SPP, NO_CLAMP
from ..paths import events
from . import rng
from .bounce_norms import BounceNorms
from .camera import ThinLensCamera
from .embree import RayCaster
from .instances import SHADOW, InstanceRows, Slot
from .lights import LightSampler
from .merge import MergedContributions, merged
from .guides import DenoiseGuides
from .recorder import Contributions, FirstBounceNorms, PathRecorder
from .shading import MaterialTable
from .sigma import RayCone, SigmaInputs
from .stages.queues import MAX_PASS_THROUGH
from .stages.camera import camera_rays
from .stages.emission import emission
from .stages.escaped import escaped
from .stages.film import BatchFilm, FirstHits, clamp_lit, clamp_splats
from .stages.intersect import intersect
from .stages.observer import Observer
from .stages.next_event import cast_shadows, light_samples
from .stages.roulette import survivors
from .stages.scatter import scatter
from .stages.surface import surface
from .world import GeometryArrays, World


@dataclass(frozen=True)
class TraceSettings:
    """How to trace. spp: samples per pixel; seed and frame key every random number.

    norm_bounces : N, how many events after the camera keep their covariance norms C, T, R
                   (bounce_norms.py); 0 turns covariance off.
    record_paths : keep every contribution with its path class and norms (the path index).
    merge_records : hand them on merged (``merge.MergedContributions``), as a merged index keeps them.
    record_sigma : with them, each event's whole 4×4 Σ (``Contributions.sigma``, trace/sigma.py).
    first_bounce_norms : sum, per pixel, the first bounce's norms (``BatchResult.first_bounce_norms``,
                 the --debug-covariance pictures); needs norm_bounces > 0.
    first_hits : count, per pixel, the camera samples whose first visible hit is each surface
                 subject (``BatchResult.first_hits``): what the Cryptomattes are made of.
    clamp_indirect : the largest channel an indirect contribution may have (stages/film.py,
                 ``clamp_splats``); NO_CLAMP (0): none is clamped.
    guides : sum, per pixel, the denoiser's albedo and normal guides (``BatchResult.guides``,
                 guides.py).
    texture_memory : the material textures' budget, MiB (texture_cache.py); None: its default
    """

    spp: int = DEFAULT_SPP
    max_depth: int = DEFAULT_MAX_DEPTH
    seed: int = DEFAULT_SEED
    roulette_depth: int = 3  # Russian roulette from this many bounces on
    norm_bounces: int = 0
    record_paths: bool = False
    merge_records: bool = False
    record_sigma: bool = False
    first_bounce_norms: bool = False
    first_hits: bool = False
    clamp_indirect: float = NO_CLAMP
    guides: bool = False
    texture_memory: int | None = None

    def __post_init__(self) -> None:
        if self.first_bounce_norms and self.norm_bounces <= 0:
            raise ValueError("TraceSettings: first_bounce_norms needs norm_bounces > 0 (covariance traced)")


@dataclass
class BatchResult:
    """Partial film for the contiguous pixel range [first_pixel, first_pixel + len(rgb)).

    rgb   : (k, 3) float64 sum of contributions (not yet divided by spp)
    alpha : (k,) float64 count of camera rays that hit geometry
    first_bounce_norms : (k, 3) float64 sums of the first bounce's C, T, R over the
            samples whose first event scatters, and first_bounce_count (k,) of them
            (None unless settings.first_bounce_norms)
    records : every contribution, merged if settings.merge_records (None unless settings.record_paths)
    first_hits : the samples' first visible hits by surface subject (None unless settings.first_hits)
    rays  : rays cast (camera + bounce + shadow), for throughput figures
    guides : (k, 6) float64 sums of the denoiser's albedo and normal over the samples
            (guides.py; None unless settings.guides)
    """

    first_pixel: int
    rgb: np.ndarray
    alpha: np.ndarray
    first_bounce_norms: np.ndarray | None = None
    first_bounce_count: np.ndarray | None = None
    records: Contributions | MergedContributions | None = None
    first_hits: FirstHits | None = None
    rays: int = 0
    guides: np.ndarray | None = None


class Integrator:
    """Everything a batch needs, shared read-only between threads."""

    def __init__(self, world: World, geometry: GeometryArrays, materials: MaterialTable, lights: LightSampler,
                 camera: ThinLensCamera, resolution: tuple[int, int], settings: TraceSettings, frame: float,
                 caster: RayCaster, vocabulary: events.EventVocabulary, triangle_subject: np.ndarray,
                 bounce_norms: BounceNorms | None = None, instance_rows: InstanceRows | None = None):
        self.world = world
        self.geometry = geometry
        self.materials = materials
        self.lights = lights
        self.camera = camera
        self.width, self.height = resolution
        self.settings = settings
        self.key = rng.frame_key(settings.seed, frame)
        self.caster = caster
        self.vocabulary = vocabulary  # names behind the event ids of recorded paths
        self.triangle_subject = triangle_subject  # (t,) the vocabulary's surface subject of each triangle
        self.instance_rows = instance_rows  # where hits through instances are placed (None: no instances)
        self.bounce_norms = bounce_norms if settings.norm_bounces > 0 else None
        self.curvature = self.bounce_norms.curvature if self.bounce_norms else np.zeros(0, np.float32)
        self.epsilon = float(np.float32(1e-5 * (world.radius + np.linalg.norm(world.center)) + 1e-7))
        # the lights whose shapes camera rays pass (light shapes only: points and lines have none)
        self.hidden_lights = ~lights.arrays.camera_visible
        # the ray cone of a camera sample: radians per pixel (the film window's width over its
        # pixels) and the lens's defocus
        self.ray_cone = RayCone(float(np.float32(2 * camera.half_width / self.width)), camera.lens_radius,
                                camera.focus_distance)

    def observers(self, first_pixel: int, pixel_count: int, first_path: int, paths: int
                  ) -> tuple[BatchFilm, FirstBounceNorms | None, PathRecorder | None, DenoiseGuides | None]:
        """A batch's observers: its film, the first-bounce norms if asked for, the recorder
        with an index, the denoiser's guides if asked for."""
        first_bounce = (FirstBounceNorms(first_pixel, pixel_count)
                        if self.bounce_norms and self.settings.first_bounce_norms else None)
        sigma = (SigmaInputs(self.world, self.lights, self.bounce_norms, self.ray_cone)
                 if self.settings.record_sigma and self.bounce_norms else None)
        recorder = (PathRecorder(self.vocabulary, self.triangle_subject,
                                 self.settings.norm_bounces if self.bounce_norms else 0, paths, sigma)
                    if self.settings.record_paths else None)
        subjects = (self.triangle_subject, len(self.vocabulary.surface_objects)) if self.settings.first_hits else None
        guides = (DenoiseGuides(first_pixel, pixel_count, first_path, paths, self.settings.spp)
                  if self.settings.guides else None)
        return BatchFilm(first_pixel, pixel_count, subjects), first_bounce, recorder, guides

    @contextmanager
    def slot(self) -> Iterator[Slot | None]:
        """This thread's scratch rows for hits through instances while the block runs
        (instances.py); None in a world without instances."""
        if self.instance_rows is None:
            yield None
        else:
            with self.instance_rows.slot() as slot:
                yield slot

    def trace(self, first_path: int, stop_path: int) -> BatchResult:
        """Trace paths [first_path, stop_path) to completion."""
        with self.slot() as slot:
            return self._trace(first_path, stop_path, slot)

    def _trace(self, first_path: int, stop_path: int, slot: Slot | None) -> BatchResult:
        settings, lights = self.settings, self.lights
        geometry, materials, light_arrays = self.geometry, self.materials.arrays, lights.arrays
        spp = settings.spp
        first_pixel = first_path // spp
        pixel_count = (stop_path - 1) // spp - first_pixel + 1
        film, first_bounce, recorder, guides = self.observers(first_pixel, pixel_count, first_path,
                                                              stop_path - first_path)
        observers: list[Observer] = [o for o in (film, first_bounce, recorder, guides) if o is not None]
        queue = camera_rays(self.camera, self.key, (self.width, self.height), spp, first_path, stop_path)
        rays = 0

        for step in range(settings.max_depth + MAX_PASS_THROUGH + 1):
            if not len(queue):
                break
            hits = intersect(self.caster, queue, geometry.triangle_light, self.hidden_lights, self.epsilon,
                             None if slot is None else slot.path_region(step))
            rays += len(queue)
            hit = hits.triangle >= 0
            if lights.has_infinite_lights:
                splats = escaped(queue, hits, light_arrays)
                clamp_splats(queue, splats, settings.clamp_indirect)
                for observer in observers:
                    observer.escaped(queue, splats)
            if not hit.any():
                break  # every path escaped (always, in a world of sky alone: no triangle to index)
            splats = emission(queue, hits, lights.triangle_emits, geometry, materials, light_arrays)
            clamp_splats(queue, splats, settings.clamp_indirect)
            for observer in observers:
                observer.emitted(queue, splats)

            # Lights absorb what reaches them.
            alive = hit & (np.take(geometry.triangle_light, hits.triangle) < 0)
            # Coverage (alpha): the first surface or light a camera ray reaches and does not pass through.
            unscattered = queue.depth == 0
            if not alive.any():
                film.add_coverage(queue, hit & unscattered, hits.triangle)
                break
            wants_norms = any(observer.wants_norms(step) for observer in observers)
            surfaces = surface(queue, hits, alive, step, geometry, materials,
                               self.curvature if wants_norms else self.curvature[:0], settings.max_depth,
                               self.key, spp, self.ray_cone)
            film.add_coverage(queue, hit & unscattered & ~surfaces.cut, hits.triangle)
            if wants_norms and self.bounce_norms:
                footprint = self.ray_cone.footprint(queue.travelled, surfaces.wo[:, 2])
                self.bounce_norms.texture(surfaces, footprint)

            if lights.has_lights:
                shadows = light_samples(queue, surfaces, step, self.epsilon, geometry, materials, light_arrays)
                rays += len(shadows)
                cast_shadows(self.caster, shadows, queue.time, geometry, materials, light_arrays, self.materials.see_through,
                             self.epsilon, None if slot is None else slot.region(SHADOW))
                clamp_lit(queue, shadows, settings.clamp_indirect)
                for observer in observers:
                    observer.lit(queue, surfaces, shadows)

            scattering = scatter(queue, surfaces, step, self.epsilon)
            for observer in observers:
                observer.scattered(queue, surfaces, scattering, step)
            queue = queue.take(survivors(queue, surfaces, scattering, step, settings.roulette_depth))

        return BatchResult(first_pixel, film.rgb, film.alpha,
                           None if first_bounce is None else first_bounce.sums,
                           None if first_bounce is None else first_bounce.count,
                           None if recorder is None else self._records(recorder, first_pixel, pixel_count),
                           film.first_hits(), rays, None if guides is None else guides.sums)

    def _records(self, recorder: PathRecorder, first_pixel: int, pixel_count: int):
        records = recorder.result()
        return merged(records, first_pixel, pixel_count) if self.settings.merge_records else records
