"""The `pxr-layers` command: one module per subcommand, each with add_arguments() and run()."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import warnings

from .. import __version__
from ..errors import PxrLayersError
from . import demo, extract, index, job, logging_flags, lpe, render

SUBCOMMANDS = {"render": render, "demo": demo, "index": index, "extract": extract, "lpe": lpe, "job": job}
EXIT_OK, EXIT_USER_ERROR, EXIT_USAGE, EXIT_INTERNAL_ERROR = 0, 1, 2, 3


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pxr-layers",
        description="Path-trace a USD stage with Embree and write a beauty EXR. "
        "Later steps of the flow cut light-path layers from the render's index.",
    )
    parser.add_argument("--version", action="version", version=f"pxr-layers {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in SUBCOMMANDS.items():
        sub = commands.add_parser(name, help=module.HELP, description=module.DESCRIPTION, parents=[logging_flags()])
        module.add_arguments(sub)
    return parser


CHATTY_LIBRARIES = ("distributed", "tornado", "bokeh")


def _quiet_libraries(record: logging.LogRecord) -> bool:
    """Dask's scheduler and workers chat at INFO: only their warnings are shown without -v.
    (A filter on the handler: Dask sets its loggers' levels itself when it is imported.)"""
    return record.levelno >= logging.WARNING or not record.name.startswith(CHATTY_LIBRARIES)


def _warning_as_log_line(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings (numpy's RuntimeWarnings above all) as our one-line warnings, with
    the module that raised them, instead of a raw two-line printout with source code."""
    logging.getLogger("pxr_layers").warning("%s: %s (%s:%d)", category.__name__, message,
                                            os.path.basename(filename), lineno)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse: 0 for --help/--version, 2 for bad usage
        return int(exit_.code or 0)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format="pxr-layers: %(levelname)s: %(message)s", stream=sys.stderr)
    if not args.verbose:
        for handler in logging.getLogger().handlers:
            handler.addFilter(_quiet_libraries)
    warnings.showwarning = _warning_as_log_line
    args.show_progress = not args.quiet and not os.environ.get("CI")
    try:
        return SUBCOMMANDS[args.command].run(args)
    except PxrLayersError as error:
        print(f"pxr-layers: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("pxr-layers: interrupted; nothing was written", file=sys.stderr)
        return 130
    except Exception as error:  # a bug of ours, not the user's input: one line, the trace with -v
        logging.getLogger(__name__).debug("internal error", exc_info=True)
        print(f"pxr-layers: internal error: {type(error).__name__}: {error} (a bug in pxr-layers; "
              "-v prints the traceback)", file=sys.stderr)
        return EXIT_INTERNAL_ERROR


if __name__ == "__main__":
    sys.exit(main())
