"""The automaton: agrees with the reference matcher, is minimal, and scales with label sets."""

from __future__ import annotations

import time

import numpy as np
import pytest

from pxr_layers import lpe
from pxr_layers.errors import LpeError, LpeSyntaxError
from pxr_layers.lpe import (
    Event,
    compile_layers,
    nodes,
    parse_path,
    reference_match,
    testing,
)
from pxr_layers.lpe.automaton import LayerAutomaton


def paths_for(rng, tree, count):
    """Paths the tree accepts, near misses, and unrelated random paths."""
    paths = []
    for _ in range(count):
        sampled = testing.sample_path(rng, tree)
        roll = rng.random()
        if sampled is not None and roll < 0.45:
            paths.append(sampled)
        elif sampled is not None and roll < 0.75:
            paths.append(testing.mutate_path(rng, sampled))
        else:
            paths.append(testing.random_path(rng, start_with_camera=False))
    return paths


def test_automaton_agrees_with_the_reference_on_random_expressions_and_paths():
    rng = np.random.default_rng(2024)
    checked = matched = 0
    for _ in range(200):
        tree = testing.random_tree(rng, depth=3)
        complete = LayerAutomaton({"x": tree})
        on_demand = LayerAutomaton({"x": tree}, build_complete=False)
        for path in paths_for(rng, tree, 8):
            expected = reference_match(tree, path)
            assert ("x" in complete.accepting_layers(path)) == expected, (nodes.canonical(tree), path)
            assert ("x" in on_demand.accepting_layers(path)) == expected, (nodes.canonical(tree), path)
            checked += 1
            matched += expected
    assert checked == 1600
    assert 0.25 < matched / checked < 0.75  # the sampled paths make both answers common


def test_one_automaton_for_many_layers_agrees_with_each_layer_alone():
    rng = np.random.default_rng(99)
    for _ in range(60):
        trees = {f"layer{i}": testing.random_tree(rng, depth=2) for i in range(3)}
        recipe = LayerAutomaton(trees)
        for tree in trees.values():
            for path in paths_for(rng, tree, 4):
                expected = {name for name, layer_tree in trees.items() if reference_match(layer_tree, path)}
                assert recipe.accepting_layers(path) == expected


@pytest.mark.parametrize(
    "expression, states, transitions",
    [
        ("C.*", 2, 2),
        ("C<RD>L", 4, 3),
        ("C<RD>.*<L.'key'>", 4, 6),
        ("[RT]*", 1, 1),
        ("(R|T)*", 1, 1),
        ("(R*T*)*", 1, 1),
        ("R{0}", 1, 0),
        ("C(RD)*L|CL", 4, 4),
        ("C(RD)*L", 4, 4),
        ("C.{2,4}L", 9, 11),
        ("[^CRTVLOB]", 0, 0),
    ],
)
def test_minimal_automaton_sizes(expression, states, transitions):
    automaton = lpe.compile(expression).automaton
    assert automaton.complete
    assert (automaton.state_count, automaton.transition_count) == (states, transitions)


def test_equivalent_spellings_minimise_to_the_same_size():
    sizes = {
        (lpe.compile(text).state_count, lpe.compile(text).transition_count)
        for text in ("C<R[DG]>+L", "C(<RD>|<RG>)(<RD>|<RG>)*L", "C[<RD><RG>]{1,}L", "C<R[DG]><R[DG]>*L")
    }
    assert len(sizes) == 1


def test_accepting_states_list_every_layer_they_feed():
    recipe = compile_layers({"beauty": "C.*", "direct": "C.L", "key": "C.*<L.'key'>", "never": "CB"})
    assert recipe.accepting_layers(parse_path("C RD L'key'").events) == {"beauty", "direct", "key"}
    assert recipe.accepting_layers(parse_path("C RD RD L'fill'").events) == {"beauty"}
    assert recipe.accepting_layers(()) == frozenset()
    assert recipe.layers == ("beauty", "direct", "key", "never")
    assert recipe.canonical["key"] == "C.*<L.'key'>"


def test_labels_the_recipe_never_names_need_no_symbol_of_their_own():
    recipe = compile_layers({"floor": "C<RD'floor'>.*"})
    before = recipe.transition_count
    for label in ("wall", "ceiling", "/World/anything", "floor2"):
        assert recipe.accepting_layers((Event("C"), Event("R", "D", {label, "floor"}), Event("L"))) == {"floor"}
        assert recipe.accepting_layers((Event("C"), Event("R", "D", {label}), Event("L"))) == frozenset()
    assert recipe.transition_count == before  # the complete automaton already covers them


def test_many_light_groups_build_states_on_demand_only():
    groups = [f"group{i}" for i in range(40)]
    started = time.perf_counter()
    recipe = compile_layers(lpe.per_light_passes(groups))
    assert not recipe.complete  # 2**40 label subsets: never enumerated
    for group in groups:
        path = (Event("C"), Event("R", "D", {"floor"}), Event("L", "", {group, f"/World/Lights/{group}"}))
        assert recipe.accepting_layers(path) == {f"light_{group}"}
    assert recipe.state_count < 50
    assert time.perf_counter() - started < 2.0


def test_compile_layers_names_the_layer_of_a_syntax_error():
    with pytest.raises(LpeSyntaxError) as caught:
        compile_layers({"good": "C.*", "bad": "C<RD"})
    assert caught.value.message.startswith("layer 'bad': position 4: ") and caught.value.position == 4
    with pytest.raises(LpeError):
        compile_layers({})


def test_accepting_layers_refuses_expressions_with_conditions():
    recipe = compile_layers({"flat": "C D@(|S_C| = 0) L"})
    with pytest.raises(LpeError, match="match()"):
        recipe.accepting_layers(parse_path("C RD L").events)


def test_per_light_groups_of_several_labels_take_them_as_one_set():
    layers = lpe.per_light_passes({"keys": ("key", "key2"), "rim": ("rim",), "none": ()})
    assert layers == {"light_keys": "C.*<L.['key''key2']>", "light_rim": "C.*<L.'rim'>",
                      "light_other": "C.*<L.[^'key''key2''rim']>|C.*[OB]"}
