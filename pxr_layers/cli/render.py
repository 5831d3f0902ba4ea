"""`pxr-layers render`: path-trace a USD stage, index its paths, deliver its recipe's layers."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import PxrLayersError, RecipeError

from ..progress import Progress
from ..recipe.model import (
    COVARIANCE_MODES,
    CRYPTOMATTE_KINDS,
    DEFAULT_CRYPTOMATTE_DEPTH,
    DEFAULT_INDEX_BOUNCES,
    INDEX_MODES,
    MAX_CRYPTOMATTE_DEPTH,
    MAX_INDEX_BOUNCES,
    PER_LIGHT_MODES,
)
from ..recipe.presets import PRESETS, preset
from ..request import (
    DEFAULT_MAX_DEPTH,
    DEFAULT_RESOLUTION,
    DEFAULT_SEED,
    DEFAULT_SPP,
    MAX_PIXELS,
    MAX_SPP,
    DEFAULT_SUBDIV_LEVEL,
    MAX_DEPTH,
    MAX_REFINED_FACES,
    MAX_SUBDIV_LEVEL,
    RenderRequest,
    VariantSelection,
)

if TYPE_CHECKING:
    from ..layers.deliver import Delivered

HELP = "render a USD stage: beauty, path index, and the layers of its recipe"
DESCRIPTION = (
    "Path-trace STAGE (any USD file) with Embree, record the path index STEM.pxlidx, and write "
    "every RenderProduct of the recipe as a multipart EXR (part 0 'rgba' the beauty, one part per "
    "RenderVar) with OCIO previews beside it. The recipe is the stage's own UsdRender settings, "
    "or --recipe layers composed over it; a stage without one gives a beauty EXR. Camera and "
    "resolution come from the recipe's products, else the settings, else the stage's first "
    "camera, else an automatic camera that frames the stage; the flags below override them. A "
    "stage that nothing lights (no light, no emissive material) gets a default rig (a dome and a key). References this USD build "
    "cannot read and missing files are warnings, and the rest renders (--strict: errors)."
)
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
                        "last --recipe that sets one, else the stage's, else its only RenderSettings prim)")
    parser.add_argument("--per-light", choices=PER_LIGHT_MODES, metavar="MODE",
                        help="add per-light layers to every product: none, lights (one layer per light) "
                        "or groups (one per pxrLayers:lightGroup); default: each product's pxrLayers:perLight")
    parser.add_argument("--spp", type=positive_int, default=DEFAULT_SPP, metavar="N",
                        help=f"samples per pixel (default {DEFAULT_SPP}, at most {MAX_SPP})")
    parser.add_argument("--max-depth", type=_non_negative, default=DEFAULT_MAX_DEPTH, metavar="N",
                        help=f"most scattering events per path; 1 = direct light only (default {DEFAULT_MAX_DEPTH}, "
                        f"at most {MAX_DEPTH})")
    parser.add_argument("--resolution", type=positive_int, nargs=2, metavar=("W", "H"),
                        help="image size in pixels (default: the recipe's, else "
                        f"{DEFAULT_RESOLUTION[0]} {DEFAULT_RESOLUTION[1]}; at most {MAX_PIXELS:,} pixels)")
    parser.add_argument("--seed", type=_non_negative, default=DEFAULT_SEED, metavar="N",
                        help=f"random seed (default {DEFAULT_SEED})")
    parser.add_argument("--frame", type=_finite, metavar="F",
                        help="time code to render (default: the stage's start time code)")
    parser.add_argument("--camera", metavar="PRIM", help="camera prim path (default: the recipe's camera)")
    parser.add_argument("--threads", type=positive_int, metavar="N", help="render threads (default: all cores)")
    parser.add_argument("--norm-bounces", type=_non_negative, metavar="N",
                        help="events per path (camera side) whose covariance norms C, T, R the path "
                        "index keeps (default: the products' pxrLayers:index:bounces, else "
                        f"{DEFAULT_INDEX_BOUNCES}, raised to --max-depth when a layer has a covariance "
                        f"condition; 0: none; at most {MAX_INDEX_BOUNCES})")
    parser.add_argument("--subdiv-level", type=_subdiv_level, default=DEFAULT_SUBDIV_LEVEL, metavar="N",
                        help="uniform refinement level of subdivision surfaces (subdivisionScheme "
                        f"catmullClark, loop, bilinear), lowered where a mesh would pass {MAX_REFINED_FACES} "
                        f"faces; 0 renders the cage (default {DEFAULT_SUBDIV_LEVEL}, at most {MAX_SUBDIV_LEVEL})")
    parser.add_argument("--variant", action="append", default=[], type=_variant, metavar="PRIM:SET=VALUE",
                        help="select a variant, e.g. /World/Teapot:modelVariant=Fancy; repeat for more")
    parser.add_argument("--no-default-lights", action="store_true",
                        help="a stage that nothing lights stays unlit (default: it gets a dome and a "
                        "key light under /pxrLayers/defaultLights)")
    parser.add_argument("--strict", action="store_true",
                        help="any composition error (a missing or unreadable reference, payload or "
                        "sublayer) is fatal, exit 1 (default: a warning, and the rest renders)")
    parser.add_argument("--no-index", action="store_true",
                        help="do not keep the path index STEM.pxlidx (it is what lets `pxr-layers extract` "
                        "cut new layers later without rendering again)")
    parser.add_argument("--index-mode", choices=INDEX_MODES, default=None,
                        help="merged (default): one index record per pixel, path class and covariance bin "
                        "(bins of ratio 2^(1/4); the index grows with the distinct classes, not with spp); "
                        "records: one per contribution with its sample number and float16 norms "
                        "(default: the products' pxrLayers:index:mode)")
    parser.add_argument("--index-covariance", choices=COVARIANCE_MODES, default=None,
                        help="norms: the index keeps C, T, R per event; sigma: also the whole 4x4 "
                        "covariance, for conditions on S11 ... S44 (default: the products' "
                        "pxrLayers:index:covariance)")
    parser.add_argument("--no-previews", action="store_true", help="do not write the PNG previews and contact sheets")
    parser.add_argument("--nuke-script", action="store_true",
                        help="also write PRODUCT.nk beside every product: the Nuke script `pxr-layers nuke` writes")
    parser.add_argument("--cryptomatte", type=cryptomatte_list, default=(), metavar="TYPES",
                        help="add Cryptomatte layers to every product, a comma-separated list of "
                        f"{', '.join(CRYPTOMATTE_KINDS)}: CryptoObject (prim paths), CryptoMaterial (bound "
                        "materials), CryptoAsset (model roots by kind, else top-level prims); recipes ask "
                        "with raw RenderVars of those sourceNames (docs/compositing.md)")
    parser.add_argument("--cryptomatte-depth", type=_cryptomatte_depth, default=DEFAULT_CRYPTOMATTE_DEPTH,
                        metavar="N", help="ids per pixel of every Cryptomatte layer, two per part NAME00, NAME01, "
                        f"... (default {DEFAULT_CRYPTOMATTE_DEPTH}, at most {MAX_CRYPTOMATTE_DEPTH})")
    parser.add_argument("--debug-covariance", action="store_true",
                        help="also write the first bounce's covariance norms beside the index: "
                        "STEM.covariance.exr (channels C 1/m, T cycles/m, R cycles/rad) and "
                        "STEM.covariance.{C,T,R}.png colour maps")


def run(args: argparse.Namespace) -> int:
    for delivered in render_stage(Path(args.stage), args):
        print(delivered.exr)
        if delivered.nuke_script:
            print(delivered.nuke_script)
    return 0


def request_from_args(stage_path: Path, args: argparse.Namespace) -> RenderRequest:
    """The render request the flags describe."""
    return RenderRequest(
        stage=stage_path, recipe_layers=tuple(preset_or_file(text) for text in args.recipe),
        variants=tuple(args.variant), settings=args.settings, camera=args.camera, per_light=args.per_light,
        resolution=tuple(args.resolution) if args.resolution else None, spp=args.spp, max_depth=args.max_depth,
        seed=args.seed, norm_bounces=args.norm_bounces, index_mode=args.index_mode,
        index_covariance=args.index_covariance, subdiv_level=args.subdiv_level,
        default_lights=not args.no_default_lights, strict=args.strict,
    )


def render_stage(stage_path: Path, args: argparse.Namespace) -> list[Delivered]:
    """Plan, render, index and deliver every product of the recipe; returns what was written."""
    # Imported here, not with the module: every command's parser imports this module, and
    # these pull in numba, Embree and the tracer (0.7 s an `extract` or `index` need not pay).
    from ..jobs.frame import FrameAssembler, plan_frame, prepare_frame
    from ..layers.debug import write_covariance_debug
    from ..jobs.frame import frame_data
    from ..trace import trace_pixels
    from ..stage import open_request

    directory, exr = output_target(args.output, Path("."))
    request = request_from_args(stage_path, args)
    shot = open_request(request)  # the stage is composed and read once for the whole render
    plan = plan_frame(request, args.frame, shot=shot, directory=directory, exr=exr, keep_index=not args.no_index,
                      previews=not args.no_previews, cryptomattes=args.cryptomatte,
                      cryptomatte_depth=args.cryptomatte_depth, nuke_scripts=args.nuke_script)
    if args.debug_covariance and plan.trace.norm_bounces == 0:
        plan = dataclasses.replace(plan, trace=dataclasses.replace(plan.trace, norm_bounces=1))
    integrator = prepare_frame(plan, shot)
    progress = Progress(plan.pixels * plan.trace.spp, "render", enabled=args.show_progress)
    start = time.perf_counter()
    with FrameAssembler(plan) as frame:
        def add(batch) -> None:
            frame.add(batch)
            progress.advance(len(batch.rgb) * plan.trace.spp)

        trace_pixels(integrator, 0, plan.pixels, add, threads=args.threads)
        log.info("rendered %d×%d at %d spp in %.1fs", *plan.resolution, plan.trace.spp, time.perf_counter() - start)
        data = frame_data(plan, integrator, threads=args.threads)
        delivered = frame.deliver(integrator.vocabulary, data, integrator.world.object_paths,
                                  show_progress=args.show_progress)
    if args.debug_covariance:
        _, norms = frame.images()
        write_covariance_debug(plan.index_path.with_suffix(".exr"), norms, plan.metadata)
    return delivered


def preset_or_file(text: str) -> Path:
    """A --recipe argument: an existing file, else a preset name."""
    path = Path(text)
    if path.exists() or text not in PRESETS:
        if not path.is_file():
            raise RecipeError(f"recipe not found (and not a preset: {', '.join(PRESETS)})", file=text)
        return path
    return preset(text)


def output_target(output: str | None, default: Path) -> tuple[Path, Path | None]:
    """(directory, explicit .exr path or None) from -o; ``default`` when -o is not given."""
    if output and output.lower().endswith(".exr"):
        return Path(output).parent, Path(output)
    return Path(output) if output else default, None


def cryptomatte_list(text: str) -> tuple[str, ...]:
    """``object,material,asset`` → the Cryptomatte sources (CryptoObject, ...)."""
    words = [word.strip() for word in text.split(",") if word.strip()]
    unknown = [word for word in words if word not in CRYPTOMATTE_KINDS]
    if unknown or not words:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(CRYPTOMATTE_KINDS)}, "
                                         f"got {text!r}")
    return tuple(dict.fromkeys(CRYPTOMATTE_KINDS[word] for word in words))


def _cryptomatte_depth(text: str) -> int:
    value = positive_int(text)
    if value > MAX_CRYPTOMATTE_DEPTH:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_CRYPTOMATTE_DEPTH}, got {text}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: an integer of 1 or more (--spp, --threads, ...)."""
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _subdiv_level(text: str) -> int:
    value = _non_negative(text)
    if value > MAX_SUBDIV_LEVEL:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_SUBDIV_LEVEL}, got {text}")
    return value


def _variant(text: str) -> VariantSelection:
    try:
        return VariantSelection.parse(text)
    except PxrLayersError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def _non_negative(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text}")
    return value
