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

import dataclasses
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
from ..errors import RecipeError
from ..layers.deliver import (
    Delivered,
    check_raw_sources,
    deliver,
    frame_suffix,
    plan_outputs,
    raw_sources,
)
from ..paths.format import SUFFIX as INDEX_SUFFIX
from ..paths.reader import PathIndex
from ..paths.writer import PathIndexWriter
from ..recipe.model import BEAUTY_RAW_SOURCE, Layer, Product, Recipe
from ..trace import DATA_AOVS, Film, TraceSettings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FramePlan:
    """Everything one frame needs, resolved; plain data (it travels to Dask workers).

    stage, frame   : the USD file and the time code (None: the stage's start)
    shot_settings  : the stage's RenderSettings prim for load_stage (None: its default)
    camera         : the camera prim path; resolution : (width, height) pixels
    trace          : the tracer's settings (spp, depth, seed, norm bounces, recording)
    recipe         : the resolved recipe; outputs : product name → EXR path
    index_path     : where the path index goes; keep_index : False removes it after
                     delivery (the layers are cut from it all the same)
    data_aovs      : the raw sources the tracer renders beside the beauty (depth, ...)
    metadata       : ``pxrLayers/`` attributes of every EXR part
    manifest       : the path index's manifest
    """

    stage: Path
    frame: float | None
    shot_settings: str | None
    camera: str
    resolution: tuple[int, int]
    trace: TraceSettings
    recipe: Recipe
    outputs: dict[str, Path]
    index_path: Path
    keep_index: bool = True
    aggregate_index: bool = False
    previews: bool = True
    data_aovs: tuple[str, ...] = ()
    metadata: dict[str, str] = field(default_factory=dict)
    manifest: dict = field(default_factory=dict)

    @property
    def pixels(self) -> int:
        return self.resolution[0] * self.resolution[1]

    @property
    def files(self) -> tuple[Path, ...]:
        """The deliverables (EXRs and index; previews go beside the EXRs)."""
        return (*self.outputs.values(), *((self.index_path,) if self.keep_index else ()))


def plan_frame(
    stage: Path,
    frame: float | None,
    *,
    recipe_layers: Sequence[Path] = (),
    settings: str | None = None,
    camera: str | None = None,
    per_light: str | None = None,
    resolution: tuple[int, int] | None = None,
    spp: int,
    max_depth: int,
    seed: int,
    norm_bounces: int | None = None,
    directory: Path,
    exr: Path | None = None,
    index_path: Path | None = None,
    product_path: Callable[[Product], Path] | None = None,
    keep_index: bool = True,
    aggregate_index: bool = False,
    previews: bool = True,
    recipe: Recipe | None = None,
    stage_sha256: str | None = None,
) -> FramePlan:
    """Resolve one frame. The recipe is ``settings`` of the stage with ``recipe_layers``
    over it; a stage without one gives its beauty alone (STEM.exr). ``recipe``: an already
    resolved recipe, ``stage_sha256``: the stage file's hash (a job works both out once for
    all its frames).

    Outputs: ``product_path(product)`` if given, else :func:`plan_outputs` (``exr``: one
    product's explicit file). The index: ``index_path``, else beside ``exr``, else
    ``directory/STEM[.FFFF].pxlidx``. norm_bounces None: the products' index bounces,
    raised to ``max_depth`` when a layer has a covariance condition (a condition under
    ``.*`` may test any event of the path).
    """
    stage = Path(stage)
    shot_settings = None if recipe_layers else settings
    if recipe is None:
        recipe = resolve_recipe(stage, recipe_layers=recipe_layers, settings=settings, camera=camera,
                                per_light=per_light, frame=frame)
    view_camera, view_resolution = recipe_view(recipe)
    resolution = tuple(resolution or view_resolution)
    check_raw_sources(recipe, DATA_AOVS, "the renderer does not produce")

    if product_path is not None:
        outputs = {product.name: Path(product_path(product)) for product in recipe.products}
    else:
        outputs = plan_outputs(recipe, frame, directory, exr)
    first = outputs[recipe.products[0].name]
    if index_path is None:
        index_path = exr.with_suffix(INDEX_SUFFIX) if exr else directory / f"{stage.stem}{frame_suffix(frame)}{INDEX_SUFFIX}"

    if norm_bounces is None:
        norm_bounces = max(product.index.bounces for product in recipe.products)
        if has_conditions(recipe) and norm_bounces < max_depth:
            log.info("the recipe has covariance conditions: the index keeps the norms of all %d bounces", max_depth)
            norm_bounces = max_depth
    # The layers are cut from the index, so lpe layers need one even when it is not kept.
    record = keep_index or any(product.expressions() for product in recipe.products)
    trace = TraceSettings(spp=spp, max_depth=max_depth, seed=seed, norm_bounces=norm_bounces, record_paths=record)
    metadata = {
        "version": __version__,
        "stage": str(stage.resolve()),
        "camera": view_camera,
        "frame": "default" if frame is None else repr(float(frame)),
        "spp": str(spp),
        "maxDepth": str(max_depth),
        "seed": str(seed),
    }
    if keep_index:
        metadata["index"] = os.path.relpath(index_path, first.parent)
    manifest = {
        **metadata, "stage_sha256": stage_sha256 or file_sha256(stage), "resolution": list(resolution), "spp": spp, "seed": seed,
        "max_depth": max_depth, "beauty": os.path.relpath(first, index_path.parent),
    }
    manifest.pop("index", None)
    return FramePlan(stage, frame, shot_settings, view_camera, resolution, trace, recipe, outputs, index_path,
                     keep_index, aggregate_index, previews, tuple(raw_sources(recipe)), metadata, manifest)


def resolve_recipe(stage: Path, *, recipe_layers: Sequence[Path] = (), settings: str | None = None,
                   camera: str | None = None, per_light: str | None = None, frame: float | None = None) -> Recipe:
    """The stage's recipe with ``recipe_layers`` over it. A stage without any gives its
    beauty alone (STEM.exr), at the stage's camera and resolution (read at ``frame``)."""
    from ..recipe import load_recipe
    from ..recipe.loader import has_recipe

    if recipe_layers or settings or has_recipe(stage):
        return load_recipe(stage, settings, recipe_layers=list(recipe_layers), camera=camera, per_light=per_light)
    from ..stage import load_stage

    _, spec = load_stage(stage, frame=frame, camera=camera)
    product = Product(name=stage.stem, output_name=f"{stage.stem}.exr", camera=spec.camera.path,
                      resolution=spec.resolution, layers=(Layer("color", "raw", BEAUTY_RAW_SOURCE),))
    return Recipe(products=(product,))


def recipe_view(recipe: Recipe) -> tuple[str, tuple[int, int]]:
    """The camera and resolution every product renders (one render feeds all products)."""
    views = {(product.camera, product.resolution) for product in recipe.products}
    if len(views) > 1:
        described = "; ".join(f"{p.prim_path or p.name}: {p.camera} at {p.resolution[0]}x{p.resolution[1]}"
                              for p in recipe.products)
        raise RecipeError("the products ask for different cameras or resolutions, and one render feeds them "
                          f"all ({described}): render them with separate --settings", file=recipe.file or None,
                          prim=recipe.settings_path or None)
    return views.pop()


def has_conditions(recipe: Recipe) -> bool:
    from ..recipe.expressions import covariance_needs

    return any(covariance_needs(lpe.compile(text))[0]
               for product in recipe.products for text in product.expressions().values())


def prepare_frame(plan: FramePlan):
    """Load the stage at the plan's frame and build its Embree scene: the tracer's Integrator."""
    from ..stage import load_stage
    from ..trace import prepare

    scene, spec = load_stage(plan.stage, frame=plan.frame, camera=plan.camera, settings=plan.shot_settings)
    spec = dataclasses.replace(spec, resolution=plan.resolution)
    return prepare(scene, spec, plan.trace)


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
                                       aggregate=plan.aggregate_index) if plan.trace.record_paths else None)

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

    def deliver(self, vocabulary, data: dict[str, np.ndarray], object_paths: Sequence[str], *,
                show_progress: bool = False) -> list[Delivered]:
        """Close the index, then write every product (EXR + previews)."""
        plan = self.plan
        if self.writer is not None:
            self.writer.close(vocabulary)
        metadata = dict(plan.metadata)
        if "primId" in data:
            metadata["primPaths"] = json.dumps(list(object_paths), separators=(",", ":"))
        rgba, _ = self.images()
        try:
            return deliver(PathIndex(plan.index_path) if self.writer else None, plan.recipe, rgba, plan.outputs,
                           data=data, metadata=metadata, previews=plan.previews, show_progress=show_progress)
        finally:
            if not plan.keep_index:
                plan.index_path.unlink(missing_ok=True)


def file_sha256(path: Path) -> str:
    """SHA-256 of the stage's root layer file (not of the layers it composes)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()

