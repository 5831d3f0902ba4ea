"""`pxr-layers render`: path-trace a USD stage, index its paths, deliver its recipe's layers."""

from __future__ import annotations

import argparse
import logging
import math
from collections.abc import Sequence
from pathlib import Path

from ..paths.format import SUFFIX as INDEX_SUFFIX
from ..request import OPTIONS, Kind, RenderRequest, Switch, Words

HELP = "render a USD stage: beauty, path index, and the layers of its recipe"
DESCRIPTION = (
    f"Path-trace STAGE (any USD file) with Embree, record the path index STEM{INDEX_SUFFIX}, and write "
    "every RenderProduct of the recipe as a multipart EXR (part 0 'rgba' the beauty, one part per "
    "RenderVar) with OCIO previews beside it. The recipe is the stage's own UsdRender settings, "
    "or --recipe layers composed over it; a stage without one gives a beauty EXR. Camera and "
    "resolution come from the recipe's products, else the settings, else the stage's first "
    "camera, else an automatic camera that frames the stage; the flags below override them. A "
    "stage that nothing lights (no light, no emissive material) gets a turntable rig (dome, key, fill "
    "and rim). References this USD build cannot read and missing files are warnings, and the rest "
    "renders (--strict: errors)."
)
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("stage", type=nonempty_path, metavar="STAGE", help="the USD stage to render (.usd, .usda, .usdc, .usdz)")
    add_render_flags(parser)


def add_render_flags(parser: argparse.ArgumentParser) -> None:
    """Every flag of a render: -o, --frame, --threads and the request's options."""
    parser.add_argument(
        "-o", "--output", type=nonempty_path, metavar="OUT",
        help="a directory that receives the recipe's products (their productName, #### = frame) "
        f"and STEM{INDEX_SUFFIX}; or, for a recipe of one product, the .exr path itself. Default: the "
        "current directory",
    )
    parser.add_argument("--frame", type=_finite, metavar="F",
                        help="time code to render (default: the stage's start time code)")
    parser.add_argument("--threads", type=positive_int, metavar="N",
                        help="render threads (default: every core this process may use: its CPU affinity "
                        "and cgroup quota)")
    add_request_flags(parser)


def add_request_flags(parser: argparse.ArgumentParser, names: Sequence[str] | None = None, *,
                      unset_defaults: bool = False, help: dict[str, str] | None = None) -> None:
    """A flag for each request option (:data:`pxr_layers.request.OPTIONS`; ``names``: only
    these), with its help and its default as the request declares them. ``unset_defaults``:
    a flag not given leaves None (``job run``: the job file's value stands); ``help``:
    option name → help text, where a command's flag means something narrower."""
    for spec in OPTIONS:
        if names is not None and spec.name not in names:
            continue
        text = (help or {}).get(spec.name, spec.flag_help)
        default = None if unset_defaults else spec.default
        if isinstance(spec.kind, Switch):
            parser.add_argument(spec.flag, dest=spec.name, action="store_false" if spec.default else "store_true",
                                default=default, help=text)
            continue
        said = "(default" in text or (isinstance(spec.kind, Words) and not spec.default)
        shown = " (default: the job file's)" if unset_defaults else "" if said else f" (default: {spec.default_text})"
        parser.add_argument(spec.flag, dest=spec.name, action=_OptionAction, kind=spec.kind, default=default,
                            metavar=spec.kind.metavar, nargs=spec.kind.nargs, help=text + shown)


class _OptionAction(argparse.Action):
    """Reads a flag's words with its option's Kind: one error line naming the flag (exit 2),
    and a repeated flag's values collected in order."""

    def __init__(self, option_strings, dest, kind: Kind, **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.kind = kind

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        try:
            value = self.kind.from_text(values)
        except ValueError as error:
            raise argparse.ArgumentError(self, str(error)) from None
        if isinstance(self.kind, Words):  # repeated or comma-separated: collected in order
            earlier = getattr(namespace, self.dest, None) or ()
            value = tuple(dict.fromkeys((*earlier, *value)))
        setattr(namespace, self.dest, value)


def run(args: argparse.Namespace) -> int:
    # Imported here, not with the module: every command's parser imports this module, and
    # the frame pulls in numba, Embree and the tracer (0.7 s an `extract` need not pay).
    from ..jobs.frame import render_frame
    from ..outputs import reading

    with reading(args.stage, *(args.recipe_layers or ())):  # never replaced by the render's outputs
        result = render_frame(request_from_args(Path(args.stage), args), args.frame, output=args.output,
                              threads=args.threads, show_progress=args.show_progress)
    for delivered in result.delivered:
        print(delivered.exr)
        if delivered.nuke_script:
            print(delivered.nuke_script)
    return 0


def request_from_args(stage_path: Path, args: argparse.Namespace) -> RenderRequest:
    """The render request the flags describe (a flag not given: the request's default)."""
    given = {spec.name: getattr(args, spec.name) for spec in OPTIONS
             if getattr(args, spec.name, None) is not None}
    return RenderRequest(stage=stage_path, **given)


def nonempty_path(text: str) -> str:
    """An argparse type: a file or folder path, refused when empty (an empty word on a command
    line is most often a shell variable that was never set: a path would silently mean '.')."""
    if not text:
        raise argparse.ArgumentTypeError("an empty path (an unset shell variable?)")
    return text


def positive_int(text: str) -> int:
    """An argparse type: an integer of 1 or more (--spp, --threads, ...)."""
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value
