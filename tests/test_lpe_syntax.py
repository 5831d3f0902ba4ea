"""LPE syntax: the tree each spelling gives, the canonical form, and errors with their caret."""

from __future__ import annotations

import numpy as np
import pytest

from pxr_layers.errors import LpeError, LpeSyntaxError, PxrLayersError
from pxr_layers.lpe import canonical, nodes, parse, testing
from pxr_layers.lpe import conditions as cond
from pxr_layers.lpe.nodes import EventPattern, LabelTerm, SymbolSet


def types(letters, negated=False):
    return SymbolSet(frozenset(letters), negated)


def scatters(letters, negated=False):
    return SymbolSet(frozenset("" if letter == "x" else letter for letter in letters), negated)


R = EventPattern(types("R"))
C = EventPattern(types("C"))
L = EventPattern(types("L"))
D = EventPattern(scatters=scatters("D"))
ANY = EventPattern()


# --- what each spelling means ----------------------------------------------------------


@pytest.mark.parametrize(
    "bare, group",
    [("D", "<.D>"), ("R", "<R.>"), ("R", "<R>"), (".", "<..>"), (".", "<>"), ("x", "<.x>"), ("'key'", "<..'key'>")],
)
def test_a_bare_letter_is_one_whole_event_with_the_other_slot_wildcard(bare, group):
    assert parse(bare) == parse(group)


def test_group_slots_are_type_scattering_then_labels():
    assert parse("<RD'floor'>") == EventPattern(types("R"), scatters("D"), (LabelTerm(("floor",)),))
    assert parse("<L.'key'>") == EventPattern(types("L"), None, (LabelTerm(("key",)),))
    assert parse("<[RT][^DG]'a'[^'b''c']>") == EventPattern(
        types("RT"), scatters("DG", negated=True), (LabelTerm(("a",)), LabelTerm(("b", "c"), negated=True))
    )
    assert parse("<R.>") == R
    # A '.' in a label slot asks for one label of any name (OSL: one custom label).
    assert parse("<R..>") == EventPattern(types("R"), None, (LabelTerm((nodes.ANY_LABEL,)),))


def test_sets_of_one_slot_fold_into_one_event():
    assert parse("[LO]") == EventPattern(types("LO"))
    assert parse("[DG]") == EventPattern(scatters=scatters("DG"))
    assert parse("['a''b']") == EventPattern(labels=(LabelTerm(("a", "b")),))
    assert parse("[^RT]") == EventPattern(types("RT", negated=True))
    assert parse("[^'a']") == EventPattern(labels=(LabelTerm(("a",), negated=True),))
    assert parse("[CRTVLOB]") == ANY  # naming every type is no constraint
    # Items of different slots stay alternatives, as in OSL.
    assert parse("[RD]") == nodes.Union((R, D))
    assert parse("[<RD>L]") == nodes.Union((EventPattern(types("R"), scatters("D")), L))


def test_standard_precedence_alternation_is_lowest():
    # OSL would read AB|CD as A(B|C)D; here it is (AB)|(CD).
    assert parse("CR|LD") == nodes.Union((nodes.Concat((C, R)), nodes.Concat((L, D))))
    assert parse("C(R|L)D") == nodes.Concat((C, nodes.Union((R, L)), D))
    assert parse("CR*") == nodes.Concat((C, nodes.Repeat(R, 0, None)))


def test_leading_parenthesised_group_keeps_what_follows():
    # OSL drops everything after a leading "(...)"; nothing is dropped here.
    assert parse("(CR)L") == nodes.Concat((C, R, L))


@pytest.mark.parametrize(
    "text, bounds",
    [("R*", (0, None)), ("R+", (1, None)), ("R?", (0, 1)), ("R{3}", (3, 3)), ("R{2,}", (2, None)),
     ("R{1,4}", (1, 4)), ("R{0}", (0, 0)), ("R{ 2 , 5 }", (2, 5))],
)
def test_repetitions(text, bounds):
    assert parse(text) == nodes.Repeat(R, *bounds)


def test_repetition_of_one_is_the_body():
    assert parse("R{1}") == R and parse("R{1,1}") == R


def test_whitespace_is_ignored_between_tokens_but_kept_in_labels():
    assert parse(" C  <R D 'my floor'> . * L ") == parse("C<RD'my floor'>.*L")
    assert parse("C<RD'my floor'>").items[1].labels[0].patterns == ("my floor",)


def test_labels_are_kept_verbatim_including_globs_and_paths():
    tree = parse("C.*<L.'/World/Lights/*'>")
    assert nodes.label_patterns(tree) == ["/World/Lights/*"]


# --- canonical form --------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, expected",
    [
        ("C<RD>.*L", "C<RD>.*L"),
        ("C <R D> .* L", "C<RD>.*L"),
        ("C<R.>L", "CRL"),
        ("C<.D>L", "CDL"),
        ("C[LO]", "C[LO]"),
        ("C[OL]", "C[LO]"),
        ("C.*<L.'key'>", "C.*<L.'key'>"),
        ("C<..'key'>", "C'key'"),
        ("C['a' 'b']", "C['a''b']"),
        ("R?", "R{0,1}"),
        ("C(R|T)L", "C(R|T)L"),
        ("CR|LD", "((CR)|(LD))"),
        ("(RD)*", "((RD)*)"),
        ("C(R*)*", "C(R*)*"),
        ("C<.x>", "Cx"),
        ("C[^x]", "C[^x]"),
        ("C<L.[^'a''b']>", "C<L.[^'a''b']>"),
    ],
)
def test_canonical_form(text, expected):
    assert canonical(parse(text)) == expected
    assert parse(expected) == parse(text)


def test_canonical_form_of_random_trees_parses_back_to_the_same_tree():
    rng = np.random.default_rng(7)
    for _ in range(300):
        tree = testing.random_tree(rng, depth=3, condition_rate=0.3, with_entries=True)
        text = canonical(tree)
        assert parse(text) == tree, text


# --- covariance conditions -------------------------------------------------------------

PAPER = cond.all_of([
    cond.Comparison(cond.Norm("C"), "=", cond.Number(0.0)),
    cond.Comparison(cond.Norm("T"), ">", cond.Number(6.0)),
    cond.Comparison(cond.Norm("R"), ">", cond.Number(2.0)),
])


@pytest.mark.parametrize(
    "text",
    [
        "D C(‖Σ_C‖ = 0) T(‖Σ_T‖ > 6) R(‖Σ_R‖ > 2)",
        "D C(|S_C| = 0) T(|S_T| > 6) R(|S_R| > 2)",
        "D C(||S_C|| = 0) T(||S_T|| > 6) R(||S_R|| > 2)",
        "DC(|S_C|=0)T(|S_T|>6)R(|S_R|>2)",
        "D@(|S_C| = 0 and |S_T| > 6 and |S_R| > 2)",
        "D @(|S_C| = 0) @(|S_T| > 6 and |S_R| > 2)",
        "<.D>@(‖Σ_C‖ = 0 and ‖Σ_T‖ > 6 and ‖Σ_R‖ > 2)",
    ],
)
def test_the_papers_notation_in_unicode_and_ascii_and_the_canonical_form_agree(text):
    assert parse(text) == EventPattern(scatters=scatters("D"), condition=PAPER)
    assert canonical(parse(text)) == "D@(|S_C| = 0 and |S_T| > 6 and |S_R| > 2)"


def test_a_condition_is_recognised_by_what_follows_the_parenthesis():
    assert parse("C(R)") == nodes.Concat((C, R))  # plain OSL: camera, then R
    assert parse("C(RD)L") == nodes.Concat((C, R, D, L))
    assert parse("C (R|T)") == nodes.Concat((C, nodes.Union((R, EventPattern(types("T"))))))
    assert parse("RC(|S_C| > 1)").condition == cond.Comparison(cond.Norm("C"), ">", cond.Number(1.0))
    assert parse("DS(S11 >> S22)") == EventPattern(
        scatters=scatters("D"), condition=cond.Comparison(cond.Entry(1, 1), ">>", cond.Entry(2, 2))
    )
    assert parse("DΣ(Σ11 ≫ Σ22)") == parse("DS(S11 >> S22)")


def test_or_inside_one_condition_and_grouping():
    tree = parse("D C(|S_C| = 0 or |S_C| > 2)")
    assert tree.condition == cond.any_of([
        cond.Comparison(cond.Norm("C"), "=", cond.Number(0.0)),
        cond.Comparison(cond.Norm("C"), ">", cond.Number(2.0)),
    ])
    chained = parse("D C(|S_C| = 0 or |S_C| > 2) T(|S_T| > 1)")
    assert canonical(chained) == "D@((|S_C| = 0 or |S_C| > 2) and |S_T| > 1)"
    assert parse(canonical(chained)) == chained
    # "and" binds tighter than "or".
    assert canonical(parse("D@(|S_C| = 0 or |S_T| > 1 and |S_R| < 2)")) == "D@(|S_C| = 0 or |S_T| > 1 and |S_R| < 2)"


@pytest.mark.parametrize(
    "spelling, canonical_spelling",
    [("==", "="), ("≠", "!="), ("≤", "<="), ("≥", ">="), ("≫", ">>"), ("!=", "!="), ("<", "<"), (">=", ">=")],
)
def test_comparison_spellings(spelling, canonical_spelling):
    assert canonical(parse(f"D@(|S_T| {spelling} 2.5)")) == f"D@(|S_T| {canonical_spelling} 2.5)"


def test_matrix_entries_are_one_based_and_symmetric():
    assert parse("D@(S21 > 0)") == parse("D@(S12 > 0)")
    assert canonical(parse("D@(Σ_43 < -1e-3)")) == "D@(S34 < -0.001)"
    assert [cond.sigma_column(i, j) for i in range(1, 5) for j in range(i, 5)] == list(range(10))


def test_conditions_attach_to_events_of_sets_and_repeat_with_them():
    assert parse("[RT]@(|S_R| > 1)").types == types("RT")
    repeated = parse("D@(|S_C| = 0)*")
    assert isinstance(repeated, nodes.Repeat) and repeated.body.condition is not None


# --- errors ----------------------------------------------------------------------------


def caret_column(error: LpeSyntaxError) -> int:
    """Column of the caret in the error text, relative to the query line above it."""
    _message, query_line, caret_line = str(error).split("\n")
    assert query_line.startswith("  ") and caret_line.startswith("  ")
    return caret_line.index("^") - 2


@pytest.mark.parametrize(
    "query, position, words",
    [
        ("", 0, "empty expression"),
        ("C<RD", 4, "expected '>' to close the event '<' opened at position 1"),
        ("C[LO", 4, "expected ']' to close the '[' at position 1"),
        ("C(RD", 4, "expected ')' to close the '(' at position 1"),
        ("CRD)", 3, "unexpected ')': no '(' is open"),
        ("C|", 2, "ends early"),
        ("|C", 0, "both sides"),
        ("C*+", 2, "two repetitions"),
        ("*C", 0, "repetition must follow"),
        ("C<R<D>>", 3, "inside <...>"),
        ("C<R*>", 3, "repetitions are not allowed inside"),
        ("C<D>", 2, "scattering"),
        ("C<L'key'>", 3, "labels come after"),
        ("C<RDL>", 4, "not a label"),
        ("C[^RD]", 4, "mixes"),
        ("C[]", 1, "empty"),
        ("C{2,1}", 1, "maximum below its minimum"),
        ("C{x}", 1, "bad repetition"),
        ("C{1000}", 1, "above 100"),
        ("C'key", 5, "expected ' to close the label opened at position 1"),
        ("C''", 1, "empty label"),
        ("Cd", 1, "unknown letter 'd'"),
        ('C"key"', 1, "single quotes"),
        ("C^R", 1, "'^'"),
        ("C@R", 1, "'@'"),
        ("C(|S_C| = 0)", 0, "must follow an event"),
        ("C R*@(|S_C| = 0)", 4, "not a repetition"),
        ("C (RD)@(|S_C| = 0)", 6, "follows one event"),
        ("C<RD@(|S_C| = 0)>", 4, "after the closing '>'"),
        ("D C(|S_C| = 0", 13, "close the condition"),
        ("D C(|S_C| ~ 0)", 10, "unexpected character"),
        ("D C(|S_C| 0)", 10, "expected a comparison"),
        ("D T(|S_C| > 2)", 2, "T(...) conditions read |S_T| only"),
        ("D @(1 < 2)", 4, "stored quantity"),
        ("D @(|S_C| < 1 < 2)", 14, "chained"),
        ("D @(|S11| > 0)", 5, "without bars"),
        ("D @(S_C > 0)", 4, "with bars"),
        ("D @(S15 > 0)", 4, "unknown quantity"),
        ("D @(|S_C| > 0 nand |S_T| > 1)", 14, "unknown word"),
        ("D @(|S_C| > )", 12, "expected |S_C|"),
        ("D @(|S_C‖ > 1)", 8, "to close the norm"),
    ],
)
def test_syntax_errors_name_the_position_with_a_caret(query, position, words):
    with pytest.raises(LpeSyntaxError) as caught:
        parse(query)
    error = caught.value
    assert words in error.message
    assert error.position == position, str(error)
    assert error.query == query
    assert caret_column(error) == position
    assert isinstance(error, LpeError) and isinstance(error, PxrLayersError)


@pytest.mark.parametrize(
    "query, position, words",
    [
        # unclosed '<': the caret where the '>' goes, the message names where the '<' opened
        ("C<RD'redWall'.*L", 13, "expected '>' to close the event '<' opened at position 1"),
        ("C<RD.*<L'key'", 4, "expected '>' to close the event '<' opened at position 1"),
        ("C<RD<L>", 4, "expected '>' to close the event '<' opened at position 1: no <...> inside"),
        ("C<RD|L>", 4, "expected '>' to close the event '<' opened at position 1: no '|'"),
        ("C<RD(L)>", 4, "expected '>' to close the event '<' opened at position 1: no (...)"),
        ("C<R+>", 3, "expected '>' to close the event '<' opened at position 1: repetitions"),
        ("C<R-D>", 3, "expected '>' to close the event '<' opened at position 1: no '-'"),
        ("C<R.'a'", 7, "expected '>' to close the event '<' opened at position 1"),
        # unclosed '[' (an alternative set, a list of letters, a list in a slot)
        ("C[<RD>L", 7, "expected ']' to close the '[' at position 1"),
        ("C[^RT", 5, "expected ']' to close the '[' at position 1"),
        ("C<[RT", 5, "expected ']' to close the '[' at position 2"),
        ("C[^R.]L", 4, "expected an event letter, a quoted label or ']' to close the '[' at position 1"),
        ("C[R|T]", 3, "expected an item or ']' to close the '[' at position 1"),
        ("C[^]", 1, "expected a letter or a label inside the '[' at position 1"),
        # unclosed '(' and '{'
        ("C((RD)L", 7, "expected ')' to close the '(' at position 1"),
        ("C(R>L)", 3, "expected ')' to close the '(' at position 1: unexpected '>'"),
        ("C()L", 2, "expected an expression inside the '(' at position 1"),
        ("C{2", 1, "expected {n}, {n,} or {n,m}"),
        # quotes
        ("C<RD'redWall>.*L", 16, "expected ' to close the label opened at position 4"),
        # conditions
        ("C D@(|S_C| = 0", 14, "expected 'and', 'or' or ')' to close the condition opened at position 4"),
        ("C D@(|S_C| = 0 L", 15,
         "expected 'and', 'or', a quantity, or ')' to close the condition opened at position 4"),
        ("C D@((|S_C| = 0 or |S_T| > 1)", 29, "to close the condition opened at position 4"),
        ("C D@((|S_C| = 0 or |S_T| > 1", 28, "to close the '(' at position 5"),
        # empty alternatives
        ("C||L", 2, "expected an event before '|': an alternative cannot be empty"),
        ("C(R|)L", 4, "expected an event before ')': an alternative cannot be empty"),
        ("C.(|R)L", 3, "expected an event before '|'"),
        # stray closers
        ("C>L", 1, "unexpected '>' without a matching '<'"),
        ("C]L", 1, "unexpected ']' without a matching '['"),
        # set difference in the wrong place
        ("C.*-", 4, "expected an expression after '-'"),
        ("-C.*", 0, "unexpected '-'"),
        ("(C.*-CL)", 4, "expected ')' to close the '(' at position 0: unexpected '-'"),
        ("C.*|-CL", 4, "unexpected '-'"),
    ],
)
def test_every_syntax_error_says_what_was_expected_where(query, position, words):
    with pytest.raises(LpeSyntaxError) as caught:
        parse(query)
    error = caught.value
    assert error.message.startswith(f"position {position}: "), error.message
    assert words in error.message, error.message
    assert error.position == position and caret_column(error) == position


def test_error_text_shows_message_query_and_caret():
    with pytest.raises(LpeSyntaxError) as caught:
        parse("C<RD>.*<L.'key'")
    assert str(caught.value) == ("position 15: expected '>' to close the event '<' opened at position 7\n"
                                 "  C<RD>.*<L.'key'\n                 ^")


def test_hints_flag_path_notation_events_written_in_an_expression():
    from pxr_layers.lpe import hints

    assert hints("C RD L") == ["'RD' at 2 is two events (R, then D); one RD event is written <RD>"]
    assert hints("C Ts<RD>L")[0].startswith("'Ts' at 2")
    for fine in ("C<RD>L", "C[RD]L", "CDL", "C R D L", "C<RD"):
        assert hints(fine) == [], fine
