"""`pxr-layers demo`: render the embedded default shot with the light-pass recipe."""

from __future__ import annotations

import argparse
import logging
from importlib import resources
from pathlib import Path

from .render import add_render_flags, render_stage

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
    parser.set_defaults(output="demo", recipe=None)


def embedded_scene(name: str = DEFAULT_SCENE) -> Path:
    """Path of a scene shipped in the package's render/ data."""
    return Path(str(resources.files("pxr_layers.render").joinpath(name)))


def run(args: argparse.Namespace) -> int:
    if args.recipe is None:  # an append action's default of None: no --recipe given
        args.recipe = [DEMO_RECIPE]
    for delivered in render_stage(embedded_scene(), args):
        print(delivered.exr)
    return 0
