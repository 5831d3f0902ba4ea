"""`pxr-layers demo`: render the embedded default shot (the Cornell box)."""

from __future__ import annotations

import argparse
import logging
from importlib import resources
from pathlib import Path

from .render import add_render_flags, render_stage

HELP = "render the embedded default shot (Cornell box)"
DESCRIPTION = "Render the Cornell box that ships with pxr-layers, at its own render settings unless overridden."
DEFAULT_SCENE = "cornell.usda"
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_render_flags(parser)
    parser.set_defaults(output="demo")


def embedded_scene(name: str = DEFAULT_SCENE) -> Path:
    """Path of a scene shipped in the package's render/ data."""
    return Path(str(resources.files("pxr_layers.render").joinpath(name)))


def run(args: argparse.Namespace) -> int:
    output = render_stage(embedded_scene(), args)
    print(output)
    return 0
