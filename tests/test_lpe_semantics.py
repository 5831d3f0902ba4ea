"""What expressions match: OSL's meaning, our documented decisions, the standard passes.

Every case runs through the automaton and through the reference matcher; they must agree.
"""

from __future__ import annotations

import itertools
import logging

import pytest

from pxr_layers import lpe
from pxr_layers.errors import LpeSyntaxError
from pxr_layers.lpe import (
    Event,
    closest_labels,
    compile_layers,
    format_path,
    parse_path,
    reference_match,
)


def matches(expression: str, path: str) -> bool:
    by_automaton = lpe.compile(expression).matches(path)
    by_reference = reference_match(expression, path)
    assert by_automaton == by_reference, (expression, path)
    return by_automaton


CASES = [
    # A bare letter is a whole event; the other slot is a wildcard.
    ("CDL", "C RD L", True),
    ("CDL", "C TD L", True),
    ("CDL", "C RG L", False),
    ("CRL", "C RG L", True),
    ("CRL", "C TG L", False),
    ("C.L", "C VS L", True),
    ("CB", "C B", True),
    ("C[LO]", "C B", False),
    # <type scattering labels...>
    ("C<RD>L", "C RD L", True),
    ("C<RD>L", "C TD L", False),
    ("C<R[DG]>L", "C RG L", True),
    ("C<[RT]D>L", "C TD L", True),
    ("C<R[^D]>L", "C RS L", True),
    ("C<R[^D]>L", "C RD L", False),
    ("C<.s><RD>L", "C Ts RD L", True),
    ("C<.s>RDL", "C Ts RD L", False),  # R then D: two events
    # x is "no scattering" (C, L, O, B)
    ("Cx", "C L", True),
    ("Cx", "C RD", False),
    ("C[^x]", "C RD", True),
    ("C<Lx>", "C L", True),
    # Labels: an event matches when any of its labels does.
    ("C<RD'floor'>L", "C RD'floor' L", True),
    ("C<RD'floor'>L", "C RD'wall' L", False),
    ("C<RD'floor'>L", "C RD L", False),
    ("C<RD'floor'>L", "C RD'wall''floor''/World/floor' L", True),
    ("C'floor'L", "C RD'/World/floor''floor' L", True),
    ("C.*'key'", "C RD L'key'", True),
    ("C<L.['key''fill']>", "C L'fill'", True),
    ("C<L.['key''fill']>", "C L'rim'", False),
    # Several label slots: each must be carried, in any order.
    ("C<RD'floor''wood'>L", "C RD'wood''floor' L", True),
    ("C<RD'wood''floor'>L", "C RD'floor''wood' L", True),
    ("C<RD'floor''wood'>L", "C RD'floor' L", False),
    # A negated label: carries none of them.
    ("C<RD[^'floor']>L", "C RD'wall' L", True),
    ("C<RD[^'floor']>L", "C RD L", True),
    ("C<RD[^'floor']>L", "C RD'wall''floor' L", False),
    ("C[^'floor''wall']L", "C RD'ceiling' L", True),
    ("C[^'floor''wall']L", "C RD'wall' L", False),
    # '.' in a label slot: at least one label.
    ("C<RD.>L", "C RD L", False),
    ("C<RD.>L", "C RD'anything' L", True),
    # Globs (fnmatch, case-sensitive, '*' crosses '/').
    ("C.*<L.'/World/Lights/*'>", "C RD L'/World/Lights/key'", True),
    ("C.*<L.'/World/Lights/*'>", "C RD L'/World/Lights/rig/key'", True),
    ("C.*<L.'/World/Lights/*'>", "C RD L'/World/Props/lamp'", False),
    ("C.*<L.'k?y'>", "C L'key'", True),
    ("C.*<L.'[kf]*'>", "C L'fill'", True),
    ("C.*<L.'Key'>", "C L'key'", False),
    ("C.*<L.[^'/World/Lights/*']>", "C L'/World/Lights/key''key'", False),
    # Negated sets of one slot.
    ("C[^RT]*L", "C VD L", True),
    ("C[^RT]*L", "C RD L", False),
    ("C[^D]L", "C RG L", True),
    ("C[^D]L", "C RD L", False),
    # Repetition bounds.
    ("C.{2}L", "C RD RD L", True),
    ("C.{2}L", "C RD L", False),
    ("C.{2}L", "C RD RD RD L", False),
    ("C.{2,}L", "C RD RD RD L", True),
    ("C.{2,}L", "C RD L", False),
    ("C.{1,2}L", "C L", False),
    ("C.{1,2}L", "C RD L", True),
    ("C.{1,2}L", "C RD TS L", True),
    ("C.{1,2}L", "C RD TS RD L", False),
    ("C.+L", "C L", False),
    ("C.*L", "C L", True),
    ("C.?L", "C L", True),
    ("C.?L", "C RD RD L", False),
    ("C<RD>{0}L", "C L", True),
    ("C(RD)*L", "C RG TD L", True),  # (RD) is two events: an R, then a D
    ("C(RD)*L", "C RD L", False),
    ("C(<RD>|<TS>)+L", "C RD TS RD L", True),
    # Precedence: alternation is lowest (OSL would read CR|LD as C(R|L)D).
    ("CR|LD", "C RD", True),
    ("CR|LD", "L RD", True),
    ("CR|LD", "C RD RD", False),
    ("C<RD>L|CL", "C L", True),
    ("(CR)L", "C RD L", True),  # OSL would drop the L after the leading group
    # Anchoring at both ends.
    ("C", "C RD L", False),
    ("<RD>", "C RD L", False),
    (".*<RD>.*", "C RD L", True),
    ("C.*", "C", True),
    ("CL", "C L RD", False),
    # Per light group.
    ("C.*<L.'key'>", "C RD'floor' RG'chrome' L'key'", True),
    ("C.*<L.'key'>", "C RD L'fill'", False),
    ("C.*<L.'key'>", "C RD O'key'", False),
    ("C.*<L.'key'>", "C L'key' RD", False),
    ("C<V.>.*", "C VD L", True),
]


@pytest.mark.parametrize("expression, path, expected", CASES)
def test_osl_semantics_and_documented_decisions(expression, path, expected):
    assert matches(expression, path) is expected


def test_event_sequences_and_text_give_the_same_answer():
    expression = lpe.compile("C<RD'floor'>.*<L.'key'>")
    events = [Event("C"), Event("R", "D", {"floor", "/World/floor"}), Event("R", "G"), Event("L", "", ["key"])]
    assert expression.matches(events) is True
    assert expression.matches(format_path(events)) is True
    assert reference_match(expression.tree, events) is True


# --- the standard passes ---------------------------------------------------------------

SCATTERING_EVENTS = [Event(t, s, labels) for t in "RTV" for s in "DGSs" for labels in (frozenset(), {"floor"})]
EMITTER_EVENTS = [Event("L", "", {"key"}), Event("O", "", {"lamp"}), Event("B")]


def every_path(max_bounces: int):
    """C, then up to max_bounces R/T/V events, then L, O or B."""
    for bounces in range(max_bounces + 1):
        for middle in itertools.product(SCATTERING_EVENTS, repeat=bounces):
            for end in EMITTER_EVENTS:
                yield (Event("C"), *middle, end)


def test_standard_passes_split_every_path_into_exactly_one_pass():
    recipe = compile_layers(lpe.STANDARD_PASSES)
    beauty = lpe.compile(lpe.BEAUTY)
    count = 0
    for path in every_path(max_bounces=3):
        layers = recipe.accepting_layers(path)
        assert len(layers) == 1, (format_path(path), sorted(layers))
        assert beauty.matches(path)
        count += 1
    assert count == 3 * (1 + 24 + 24**2 + 24**3)


@pytest.mark.parametrize(
    "path, layer",
    [
        ("C L'key'", "emission"),
        ("C O'lamp'", "emission"),
        ("C B", "background"),
        ("C RD'floor' L'key'", "diffuse_direct"),
        ("C RD'floor' B", "diffuse_direct"),
        ("C RD'floor' O'lamp'", "diffuse_direct"),
        ("C RD RG'chrome' L'key'", "diffuse_indirect"),
        ("C RG'chrome' L'key'", "glossy_direct"),
        ("C RS'mirror' RD L", "glossy_indirect"),
        ("C TS'glass' RD L", "transmission"),
        ("C Ts RD'wall' O'lamp'", "transmission"),
        ("C VD L", "volume"),
    ],
)
def test_typical_paths_land_in_the_expected_standard_pass(path, layer):
    recipe = compile_layers(lpe.STANDARD_PASSES)
    assert recipe.accepting_layers(parse_path(path).events) == {layer}
    assert reference_match(lpe.STANDARD_PASSES[layer], path)


def test_the_table_in_lpe_md_leaves_paths_out_which_the_shipped_passes_cover():
    as_written = {
        "emission": "C[LO]", "background": "CB",
        "diffuse_direct": "C<RD>L", "diffuse_indirect": "C<RD>.+[LOB]",
        "glossy_direct": "C<R[GS]>L", "glossy_indirect": "C<R[GS]>.+[LOB]",
        "transmission": "C<T.>.*",
    }
    recipe = compile_layers(as_written)
    for path in ("C RD B", "C RD O", "C RG B", "C VD L", "C Rs L"):
        assert recipe.accepting_layers(parse_path(path).events) == frozenset(), path


def test_per_light_split_is_complete_when_a_light_carries_at_most_one_group():
    groups = ["key", "fill", "rim"]
    recipe = compile_layers(lpe.per_light_passes(groups))
    emitters = [Event("L", "", {group, f"/World/Lights/{group}"}) for group in groups]
    emitters += [Event("L", "", {"practical"}), Event("L"), Event("O", "", {"lamp"}), Event("B")]
    for bounces in range(3):
        for middle in itertools.product(SCATTERING_EVENTS[::3], repeat=bounces):
            for end in emitters:
                layers = recipe.accepting_layers((Event("C"), *middle, end))
                group = end.labels & set(groups)
                expected = f"light_{min(group)}" if group else "light_other"
                assert layers == {expected}


# --- events, path notation, label help -------------------------------------------------


def test_events_validate_their_letters_and_store_labels_as_a_frozenset():
    assert Event("R", "D", ["a", "b", "a"]).labels == frozenset({"a", "b"})
    with pytest.raises(ValueError):
        Event("X")
    with pytest.raises(ValueError):
        Event("R", "q")
    assert str(Event("R", "D", {"wood", "floor"})) == "RD'floor''wood'"


def test_path_notation_round_trips():
    text = "C RD'floor' RG'chrome' L'key'"
    parsed = parse_path(text)
    assert parsed.events == (
        Event("C"), Event("R", "D", {"floor"}), Event("R", "G", {"chrome"}), Event("L", "", {"key"})
    )
    assert format_path(parsed.events) == text
    assert parse_path("CRD'floor'L") == parse_path("C RD 'floor' L")
    with_values = parse_path("C RD'floor'{C=0, T=3.2, R=0} RG{S11=4, S21=-1} L")
    assert parse_path(str(with_values)) == with_values


@pytest.mark.parametrize(
    "path, position, words",
    [
        ("", 0, "empty path"),
        ("C R L", 3, "need a scattering letter"),
        ("C LD", 3, "no scattering letter"),
        ("C RD'floor", 4, "not closed"),
        ("C RD'' L", 4, "empty label"),
        ("C{C=0} L", 1, "camera"),
        ("C RD{C=0, C=1}", 10, "given twice"),
        ("C RD{X=1}", 5, "expected C, T, R"),
        ("C RD{C 1}", 7, "expected '='"),
        ("C RD{C=}", 7, "expected a number"),
        ("C RD{C=0", 4, "missing '}'"),
        ("C Q", 2, "expected an event type"),
    ],
)
def test_path_notation_errors_have_a_caret(path, position, words):
    with pytest.raises(LpeSyntaxError) as caught:
        parse_path(path)
    assert words in caught.value.message and caught.value.position == position


def test_closest_labels_suggests_near_names_and_path_tails():
    known = ["key", "fill", "rim", "/World/Lights/key", "/World/Lights/fill", "floor"]
    assert closest_labels("kye", known)[0] == "key"
    assert closest_labels("/World/Lights/kye", known)[0] == "/World/Lights/key"
    assert closest_labels("zzzz", known) == []
    assert len(closest_labels("fil", known, n=1)) == 1


def test_unknown_labels_are_warned_about_with_the_closest_known_names(caplog):
    recipe = compile_layers({"key": "C.*<L.'kye'>", "lights": "C.*<L.'/World/Lights/*'>", "any": "C<..>"})
    with caplog.at_level(logging.WARNING):
        warnings = recipe.unknown_labels(["key", "fill", "/World/Lights/key"])
    assert len(warnings) == 1
    assert "layer 'key'" in warnings[0] and "'kye'" in warnings[0] and "'key'" in warnings[0]
    assert warnings[0] in caplog.text
