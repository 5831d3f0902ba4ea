"""The tracer's stages for one frame: :func:`prepare` builds the Integrator, :func:`trace_pixels`
traces batches of paths over a thread pool (in path order), :class:`Film` sums them. A frame is
assembled from these by :func:`pxr_layers.jobs.frame.render_frame` alone."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..cores import available_cores
from ..errors import RenderSettingsError
from ..request import check_work
from ..paths.events import EventVocabulary
from ..scene import FLOAT, RenderSpec, SceneData
from .bounce_norms import BounceNorms
from .camera import ThinLensCamera
from .guides import GUIDE_CHANNELS
from .embree import RayCaster
from .instances import MAX_SLOTS, InstanceRows, InstanceTables, RowTables, rows_needed
from .integrator import BatchResult, Integrator, TraceSettings
from .stages.film import FirstHits
from .lights import LightSampler
from .shading import MaterialTable, diffuse_texture
from .texture_cache import ANY_LEVEL, NOT_WANTED
from ..texture_files import level_count
from .world import World, build_world, flatten_instances, geometry_arrays

log = logging.getLogger(__name__)

DEFAULT_BATCH_PATHS = 1 << 16


def prepare(scene: SceneData, spec: RenderSpec, settings: TraceSettings) -> Integrator:
    """Build the world, its Embree scene, material and light tables for one frame: the
    textures the frame's visibility pre-pass (:func:`_texture_levels`) looked up, at the
    MIP levels it asked for."""
    width, height = spec.resolution
    if width <= 0 or height <= 0:
        raise RenderSettingsError(f"resolution must be positive, got {width}×{height}")
    if settings.spp <= 0:
        raise RenderSettingsError(f"samples per pixel must be positive, got {settings.spp}")
    if settings.max_depth < 0:
        raise RenderSettingsError(f"max depth must be 0 or more, got {settings.max_depth}")
    check_work(spec.resolution, settings.spp)  # a recipe's own resolution too
    if settings.record_sigma and any(mesh.prototype >= 0 for mesh in scene.meshes):
        # A Σ record keeps its vertices' rows until the batch ends, when a placed row
        # (instances.py) has been written over: the whole Σ is recorded on flat rows.
        log.info("%s: instanced surfaces flattened, since the index keeps each event's whole Σ", scene.stage_path)
        scene = flatten_instances(scene)
    placing = bool(scene.strands) or any(mesh.prototype >= 0 or mesh.motion_points is not None for mesh in scene.meshes)
    # the most lanes one query places: a batch's paths (trace_pixels), a row of data passes
    lanes, slots = max(DEFAULT_BATCH_PATHS, width), min(available_cores(), MAX_SLOTS)
    world = build_world(scene, rows_needed(lanes, slots) if placing else 0)
    geometry = geometry_arrays(world)
    camera = ThinLensCamera.from_spec(spec)
    caster = RayCaster(world)  # one BVH for the pre-pass and the frame
    finest = _texture_levels(scene, spec, settings, world, geometry, camera, caster, lanes, slots)
    materials = MaterialTable(scene, world.primvar_columns, finest, settings.texture_memory)
    integrator = _integrator(scene, spec.resolution, settings, world, geometry, camera, caster, materials, lanes, slots)
    if integrator.lights.darkness:
        log.warning("%s: %s", scene.stage_path, integrator.lights.darkness)
    return integrator


def _integrator(scene: SceneData, resolution: tuple[int, int], settings: TraceSettings, world: World, geometry,
                camera: ThinLensCamera, caster: RayCaster, materials: MaterialTable, lanes: int,
                slots: int) -> Integrator:
    """The Integrator of `world` (its Embree scene `caster`) with `materials`: its lights,
    norms, subjects and rows."""
    lights = LightSampler(scene, world, materials, geometry)
    bounce_norms = BounceNorms(scene, world, materials) if settings.norm_bounces > 0 else None
    pairs, triangle_subject, subject_first, subject_rank = _subjects(world)
    instance_rows = None
    if world.needs_placing:
        rows = RowTables.of(world, geometry, triangle_subject,
                            bounce_norms.curvature if bounce_norms else np.zeros(0, FLOAT), lights.arrays.link_group)
        instances = InstanceTables.of(world, subject_first, subject_rank, lights.object_link_group)
        instance_rows = InstanceRows(world, rows, instances, lanes, slots)
    vocabulary = EventVocabulary(
        surface_objects=tuple(pairs[:, 0].tolist()), surface_materials=tuple(pairs[:, 1].tolist()),
        object_names=world.object_names, object_paths=world.object_paths,
        material_names=tuple(m.name for m in scene.materials), material_paths=tuple(m.path for m in scene.materials),
        light_names=tuple(light.name for light in scene.lights), light_paths=tuple(light.path for light in scene.lights),
    )
    return Integrator(world, geometry, materials, lights, camera, resolution, settings, scene.frame, caster,
                      vocabulary, triangle_subject, bounce_norms, instance_rows)


PREPASS_PATHS = 1 << 17
"""Camera paths of the visibility pre-pass at most: a film 2^k times coarser than the frame's (k
the smallest that fits), with as many samples a pixel as fit, at most the frame's."""
SPECTRUM_LEVELS = 2
"""How many levels finer still a texture that drives the covariance norm T is held, when the
frame traces the norms: its spectrum (covariance/texture_spectrum.py) is measured on its finest
resident level, and a level's box filter has already weakened the frequencies near its own
limit, which T at the lookups' footprint still counts."""
ANY_LEVEL_STEPS = 8
"""A texture that only footprint-less lookups asked for (shadow rays through cut-outs, light
sampling: they read whatever level is resident) is held from the level 8 steps above 1 × 1,
256 texels on its larger side."""


def _texture_levels(scene: SceneData, spec: RenderSpec, settings: TraceSettings, world: World, geometry,
                    camera: ThinLensCamera, caster: RayCaster, lanes: int, slots: int) -> dict[int, int | None] | None:
    """SceneData.textures index → the finest MIP level to hold (None: none), from a visibility
    pre-pass: the frame traced on a film 2^k times coarser, at as many samples a pixel as
    PREPASS_PATHS allows (at least 1, at most the frame's), the same depth and seed, with
    only the decoded images resident; its lookups record the level each texture asked for
    (texture_cache ``wanted``), which is k levels coarser than the frame's own; the frame
    holds one level finer still, since the pre-pass sees a texture at fewer places than the
    frame's samples do (SPECTRUM_LEVELS more for the textures of T). None when every texture
    is decoded already (nothing to choose). Traced on this thread alone, so the levels, and
    the render, do not depend on thread timing."""
    lazy = [index for index, image in enumerate(scene.textures) if image.pixels is None]
    if not lazy:
        return None
    decoded = {index: 0 for index, image in enumerate(scene.textures) if image.pixels is not None}
    probe = MaterialTable(scene, world.primvar_columns, decoded, settings.texture_memory)
    width, height = spec.resolution
    shrink = 0
    while -(-width >> shrink) * -(-height >> shrink) > PREPASS_PATHS:
        shrink += 1
    size = (-(-width >> shrink), -(-height >> shrink))
    spp = max(1, min(settings.spp, PREPASS_PATHS // (size[0] * size[1])))
    pre_pass = TraceSettings(spp=spp, max_depth=settings.max_depth, seed=settings.seed,
                             roulette_depth=settings.roulette_depth)
    integrator = _integrator(scene, size, pre_pass, world, geometry, camera, caster, probe, lanes, slots)
    paths = size[0] * size[1] * spp
    for first in range(0, paths, DEFAULT_BATCH_PATHS):
        integrator.trace(first, min(first + DEFAULT_BATCH_PATHS, paths))
    finest: dict[int, int | None] = dict(decoded)
    of_norms = {found[0] for found in map(diffuse_texture, scene.materials) if found} if settings.norm_bounces else set()
    for index, row in probe.texture_rows.items():
        asked = int(probe.arrays.texture_wanted[row])
        if index in finest or asked == NOT_WANTED:
            continue
        header = scene.textures[index].header
        if asked == ANY_LEVEL:
            finest[index] = max(0, level_count(header.width, header.height) - 1 - ANY_LEVEL_STEPS)
        else:
            finest[index] = max(0, asked - shrink - 1 - (SPECTRUM_LEVELS if index in of_norms else 0))
    log.info("%s: %d of %d textures looked up by the visibility pre-pass (%d×%d, %d spp)", scene.stage_path,
             sum(1 for index in lazy if finest.get(index) is not None), len(lazy), *size, spp)
    return finest


def _subjects(world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The event subjects: every distinct (object, material) pair of the flat rows and of
    each instance with its prototype's materials, in (object, material) order (unique of
    one int64 key: far faster than rows of a matrix).

    Returns pairs (s, 2) int64; triangle_subject (rows,) int64 each flat row's subject (0
    elsewhere until placed); subject_first (i,) int64 each instance's first subject and
    subject_rank (rows,) int64 a prototype row's material among its prototype's distinct
    materials (instances.InstanceTables: an instance's pairs are consecutive, one object).
    """
    flat = world.own_rows
    rows = len(world.triangle_object)
    materials = []  # each prototype's distinct materials, sorted
    subject_rank = np.zeros(rows, np.int64)
    for first, triangles in zip(world.prototype_first.tolist(), world.prototype_triangles):
        own = world.triangle_material[first:first + len(triangles)]
        materials.append(np.unique(own))
        subject_rank[first:first + len(triangles)] = np.searchsorted(materials[-1], own)
    per_instance = np.array([len(materials[prototype]) for prototype in world.instance_prototype.tolist()], np.int64)
    objects = np.concatenate([world.triangle_object[:flat], np.repeat(world.instance_object, per_instance)])
    pair_materials = np.concatenate([world.triangle_material[:flat],
                                     *(materials[prototype] for prototype in world.instance_prototype.tolist())])
    pairs, inverse = _distinct_pairs(objects, pair_materials)
    triangle_subject = np.zeros(rows, np.int64)
    triangle_subject[:flat] = inverse[:flat]
    subject_first = inverse[flat + np.cumsum(per_instance) - per_instance] if len(per_instance) else np.zeros(0, np.int64)
    return pairs, triangle_subject, subject_first.astype(np.int64), subject_rank


def _distinct_pairs(first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(np.stack([first, second], 1), axis=0, return_inverse=True)`` for (n,)
    integer arrays, through one int64 key per pair."""
    first, second = np.asarray(first, np.int64), np.asarray(second, np.int64)
    if not len(first):
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    low, span = second.min(), int(second.max() - second.min()) + 1
    keys, inverse = np.unique((first - first.min()) * span + (second - low), return_inverse=True)
    pairs = np.stack([keys // span + first.min(), keys % span + low], axis=1)
    return pairs, inverse.reshape(-1)


def batch_pixels(spp: int, batch_paths: int = DEFAULT_BATCH_PATHS) -> int:
    """Pixels per batch: whole pixels (a batch never straddles one, so each pixel's samples
    are summed in one order), about ``batch_paths`` paths."""
    return max(1, batch_paths // spp)


def trace_pixels(integrator: Integrator, first_pixel: int, stop_pixel: int, on_batch: Callable[[BatchResult], None],
                 *, threads: int | None = None, batch_paths: int = DEFAULT_BATCH_PATHS) -> None:
    """Trace every sample of pixels [first_pixel, stop_pixel) on a thread pool; on_batch
    receives the BatchResults in path order.

    Batches start at multiples of :func:`batch_pixels` from pixel 0, so a range that starts
    on such a multiple is cut into the same batches as the whole image: tracing an image
    in such ranges (a job's tiles) gives the same batches, hence the same bytes."""
    spp = integrator.settings.spp
    step = batch_pixels(spp, batch_paths)
    workers = threads or available_cores()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        first = first_pixel
        while first < stop_pixel:
            stop = min((first // step + 1) * step, stop_pixel)
            pending.append(pool.submit(integrator.trace, first * spp, stop * spp))
            first = stop
            if len(pending) >= 2 * workers:
                on_batch(pending.popleft().result())
        while pending:
            on_batch(pending.popleft().result())
    integrator.materials.report_unresident()


class Film:
    """Whole-image sums, filled batch by batch. Batches cover disjoint pixels, so the sums
    do not depend on the order batches arrive in."""

    def __init__(self, pixels: int, spp: int, norms: bool, guides: bool = False):
        self.spp = spp
        self.rgb = np.zeros((pixels, 3))
        self.guide_sums = np.zeros((pixels, GUIDE_CHANNELS)) if guides else None
        self.coverage = np.zeros(pixels)
        self.norm_sums = np.zeros((pixels, 3)) if norms else None
        self.norm_counts = np.zeros(pixels) if norms else None
        self._first_hits: list[FirstHits] = []
        self.rays = 0

    def add(self, batch: BatchResult) -> None:
        span = slice(batch.first_pixel, batch.first_pixel + len(batch.rgb))
        self.rgb[span] += batch.rgb
        self.coverage[span] += batch.alpha
        if self.norm_sums is not None:
            self.norm_sums[span] += batch.first_bounce_norms
            self.norm_counts[span] += batch.first_bounce_count
        if batch.first_hits is not None:
            self._first_hits.append(batch.first_hits)
        if self.guide_sums is not None:
            self.guide_sums[span] += batch.guides
        self.rays += batch.rays

    def first_hits(self) -> FirstHits:
        """Every batch's FirstHits (TraceSettings.first_hits), in pixel order whatever order
        the batches came in (they cover disjoint pixel ranges)."""
        return FirstHits.concatenate(sorted(self._first_hits, key=lambda part: part.pixel[:1].tolist()))

    def guides(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The denoiser's guides (guides.py), each (h, w, 3) float32: the mean albedo and the
        mean normal over each pixel's samples; None unless asked for."""
        if self.guide_sums is None:
            return None
        means = (self.guide_sums / self.spp).reshape(height, width, GUIDE_CHANNELS).astype(FLOAT)
        return means[..., :3].copy(), means[..., 3:].copy()

    def images(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray | None]:
        """rgba (h, w, 4) float32 and the mean first-bounce norms (h, w, 3) or None."""
        rgba = np.empty((height, width, 4), FLOAT)
        rgba[..., :3] = (self.rgb / self.spp).reshape(height, width, 3)
        rgba[..., 3] = (self.coverage / self.spp).reshape(height, width)
        if self.norm_sums is None:
            return rgba, None
        with np.errstate(invalid="ignore", divide="ignore"):
            means = self.norm_sums / self.norm_counts[:, None]
        return rgba, means.reshape(height, width, 3).astype(FLOAT)
