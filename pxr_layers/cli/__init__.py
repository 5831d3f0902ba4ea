"""The `pxr-layers` command line: one module per subcommand (see main.py)."""

from __future__ import annotations

import argparse


def logging_flags(nested: bool = False) -> argparse.ArgumentParser:
    """-q/--quiet and -v/--verbose, as a parent parser every (sub)command takes.

    nested: for the actions of a subcommand (`job run`), whose flags must not reset what
    the subcommand's own parser read (`job -q run` and `job run -q` both work).
    """
    flags = argparse.ArgumentParser(add_help=False)
    default = argparse.SUPPRESS if nested else False
    flags.add_argument("-q", "--quiet", action="store_true", default=default,
                       help="no progress bar, warnings and errors only")
    flags.add_argument("-v", "--verbose", action="store_true", default=default, help="debug logging")
    return flags
