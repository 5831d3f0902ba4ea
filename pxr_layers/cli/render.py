"""`pxr-layers render`: path-trace a USD stage into a beauty EXR."""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import math
import os
from pathlib import Path

from .. import __version__, lpe
from ..errors import RecipeError
from ..layers.debug import write_covariance_debug
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
from ..recipe.model import BEAUTY_RAW_SOURCE, PER_LIGHT_MODES, Layer, Product, Recipe
from ..recipe.presets import PRESETS, preset
from ..trace import DATA_AOVS, TraceSettings
from ..trace import render as trace_render

HELP = "render a USD stage: beauty, path index, and the layers of its recipe"
DESCRIPTION = (
    "Path-trace STAGE (any USD file) with Embree, record the path index STEM.pxlidx, and write "
    "every RenderProduct of the recipe as a multipart EXR (part 0 'rgba' the beauty, one part per "
    "RenderVar) with OCIO previews beside it. The recipe is the stage's own UsdRender settings, "
    "or --recipe layers composed over it; a stage without one gives a beauty EXR. Camera and "
    "resolution come from the recipe's products, else the settings, else the stage's first "
    "camera; the flags below override them."
)
DEFAULT_SPP = 64
DEFAULT_MAX_DEPTH = 8
DEFAULT_NORM_BOUNCES = 5
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("stage", metavar="STAGE", help="the USD stage to render (.usd, .usda, .usdc, .usdz)")
    add_render_flags(parser)


def add_render_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "-o", "--output", metavar="OUT",
        help="a directory that receives the recipe's products (their productName, #### = frame) "
        "and STEM.pxlidx; or, for a recipe of one product, the .exr path itself. Default: the "
        "current directory",
    )
    parser.add_argument("--recipe", action="append", default=[], metavar="RECIPE",
                        help="a USD layer recipe composed over the stage (a file, or a preset name: "
                        f"{', '.join(PRESETS)}); repeat for more, the first is the strongest")
    parser.add_argument("--settings", metavar="PRIM",
                        help="the RenderSettings prim to use (default: the renderSettingsPrimPath of the "
                        "last --recipe that sets one, else the stage's)")
    parser.add_argument("--per-light", choices=PER_LIGHT_MODES, metavar="MODE",
                        help="add per-light layers to every product: none, lights (one layer per light) "
                        "or groups (one per pxrLayers:lightGroup); default: each product's pxrLayers:perLight")
    parser.add_argument("--spp", type=_positive, default=DEFAULT_SPP, metavar="N",
                        help=f"samples per pixel (default {DEFAULT_SPP})")
    parser.add_argument("--max-depth", type=_non_negative, default=DEFAULT_MAX_DEPTH, metavar="N",
                        help=f"most scattering events per path; 1 = direct light only (default {DEFAULT_MAX_DEPTH})")
    parser.add_argument("--resolution", type=_positive, nargs=2, metavar=("W", "H"),
                        help="image size in pixels (default: the recipe's, else 512 512)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    parser.add_argument("--frame", type=float, metavar="F",
                        help="time code to render (default: the stage's start time code)")
    parser.add_argument("--camera", metavar="PRIM", help="camera prim path (default: the recipe's camera)")
    parser.add_argument("--threads", type=_positive, metavar="N", help="render threads (default: all cores)")
    parser.add_argument("--norm-bounces", type=_non_negative, metavar="N",
                        help="events per path (camera side) whose covariance norms C, T, R the path "
                        "index keeps (default: the products' pxrLayers:index:bounces, else "
                        f"{DEFAULT_NORM_BOUNCES}; 0: none)")
    parser.add_argument("--no-index", action="store_true",
                        help="do not keep the path index STEM.pxlidx (it is what lets `pxr-layers extract` "
                        "cut new layers later without rendering again)")
    parser.add_argument("--aggregate-index", action="store_true",
                        help="merge the index records of one pixel that share their path class and "
                        "norms (as stored, float16) into one: the index grows less than linearly with "
                        "spp; layers are unchanged, the sample number of each record is lost")
    parser.add_argument("--no-previews", action="store_true", help="do not write the PNG previews and contact sheets")
    parser.add_argument("--debug-covariance", action="store_true",
                        help="also write the first bounce's covariance norms beside the index: "
                        "STEM.covariance.exr (channels C 1/m, T cycles/m, R cycles/rad) and "
                        "STEM.covariance.{C,T,R}.png colour maps")


def run(args: argparse.Namespace) -> int:
    for delivered in render_stage(Path(args.stage), args):
        print(delivered.exr)
    return 0


def render_stage(stage_path: Path, args: argparse.Namespace, recipes: list[Path] | None = None) -> list[Delivered]:
    """Load, render, index and deliver every product of the recipe; returns what was written.

    recipes: recipe layers to compose over the stage (default: args.recipe).
    """
    from ..recipe import load_recipe  # these import pxr: only when needed
    from ..stage import load_stage

    recipe_layers = [preset_or_file(text) for text in args.recipe] if recipes is None else recipes
    shot_settings = None if recipe_layers else args.settings
    scene, spec = load_stage(stage_path, frame=args.frame, camera=args.camera, settings=shot_settings)
    if recipe_layers or args.settings or spec.settings_path:
        recipe = load_recipe(stage_path, args.settings, recipe_layers=recipe_layers, camera=args.camera,
                             per_light=args.per_light)
        camera, resolution = _view(recipe)
        if camera != spec.camera.path:
            scene, spec = load_stage(stage_path, frame=args.frame, camera=camera, settings=shot_settings)
        spec = dataclasses.replace(spec, resolution=resolution)
    else:  # a stage without a recipe: its beauty alone, STEM.exr
        product = Product(name=stage_path.stem, output_name=f"{stage_path.stem}.exr", camera=spec.camera.path,
                          resolution=spec.resolution, layers=(Layer("color", "raw", BEAUTY_RAW_SOURCE),))
        recipe = Recipe(products=(product,))
    if args.resolution:
        spec = dataclasses.replace(spec, resolution=tuple(args.resolution))
    check_raw_sources(recipe, DATA_AOVS, "the renderer does not produce")

    frame = args.frame
    directory, exr = _output(args.output)
    outputs = plan_outputs(recipe, frame, directory, exr)
    first = outputs[recipe.products[0].name]
    index_path = first.with_suffix(INDEX_SUFFIX) if exr else directory / f"{stage_path.stem}{frame_suffix(frame)}{INDEX_SUFFIX}"
    norm_bounces = args.norm_bounces
    if norm_bounces is None:
        norm_bounces = max(product.index.bounces for product in recipe.products)
        if _has_conditions(recipe) and norm_bounces < args.max_depth:
            # A condition under `.*` (the paper's "last bounce on ...") may test any event up
            # to the path's last: keep the norms of every event a path can have.
            log.info("the recipe has covariance conditions: the index keeps the norms of all %d bounces",
                     args.max_depth)
            norm_bounces = args.max_depth
    if args.debug_covariance:
        norm_bounces = max(norm_bounces, 1)  # the pictures need the first bounce
    settings = TraceSettings(spp=args.spp, max_depth=args.max_depth, seed=args.seed, norm_bounces=norm_bounces)
    metadata = {
        "version": __version__,
        "stage": str(stage_path.resolve()),
        "camera": spec.camera.path,
        "frame": "default" if math.isnan(scene.frame) else repr(scene.frame),
        "spp": str(settings.spp),
        "maxDepth": str(settings.max_depth),
        "seed": str(settings.seed),
    }
    manifest = {
        **metadata, "stage_sha256": file_sha256(stage_path), "resolution": list(spec.resolution),
        "spp": settings.spp, "seed": settings.seed, "max_depth": settings.max_depth,
        "beauty": os.path.relpath(first, index_path.parent),
    }
    # The layers are cut from the index, so a recipe with lpe layers needs one even with --no-index.
    needs_index = not args.no_index or any(product.expressions() for product in recipe.products)
    settings = dataclasses.replace(settings, record_paths=needs_index)
    writer = PathIndexWriter(index_path, manifest, settings.norm_bounces, aggregate=args.aggregate_index) \
        if needs_index else None
    try:
        result = trace_render(scene, spec, settings, threads=args.threads, show_progress=args.show_progress,
                              on_batch=writer and (lambda batch: writer.add(batch.records)),
                              data_aovs=tuple(raw_sources(recipe)))
        if writer:
            writer.close(result.vocabulary)
    except BaseException:
        if writer:
            writer.abort()
        raise
    if "primId" in result.data:
        metadata["primPaths"] = json.dumps(result.object_paths, separators=(",", ":"))
    if not args.no_index:
        metadata["index"] = os.path.relpath(index_path, first.parent)
    try:
        delivered = deliver(PathIndex(index_path) if writer else None, recipe, result.rgba, outputs,
                            data=result.data, metadata=metadata, previews=not args.no_previews,
                            show_progress=args.show_progress)
    finally:
        if args.no_index:
            index_path.unlink(missing_ok=True)
    if args.debug_covariance:
        write_covariance_debug(index_path.with_suffix(".exr"), result.first_bounce_norms, metadata)
    return delivered


def preset_or_file(text: str) -> Path:
    """A --recipe argument: an existing file, else a preset name."""
    path = Path(text)
    if path.exists() or text not in PRESETS:
        if not path.is_file():
            raise RecipeError(f"recipe not found (and not a preset: {', '.join(PRESETS)})", file=text)
        return path
    return preset(text)


def _has_conditions(recipe: Recipe) -> bool:
    from ..recipe.expressions import covariance_needs

    return any(covariance_needs(lpe.compile(text))[0]
               for product in recipe.products for text in product.expressions().values())


def _view(recipe: Recipe) -> tuple[str, tuple[int, int]]:
    """The camera and resolution every product renders (one render feeds all products)."""
    views = {(product.camera, product.resolution) for product in recipe.products}
    if len(views) > 1:
        described = "; ".join(f"{p.prim_path or p.name}: {p.camera} at {p.resolution[0]}x{p.resolution[1]}"
                              for p in recipe.products)
        raise RecipeError("the products ask for different cameras or resolutions, and one render feeds them "
                          f"all ({described}): render them with separate --settings", file=recipe.file or None,
                          prim=recipe.settings_path or None)
    return views.pop()


def _output(output: str | None) -> tuple[Path, Path | None]:
    """(directory, explicit .exr path or None) from -o."""
    if output and output.lower().endswith(".exr"):
        return Path(output).parent, Path(output)
    return Path(output or "."), None


def file_sha256(path: Path) -> str:
    """SHA-256 of the stage's root layer file (not of the layers it composes)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _positive(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _non_negative(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text}")
    return value
