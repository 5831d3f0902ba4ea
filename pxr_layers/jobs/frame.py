"""One frame of a shot, from a request to its delivered files: :func:`render_frame` is the
only assembly of a frame (stage → trace → index → products), called by `pxr-layers render`
and `demo`, by a job's frame assembly (whose batches were traced as tiles on workers), by
the tests and by the benchmarks alike.

* :func:`plan_frame` resolves the recipe (over the stage), the camera, the resolution, the
  trace settings and every output path into a :class:`FramePlan`: plain, picklable data.
* :func:`prepare_frame` loads the stage at the frame and builds its Embree scene (a
  worker does this once per frame).
* :class:`FrameAssembler` takes the frame's batches **in path order** (the film sums and
  the path index are written from them; the same batches in the same order give the same
  bytes) and then delivers the recipe's products with :func:`pxr_layers.layers.deliver`.
* a :class:`FrameSource` gives the batches and the frame's data: :class:`LocalTrace` traces
  them here on a thread pool; a job's committed tiles (jobs/executor.py) read them back.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, Self

import numpy as np

from .. import __version__, lpe
from ..layers.deliver import (
    Delivered,
    check_raw_sources,
    deliver,
    frame_suffix,
    output_target,
    plan_outputs,
    raw_sources,
)
from ..errors import RenderSettingsError
from ..outputs import OutputSet
from ..paths.events import path_text
from ..paths.format import SUFFIX as INDEX_SUFFIX
from ..paths.reader import AUTOMATIC_SUBDIV_LEVEL, PathIndex
from ..paths.writer import PathIndexWriter
from ..recipe.model import CRYPTOMATTE_SOURCES, Product, Recipe
from ..request import RenderRequest
from ..trace import DATA_AOVS, Film, TraceSettings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FramePlan:
    """Everything one frame needs, resolved; plain data (it travels to Dask workers).

    request        : what to render (stage, recipe layers, variants, trace settings, ...)
    frame          : the time code (None: the stage's start)
    camera         : the camera prim path; resolution : (width, height) pixels
    trace          : the tracer's settings (spp, depth, seed, norm bounces, recording)
    recipe         : the resolved recipe; outputs : product name → EXR path
    index_path     : where the path index goes (the request's keep_index False removes it
                     after delivery: the layers are cut from it all the same)
    data_aovs      : the raw sources the tracer renders beside the beauty (depth, ...)
    metadata       : ``pxrLayers/`` attributes of every EXR part
    manifest       : the path index's manifest (paths/format.py; ``model_paths`` and
                     ``light_groups``: stage_names)
    cryptomattes   : the Cryptomatte sources of the recipe (CryptoObject, ...)
    model_paths    : the stage's models (kind component, group, assembly), CryptoAsset's roots
    """

    request: RenderRequest
    frame: float | None
    camera: str
    resolution: tuple[int, int]
    trace: TraceSettings
    recipe: Recipe
    outputs: dict[str, Path]
    index_path: Path
    data_aovs: tuple[str, ...] = ()
    metadata: dict[str, str] = field(default_factory=dict)
    manifest: dict = field(default_factory=dict)
    cryptomattes: tuple[str, ...] = ()
    model_paths: tuple[str, ...] = ()

    @property
    def stage(self) -> Path:
        return self.request.stage

    @property
    def pixels(self) -> int:
        return self.resolution[0] * self.resolution[1]

    @property
    def files(self) -> tuple[Path, ...]:
        """The deliverables (EXRs and index; previews go beside the EXRs)."""
        return (*self.outputs.values(), *((self.index_path,) if self.request.keep_index else ()))


def plan_frame(
    request: RenderRequest,
    frame: float | None,
    *,
    directory: Path,
    exr: Path | None = None,
    index_path: Path | None = None,
    product_path: Callable[[Product], Path] | None = None,
    recipe: Recipe | None = None,
    stage_sha256: str | None = None,
    shot=None,
) -> FramePlan:
    """Resolve one frame of ``request``. ``recipe``: an already resolved recipe, else read
    from ``shot`` (an open :class:`pxr_layers.stage.Shot`, else the request's stage is
    opened); ``stage_sha256``: the stage file's hash (a job works both out once for all its
    frames).

    Outputs: ``product_path(product)`` if given, else :func:`plan_outputs` (``exr``: one
    product's explicit file). The index: ``index_path``, else beside ``exr``, else
    ``directory/STEM[.FFFF].pxlidx``. Norm bounces: :meth:`RenderRequest.resolved_norm_bounces`.
    The request's Cryptomattes are added to every product, each of ``cryptomatte_depth`` ranks
    (those the recipe asks for too).
    """
    from ..stage.defaults import AUTO_CAMERA_PATH

    stage = request.stage
    shot = shot or _open(request)  # once: the recipe and the index's stage names both read it
    if recipe is None:
        recipe = resolve_recipe(request, frame, shot)
    if request.cryptomattes:
        recipe = recipe.with_cryptomattes(request.cryptomattes)
    if request.denoise:
        recipe = recipe.with_denoise()
    view = recipe.shared_view()
    view_camera, view_resolution = view.camera, view.resolution
    resolution = tuple(request.resolution or view_resolution)
    check_raw_sources(recipe, (*DATA_AOVS, *CRYPTOMATTE_SOURCES), "the renderer does not produce")
    if recipe.denoises:
        from ..layers.denoise import available

        missing = available()
        if missing:
            raise RenderSettingsError(f"denoising: {missing}")
    sources = raw_sources(recipe)
    crypto_sources = tuple(source for source in sources if source in CRYPTOMATTE_SOURCES)
    model_paths, light_groups = stage_names(shot, recipe, frame)

    if product_path is not None:
        outputs = {product.name: Path(product_path(product)) for product in recipe.products}
    else:
        outputs = plan_outputs(recipe, frame, directory, exr)
    first = outputs[recipe.products[0].name]
    if index_path is None:
        index_path = exr.with_suffix(INDEX_SUFFIX) if exr else directory / f"{stage.stem}{frame_suffix(frame)}{INDEX_SUFFIX}"

    product_bounces = max(product.index.bounces for product in recipe.products)
    norm_bounces = request.resolved_norm_bounces(product_bounces, has_conditions(recipe))
    if norm_bounces > product_bounces and request.norm_bounces is None:
        log.info("the recipe has covariance conditions: the index keeps the norms of all %d bounces", norm_bounces)
    keep_index = request.keep_index
    # The layers are cut from the index, so lpe layers need one even when it is not kept.
    record = keep_index or any(product.expressions() for product in recipe.products)
    index_mode, sigma = index_settings(request, recipe)
    trace = TraceSettings(spp=request.spp, max_depth=request.max_depth, seed=request.seed, norm_bounces=norm_bounces,
                          record_paths=record, merge_records=record and index_mode == "merged",
                          record_sigma=record and sigma and norm_bounces > 0, first_hits=bool(crypto_sources),
                          first_bounce_norms=request.debug_covariance,
                          clamp_indirect=request.clamp_indirect, guides=recipe.denoises,
                          texture_memory=request.texture_memory)
    metadata = {
        "version": __version__,
        "stage": str(stage.resolve()),
        "camera": view_camera,
        "frame": "default" if frame is None else repr(float(frame)),
        "spp": str(request.spp),
        "maxDepth": str(request.max_depth),
        "seed": str(request.seed),
    }
    if request.clamp_indirect:  # only then: unclamped renders keep their bytes
        metadata["clampIndirect"] = repr(request.clamp_indirect)
    if request.variants:
        metadata["variants"] = " ".join(str(selection) for selection in request.variants)
    if not request.default_lights:
        metadata["defaultLights"] = "false"
    if view_camera == AUTO_CAMERA_PATH:
        metadata["autoCamera"] = request.auto_camera
    if keep_index:
        metadata["index"] = os.path.relpath(index_path, first.parent)
    manifest = {
        **metadata, "stage_sha256": stage_sha256 or file_sha256(stage), "resolution": list(resolution),
        "spp": request.spp, "seed": request.seed, "max_depth": request.max_depth,
        "subdiv_level": AUTOMATIC_SUBDIV_LEVEL if request.subdiv_level is None else request.subdiv_level,
        "beauty": os.path.relpath(first, index_path.parent),
    }
    manifest.pop("index", None)
    if request.clamp_indirect:
        manifest["clamp_indirect"] = request.clamp_indirect
    if view.pixel_aspect_ratio != 1.0:  # only then: square-pixel indexes keep their bytes
        manifest["pixel_aspect_ratio"] = view.pixel_aspect_ratio
    if model_paths:  # only then: a stage without models (or light groups) keeps its bytes
        manifest["model_paths"] = sorted(model_paths)
    if light_groups:
        manifest["light_groups"] = light_groups
    return FramePlan(request, frame, view_camera, resolution, trace, recipe, outputs, index_path,
                     tuple(source for source in sources if source not in CRYPTOMATTE_SOURCES),
                     metadata, manifest, crypto_sources, model_paths)


def _open(request: RenderRequest):
    from ..stage import open_request

    return open_request(request)


def stage_names(shot, recipe: Recipe, frame: float | None) -> tuple[tuple[str, ...], dict[str, str]]:
    """What the index records of the stage beyond its events, for whole-path layers
    (docs/suggest.md): the stage's models (prim paths of kind component, group, assembly,
    in traversal order: CryptoAsset's roots, layers.cryptomatte.asset_roots) and each light
    the render sees that has a ``pxrLayers:lightGroup``, as {light prim path: group}, sorted
    by path. The prim path is the label a light event of the index carries (paths/events.py),
    so the mapping needs no translation. shot : the open :class:`pxr_layers.stage.Shot`."""
    from ..stage.recipe_reader import model_prim_paths

    settings = shot.find_settings(recipe.settings_path) if recipe.settings_path else None
    groups = {path: group for _, path, group in shot.lights(settings, frame) if group}
    return model_prim_paths(shot.stage), dict(sorted(groups.items()))


def index_settings(request: RenderRequest, recipe: Recipe) -> tuple[str, bool]:
    """The frame's one index: its mode and whether it keeps Σ. The request's flags win;
    else the products' (records if any product asks for per-contribution records, Σ if
    any asks for it: the index serves them all)."""
    products = [product.index for product in recipe.products]
    mode = request.index_mode or ("records" if any(index.mode == "records" for index in products) else "merged")
    covariance = request.index_covariance or (
        "sigma" if any(index.covariance == "sigma" for index in products) else "norms")
    return mode, covariance == "sigma"


def resolve_recipe(request: RenderRequest, frame: float | None = None, shot=None) -> Recipe:
    """The request's recipe: its stage's own with its recipe layers over it, or the beauty
    alone for a stage without any (per-light layers list the lights at ``frame``)."""
    from ..stage import open_request

    shot = shot or open_request(request)
    return shot.recipe(settings=request.settings, camera=request.camera, per_light=request.per_light, frame=frame)


def has_conditions(recipe: Recipe) -> bool:
    from ..recipe.expressions import covariance_needs

    return any(covariance_needs(lpe.compile(text))[0]
               for product in recipe.products for text in product.expressions().values())


def prepare_frame(plan: FramePlan, shot=None):
    """Read the plan's frame (from ``shot``, an open Shot of the plan's request, else the
    stage is opened) and build its Embree scene: the tracer's Integrator."""
    from ..stage import open_request
    from ..trace import prepare

    shot = shot or open_request(plan.request)
    spec = shot.spec(plan.frame, plan.recipe, camera=plan.camera, resolution=plan.resolution,
                     auto_camera=plan.request.auto_camera)
    return prepare(shot.scene(spec, subdiv_level=plan.request.subdiv_level), spec, plan.trace)


def frame_data(plan: FramePlan, integrator, threads: int | None = None) -> dict:
    """What the frame's raw vars need from the tracer besides the beauty: the data AOVs
    (name → image) and how each Cryptomatte names what the beauty's samples hit (source →
    trace.cryptomatte.CoverageNames; :meth:`FrameAssembler.deliver` ranks them from the
    film's first hits)."""
    from ..layers.cryptomatte import asset_roots
    from ..trace import render_data_aovs
    from ..trace.cryptomatte import coverage_names

    data: dict = render_data_aovs(integrator, plan.data_aovs, threads=threads)
    roots = asset_roots(integrator.world.object_paths, plan.model_paths) if "CryptoAsset" in plan.cryptomattes else None
    data.update(coverage_names(integrator, plan.cryptomattes, asset_paths=roots))
    return data


class FrameAssembler:
    """Receives a frame's batches in path order (the index writer's own thread writes them as
    they come); then closes the index and delivers.

    Use as a context manager: an exception (or Ctrl-C) before :meth:`deliver` stops the
    writer's thread, removes the index's temporary file and leaves no output behind.
    """

    def __init__(self, plan: FramePlan):
        self.plan = plan
        width, height = plan.resolution
        self.film = Film(width * height, plan.trace.spp, plan.trace.first_bounce_norms, plan.trace.guides)
        self.writer = (PathIndexWriter(plan.index_path, plan.manifest, plan.trace.norm_bounces,
                                       mode="merged" if plan.trace.merge_records else "records",
                                       sigma=plan.trace.record_sigma) if plan.trace.record_paths else None)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, kind, error, traceback) -> None:
        if kind is not None and self.writer is not None:
            self.writer.abort()

    def add(self, batch) -> None:
        self.film.add(batch)
        if self.writer is not None:
            self.writer.add(batch.records)

    def images(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The beauty (h, w, 4) and the mean first-bounce norms (h, w, 3) or None."""
        return self.film.images(*self.plan.resolution)

    def cryptomattes(self, data: dict) -> dict:
        """``data`` (frame_data's) with each Cryptomatte's CoverageNames replaced by its
        ranks (layers.cryptomatte.Cryptomatte), counted from the film's first hits."""
        if not self.plan.cryptomattes:
            return data
        from ..layers.cryptomatte import rank
        from ..trace.cryptomatte import coverage

        plan, hits = self.plan, self.film.first_hits()
        ranked = dict(data)
        for source in plan.cryptomattes:
            found = coverage(data[source], hits, plan.trace.spp)
            ranked[source] = rank(found.names, found.pixel, found.name, found.weight, plan.resolution,
                                  plan.request.cryptomatte_depth, type_name=source)
        return ranked

    def deliver(self, vocabulary, data: dict[str, np.ndarray], object_paths: Sequence[str], *,
                show_progress: bool = False) -> list[Delivered]:
        """Close the index, then write every product (EXR + previews), ``data`` being
        :func:`frame_data`'s. They appear together, the index last, or (on an error, Ctrl-C or
        SIGTERM) none of them does."""
        plan = self.plan
        data = self.cryptomattes(data)
        rgba, _ = self.images()
        render_id = render_identity(plan.manifest, rgba)
        metadata = {**plan.metadata, "renderId": render_id}
        if "primId" in data:
            metadata["primPaths"] = json.dumps(list(object_paths), separators=(",", ":"))
        with OutputSet() as outputs:
            index = None
            if self.writer is not None:
                self.writer.manifest["render_id"] = render_id
                self.writer.close(vocabulary)
                index = self.writer.opened()  # its tables from the footer in memory, not parsed again
            check_beauty(rgba, index, plan.stage)
            delivered = deliver(index, plan.recipe, rgba, plan.outputs, data=data, metadata=metadata,
                                previews=plan.request.previews, nuke_scripts=plan.request.nuke_scripts,
                                show_progress=show_progress, guides=self.film.guides(*plan.resolution))
            if not plan.request.keep_index:
                outputs.discard(plan.index_path)
        return delivered


def render_identity(manifest: dict, rgba: np.ndarray) -> str:
    """The render's id (32 hex digits): SHA-256 of what was asked (the index manifest) and of
    the beauty it gave. The index manifest (``render_id``) and every EXR part
    (``pxrLayers/renderId``) carry it, so ``extract`` can tell an index from the EXR of
    another render written into the same folder. Derived rather than random: rendering the
    same thing again gives byte-identical files (a resumed job equals an uninterrupted one).

    rgba: (h, w, 4) float32, the beauty as written.
    """
    digest = hashlib.sha256(json.dumps(manifest, sort_keys=True, default=str).encode())
    digest.update(np.ascontiguousarray(rgba, dtype=np.float32).tobytes())
    return digest.hexdigest()[:32]


_CULPRITS_NAMED = 3


def check_beauty(rgba: np.ndarray, index: PathIndex | None, stage: Path) -> None:
    """Refuse a beauty with NaN or infinite pixels, and warn of negative ones (a wide-gamut
    HDRI can hold small negative texels), naming the paths (and so the prims: objects,
    materials, lights) whose contributions made them, from the index.

    rgba : (h, w, 4) float32. Raises RenderSettingsError for non-finite pixels.
    """
    colour = rgba[..., :3]
    non_finite = ~np.isfinite(colour).all(axis=-1)
    negative = (colour < 0.0).any(axis=-1) & ~non_finite
    for bad, fatal, what in ((non_finite, True, "NaN or infinite"), (negative, False, "negative")):
        if not bad.any():
            continue
        y, x = np.argwhere(bad)[0]
        message = (f"{stage}: the beauty has {int(bad.sum())} {what} pixels (the first at x={x}, y={y}), brought "
                   f"by the paths {_culprit_paths(index, fatal)}: check the values of those prims (light "
                   "intensity, exposure, colour, textures; material inputs)")
        if fatal:
            raise RenderSettingsError(message + "; nothing was written")
        log.warning(message)


def _culprit_paths(index: PathIndex | None, non_finite: bool) -> str:
    """The path classes of the index with most non-finite (else negative) contributions."""
    if index is None:
        return "(unknown: the render kept no path index)"
    culprits: dict[int, int] = {}
    for chunk in index.records(norms=False):
        wrong = ~np.isfinite(chunk.rgb).all(axis=1) if non_finite else (chunk.rgb < 0.0).any(axis=1)
        ids, counts = np.unique(chunk.class_id[wrong], return_counts=True)
        for class_id, count in zip(ids.tolist(), counts.tolist()):
            culprits[class_id] = culprits.get(class_id, 0) + count
    named = sorted(culprits, key=culprits.get, reverse=True)[:_CULPRITS_NAMED]
    return "; ".join(path_text(index.classes[class_id].events) for class_id in named) if named else "unknown"


# -- a black picture's reason --------------------------------------------------------------

BLACK_LEVEL = 1e-6
"""A beauty none of whose colour values is above this (linear; 20 stops under 1, nothing a
display shows) is a black picture, whose reason :func:`warn_of_black_picture` looks for."""

INSIDE_SHARE = 0.95
"""Share of the camera's probe rays (trace.aovs.camera_surroundings) that must hit back faces
for the camera to be inside closed geometry: nearly all, leaving a few to slip through seams."""

ENCLOSING_NAMED = 3
"""Prims a camera-inside warning names at most (those whose insides most probe rays hit)."""


def warn_of_black_picture(plan: FramePlan, rgba: np.ndarray, integrator=None) -> str | None:
    """Warn (one line, logged and returned) when the beauty is black for a reason the
    render can see: no camera ray hits anything (the camera looks away from the scene, or
    clips it), or the camera is inside closed geometry (nearly every ray through its film
    hits the back of a surface: INSIDE_SHARE), naming the prims around it. A black picture
    because no light sends anything is told when the lights are built (trace.lights.darkness).

    rgba       : (h, w, 4) float32, the traced beauty
    integrator : the frame's trace.Integrator; None (a job's committed tiles) prepares the
                 frame again, for a black picture only
    """
    if not (rgba[..., :3] <= BLACK_LEVEL).all():  # NaN is not black: check_beauty refuses it
        return None
    if not (rgba[..., 3] > 0).any():
        reason = (f"no ray of the camera {plan.camera} hits anything (look at its position, its direction and its "
                  "clipping range) and no light shows in the background")
    else:
        from ..trace.aovs import camera_surroundings

        around = camera_surroundings(integrator or prepare_frame(plan))
        if around.back_faces < INSIDE_SHARE * around.rays:
            return None
        named = ", ".join(around.enclosing[:ENCLOSING_NAMED])
        more = len(around.enclosing) - ENCLOSING_NAMED
        reason = (f"the camera {plan.camera} is inside {named}{f' and {more} more' if more > 0 else ''}: "
                  f"{around.back_faces} of {around.rays} rays through its film hit the back of a surface")
    message = f"{plan.stage}: the picture is black: {reason}"
    log.warning(message)
    return message


def file_sha256(path: Path) -> str:
    """SHA-256 of the stage's root layer file (not of the layers it composes)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()



# -- the one entry ----------------------------------------------------------------------------


class FrameSource(Protocol):
    """Where a frame's batches and data come from (:func:`render_frame`)."""

    def trace(self, add: Callable) -> None:
        """Call ``add(batch)`` for every BatchResult of the frame, in path order."""

    def frame_data(self) -> tuple[dict, object, tuple[str, ...]]:
        """(:func:`frame_data`'s dict, the EventVocabulary, the object paths by primId)."""


class LocalTrace:
    """A frame traced in this process, on ``threads`` threads (default: every core this
    process may use, :func:`pxr_layers.cores.available_cores`)."""

    def __init__(self, plan: FramePlan, shot=None, *, threads: int | None = None, show_progress: bool = False):
        from ..cores import available_cores

        self.plan = plan
        self.threads = threads or available_cores()
        self.show_progress = show_progress
        self.integrator = prepare_frame(plan, shot)

    def trace(self, add: Callable) -> None:
        from ..progress import Progress
        from ..trace import trace_pixels

        plan = self.plan
        progress = Progress(plan.pixels * plan.trace.spp, "render", enabled=self.show_progress)
        log.info("rendering %d×%d at %d spp on %d thread%s", *plan.resolution, plan.trace.spp, self.threads,
                 "" if self.threads == 1 else "s")

        def counted(batch) -> None:
            add(batch)
            progress.advance(len(batch.rgb) * plan.trace.spp)

        trace_pixels(self.integrator, 0, plan.pixels, counted, threads=self.threads)

    def frame_data(self) -> tuple[dict, object, tuple[str, ...]]:
        integrator = self.integrator
        return (frame_data(self.plan, integrator, threads=self.threads), integrator.vocabulary,
                tuple(integrator.world.object_paths))


@dataclass(frozen=True)
class FrameResult:
    """What :func:`render_frame` wrote and traced.

    plan       : the frame's resolved plan (outputs, index path, trace settings, recipe)
    delivered  : every product written (EXR, previews, Nuke script), in the recipe's order
    rgba       : (h, w, 4) float32, the beauty as written (linear radiance; A = coverage)
    first_bounce_norms : (h, w, 3) float32 mean C (1/m), T (cycles/m), R (cycles/rad) of
                 the first bounce (NaN where no sample scatters), or None unless the request's
                 ``debug_covariance``
    data       : the data AOVs and Cryptomattes (name → image or ranks) the products hold
    vocabulary : the frame's event names (paths.events.EventVocabulary)
    object_paths : the prim path of each object, indexed by primId
    rays, seconds : rays cast, and the wall-clock seconds of trace and delivery
    guides     : the denoiser's (albedo, normal), each (h, w, 3) float32 (trace/guides.py),
                 or None unless the request's ``denoise``
    """

    plan: FramePlan
    delivered: list[Delivered]
    rgba: np.ndarray
    first_bounce_norms: np.ndarray | None
    data: dict
    vocabulary: object
    object_paths: tuple[str, ...]
    rays: int
    seconds: float
    guides: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def index_path(self) -> Path | None:
        """The path index written, or None (``keep_index`` False)."""
        return self.plan.index_path if self.plan.request.keep_index else None


def render_frame(request: RenderRequest, frame: float | None = None, *, output: str | os.PathLike | None = None,
                 threads: int | None = None, show_progress: bool = False, plan: FramePlan | None = None,
                 source: FrameSource | None = None) -> FrameResult:
    """Render one frame of ``request`` and deliver its products: the one way a frame is made.

    output  : a folder for the products (their productName) and the index, or one product's
              .exr path (``pxr-layers render -o``); default the current folder
    frame   : the time code (None: the stage's start)
    threads : trace threads (default: every core this process may use)
    plan    : an already resolved plan (a job's, whose output names are its own); else
              :func:`plan_frame` resolves it from ``output``
    source  : where the batches come from (default: :class:`LocalTrace`, here)

    The products and the index appear together or not at all (an error, Ctrl-C or SIGTERM
    leaves none); with ``debug_covariance``, STEM.covariance.exr and its maps after them.
    """
    start = time.perf_counter()
    shot = None
    if plan is None:
        from ..stage import open_request

        shot = open_request(request)  # the stage is composed and read once for the whole frame
        directory, exr = output_target(output)
        plan = plan_frame(request, frame, shot=shot, directory=directory, exr=exr)
    source = source or LocalTrace(plan, shot, threads=threads, show_progress=show_progress)
    with FrameAssembler(plan) as assembler:
        source.trace(assembler.add)
        # LocalTrace holds the frame's Integrator; a job's committed tiles do not (None)
        warn_of_black_picture(plan, assembler.images()[0], getattr(source, "integrator", None))
        data, vocabulary, object_paths = source.frame_data()
        delivered = assembler.deliver(vocabulary, data, object_paths, show_progress=show_progress)
    rgba, norms = assembler.images()
    rays = assembler.film.rays  # the film counts every batch's rays
    if request.debug_covariance:
        from ..layers.debug import write_covariance_debug

        write_covariance_debug(plan.index_path.with_suffix(".exr"), norms, plan.metadata)
    seconds = time.perf_counter() - start
    log.info("rendered %d×%d at %d spp in %.1fs (%.2f M rays/s)", *plan.resolution, plan.trace.spp, seconds,
             rays / max(seconds, 1e-9) / 1e6)
    return FrameResult(plan, delivered, rgba, norms, data, vocabulary, object_paths, rays, seconds,
                       assembler.film.guides(*plan.resolution))
