"""`pxr-layers demo`: render the embedded default shot with the light-pass recipe."""

from __future__ import annotations

import argparse
import logging
from importlib import resources
from pathlib import Path

from ..recipe.presets import preset
from .render import add_render_flags, request_from_args

HELP = "render the embedded default shot (Cornell box) into light passes"
DEMO_RECIPE = "light_passes"
DESCRIPTION = (
    "Render the Cornell box that ships with pxr-layers with the light_passes recipe preset (the "
    "--recipe default): OUT/light_passes.exr (beauty + the standard passes, which add up to it), "
    "OUT/cornell.pxlidx (the path index, for `pxr-layers extract`) and the PNG previews and contact "
    "sheet. Every `pxr-layers render` flag applies."
)
DEFAULT_SCENE = "cornell.usda"
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_render_flags(parser)
    parser.set_defaults(output="demo", recipe_layers=None)


def embedded_scene(name: str = DEFAULT_SCENE) -> Path:
    """Path of a scene shipped in the package's render/ data."""
    return Path(str(resources.files("pxr_layers.render").joinpath(name)))


def run(args: argparse.Namespace) -> int:
    from ..jobs.frame import render_frame

    if args.recipe_layers is None:  # no --recipe given
        args.recipe_layers = (preset(DEMO_RECIPE),)
    result = render_frame(request_from_args(embedded_scene(), args), args.frame, output=args.output,
                          threads=args.threads, show_progress=args.show_progress)
    for delivered in result.delivered:
        print(delivered.exr)
    return 0
