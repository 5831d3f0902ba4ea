"""`pxr-layers nuke`: a Nuke script that rebuilds a product's beauty from its layers."""

from __future__ import annotations

import argparse
from pathlib import Path

from .render import nonempty_path

HELP = "write a Nuke script (.nk) that rebuilds a product's beauty from its layers"
DESCRIPTION = (
    "Write a Nuke script for PRODUCT (a multipart EXR of `pxr-layers render` or `extract`): a Read of the "
    "EXR, a Shuffle and a Grade (unit gain) per colour layer, a Merge (plus) chain that adds them up to "
    "the beauty (with a 'rest of the beauty' branch when the layers do not sum to it), and a "
    "Cryptomatte gizmo per Cryptomatte layer (CryptoObject, ...) ready for picking. Data layers "
    "(depth, normals, ids) stay in the Read's channels. The script reads the EXR relative to its own "
    "folder when it lies there or below. docs/compositing.md shows how Nuke reads every part."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("product", type=nonempty_path, metavar="PRODUCT", help="the multipart EXR (.exr)")
    parser.add_argument("-o", "--output", type=nonempty_path, metavar="SCRIPT",
                        help="the .nk file to write (default: PRODUCT with .nk instead of .exr)")


def run(args: argparse.Namespace) -> int:
    from ..layers.nuke import NUKE_SCRIPT_SUFFIX
    from ..outputs import check_output, reading

    product = Path(args.product)
    output = Path(args.output) if args.output else product.with_suffix(NUKE_SCRIPT_SUFFIX)
    with reading(product):  # `-o` naming the product itself must not replace it
        check_output(output, "Nuke script", (NUKE_SCRIPT_SUFFIX,))  # before the EXR is read
        print(write_product_script(product, output))
    return 0


def write_product_script(product: Path, output: Path) -> Path:
    """Write the Nuke script of the EXR ``product`` at ``output``; returns ``output``."""
    from ..layers import nuke
    from ..layers.multipart import read_multipart

    image = read_multipart(product)
    nuke.write_product_script(output, product, image.beauty, image.colour_layers(),
                              {name: matte.depth for name, matte in image.cryptomattes.items()},
                              image.pixel_aspect_ratio)
    return output
