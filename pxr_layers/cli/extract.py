"""`pxr-layers extract`: cut layers from a path index with LPEs, without rendering again."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from .. import lpe
from ..layers.deliver import (
    at_index_view,
    beauty_beside,
    check_raw_sources,
    cryptomattes_beside,
    deliver,
    guides_beside,
    index_frame,
    index_inputs,
    index_metadata,
    output_target,
    plan_outputs,
)
from ..layers.extract import extraction_threads
from ..outputs import OutputSet, reading
from ..paths.reader import PathIndex
from ..recipe.model import Layer, Product, Recipe
from ..request import VariantSelection
from .render import add_request_flags, nonempty_path, positive_int

HELP = "cut light layers out of a path index with Light Path Expressions"
DESCRIPTION = (
    "Extract layers from INDEX (a .pxlidx written by `pxr-layers render`) without rendering again, and "
    "write them as multipart EXRs with OCIO previews: part 0 'rgba' is the beauty (read from the render's "
    "EXR beside the index, else rebuilt from the index as C.* with alpha 1), then one part per layer with "
    "channels NAME.R/G/B. Layers come from USD recipes (--recipe: every RenderProduct is written, as "
    "`pxr-layers render` would have written it) and/or from the command line (--layer, --passes, --lights: "
    "one EXR). Expressions are OSL Light Path Expressions with covariance conditions (docs/lpe.md), "
    "e.g. --layer key_diffuse=\"C<RD>'key'\" --layer flat=\"C<R.>@(|S_C| = 0).*\". "
    "Cryptomatte layers cannot be cut from the index (it keeps the light paths' records, merged per "
    "pixel and class, not every camera sample's first hit): they are copied from the render's EXR "
    "beside the index, which has them when the render was asked for them."
)
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index", type=nonempty_path, metavar="INDEX", help="the path index (.pxlidx)")
    add_request_flags(parser, ("recipe_layers", "settings", "per_light"), help={
        "recipe_layers": "a USD layer recipe (a file, or a preset name), composed over the index's stage "
        "when that file still exists; repeat for more, the first is the strongest",
        "settings": "the recipe's RenderSettings prim (default: its renderSettingsPrimPath)"})
    parser.add_argument("--layer", action="append", default=[], type=_layer, metavar="NAME=EXPR",
                        help="a layer: its name and its expression (repeat for more layers)")
    parser.add_argument("--passes", action="store_true",
                        help="add the standard light passes (emission, background, diffuse/glossy "
                        "direct/indirect, transmission, volume): they sum to the beauty")
    parser.add_argument("--lights", action="store_true",
                        help="add one layer per light (light_NAME = C.*<L.'NAME'>) and light_other: "
                        "they sum to the beauty")
    parser.add_argument("-o", "--output", type=nonempty_path, metavar="OUT",
                        help="a directory for the EXRs (recipe products by their productName, the "
                        "command-line layers as INDEX-stem.layers.exr), or the .exr path when one EXR "
                        "is written (default: the index's directory)")
    parser.add_argument("--threads", type=positive_int, metavar="N",
                        help="threads that read and decode the index's chunks for layers with covariance "
                        "conditions (default: every core this process may use; chunks read without "
                        "their covariance decode faster on one); the layers are the same, bit for bit, "
                        "whatever N is")
    add_request_flags(parser, ("previews", "nuke_scripts", "cryptomattes", "denoise"), help={
        "denoise": "also write every EXR's denoised twin NAME.denoised.exr (the same parts and channels, colour "
        "layers denoised, the beauty their sum) with the albedo and normal guides of the render, read from its "
        "EXR beside the index (render it with --denoise)",
        "cryptomattes": "add the Cryptomatte layers (comma-separated: object, material, asset) to every "
        "EXR, copied from the render's EXR beside the index (render it with --cryptomatte); the index "
        "itself cannot give them exactly"})


def run(args: argparse.Namespace) -> int:
    with extraction_threads(args.threads):  # the extractions of deliver and of beauty_beside
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    index = PathIndex(args.index)
    # What this command reads is never replaced by what it writes (-o onto the render's EXR)
    with reading(*index_inputs(index), *(args.recipe_layers or ())):
        return _cut(index, args)


def _cut(index: PathIndex, args: argparse.Namespace) -> int:
    loaded = _recipe(index, args) if args.recipe_layers else None
    products = list(loaded.products) if loaded else []
    expressions, clash = _command_line_layers(args, index)
    if clash:
        print(f"pxr-layers extract: error: {clash}: every layer needs its own name", file=sys.stderr)
        return 2
    if expressions:
        stem = index.path.stem + ".layers"
        products.append(Product(name=stem, output_name=stem + ".exr", camera=index.manifest.get("camera", ""),
                                resolution=tuple(index.manifest["resolution"]),
                                layers=tuple(Layer(name, "lpe", text) for name, text in expressions.items())))
    if not products:
        print("pxr-layers extract: error: no layers: give --recipe, --layer NAME=EXPR, --passes or --lights",
              file=sys.stderr)
        return 2
    recipe = Recipe(products=tuple(at_index_view(product, index) for product in products),
                    settings_path=loaded.settings_path if loaded else "", file=loaded.file if loaded else "")
    if args.cryptomattes:
        recipe = recipe.with_cryptomattes(args.cryptomattes)
    if args.denoise:
        recipe = recipe.with_denoise()
    copied = cryptomattes_beside(index) if any(layer.is_cryptomatte for product in recipe.products
                                               for layer in product.layers) else {}
    check_raw_sources(recipe, tuple(copied), "the path index does not hold (it keeps light paths; data AOVs need "
                      "a render; Cryptomattes are copied from the render's EXR beside the index, and it has none "
                      "of that source)")
    frame = index_frame(index)
    directory, exr = output_target(args.output, index.path.parent)
    outputs = plan_outputs(recipe, frame, directory, exr)
    metadata = index_metadata(index, directory)
    beauty = beauty_beside(index)
    guides = None
    if recipe.denoises:
        from ..layers.denoise import available

        missing = available()
        if missing:
            print(f"pxr-layers extract: error: denoising: {missing}", file=sys.stderr)
            return 1
        guides = guides_beside(index)
        if guides is None:
            print(f"pxr-layers extract: error: denoising: the render's EXR beside {index.path.name} holds no "
                  "denoising guides (denoiseAlbedo, denoiseNormal): render it with --denoise", file=sys.stderr)
            return 1
    with OutputSet():  # every EXR and preview of the command, or none
        delivered = deliver(index, recipe, beauty, outputs, data=copied, metadata=metadata, previews=args.previews,
                            nuke_scripts=args.nuke_scripts, show_progress=args.show_progress, guides=guides)
    for product in delivered:
        print(product.exr)
        if product.nuke_script:
            print(product.nuke_script)
    return 0


def _command_line_layers(args: argparse.Namespace, index: PathIndex) -> tuple[dict[str, str], str]:
    """(name → expression of the --layer, --passes and --lights layers, "" or what names a
    layer twice: a later one would silently replace the earlier)."""
    expressions: dict[str, str] = {}
    given: dict[str, str] = {}  # name → the flag that gave it
    sources = [(f"--layer {name}={text}", {name: text}) for name, text in args.layer]
    if args.passes:
        sources.append(("--passes", lpe.STANDARD_PASSES))
    if args.lights:
        names = sorted({event.name for event in index.events if event.type == "L" and event.name})
        sources.append(("--lights", lpe.per_light_passes(names)))
    for flag, layers in sources:
        for name, text in layers.items():
            if name in given:
                return expressions, f"the layer name {name!r} is given twice ({given[name]} and {flag})"
            given[name], expressions[name] = flag, text
    return expressions, ""


def _recipe(index: PathIndex, args: argparse.Namespace) -> Recipe:
    """The --recipe layers, composed over the index's stage as the render composed it (its
    variant selections, its default lights, per-light layers listed at its frame) when the
    stage is still there; else the recipe layers alone (without a default rig: nothing of the
    index could match its lights)."""
    from ..stage import open_shot

    layers = list(args.recipe_layers)
    stage = Path(index.manifest.get("stage", ""))
    if stage.is_file():
        from ..jobs.frame import file_sha256  # here: jobs.frame pulls in the tracer, which extract does not need

        if index.manifest.get("stage_sha256") not in (None, file_sha256(stage)):
            log.warning("%s has changed since %s was rendered: the recipe is read against today's stage",
                        stage, index.path)
        variants = [VariantSelection.parse(text) for text in index.manifest.get("variants", "").split()]
        shot = open_shot(stage, recipe_layers=layers, variants=variants,
                         default_lights=index.manifest.get("defaultLights", "true") == "true")
    else:
        log.warning("the stage %s of %s is not there: reading the recipe on its own", stage, index.path)
        shot = open_shot(layers[0], recipe_layers=layers[1:], default_lights=False)
    return shot.recipe(settings=args.settings, per_light=args.per_light, frame=index_frame(index))


def _layer(text: str) -> tuple[str, str]:
    name, separator, expression = text.partition("=")
    if not separator or not name.strip() or not expression.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=EXPR, got {text!r}")
    return name.strip(), expression.strip()
