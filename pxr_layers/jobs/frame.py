"""One frame of a shot, from a plan to its delivered files: what `pxr-layers render` does
for one frame, and what every frame of a job does with its batches spread over workers.

* :func:`plan_frame` resolves the recipe (over the stage), the camera, the resolution, the
  trace settings and every output path into a :class:`FramePlan`: plain, picklable data.
* :func:`prepare_frame` loads the stage at the frame and builds its Embree scene (a
  worker does this once per frame).
* :class:`FrameAssembler` takes the frame's batches **in path order** (the film sums and
  the path index are written from them; the same batches in the same order give the same
  bytes) and then delivers the recipe's products with :func:`pxr_layers.layers.deliver`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

import numpy as np

from .. import __version__, lpe
from ..layers.deliver import (
    Delivered,
    check_raw_sources,
    deliver,
    frame_suffix,
    plan_outputs,
    raw_sources,
)
from ..errors import RenderSettingsError
from ..outputs import OutputSet
from ..paths.events import path_text
from ..paths.format import SUFFIX as INDEX_SUFFIX
from ..paths.reader import PathIndex
from ..paths.writer import PathIndexWriter
from ..recipe.model import CRYPTOMATTE_SOURCES, DEFAULT_CRYPTOMATTE_DEPTH, MAX_CRYPTOMATTE_DEPTH, Product, Recipe
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
    index_path     : where the path index goes; keep_index : False removes it after
                     delivery (the layers are cut from it all the same)
    data_aovs      : the raw sources the tracer renders beside the beauty (depth, ...)
    metadata       : ``pxrLayers/`` attributes of every EXR part
    manifest       : the path index's manifest
    cryptomattes   : the Cryptomatte sources of the recipe (CryptoObject, ...)
    cryptomatte_depth : ranks per pixel of each
    model_paths    : the stage's models (kind component, group, assembly), CryptoAsset's roots
    nuke_scripts   : a Nuke script beside every product (``--nuke-script``)
    """

    request: RenderRequest
    frame: float | None
    camera: str
    resolution: tuple[int, int]
    trace: TraceSettings
    recipe: Recipe
    outputs: dict[str, Path]
    index_path: Path
    keep_index: bool = True
    previews: bool = True
    data_aovs: tuple[str, ...] = ()
    metadata: dict[str, str] = field(default_factory=dict)
    manifest: dict = field(default_factory=dict)
    cryptomattes: tuple[str, ...] = ()
    cryptomatte_depth: int = DEFAULT_CRYPTOMATTE_DEPTH
    model_paths: tuple[str, ...] = ()
    nuke_scripts: bool = False

    @property
    def stage(self) -> Path:
        return self.request.stage

    @property
    def pixels(self) -> int:
        return self.resolution[0] * self.resolution[1]

    @property
    def files(self) -> tuple[Path, ...]:
        """The deliverables (EXRs and index; previews go beside the EXRs)."""
        return (*self.outputs.values(), *((self.index_path,) if self.keep_index else ()))


def plan_frame(
    request: RenderRequest,
    frame: float | None,
    *,
    directory: Path,
    exr: Path | None = None,
    index_path: Path | None = None,
    product_path: Callable[[Product], Path] | None = None,
    keep_index: bool = True,
    previews: bool = True,
    recipe: Recipe | None = None,
    stage_sha256: str | None = None,
    shot=None,
    cryptomattes: tuple[str, ...] = (),
    cryptomatte_depth: int = DEFAULT_CRYPTOMATTE_DEPTH,
    nuke_scripts: bool = False,
) -> FramePlan:
    """Resolve one frame of ``request``. ``recipe``: an already resolved recipe, else read
    from ``shot`` (an open :class:`pxr_layers.stage.Shot`, else the request's stage is
    opened); ``stage_sha256``: the stage file's hash (a job works both out once for all its
    frames).

    Outputs: ``product_path(product)`` if given, else :func:`plan_outputs` (``exr``: one
    product's explicit file). The index: ``index_path``, else beside ``exr``, else
    ``directory/STEM[.FFFF].pxlidx``. Norm bounces: :meth:`RenderRequest.resolved_norm_bounces`.
    ``cryptomattes``: Cryptomatte sources added to every product (``--cryptomatte``), each of
    ``cryptomatte_depth`` ranks (those the recipe asks for too). ``nuke_scripts``: a Nuke
    script beside every product.
    """
    stage = request.stage
    if recipe is None:
        recipe = resolve_recipe(request, frame, shot)
    if cryptomattes:
        recipe = recipe.with_cryptomattes(cryptomattes)
    view_camera, view_resolution = recipe.view()
    resolution = tuple(request.resolution or view_resolution)
    check_raw_sources(recipe, (*DATA_AOVS, *CRYPTOMATTE_SOURCES), "the renderer does not produce")
    sources = raw_sources(recipe)
    crypto_sources = tuple(source for source in sources if source in CRYPTOMATTE_SOURCES)
    if not 1 <= cryptomatte_depth <= MAX_CRYPTOMATTE_DEPTH:
        raise RenderSettingsError(f"the Cryptomatte depth must be 1 to {MAX_CRYPTOMATTE_DEPTH}, not {cryptomatte_depth}")
    model_paths: tuple[str, ...] = ()
    if "CryptoAsset" in crypto_sources:
        from ..stage import open_request
        from ..stage.recipe_reader import model_prim_paths

        model_paths = model_prim_paths((shot or open_request(request)).stage)

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
    # The layers are cut from the index, so lpe layers need one even when it is not kept.
    record = keep_index or any(product.expressions() for product in recipe.products)
    index_mode, sigma = index_settings(request, recipe)
    trace = TraceSettings(spp=request.spp, max_depth=request.max_depth, seed=request.seed, norm_bounces=norm_bounces,
                          record_paths=record, merge_records=record and index_mode == "merged",
                          record_sigma=record and sigma and norm_bounces > 0, first_hits=bool(crypto_sources))
    metadata = {
        "version": __version__,
        "stage": str(stage.resolve()),
        "camera": view_camera,
        "frame": "default" if frame is None else repr(float(frame)),
        "spp": str(request.spp),
        "maxDepth": str(request.max_depth),
        "seed": str(request.seed),
    }
    if request.variants:
        metadata["variants"] = " ".join(str(selection) for selection in request.variants)
    if not request.default_lights:
        metadata["defaultLights"] = "false"
    if keep_index:
        metadata["index"] = os.path.relpath(index_path, first.parent)
    manifest = {
        **metadata, "stage_sha256": stage_sha256 or file_sha256(stage), "resolution": list(resolution),
        "spp": request.spp, "seed": request.seed, "max_depth": request.max_depth,
        "subdiv_level": request.subdiv_level, "beauty": os.path.relpath(first, index_path.parent),
    }
    manifest.pop("index", None)
    return FramePlan(request, frame, view_camera, resolution, trace, recipe, outputs, index_path,
                     keep_index, previews, tuple(source for source in sources if source not in CRYPTOMATTE_SOURCES),
                     metadata, manifest, crypto_sources, cryptomatte_depth, model_paths, nuke_scripts)


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
    spec = shot.spec(plan.frame, plan.recipe, camera=plan.camera, resolution=plan.resolution)
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
    """Receives a frame's batches in path order; then writes the index and delivers.

    Use as a context manager: an exception (or Ctrl-C) before :meth:`deliver` removes the
    index's temporary file and leaves no output behind.
    """

    def __init__(self, plan: FramePlan):
        self.plan = plan
        width, height = plan.resolution
        self.film = Film(width * height, plan.trace.spp, plan.trace.norm_bounces > 0)
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
                                  plan.cryptomatte_depth)
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
                index = PathIndex(self.writer.close(vocabulary), shown_as=plan.index_path)
            check_beauty(rgba, index, plan.stage)
            delivered = deliver(index, plan.recipe, rgba, plan.outputs, data=data, metadata=metadata,
                                previews=plan.previews, nuke_scripts=plan.nuke_scripts, show_progress=show_progress)
            if not plan.keep_index:
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


def file_sha256(path: Path) -> str:
    """SHA-256 of the stage's root layer file (not of the layers it composes)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()

