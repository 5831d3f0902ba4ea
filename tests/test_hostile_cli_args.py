"""Hostile command lines (issue 33): hypothesis draws, for each command, any mix of its own
flags (read from its argparse parser, so a new flag is tried the day it is added) with
hostile values — words no value could be, numbers past every limit, NaN, control
characters, undecodable bytes as a shell hands them over, and paths to a FIFO, a folder, a
garbage file, a truncated index, a name with a newline — beside valid ones. Whatever is
drawn, the command answers as a user expects: exit 0, or one line ``pxr-layers: error:``
and exit 1, or argparse's usage and exit 2; never an internal error (exit 3), never a
traceback, never a hang.

Everything runs in this process (``main(argv)``), in a scratch folder that is the working
directory, so a relative ``-o`` lands there. Flags whose valid values cost time (samples,
resolution, depth, -k) are given small values again at the end of every command line: the
drawn value is still parsed and checked (argparse reads every occurrence), the last one is
rendered. The number of examples per command is PROPERTY_EXAMPLES (CI's small form);
HYPOTHESIS_EXAMPLES in the environment asks for more.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_cli import RENDER_DIR

from pxr_layers.cli.main import EXIT_OK, EXIT_USAGE, EXIT_USER_ERROR, build_parser, main

PROPERTY_EXAMPLES = int(os.environ.get("HYPOTHESIS_EXAMPLES", "25"))
PROPERTY = settings(deadline=None, derandomize=True, database=None, max_examples=PROPERTY_EXAMPLES,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

HANG_SECONDS = 60
"""Longer than any command here takes on a slow machine: past it, the command hangs."""

CHEAP_TAIL = {
    "render": ["--spp", "1", "--resolution", "8", "8", "--max-depth", "2", "--no-previews"],
    "job run": ["--spp", "1", "--resolution", "8", "8", "--max-depth", "2", "--no-previews", "--workers", "1"],
    "suggest": ["-k", "2", "--no-previews"],
    "extract": ["--no-previews"],
}
"""Given after the drawn flags: valid values that keep a command that runs small."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """The paths hypothesis draws from: a real render's index, EXR and stage, and what no
    command can read."""
    folder = tmp_path_factory.mktemp("hostile_cli")
    stage = folder / "cornell.usda"
    shutil.copy(RENDER_DIR / "cornell.usda", stage)
    assert main(["render", str(stage), "-o", str(folder / "render"), "--spp", "1", "--resolution", "12", "12",
                 "--max-depth", "2", "--no-previews", "--quiet"]) == EXIT_OK
    index = folder / "render" / "cornell.pxlidx"
    fifo = folder / "fifo"
    os.mkfifo(fifo)
    garbage = folder / "garbage.usda"
    garbage.write_bytes(b"#usda 1.0\n\x00\xff(((")
    truncated = folder / "truncated.pxlidx"
    truncated.write_bytes(index.read_bytes()[:200])
    newline = folder / "new\nline.usda"
    shutil.copy(stage, newline)
    job = folder / "job.toml"
    job.write_text(f'stage = "{stage}"\nframes = "1"\n[output]\ndirectory = "{folder / "job"}"\n')
    return {"stage": stage, "index": index, "exr": folder / "render" / "cornell.exr", "job": job,
            "fifo": fifo, "folder": folder, "garbage": garbage, "truncated": truncated,
            "newline": newline, "missing": folder / "missing.usda"}


NUMBERS = ["0", "-1", "1", "2", "3", "7", "65536", "1e308", "-1e308", "nan", "inf", "-inf", "1.5", "0x10",
           "99999999999999999999999", "-0", "١٢"]
WORDS = ["", " ", "-", "--", "\n", "a\nb", "\t", "x" * 300, "\udcff\udcfe", "é", "🙂", "[python {print 1}]",
         "$(touch pwned)", "../../x", "/", "lights", "groups", "object,material", "asset,,", "beam", "greedy",
         "/World", "/World/Camera", "//x", "/World/x:y", "World", "C.*L", "C<RD>.*<L.'key'>", "CD(|S_C|>1e308)L",
         "x=C.*", "=C.*", "a=", "a b=C", "rgba=C.*", "light_passes", "showcase", "4", "8 8", "1-4", "1-4x0",
         "tcp://", "tcp://host:0", "local", "flat", "covariance", "/World/x:v=w", "x.exr", "x.png", "x.usda"]


def values(inputs: dict[str, Path]) -> st.SearchStrategy[str]:
    paths = st.sampled_from([str(path) for path in inputs.values()])
    return st.one_of(st.sampled_from(NUMBERS), st.sampled_from(WORDS), paths, st.text(max_size=12))


def command_parser(words: str) -> argparse.ArgumentParser:
    parser = build_parser()
    for word in words.split():
        (subparsers,) = [action for action in parser._actions if isinstance(action, argparse._SubParsersAction)]
        parser = subparsers.choices[word]
    return parser


def flags(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The parser's optional arguments but those that print and exit (-h) or change only
    how much is logged."""
    return [action for action in parser._actions if action.option_strings
            and not {"-h", "-v", "-q"} & set(action.option_strings)]


@st.composite
def command_line(draw, parser: argparse.ArgumentParser, positionals: list[str], value: st.SearchStrategy[str]):
    words: list[str] = []
    optional = flags(parser)
    for action in draw(st.lists(st.sampled_from(optional), max_size=5)) if optional else ():
        words.append(draw(st.sampled_from(action.option_strings)))
        count = {None: 1, "?": draw(st.integers(0, 1)), "*": draw(st.integers(0, 2)),
                 "+": draw(st.integers(1, 2))}.get(action.nargs, action.nargs)
        own = st.sampled_from(sorted(map(str, action.choices))) if action.choices else value
        words += [draw(st.one_of(own, value)) for _ in range(count)]
    for positional in positionals:
        words.append(draw(st.one_of(st.just(positional), value)))
    return draw(st.permutations(words)) if draw(st.booleans()) else words


COMMANDS = {
    "render": ["stage"],
    "extract": ["index"],
    "suggest": ["index"],
    "nuke": ["exr"],
    "index info": ["index"],
    "lpe check": [],
    "job run": ["job"],
    "job status": ["job"],
}
"""The commands tried and the input each normally takes. (`view` serves until stopped: its
requests have their own property tests; `demo` takes no input.)"""


@pytest.fixture
def hang_alarm():
    """SIGALRM raises TimeoutError while the test runs."""
    def hang(signal_number, frame):
        raise TimeoutError(f"no answer in {HANG_SECONDS} s")

    previous = signal.signal(signal.SIGALRM, hang)
    yield
    signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_any_command_line_is_answered_in_one_line(command, inputs, tmp_path, monkeypatch, capsys, hang_alarm):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CI", "1")  # no progress bars
    parser = command_parser(command)
    positionals = [str(inputs[name]) for name in COMMANDS[command]]
    if command == "lpe check":
        positionals = ["C<RD>.*L"]

    @PROPERTY
    @given(command_line(parser, positionals, values(inputs)))
    def answered(words):
        argv = [*command.split(), *words, *CHEAP_TAIL.get(command, []), "--quiet"]
        signal.alarm(HANG_SECONDS)  # a hang becomes an internal error, reported below
        try:
            code = main(argv)
        finally:
            signal.alarm(0)
        err = capsys.readouterr().err
        assert "Traceback" not in err and "internal error" not in err, (argv, err)
        assert code in (EXIT_OK, EXIT_USER_ERROR, EXIT_USAGE), (argv, code, err)
        if code == EXIT_USER_ERROR:
            assert sum(line.startswith("pxr-layers: error: ") for line in err.splitlines()) == 1, (argv, err)
        if code == EXIT_USAGE:
            assert err.rstrip().splitlines()[-1].startswith("pxr-layers"), (argv, err)

    answered()
