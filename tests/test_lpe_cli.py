"""`pxr-layers lpe check|match`, called in-process (run(args) and the module's main(argv))."""

from __future__ import annotations

import argparse

import pytest

from pxr_layers.cli import lpe as lpe_cli


def parse_args(*argv: str) -> argparse.Namespace:
    """Arguments as `pxr-layers` would parse them, with the lpe subcommand added to it."""
    parser = argparse.ArgumentParser(prog="pxr-layers")
    commands = parser.add_subparsers(dest="command", required=True)
    lpe_parser = lpe_cli.add_parser(commands)
    lpe_parser.add_argument("-q", "--quiet", action="store_true")  # as main.py adds to every subcommand
    return parser.parse_args(argv)


def test_check_prints_the_canonical_form_and_the_automaton_size(capsys):
    assert lpe_cli.run(parse_args("lpe", "check", "C <R D> .* <L . 'key'>")) == 0
    assert capsys.readouterr().out == "canonical: C<RD>.*<L.'key'>\nautomaton: 4 states, 6 transitions\n"


def test_check_prints_conditions_in_canonical_form(capsys):
    assert lpe_cli.run(parse_args("lpe", "check", "C.*D C(‖Σ_C‖ = 0) T(‖Σ_T‖ > 6) R(‖Σ_R‖ > 2).*")) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "canonical: C.*D@(|S_C| = 0 and |S_T| > 6 and |S_R| > 2).*"
    assert lines[1].startswith("automaton: ") and lines[1].endswith("transitions")


def test_check_says_when_the_automaton_is_built_on_demand(capsys):
    many = "|".join(f"C.*<L.'light{i}'>" for i in range(14))
    assert lpe_cli.run(parse_args("lpe", "check", many)) == 0
    assert "built on demand" in capsys.readouterr().out


def test_match_prints_one_line_per_path_in_order(capsys):
    paths = ["C RD'floor' RG'chrome' L'key'", "C RG L'key'", "C RD L'fill'"]
    args = parse_args("lpe", "match", "C<RD>.*<L.'key'>", *paths)
    assert lpe_cli.run(args) == 0
    assert capsys.readouterr().out == "match\nno match\nno match\n"


def test_match_evaluates_conditions_from_the_values_in_the_path(capsys):
    args = parse_args("lpe", "match", "C.*<RD>@(|S_C| = 0).*", "C RD{C=0, T=1, R=0} L", "C RD{C=2} L", "C RG L")
    assert lpe_cli.run(args) == 0
    assert capsys.readouterr().out == "match\nno match\nno match\n"


def test_match_warns_about_labels_no_path_carries(capsys, caplog):
    assert lpe_cli.run(parse_args("lpe", "match", "C.*<L.'kye'>", "C RD L'key'")) == 0
    assert capsys.readouterr().out == "no match\n"
    assert "'kye'" in caplog.text and "closest: 'key'" in caplog.text


def test_quiet_is_accepted_before_and_after_the_action():
    assert parse_args("lpe", "-q", "check", "C.*").quiet
    assert parse_args("lpe", "check", "C.*", "-q").quiet
    assert not parse_args("lpe", "check", "C.*").quiet


def test_a_syntax_error_is_exit_1_with_the_caret_on_stderr(capsys):
    assert lpe_cli.main(["check", "C<RD"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == ("pxr-layers: error: position 4: expected '>' to close the event '<' opened at position 1\n"
                            "  C<RD\n      ^\n")


def test_a_bad_path_is_exit_1_and_nothing_is_printed(capsys):
    assert lpe_cli.main(["match", "C.*", "C L", "C R L"]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and "need a scattering letter" in captured.err


def test_a_condition_without_values_in_the_path_is_exit_1(capsys):
    assert lpe_cli.main(["match", "C <RD>@(|S_C| = 0) L", "C RD L"]) == 1
    assert "gives none" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [[], ["check"], ["match", "C.*"], ["bogus", "C.*"], ["check", "C.*", "--nope"]])
def test_usage_errors_are_exit_2(argv, capsys):
    assert lpe_cli.main(argv) == 2
    assert "usage:" in capsys.readouterr().err


def test_help_is_exit_0(capsys):
    assert lpe_cli.main(["match", "--help"]) == 0
    assert "PATH" in capsys.readouterr().out


def test_an_event_spelled_as_in_the_path_notation_gets_a_note(capsys, caplog):
    assert lpe_cli.run(parse_args("lpe", "match", "C RD L", "C RD L")) == 0
    assert capsys.readouterr().out == "no match\n"  # R then D: four events
    assert "'RD' at 2 is two events (R, then D); one RD event is written <RD>" in caplog.text


def test_nothing_is_printed_when_one_path_cannot_be_decided(capsys):
    assert lpe_cli.main(["match", "C <RD>@(|S_C| = 0) L", "C RG L", "C RD L"]) == 1
    assert capsys.readouterr().out == ""
