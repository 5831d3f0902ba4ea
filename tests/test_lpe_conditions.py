"""Covariance conditions: per-class outcomes, vectorised masks, and the errors around them."""

from __future__ import annotations

import numpy as np
import pytest

from pxr_layers import lpe
from pxr_layers.errors import LpeError
from pxr_layers.lpe import (
    ALWAYS,
    NEVER,
    Event,
    compile_layers,
    nodes,
    parse_path,
    reference_match,
    testing,
)
from pxr_layers.lpe import conditions as cond
from pxr_layers.lpe.automaton import LayerAutomaton

PAPER = "C.*D C(‖Σ_C‖ = 0) T(‖Σ_T‖ > 6) R(‖Σ_R‖ > 2).*"
"""The example of Desrichard & Vanderhaeghe: a diffuse bounce on locally flat geometry
whose texture and reflectance both hold high frequencies."""

C_, T_, R_ = 0, 1, 2  # columns of the norms array


def events(text: str) -> tuple[Event, ...]:
    return parse_path(text).events


def norms_for(records: int, kept: int, rows: dict) -> np.ndarray:
    """(records, kept, 3) float32 zeros, with rows[event index] = (r, 3) values filled in."""
    norms = np.zeros((records, kept, 3), dtype=np.float32)
    for index, values in rows.items():
        norms[:, index - 1] = values
    return norms


def test_the_papers_example_depends_on_the_diffuse_bounce_only(rng):
    outcome = lpe.compile(PAPER).outcome(events("C RG'chrome' RD'floor' L'key'"))
    assert outcome.kind == "conditional" and outcome.bounces == (2,)
    values = rng.choice([0.0, 1.0, 3.0, 7.0], size=(64, 3)).astype(np.float32)
    norms = norms_for(64, 5, {1: rng.random((64, 3)), 2: values})
    expected = (values[:, C_] == 0) & (values[:, T_] > 6) & (values[:, R_] > 2)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(outcome.mask(norms), expected)


def test_without_a_diffuse_bounce_the_papers_example_never_matches_and_needs_no_norms():
    outcome = lpe.compile(PAPER).outcome(events("C RG RS L"))
    assert outcome is NEVER and outcome.bounces == ()
    assert outcome.mask(np.zeros((7, 5, 3), np.float32)).tolist() == [False] * 7


def test_or_inside_one_condition():
    outcome = lpe.compile("C D C(|S_C| = 0 or |S_C| > 2) L").outcome(events("C RD L"))
    curvature = np.array([0, 0.5, 2, 2.5, 40], dtype=np.float32)
    norms = norms_for(5, 5, {1: np.stack([curvature, curvature, curvature], axis=1)})
    assert outcome.mask(norms).tolist() == [True, False, False, True, True]


def test_a_condition_that_several_bounces_could_meet_is_an_or_over_them():
    outcome = lpe.compile("C.*<RD>@(|S_C| = 0).*L").outcome(events("C RD RG RD L"))
    assert outcome.bounces == (1, 3)
    first = np.array([0, 0, 1, 1], dtype=np.float32)[:, None].repeat(3, axis=1)
    third = np.array([0, 1, 0, 1], dtype=np.float32)[:, None].repeat(3, axis=1)
    norms = norms_for(4, 5, {1: first, 3: third})
    assert outcome.mask(norms).tolist() == [True, True, True, False]


def test_conditions_that_cannot_change_the_answer_disappear():
    assert lpe.compile("C(D@(|S_C| = 0)|D)L").outcome(events("C RD L")) is ALWAYS
    assert lpe.compile("C.*|C D@(|S_C| = 0) L").outcome(events("C RD L")) is ALWAYS
    # Conditions are opaque: one that always holds on numbers is still an input (NaN fails it).
    outcome = lpe.compile("C D@(|S_C| = 0) D@(|S_T| > 1 or |S_T| <= 1) L").outcome(events("C RD TD L"))
    assert outcome.bounces == (1, 2)


def test_complementary_layers_split_every_record():
    recipe = compile_layers({
        "flat": "C<RD>@(|S_C| = 0).*",
        "curved": "C<RD>@(|S_C| > 0).*",
        "diffuse": "C<RD>.*",
    })
    outcomes = recipe.match(events("C RD'floor' RG L'key'"))
    assert outcomes["diffuse"] is ALWAYS
    curvature = np.array([0, 1e-6, 0, 3], dtype=np.float32)
    norms = norms_for(4, 5, {1: np.stack([curvature] * 3, axis=1)})
    flat, curved = outcomes["flat"].mask(norms), outcomes["curved"].mask(norms)
    assert (flat ^ curved).all() and flat.tolist() == [True, False, True, False]


def test_much_greater_means_ten_times():
    assert lpe.MUCH_GREATER_FACTOR == 10.0
    outcome = lpe.compile("C RD Σ(Σ11 ≫ Σ22) L").outcome(events("C RG RD L"))
    sigma = np.zeros((3, 5, 10), dtype=np.float32)
    sigma[:, 1, cond.sigma_column(1, 1)] = [10.5, 9.5, 0.0]
    sigma[:, 1, cond.sigma_column(2, 2)] = [1.0, 1.0, 0.0]
    assert outcome.mask(np.zeros((3, 5, 3), np.float32), sigma).tolist() == [True, False, False]


def test_entries_are_read_from_the_upper_triangle_in_row_major_order():
    names = ["xx", "xy", "xu", "xv", "yy", "yu", "yv", "uu", "uv", "vv"]
    sigma = np.arange(10, dtype=np.float32)[None, None, :]
    for column, name in enumerate(names):
        row, col = "xyuv".index(name[0]) + 1, "xyuv".index(name[1]) + 1
        expression = lpe.compile(f"C <RD>@(S{col}{row} = {column}) L")  # S21 is S12: symmetric
        assert expression.outcome(events("C RD L")).mask(np.zeros((1, 1, 3), np.float32), sigma).tolist() == [True]


def test_comparisons_happen_in_float32_like_the_index():
    expression = lpe.compile("C <RD>@(|S_T| = 3.2 and |S_R| < 0.1) L")
    norms = np.array([[[0.0, 3.2, 0.1]]], dtype=np.float32)
    assert expression.outcome(events("C RD L")).mask(norms).tolist() == [False]  # 0.1 < 0.1 is false
    norms[0, 0, R_] = 0.0999
    assert expression.outcome(events("C RD L")).mask(norms).tolist() == [True]


def test_path_text_values_feed_the_conditions():
    expression = lpe.compile("C.*D C(|S_C| = 0) T(|S_T| > 6).*")
    assert expression.matches("C RG RD'floor'{C=0, T=7, R=0} L")
    assert not expression.matches("C RG RD'floor'{C=0, T=6, R=0} L")
    assert not expression.matches("C RG L")  # no diffuse bounce: no values needed
    assert expression.matches([Event("C"), Event("R", "D"), Event("L")], norms_row=[[0, 9, 0], [0, 0, 0]])


def test_a_path_without_the_values_a_condition_reads_is_an_error():
    expression = lpe.compile("C.*D C(|S_C| = 0).*")
    with pytest.raises(LpeError, match="gives none"):
        expression.matches("C RD'floor' L")
    with pytest.raises(LpeError, match=r"no \|S_C\| for event 1"):
        expression.matches("C RD'floor'{T=1} L")
    with pytest.raises(LpeError, match="no S12 for event 1"):
        lpe.compile("C D@(S12 > 0) L").matches("C RD{C=0, S11=1} L")


def test_a_condition_on_a_bounce_the_index_did_not_keep_is_an_error():
    outcome = lpe.compile("C.{5}<RD>@(|S_C| = 0)L").outcome(events("C RG RG RG RG RG RD L"))
    assert outcome.bounces == (6,)
    with pytest.raises(LpeError, match=r"event 6 \(RD\).*events 1\.\.5 only"):
        outcome.mask(np.zeros((2, 5, 3), np.float32))
    assert outcome.mask(np.zeros((2, 6, 3), np.float32)).tolist() == [True, True]


def test_a_condition_on_an_entry_without_sigma_is_an_error():
    outcome = lpe.compile("C D@(S11 >> S22) L").outcome(events("C RD L"))
    with pytest.raises(LpeError, match="reads entries of Σ.*--index-covariance sigma"):
        outcome.mask(np.zeros((2, 5, 3), np.float32))


def test_a_condition_on_the_camera_event_is_an_error():
    outcome = lpe.compile("C@(|S_C| = 0).*").outcome(events("C RD L"))
    with pytest.raises(LpeError, match="camera"):
        outcome.mask(np.zeros((1, 5, 3), np.float32))


def test_array_shapes_are_checked():
    outcome = lpe.compile("C D@(|S_C| = 0) L").outcome(events("C RD L"))
    with pytest.raises(LpeError, match="norms must be"):
        outcome.mask(np.zeros((2, 5), np.float32))
    with pytest.raises(LpeError, match="sigma must be"):
        outcome.mask(np.zeros((2, 5, 3), np.float32), np.zeros((2, 4, 10), np.float32))


def test_reference_match_needs_values_for_the_conditions_it_tests():
    with pytest.raises(LpeError, match="needs the norms"):
        reference_match("C D@(|S_C| = 0) L", "C RD L")
    assert reference_match("C D@(|S_C| = 0) L", "C RD L", norms_row=np.zeros((2, 3)))


def test_vectorised_masks_agree_with_the_reference_on_random_expressions():
    rng = np.random.default_rng(31)
    camera = nodes.EventPattern(nodes.SymbolSet(frozenset("C")))
    kinds = {"never": 0, "always": 0, "conditional": 0}
    for _ in range(120):
        # Two layers in one automaton; the paths are drawn from the first.
        trees = {
            name: nodes.concat([camera, testing.random_tree(rng, depth, condition_rate=0.35, with_entries=True)])
            for name, depth in (("first", 3), ("second", 2))
        }
        recipe = LayerAutomaton(trees)
        for _ in range(4):
            path = testing.sample_path(rng, trees["first"])
            if path is None or rng.random() < 0.25:
                path = testing.random_path(rng) if path is None else testing.mutate_path(rng, path)
            if not path or path[0].type != "C":
                continue
            norms, sigma = testing.random_values(rng, 8, len(path) - 1)
            for name, outcome in recipe.match(path).items():
                kinds[outcome.kind] += 1
                expected = [reference_match(trees[name], path, norms[i], sigma[i]) for i in range(8)]
                assert outcome.mask(norms, sigma).tolist() == expected, (nodes.canonical(trees[name]), path, outcome)
    assert min(kinds.values()) >= 20, kinds


@pytest.mark.parametrize("limit", [0, 2])
def test_classes_past_the_truth_table_limit_run_per_record_with_the_same_answers(monkeypatch, limit):
    """Long paths under `.*` with several conditions depend on more (event, condition) atoms
    than a truth table can hold: their records then walk the DFA one by one."""
    from pxr_layers.lpe import automaton as automaton_module

    monkeypatch.setattr(automaton_module, "MAX_ATOMS_PER_CLASS", limit)
    rng = np.random.default_rng(47)
    camera = nodes.EventPattern(nodes.SymbolSet(frozenset("C")))
    per_record = 0
    for _ in range(80):
        trees = {name: nodes.concat([camera, testing.random_tree(rng, depth, condition_rate=0.4, with_entries=True)])
                 for name, depth in (("first", 3), ("second", 2))}
        recipe = LayerAutomaton(trees)
        for _ in range(4):
            path = testing.sample_path(rng, trees["first"]) or testing.random_path(rng)
            if not path or path[0].type != "C":
                continue
            norms, sigma = testing.random_values(rng, 8, len(path) - 1)
            for name, outcome in recipe.match(path).items():
                per_record += isinstance(outcome, automaton_module.PerRecord)
                expected = [reference_match(trees[name], path, norms[i], sigma[i]) for i in range(8)]
                assert outcome.mask(norms, sigma).tolist() == expected, (nodes.canonical(trees[name]), path, outcome)
    assert per_record >= 40


def test_the_papers_selections_on_deep_paths_need_no_truth_table():
    """Five conditional layers over an 8-event path: far past 2**16 truth-table rows."""
    layers = lpe.compile_layers({
        "texture_high": "C .* R T(|S_T| > 4.5) [LOB]",
        "texture_low": "C .* R T(|S_T| > 0) T(|S_T| <= 4.5) [LOB]",
        "glossy_last": "C .* <R.> R(|S_R| > 2) [LOB]",
        "flat": "C <R.> C(|S_C| = 0) .*",
        "curved": "C <R.> C(|S_C| > 0) .*",
    })
    path = events("C RD RG RD RD RG RD RD L")
    norms = np.zeros((3, 8, 3), np.float32)
    norms[0, 6, 1] = 9.0  # record 0: high texture on the last bounce
    norms[1, 6, 2] = 5.0  # record 1: a sharp lobe at the last bounce
    norms[2, 0, 0] = 2.5  # record 2: curved first bounce
    masks = {name: outcome.mask(norms).tolist() for name, outcome in layers.match(path).items()}
    assert masks["texture_high"] == [True, False, False]
    assert masks["glossy_last"] == [False, True, False]
    assert masks["flat"] == [True, True, False] and masks["curved"] == [False, False, True]
