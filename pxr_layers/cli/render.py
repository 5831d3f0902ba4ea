"""`pxr-layers render`: path-trace a USD stage into a beauty EXR."""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import logging
import math
from pathlib import Path

from .. import __version__
from ..layers.debug import write_covariance_debug
from ..layers.exr import write_rgba
from ..paths.format import SUFFIX as INDEX_SUFFIX
from ..paths.writer import PathIndexWriter
from ..trace import TraceSettings
from ..trace import render as trace_render

HELP = "render a USD stage to a beauty EXR"
DESCRIPTION = (
    "Path-trace STAGE (any USD file) with Embree. Camera, resolution and material binding "
    "purposes come from the stage's UsdRender settings when it has them (else its first "
    "camera); the flags below override them."
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
        help="a path ending in .exr names the beauty file; anything else is a directory that "
        "receives STEM.exr (STEM.FFFF.exr with --frame). Default: the current directory",
    )
    parser.add_argument("--spp", type=_positive, default=DEFAULT_SPP, metavar="N",
                        help=f"samples per pixel (default {DEFAULT_SPP})")
    parser.add_argument("--max-depth", type=_non_negative, default=DEFAULT_MAX_DEPTH, metavar="N",
                        help=f"most scattering events per path; 1 = direct light only (default {DEFAULT_MAX_DEPTH})")
    parser.add_argument("--resolution", type=_positive, nargs=2, metavar=("W", "H"),
                        help="image size in pixels (default: the render settings', else 512 512)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    parser.add_argument("--frame", type=float, metavar="F",
                        help="time code to render (default: the stage's start time code)")
    parser.add_argument("--camera", metavar="PRIM", help="camera prim path (default: the settings' camera)")
    parser.add_argument("--settings", metavar="PRIM",
                        help="UsdRender RenderSettings prim (default: the stage's renderSettingsPrimPath)")
    parser.add_argument("--threads", type=_positive, metavar="N", help="render threads (default: all cores)")
    parser.add_argument("--norm-bounces", type=_non_negative, default=DEFAULT_NORM_BOUNCES, metavar="N",
                        help="events per path (camera side) whose covariance norms C, T, R the path "
                        f"index keeps (default {DEFAULT_NORM_BOUNCES}; 0: none)")
    parser.add_argument("--no-index", action="store_true",
                        help="do not write the path index STEM.pxlidx beside the beauty (it is what "
                        "lets `pxr-layers extract` cut layers later without rendering again)")
    parser.add_argument("--aggregate-index", action="store_true",
                        help="merge the index records of one pixel that share their path class and "
                        "norms (as stored, float16) into one: the index grows less than linearly with "
                        "spp; layers are unchanged, the sample number of each record is lost")
    parser.add_argument("--debug-covariance", action="store_true",
                        help="also write the first bounce's covariance norms beside the beauty: "
                        "STEM.covariance.exr (channels C 1/m, T cycles/m, R cycles/rad) and "
                        "STEM.covariance.{C,T,R}.png colour maps")


def run(args: argparse.Namespace) -> int:
    render_stage(Path(args.stage), args)
    return 0


def render_stage(stage_path: Path, args: argparse.Namespace) -> Path:
    """Load, render and write the beauty EXR; returns its path."""
    from ..stage import (
        load_stage,  # the only module that imports pxr; load it when needed
    )

    scene, spec = load_stage(stage_path, frame=args.frame, camera=args.camera, settings=args.settings)
    if args.resolution:
        spec = dataclasses.replace(spec, resolution=tuple(args.resolution))
    write_index = not args.no_index
    norm_bounces = args.norm_bounces if write_index else 0
    if args.debug_covariance:
        norm_bounces = max(norm_bounces, 1)  # the pictures need the first bounce
    settings = TraceSettings(spp=args.spp, max_depth=args.max_depth, seed=args.seed, norm_bounces=norm_bounces,
                             record_paths=write_index)
    output = beauty_path(stage_path, args.output, args.frame)
    metadata = {
        "version": __version__,
        "stage": str(stage_path.resolve()),
        "camera": spec.camera.path,
        "frame": "default" if math.isnan(scene.frame) else repr(scene.frame),
        "spp": str(settings.spp),
        "maxDepth": str(settings.max_depth),
        "seed": str(settings.seed),
    }
    index = None
    if write_index:
        manifest = {
            **metadata, "stage_sha256": _file_sha256(stage_path), "resolution": list(spec.resolution),
            "spp": settings.spp, "seed": settings.seed, "max_depth": settings.max_depth, "beauty": output.name,
        }
        index = PathIndexWriter(output.with_suffix(INDEX_SUFFIX), manifest, settings.norm_bounces,
                                aggregate=args.aggregate_index)
    try:
        result = trace_render(scene, spec, settings, threads=args.threads, show_progress=args.show_progress,
                              on_batch=(lambda batch: index.add(batch.records)) if index else None)
        write_rgba(output, result.rgba, metadata)
        if index:
            index.close(result.vocabulary)
    except BaseException:
        if index:
            index.abort()
        raise
    log.info("wrote %s", output)
    if args.debug_covariance:
        write_covariance_debug(output, result.first_bounce_norms, metadata)
    return output


def _file_sha256(path: Path) -> str:
    """SHA-256 of the stage's root layer file (not of the layers it composes)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def beauty_path(stage_path: Path, output: str | None, frame: float | None) -> Path:
    """Where the beauty goes: OUT.exr as given, else STEM[.FFFF].exr in the OUT directory."""
    if output and output.lower().endswith(".exr"):
        return Path(output)
    stem = stage_path.stem
    if frame is not None:
        stem += f".{frame:04.0f}" if float(frame).is_integer() else f".{frame:g}"
    return Path(output or ".") / f"{stem}.exr"


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
