"""`pxr-layers lpe`: check a Light Path Expression, or match it against paths.

    pxr-layers lpe check "C<RD>.*<L.'key'>"
    pxr-layers lpe match "C<RD>.*L" "C RD'floor' L'key'" "C RG L"

The same module runs on its own: ``python -m pxr_layers.cli.lpe check EXPR``.
"""

from __future__ import annotations

import argparse
import logging
import sys

from ..errors import PxrLayersError
from ..lpe import compile as compile_expression
from ..lpe import hints, parse_path
from . import logging_flags

HELP = "check a Light Path Expression or match it against paths"
DESCRIPTION = (
    "Light Path Expressions (OSL's, with covariance conditions; see docs/lpe.md). "
    "'check' prints the canonical form and the size of the automaton; 'match' prints, for "
    "each PATH, 'match' or 'no match'."
)
PATH_HELP = (
    "a path in the textual notation, quoted: \"C RD'floor' RG'chrome' L'key'\"; "
    "covariance values in braces feed the conditions: \"C RD{C=0,T=3.2,R=0} L\""
)
EXIT_OK, EXIT_USER_ERROR, EXIT_USAGE = 0, 1, 2
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `check` and `match` actions, under an `lpe` parser made by the caller."""
    actions = parser.add_subparsers(dest="lpe_action", metavar="ACTION", required=True)
    check = actions.add_parser(
        "check", help="print the canonical form and the automaton size", parents=[logging_flags(nested=True)],
        description="Parse EXPR; print its canonical form and the size of its minimal automaton.",
    )
    check.add_argument("expression", metavar="EXPR", help="the expression, quoted: \"C<RD>.*L\"")
    match = actions.add_parser(
        "match", help="match paths against an expression", parents=[logging_flags(nested=True)],
        description="Print one line per PATH, in order: 'match' or 'no match'.",
    )
    match.add_argument("expression", metavar="EXPR", help="the expression, quoted")
    match.add_argument("paths", metavar="PATH", nargs="+", help=PATH_HELP)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `lpe` subcommand to an argparse subparsers object; returns its parser."""
    parser = subparsers.add_parser("lpe", help=HELP, description=DESCRIPTION)
    add_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    expression = compile_expression(args.expression)
    for note in hints(args.expression):
        log.warning("note: %s", note)
    if args.lpe_action == "check":
        print(f"canonical: {expression.canonical}")
        automaton = expression.automaton
        if automaton.complete:
            print(f"automaton: {_count(automaton.state_count, 'state')}, "
                  f"{_count(automaton.transition_count, 'transition')}")
        else:
            print(f"automaton: built on demand ({automaton.on_demand_reason})")
        return EXIT_OK
    paths = [parse_path(text) for text in args.paths]
    known_labels = {label for path in paths for event in path.events for label in event.labels}
    if known_labels:
        expression.automaton.unknown_labels(known_labels)
    answers = [expression.matches(path) for path in paths]  # a path that cannot be decided fails before any output
    for matched in answers:
        print("match" if matched else "no match")
    return EXIT_OK


def _count(number: int, noun: str) -> str:
    return f"{number} {noun}" + ("" if number == 1 else "s")


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point, with the exit codes of `pxr-layers`."""
    parser = argparse.ArgumentParser(prog="pxr-layers lpe", description=DESCRIPTION)
    add_arguments(parser)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse: 0 for --help, 2 for bad usage
        return int(exit_.code or 0)
    verbose, quiet = getattr(args, "verbose", False), getattr(args, "quiet", False)
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(level=level, format="pxr-layers: %(levelname)s: %(message)s", stream=sys.stderr)
    try:
        return run(args)
    except PxrLayersError as error:
        print(f"pxr-layers: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == "__main__":
    sys.exit(main())
