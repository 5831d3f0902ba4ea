"""The `pxr-layers` command: one module per subcommand, each with add_arguments() and run().

Only the standard library is imported before main() runs: the subcommands (numpy, USD,
Embree...) are imported inside it, where Ctrl-C and SIGTERM are already handled.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import sys
import warnings

from .. import __version__
from ..errors import PxrLayersError, Terminated
from ..interrupts import noted, signals_raise
from . import logging_flags

SUBCOMMAND_NAMES = ("render", "demo", "index", "extract", "lpe", "job", "view", "suggest", "nuke")
EXIT_OK, EXIT_USER_ERROR, EXIT_USAGE, EXIT_INTERNAL_ERROR = 0, 1, 2, 3
EXIT_INTERRUPTED = 130
"""128 + SIGINT: what a shell reports for a command stopped by Ctrl-C (SIGTERM: 143)."""
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES,
                                errno.ENAMETOOLONG, errno.ELOOP})
"""OSErrors that reach main() as one user-facing line rather than an internal error (a full
disk, a quota, a permission; a name too long for the file system, a loop of links)."""


def subcommand(name: str):
    """The module of subcommand `name` (imported on first use: they pull in numpy, USD, Embree)."""
    return importlib.import_module(f"{__package__}.{name}")


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The command's parser. When `argv` names a subcommand first, only that one's module is
    imported (the others get empty parsers, never used): `pxr-layers extract` must not pay
    for importing the renderer (numba, USD, Embree: half a second). Otherwise (``--help``,
    a typo) every subcommand is imported, for the list of them and their help."""
    chosen = argv[0] if argv and argv[0] in SUBCOMMAND_NAMES else None
    parser = argparse.ArgumentParser(
        prog="pxr-layers",
        description="Path-trace a USD stage with Embree and write a beauty EXR. "
        "Later steps of the flow cut light-path layers from the render's index.",
    )
    parser.add_argument("--version", action="version", version=f"pxr-layers {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_NAMES:
        if chosen not in (None, name):
            commands.add_parser(name)
            continue
        module = subcommand(name)
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
    with signals_raise():  # SIGTERM unwinds like Ctrl-C: the same clean-up, exit 143
        return _command(argv)


def _command(argv: list[str] | None) -> int:
    try:
        arguments = sys.argv[1:] if argv is None else argv
        parser = build_parser(arguments)
        try:
            args = parser.parse_args(arguments)
        except SystemExit as exit_:  # argparse: 0 for --help/--version, 2 for bad usage
            return int(exit_.code or 0)
    except KeyboardInterrupt as interrupt:  # during start-up (the imports): nothing was begun
        return _interrupted(interrupt)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format="pxr-layers: %(levelname)s: %(message)s", stream=sys.stderr)
    if not args.verbose:
        for handler in logging.getLogger().handlers:
            handler.addFilter(_quiet_libraries)
    warnings.showwarning = _warning_as_log_line
    args.show_progress = not args.quiet and not os.environ.get("CI")
    from ..outputs import forget_committed

    forget_committed()  # what this command writes, not an earlier one in the same process
    try:
        return subcommand(args.command).run(args)
    except PxrLayersError as error:
        print(f"pxr-layers: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt as interrupt:
        return _interrupted(interrupt)
    except OSError as error:
        if noted():  # the interrupt, as a library reported it
            return _interrupted(noted())
        if error.errno not in ENVIRONMENT_ERRNOS:
            return _internal_error(error)
        # The machine, not the input nor pxr-layers: a full disk, a quota or a permission met
        # while a library (numba's kernel cache, a Dask spill) writes a file of its own.
        where = f"{error.filename}: " if error.filename else ""
        cause = ("a name the file system refuses" if error.errno in (errno.ENAMETOOLONG, errno.ELOOP)
                 else "the disk, a quota or a permission of this machine")
        print(f"pxr-layers: error: {where}{error.strerror or error} ({cause})", file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception as error:
        if noted():  # the interrupt, as a library reported it (pybind11: "initialization failed")
            return _interrupted(noted())
        return _internal_error(error)


def _internal_error(error: Exception) -> int:
    """A bug of ours, not the user's input: one line, the traceback with -v."""
    logging.getLogger(__name__).debug("internal error", exc_info=error)
    print(f"pxr-layers: internal error: {type(error).__name__}: {error} (a bug in pxr-layers; "
          "-v prints the traceback)", file=sys.stderr)
    return EXIT_INTERNAL_ERROR


def _interrupted(interrupt: KeyboardInterrupt) -> int:
    """Say what an interrupted command left in place (whole files only), and exit 130 for
    Ctrl-C, 143 for SIGTERM."""
    from ..outputs import committed_counts

    print(f"pxr-layers: {interruption(interrupt)}; {_written(committed_counts())}", file=sys.stderr)
    return getattr(interrupt, "exit_code", EXIT_INTERRUPTED)


def interruption(interrupt: KeyboardInterrupt) -> str:
    """'terminated' (SIGTERM) or 'interrupted' (Ctrl-C)."""
    return "terminated" if isinstance(interrupt, Terminated) else "interrupted"


def _written(counts: dict) -> str:
    if not counts:
        return "nothing was written"
    return (f"{sum(counts.values())} complete files had been written (in {', '.join(sorted(map(str, counts)))}), "
            "nothing else")


if __name__ == "__main__":
    sys.exit(main())
