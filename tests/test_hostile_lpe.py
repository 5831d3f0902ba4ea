"""Hostile Light Path Expressions: blow-ups, huge numbers, wide characters and random text.

Every query either compiles, within a second and to a bounded automaton, or is an LpeError
(a syntax error with its caret under the fault); never another exception. The canonical
form of whatever compiles parses back to the same tree and matches the same paths.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pxr_layers import lpe
from pxr_layers.cli import lpe as lpe_cli
from pxr_layers.errors import LpeError, LpeSyntaxError
from pxr_layers.lpe import automaton as automaton_module
from pxr_layers.lpe import testing
from pxr_layers.lpe.automaton import build_nfa, nfa_state_count
from pxr_layers.lpe.limits import MAX_DFA_STATES, MAX_NESTING, MAX_NFA_STATES, MAX_QUERY_LENGTH, MAX_TOKENS

COMPILE_SECONDS = 1.0
"""What one compile may take, even on a slow machine: the limits keep it far below. Measured
in CPU time of this process, so that other processes loading the machine do not count."""

PROPERTY = settings(deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow])  # reproducible, leaves no .hypothesis/


def timed_compile(query: str):
    """lpe.compile(query) and its time in seconds; the exception instead of the expression if it raises."""
    started = time.process_time()
    try:
        result = lpe.compile(query)
    except Exception as error:  # the caller checks what it is
        result = error
    return result, time.process_time() - started


def syntax_error(query: str) -> LpeSyntaxError:
    with pytest.raises(LpeSyntaxError) as raised:
        lpe.compile(query)
    return raised.value


def caret_line(error: LpeSyntaxError) -> str:
    return str(error).split("\n")[-1]


# --- the size of the automaton, bounded before it is built ------------------------------

BLOW_UPS = [
    # query, position of the caret, what the message says
    ("C(R{1,100}){1,100}L", 11, "this repetition"),  # 100 copies of R{1,100}
    ("C((.{0,100}){0,100}){0,100}L", 12, "this repetition"),  # (.{0,100}){0,100} is past it already
    ("C" + ".{0,100}" * 50 + "L", 1 + 9 * 8, "at this item"),  # the tenth .{0,100} takes it past
    ("C" + "." * 10_000 + "L", 1000, "at this item"),  # event 1000
]


@pytest.mark.parametrize("query, position, words", BLOW_UPS,
                         ids=["nested-R", "nested-dots", "fifty-ranges", "ten-thousand-dots"])
def test_expressions_whose_automaton_would_blow_up_are_refused_at_the_fault_before_it_is_built(query, position, words):
    error, seconds = timed_compile(query)
    assert isinstance(error, LpeSyntaxError), error
    assert seconds < COMPILE_SECONDS
    assert words in error.message and f"{MAX_NFA_STATES}" in error.message and "MAX_NFA_STATES" in error.message
    assert error.position == position
    assert len(str(error).split("\n")[1]) < 2 * LpeSyntaxError.SHOWN_CONTEXT + 10  # a long query is cut


def test_the_cli_refuses_a_blow_up_in_one_error_and_exit_1(capsys):
    started = time.process_time()
    assert lpe_cli.main(["check", "C(R{1,100}){1,100}L"]) == 1
    assert time.process_time() - started < COMPILE_SECONDS
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("pxr-layers: error: position 11: this repetition makes the expression too large: "
                                   "100 copies")
    assert captured.err.endswith("  C(R{1,100}){1,100}L\n             ^\n")


def test_a_long_alternation_is_refused_at_the_alternative_that_takes_it_past():
    alternative = "C" + "." * 300  # 603 states
    query = "|".join([alternative] * 5)
    assert syntax_error(query).position == 3 * (len(alternative) + 1)  # the fourth


def test_the_longest_sequence_within_the_limit_compiles_and_one_event_more_does_not():
    # C and n dots: a sequence (1 state) of n + 1 events (2 each).
    longest = "C" + "." * ((MAX_NFA_STATES - 3) // 2)
    assert MAX_NFA_STATES - 1 <= nfa_state_count(lpe.parse(longest)) <= MAX_NFA_STATES
    assert lpe.compile(longest).automaton.complete
    assert syntax_error(longest + ".").position == len(longest)


def test_the_estimate_is_exactly_the_nfa_the_compiler_builds():
    rng = np.random.default_rng(18)
    queries = ["C.{0,100}L", "C(R{1,3}|T*){2,}L", "R{0}", "(R{0}){5}", "C[<RD>L]{3,7}", "C<RD>@(|S_C| = 0)*L"]
    trees = [lpe.parse(query) for query in queries] + [testing.random_tree(rng, 4) for _ in range(100)]
    for tree in trees:
        # build_nfa adds one start state shared by every layer.
        assert nfa_state_count(tree) == build_nfa({"x": tree}).state_count - 1, lpe.canonical(tree)


def test_trees_built_in_code_are_bounded_too():
    tree = lpe.parse("C.{0,100}")
    for _ in range(2):
        tree = lpe.nodes.repeat(tree, 0, 100)
    with pytest.raises(LpeError, match="MAX_NFA_STATES"):
        lpe.LayerAutomaton({"huge": tree})


def test_empty_repetitions_count_too():
    # R{0} reads nothing but is two states; nested, copies of it still multiply.
    error = syntax_error("C((R{0}){100}){100}L")
    assert error.position == 14 and "this repetition" in error.message


HARDEST_ACCEPTED = {
    "exponential, complete": "C.*R.{11}L",  # the 2**11 states of the last events
    "exponential, on demand": "C.*R.{12}L",
    "a thousand events": "C" + "." * 997 + "L",
    "nested ranges": "C(.{0,30}){0,30}L",
    "nested counts": "C(R{1,30}){1,30}L",
    "chain of ranges": "C" + ".{0,100}" * 9 + "L",
    "many guards": "C(" + "|".join(f"<{t}{s}'l{i}'>" for t in "RTV" for s in "DGSs" for i in range(13)) + ")*L",
    "a long sequence of guards": "C" + "".join(f"<{t}{s}'l{i}'>" for i in range(13) for t in "RTV" for s in "DG") + "L",
    "guards with conditions": "C(" + "|".join(f"<{t}{s}'l{i}'>@(|S_C| > {i})" for t in "RT" for s in "DG"
                                              for i in range(13)) + ")*L",
    "many label sets": "C.*(" + "|".join(f"<L.[^'l{i}']>" for i in range(13)) + ").{5}",
}


@pytest.mark.parametrize("query", HARDEST_ACCEPTED.values(), ids=HARDEST_ACCEPTED.keys())
def test_lpe_check_takes_under_a_second_on_the_hardest_expressions_it_accepts(query, capsys):
    started = time.process_time()
    assert lpe_cli.main(["check", query]) == 0
    assert time.process_time() - started < COMPILE_SECONDS
    assert capsys.readouterr().out.splitlines()[1].startswith("automaton: ")


def test_an_exponential_subset_construction_is_built_on_demand_and_says_so(capsys):
    assert lpe_cli.main(["check", "C.*R.{12}L"]) == 0
    assert "automaton: built on demand (building it complete takes more than" in capsys.readouterr().out


def test_matching_past_the_dfa_state_limit_is_an_lpe_error(monkeypatch):
    monkeypatch.setattr(automaton_module, "MAX_DFA_STATES", 300)  # the real limit takes 50 000 states to reach
    expression = lpe.compile("C.*R.{12}L")
    assert not expression.automaton.complete
    rng = np.random.default_rng(0)
    with pytest.raises(LpeError, match="needs more than 300 states .*MAX_DFA_STATES"):
        for _ in range(1000):
            middle = [lpe.Event("R" if rng.random() < 0.5 else "T", "D") for _ in range(20)]
            expression.matches([lpe.Event("C"), *middle, lpe.Event("L")])
    assert expression.state_count <= 300


def test_the_complete_build_stops_at_the_dfa_state_limit(monkeypatch):
    monkeypatch.setattr(automaton_module, "MAX_DFA_STATES", 100)
    automaton = lpe.compile("C.*R.{8}L").automaton  # 2**8 states and more
    assert not automaton.complete and "100 states" in automaton.on_demand_reason


def test_long_queries_are_refused_past_the_token_and_length_limits():
    letters = "[" + "R" * (MAX_TOKENS - 2) + "]"  # one event, as many tokens as allowed
    expression, seconds = timed_compile(letters)
    assert isinstance(expression, lpe.Expression) and seconds < COMPILE_SECONDS
    error = syntax_error("[R" + letters[1:])
    assert error.position == MAX_TOKENS and "MAX_TOKENS" in error.message
    condition = "C<RD>@(" + " or ".join(["|S_C| > 1"] * (MAX_TOKENS // 5)) + ")L"  # "| S_C | > 1 or": 6 tokens
    error = syntax_error(condition)
    assert "MAX_TOKENS" in error.message and len("C<RD>@(") < error.position < len(condition) - 2
    assert "MAX_QUERY_LENGTH" in syntax_error("C" + " " * MAX_QUERY_LENGTH + "L").message


def test_a_per_light_expression_over_thousands_of_lights_compiles_quickly():
    lights = [f"/World/Lights/rig/light_{i:05d}" for i in range(5000)]
    started = time.process_time()
    automaton = lpe.compile_layers(lpe.per_light_passes({"rig": lights, "key": ["/World/Lights/key"]}))
    assert time.process_time() - started < COMPILE_SECONDS
    event = lpe.Event("L", "", {lights[1234]})
    assert automaton.accepting_layers([lpe.Event("C"), event]) == {"light_rig"}


# --- numbers -----------------------------------------------------------------------------


@pytest.mark.parametrize("number", ["1e999", "-1e999", "1e39", "-3.5e38", "9" * 400])
def test_numbers_past_float32_are_refused_at_their_position(number):
    query = f"C.*D@(|S_C| > {number}).*"
    error = syntax_error(query)
    assert error.position == query.index(number.lstrip("-")) - number.startswith("-")
    assert "out of range" in error.message and "3.4028235e+38" in error.message
    assert len(error.message) < 100  # a number of 400 digits is cut


def test_the_largest_float32_and_tiny_numbers_round_trip():
    for number, printed in [("3.4028234663852886e38", "3.4028234663852886e+38"), ("-3e38", "-3e+38"),
                            ("1e-999", "0"), ("1e-50", "1e-50"), ("-0", "-0")]:
        expression = lpe.compile(f"C D@(|S_C| > {number}) L")
        assert expression.canonical == f"CD@(|S_C| > {printed})L"
        assert lpe.compile(expression.canonical).tree == expression.tree


def test_much_greater_than_a_huge_number_compares_without_overflow():
    # 10·3e38 is past float32: the comparison takes it as +inf, which no finite value exceeds.
    norms = np.array([[[0, 0, 0]], [[3e38, 3e38, 3e38]]], np.float32)
    for query, expected in [("C D@(|S_C| >> 3e38) L", [False, False]), ("C D@(|S_C| >> -3e38) L", [True, True]),
                            ("C D@(|S_C| >> |S_T|) L", [False, False])]:
        outcome = lpe.compile(query).outcome(lpe.parse_path("C RD L").events)
        assert outcome.mask(norms).tolist() == expected, query


def test_path_values_past_float32_are_refused():
    with pytest.raises(LpeSyntaxError, match="out of range") as raised:
        lpe.parse_path("C RD{C=0, T=1e999} L")
    assert raised.value.position == 12


# --- other hostile text ------------------------------------------------------------------


@pytest.mark.parametrize("bound", ["²", "٣", "9" * 5000, "1,0" + "0" * 5000])
def test_repetition_bounds_are_ascii_digits_of_at_most_the_limit(bound):
    error = syntax_error(f"C.{{{bound}}}L")
    assert error.position == 2


def test_leading_zeros_of_a_bound_are_ignored_however_many():
    assert lpe.compile("C.{" + "0" * 5000 + "3}L").canonical == "C.{3}L"


def test_parentheses_in_a_condition_nest_at_most_the_limit():
    def nested(depth):
        return "C D@(" + "(" * depth + "|S_C| = 0" + ")" * depth + ") L"

    assert lpe.compile(nested(MAX_NESTING)).canonical == "CD@(|S_C| = 0)L"
    error = syntax_error(nested(MAX_NESTING + 1))
    assert "nest more than" in error.message and error.position == 5 + MAX_NESTING
    assert "nest more than" in syntax_error(nested(5000)).message  # not a RecursionError


# --- the caret, by display width ---------------------------------------------------------


@pytest.mark.parametrize(
    "before, padding",
    [
        ("'光'", "    "),  # a wide character takes two columns
        ("'ｆｕｌｌ'", "  " + "  " * 4),  # full-width letters too
        ("'😀'", "    "),  # an emoji
        ("'e\u0301'", "   "),  # a combining accent takes none
        ("'👩\u200d💻'", "    "),  # a joined emoji is one glyph
        ("\t'a'", "\t   "),  # a tab stays a tab
        ("'\x1b[31m'", " " * len("'\\x1b[31m'")),  # a control character is shown escaped
    ],
)
def test_the_caret_sits_under_the_fault_after_wide_combining_and_control_characters(before, padding):
    error = syntax_error(f"C{before}Z")
    assert error.position == 1 + len(before)
    query_line, carets = str(error).split("\n")[1:]
    assert "\x1b" not in query_line
    assert carets == "  " + " " + padding + "^"


def test_a_long_line_is_cut_around_the_caret():
    error = syntax_error("C" + "." * 500 + "Z" + "." * 500)
    _, query_line, carets = str(error).split("\n")
    context = LpeSyntaxError.SHOWN_CONTEXT
    assert query_line == "  …" + "." * context + "Z" + "." * (context - 1) + "…"
    assert carets == "  " + " " * (1 + context) + "^"


# --- random expressions, random text -----------------------------------------------------

LABELS = ["key", "fill", "floor", "/World/Lights/*", "k*", "光", "😀", "e\u0301", "a b"]
NUMBERS = ["0", "1", "2.5", "-3", ".5", "6e-1", "1e999", "1e-999", "3.5e38", "1e38", "+7"]
QUANTITIES = ["|S_C|", "|S_T|", "|S_R|", "‖Σ_C‖", "S12", "Σ33", "S21"]
COMPARATORS = ["=", "==", "!=", "≠", "<", "<=", "≤", ">", ">=", "≥", ">>", "≫"]
PAPER_CONDITIONS = ["C(|S_C| = 0)", "T(‖Σ_T‖ > 6)", "R(|S_R| > 2)", "Σ(Σ11 >> Σ22)", "S(S12 < 0)"]
LPE_CHARACTERS = "CRTVLOBDGSsx.'<>[]^()|*+?{},@ S_|‖Σ=!<>0123456789.e-and or \t\n光😀\u0301"


def joined(*parts):
    """A strategy for the text of its parts (strategies of text or of lists of text) in a row."""
    return st.tuples(*parts).map(lambda drawn: "".join(part if isinstance(part, str) else "".join(part)
                                                       for part in drawn))


labels = st.sampled_from(LABELS).map(lambda label: f"'{label}'")
types = st.sampled_from("CRTVLOB")
scatters = st.sampled_from("DGSsx")


def letter_list(letters, openings=("[", "[^")):
    return joined(st.sampled_from(openings), st.lists(letters, min_size=1, max_size=3), st.just("]"))


def slot(letters):
    return st.one_of(letters, st.just("."), letter_list(letters))


label_slots = st.lists(st.one_of(labels, st.just("."), letter_list(labels)), max_size=2)
groups = joined(st.just("<"), slot(types), slot(scatters), label_slots, st.just(">")) | st.sampled_from(["<>", "<R>"])
events = st.one_of(types, scatters, st.just("."), labels, groups, letter_list(types | scatters, openings=("[^",)))

operands = st.sampled_from(QUANTITIES) | st.sampled_from(NUMBERS)
comparisons = st.tuples(operands, st.sampled_from(COMPARATORS), operands).map(" ".join)
condition_bodies = st.recursive(
    comparisons,
    lambda inner: joined(inner, st.sampled_from([" and ", " or "]), inner) | inner.map(lambda body: f"({body})"),
    max_leaves=4,
)
conditions = condition_bodies.map(lambda body: f"@({body})") | st.sampled_from(PAPER_CONDITIONS)
bounds = st.integers(0, 110)  # past MAX_REPETITION too
repetitions = st.one_of(
    st.sampled_from(["", "", "", "*", "+", "?"]),
    bounds.map(lambda n: f"{{{n}}}"),
    bounds.map(lambda n: f"{{{n},}}"),
    st.tuples(bounds, bounds).map(lambda pair: f"{{{min(pair)},{max(pair)}}}"),
)
items = joined(events, st.lists(conditions, max_size=1), repetitions)
expressions = st.recursive(
    items,
    lambda inner: st.one_of(
        st.lists(inner, min_size=1, max_size=4).map("".join),  # a sequence
        st.lists(inner, min_size=2, max_size=3).map("|".join),  # an alternation
        joined(st.just("("), inner, st.just(")"), repetitions),  # a group, repeated or not
        joined(st.just("["), st.lists(inner, min_size=1, max_size=3), st.just("]")),  # a set
        inner.map(lambda text: f" {text} "),
    ),
    max_leaves=10,
)
garbage = st.text(alphabet=LPE_CHARACTERS, max_size=40) | st.text(max_size=30)  # the second: any unicode


@st.composite
def mutated(draw):
    """A random expression with a few characters deleted or inserted."""
    text = draw(expressions)
    for _ in range(draw(st.integers(1, 3))):
        position = draw(st.integers(0, len(text)))
        if draw(st.booleans()):
            text = text[:position] + text[position + 1:]
        else:
            text = text[:position] + draw(st.text(alphabet=LPE_CHARACTERS, min_size=1, max_size=2)) + text[position:]
    return text


def check_compiles_or_refuses(query: str):
    """The expression, or None when refused; asserts the time, the automaton's size and the error's form."""
    result, seconds = timed_compile(query)
    assert seconds < COMPILE_SECONDS, (query, seconds)
    if isinstance(result, Exception):
        assert isinstance(result, LpeError), (query, repr(result))
        if isinstance(result, LpeSyntaxError):
            assert 0 <= result.position <= len(query)
            assert caret_line(result).endswith("^") and result.message in str(result)
        return None
    assert result.automaton.nfa.state_count <= MAX_NFA_STATES + 1  # + the start state
    assert result.state_count <= MAX_DFA_STATES
    return result


@settings(PROPERTY, max_examples=250)
@given(query=st.one_of(expressions, mutated(), garbage))
def test_any_text_compiles_in_bounded_time_and_size_or_is_an_lpe_error(query):
    check_compiles_or_refuses(query)
    assert isinstance(lpe.hints(query), list)


def agrees_with_the_reference(expression: lpe.Expression, path, rng) -> str:
    """Asserts that the automaton says of ``path`` what the reference matcher says (on random
    covariance values when it has conditions); returns the outcome's kind."""
    outcome = expression.outcome(path)
    if not expression.has_conditions:
        assert (outcome.kind == "always") == lpe.reference_match(expression.tree, path), (expression.canonical, path)
        return outcome.kind
    norms, sigma = testing.random_values(rng, 8, max(len(path) - 1, 1))
    try:
        mask = outcome.mask(norms, sigma)
    except LpeError:  # the answer depends on a condition on the camera event
        return outcome.kind
    for record in range(len(norms)):
        try:
            expected = lpe.reference_match(expression.tree, path, norms[record], sigma[record])
        except LpeError:  # the reference tests every condition it meets, the camera's too
            continue
        assert mask[record] == expected, (expression.canonical, path, record)
    return outcome.kind


@settings(PROPERTY, max_examples=200)
@given(query=expressions, seed=st.integers(0, 2**32 - 1))
def test_the_canonical_form_round_trips_and_matches_the_same_paths(query, seed):
    expression = check_compiles_or_refuses(query)
    if expression is None:
        return
    again = check_compiles_or_refuses(expression.canonical)
    assert again is not None, expression.canonical
    assert again.tree == expression.tree and again.canonical == expression.canonical
    rng = np.random.default_rng(seed)
    for _ in range(4):
        sampled = testing.sample_path(rng, expression.tree)  # a path it should match, conditions aside
        for path in (testing.random_path(rng, max_length=6), sampled):
            if path is not None and len(path) <= 12:
                assert agrees_with_the_reference(expression, path, rng) == agrees_with_the_reference(again, path, rng)
