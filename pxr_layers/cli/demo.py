"""`pxr-layers demo`: render the embedded demo shot with its own recipe: its light passes and
per-light layers, denoised."""

from __future__ import annotations

import argparse
import logging
from importlib import resources
from pathlib import Path

from .render import add_render_flags, request_from_args

HELP = "render the embedded demo shot into denoised light passes and per-light layers"
DESCRIPTION = (
    "Render the demo shot that ships with pxr-layers (render/demo.usda: a small studio with matte, textured, "
    "glossy, mirror and glass objects, a neon bar and three named lights) with its own recipe: "
    "OUT/demo_passes.exr (the beauty and six light passes that add up to it: emission, diffuse and glossy "
    "direct and indirect, transmission), OUT/demo_lights.exr (one layer per light and light_other), each "
    "with its denoised twin OUT/demo_*.denoised.exr, OUT/demo.pxlidx (the path index, for `pxr-layers "
    "extract`) and the PNG previews and contact sheets of the denoised stacks. Every `pxr-layers render` flag "
    "applies (--recipe replaces the demo's own)."
)
DEFAULT_SCENE = "demo.usda"
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_render_flags(parser)
    parser.set_defaults(output="demo", recipe_layers=None)


def embedded_scene(name: str = DEFAULT_SCENE) -> Path:
    """Path of a scene shipped in the package's render/ data."""
    return Path(str(resources.files("pxr_layers.render").joinpath(name)))


def run(args: argparse.Namespace) -> int:
    from ..jobs.frame import render_frame

    if args.recipe_layers is None:  # no --recipe given: the demo's own
        args.recipe_layers = ()
    result = render_frame(request_from_args(embedded_scene(), args), args.frame, output=args.output,
                          threads=args.threads, show_progress=args.show_progress)
    for delivered in result.delivered:
        print(delivered.exr)
    return 0
