"""`pxr-layers extract`: cut layers from a path index with LPEs, without rendering again."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from .. import lpe
from ..layers.extract import extract
from ..paths.reader import PathIndex

HELP = "cut light layers out of a path index with Light Path Expressions"
DESCRIPTION = (
    "Extract layers from INDEX (a .pxlidx written by `pxr-layers render`) without rendering again, and "
    "write them as a multipart EXR: part 0 'rgba' is the beauty (read from the EXR beside the index, "
    "else rebuilt from the index as C.* with alpha 1), then one part per layer with channels "
    "NAME.R/G/B. Expressions are OSL Light Path Expressions with covariance conditions (docs/lpe.md), "
    "e.g. --layer key_diffuse=\"C<RD>'key'\" --layer flat=\"C<R.>@(|S_C| = 0).*\"."
)
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("index", metavar="INDEX", help="the path index (.pxlidx)")
    parser.add_argument("--layer", action="append", default=[], type=_layer, metavar="NAME=EXPR",
                        help="a layer: its name and its expression (repeat for more layers)")
    parser.add_argument("--passes", action="store_true",
                        help="add the standard light passes (emission, background, diffuse/glossy "
                        "direct/indirect, transmission, volume): they sum to the beauty")
    parser.add_argument("--lights", action="store_true",
                        help="add one layer per light (light_NAME = C.*<L.'NAME'>) and light_other: "
                        "they sum to the beauty")
    parser.add_argument("-o", "--output", metavar="OUT.exr",
                        help="the multipart EXR to write (default: INDEX's stem + .layers.exr beside it)")


def run(args: argparse.Namespace) -> int:
    from ..layers.multipart import write_multipart
    from ..recipe.model import Layer, Product

    index = PathIndex(args.index)
    expressions = dict(args.layer)
    if args.passes:
        expressions.update(lpe.STANDARD_PASSES)
    if args.lights:
        names = sorted({event.name for event in index.events if event.type == "L" and event.name})
        expressions.update(lpe.per_light_passes(names))
    if not expressions:
        print("pxr-layers extract: error: no layers: give --layer NAME=EXPR, --passes or --lights", file=sys.stderr)
        return 2
    extraction = extract(index, expressions, show_progress=args.show_progress)
    output = Path(args.output) if args.output else index.path.with_name(index.path.stem + ".layers.exr")
    metadata = {key: index.manifest[key] for key in ("stage", "camera", "frame", "spp", "seed") if key in index.manifest}
    metadata["index"] = str(index.path)
    resolution = tuple(index.manifest["resolution"])
    product = Product(name=output.stem, output_name=output.name, camera=index.manifest.get("camera", ""),
                      resolution=resolution, layers=tuple(Layer(name, "lpe", text) for name, text in expressions.items()))
    write_multipart(output, _beauty(index, extraction.layers), extraction.layers, product, metadata=metadata)
    log.info("wrote %s (%d layers)", output, len(expressions))
    print(output)
    return 0


def _beauty(index: PathIndex, layers: dict[str, np.ndarray]) -> np.ndarray:
    """The render's beauty EXR beside the index, else C.* from the index with alpha 1."""
    import OpenEXR

    beside = index.path.with_name(index.manifest.get("beauty", index.path.stem + ".exr"))
    if beside.exists():
        rgba = OpenEXR.File(str(beside)).channels().get("RGBA")
        if rgba is not None and rgba.pixels.shape[:2] == next(iter(layers.values())).shape[:2]:
            return np.ascontiguousarray(rgba.pixels, dtype=np.float32)
    rgb = extract(index, {"beauty": lpe.BEAUTY}).layers["beauty"]
    return np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], axis=2)


def _layer(text: str) -> tuple[str, str]:
    name, separator, expression = text.partition("=")
    if not separator or not name.strip() or not expression.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=EXPR, got {text!r}")
    return name.strip(), expression.strip()
