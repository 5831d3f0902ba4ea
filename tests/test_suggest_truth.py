"""Known-truth tests of `pxr-layers suggest` (issue 40): stages built here whose right
answer is known by construction (tests/truth_stages.py), the adjusted Rand index of the
per-pixel dominant suggested layer against it, and the layers summing to the beauty."""

from __future__ import annotations

import logging
import subprocess
import sys

import numpy as np
import pytest
import truth_stages

from pxr_layers import lpe
from pxr_layers.layers.extract import extract
from pxr_layers.paths.reader import PathIndex
from pxr_layers.suggest import check_partition, suggest
from pxr_layers.suggest.atoms import gather
from pxr_layers.suggest.layers import Node


def adjusted_rand_index(labels: np.ndarray, truth: np.ndarray) -> float:
    """Hubert & Arabie's (1985) adjusted Rand index of two labellings of the same items
    (1: the same partition, ~0: as good as chance). Two trivial labellings (one cluster
    each, or all singletons on both sides) are 1 if equal as partitions, else 0."""
    _, a = np.unique(np.asarray(labels).reshape(-1), return_inverse=True)
    _, b = np.unique(np.asarray(truth).reshape(-1), return_inverse=True)
    table = np.zeros((a.max() + 1, b.max() + 1))
    np.add.at(table, (a.reshape(-1), b.reshape(-1)), 1)

    def pairs(counts: np.ndarray) -> float:
        return float((counts * (counts - 1) / 2).sum())

    index, rows, columns, total = pairs(table), pairs(table.sum(1)), pairs(table.sum(0)), pairs(np.array([a.size]))
    expected = rows * columns / total
    maximum = (rows + columns) / 2
    if maximum == expected:
        return 1.0 if index == maximum else 0.0
    return (index - expected) / (maximum - expected)


log = logging.getLogger(__name__)

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
SPP = 16
LIT = 0.02
"""A pixel counts when its luminance is at least this fraction of the 99th percentile of the
construction's pixels (black gaps, unlit lips and the back of the walls are left out)."""
STAGES = {
    # name: (builder, width, height, classes of the truth)
    "compartments": (truth_stages.compartments, 96, 48, 3),
    "mirror": (truth_stages.mirror, 64, 64, 2),
    "textured": (truth_stages.textured, 64, 48, 2),
    "light_groups": (truth_stages.light_groups, 96, 48, 2),
    "assets": (truth_stages.assets, 96, 48, 2),
}


_BUILT: dict[str, tuple] = {}


def built(name: str, tmp_path_factory) -> tuple:
    """(name, index, truth (h, w), lit (h, w) bool, beauty (h, w, 3) float64) of one stage,
    rendered once for the session."""
    if name in _BUILT:
        return _BUILT[name]
    builder, width, height, _ = STAGES[name]
    folder = tmp_path_factory.mktemp(name)
    path, truth_of = builder(folder, width, height)
    result = subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", "render", str(path), "-o", str(folder), "-q",
                             "--resolution", str(width), str(height), "--spp", str(SPP), "--max-depth", "4",
                             "--no-previews"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    index = PathIndex(folder / f"{name}.pxlidx")
    truth = truth_of(width, height)
    beauty = extract(index, {"beauty": lpe.BEAUTY}).layers["beauty"].astype(np.float64)
    luminance = beauty @ LUMINANCE
    lit = (truth >= 0) & (luminance > LIT * np.percentile(luminance[truth >= 0], 99))
    _BUILT[name] = (name, index, truth, lit, beauty)
    return _BUILT[name]


@pytest.fixture(params=sorted(STAGES))
def stage(request, tmp_path_factory):
    """Each stage in turn (built())."""
    return built(request.param, tmp_path_factory)


def _one_stage(name: str):
    @pytest.fixture
    def fixture(tmp_path_factory):
        return built(name, tmp_path_factory)
    fixture.__doc__ = f"The {name} stage (built())."
    return fixture


compartments = _one_stage("compartments")
mirror = _one_stage("mirror")
light_groups = _one_stage("light_groups")
assets = _one_stage("assets")


def dominant(layers: dict[str, np.ndarray]) -> np.ndarray:
    """(h, w) index of the layer with the most luminance at each pixel."""
    return np.argmax(np.stack([image @ LUMINANCE for image in layers.values()]), axis=0)


def assert_sums_to_beauty(layers: dict[str, np.ndarray], beauty: np.ndarray, tolerance: float = 1e-4) -> None:
    """Relative to each pixel (at least 1e-3 of the brightest): the issue's 1e-4."""
    total = np.sum([image.astype(np.float64) for image in layers.values()], axis=0)
    scale = np.maximum(np.abs(beauty), 1e-3 * beauty.max())
    assert np.max(np.abs(total - beauty) / scale) <= tolerance


def test_the_dominant_suggested_layer_is_the_truth(stage):
    """K = the truth's classes: which light (compartments), mirror or direct (mirror),
    textured or flat (textured) per pixel, by construction; ARI >= 0.9, sum within 1e-4."""
    name, index, truth, lit, beauty = stage
    suggestion = suggest([index], STAGES[name][3])
    layers = extract(index, suggestion.layers).layers
    score = adjusted_rand_index(dominant(layers)[lit], truth[lit])
    log.info("%s: ARI %.3f over %d lit pixels; layers %s", name, score, int(lit.sum()),
                {layer: suggestion.explanations[layer] for layer in suggestion.layers})
    assert score >= 0.9, (name, score, suggestion.layers)
    assert_sums_to_beauty(layers, beauty)
    assert all(suggestion.explanations[layer] for layer in suggestion.layers)


def test_the_elbow_refines_the_truth(stage):
    """K left out: the elbow's layers each hold (at least 90 % of their light) one class of
    the truth, so that no suggested layer mixes what the construction keeps apart."""
    name, index, truth, lit, beauty = stage
    suggestion = suggest([index])
    assert suggestion.chosen_k == "elbow" and len(suggestion.layers) >= STAGES[name][3]
    layers = extract(index, suggestion.layers).layers
    assert_sums_to_beauty(layers, beauty)
    for layer, image in layers.items():
        light = (image @ LUMINANCE)[lit]
        per_class = np.bincount(truth[lit], light, minlength=STAGES[name][3])
        assert per_class.max() >= 0.9 * per_class.sum(), (name, layer, per_class)
    log.info("%s: the elbow chose %d layers (%s) from J = %s", name, len(suggestion.layers),
                ", ".join(suggestion.layers), " ".join(f"{value:.3f}" for value in suggestion.objectives))


def test_the_three_lights_are_named_and_explained(compartments):
    name, index, *_ = compartments
    suggestion = suggest([index], 3)
    assert set(suggestion.layers) == {"red", "green", "blue"}
    assert suggestion.explanations["red"] == "the red light's light"


def test_a_whole_path_touch_is_an_exact_split(mirror):
    """The screen is seen only through the mirror: 'touches the screen' (at any bounce) is
    the mirror's half of the picture, and with its complement (a set difference) it
    partitions the paths and sums to the beauty."""
    name, index, truth, lit, beauty = mirror
    atoms = gather([index])
    via, without = Node().split("touches", "object:/World/screen")
    present = [{"light": "L:/World/lamp", "object": None, "material": None}]
    expressions = {"via_screen": via.expression(atoms.labels), "without_screen": without.expression(atoms.labels)}
    assert expressions == {"via_screen": "C.* - C[^'/World/screen']*", "without_screen": "C.* - C.*'/World/screen'.*"}
    assert via.explain(present, atoms.names) == "the lamp light's light by way of the screen"
    assert check_partition(index, expressions) > 0
    layers = extract(index, expressions).layers
    assert_sums_to_beauty(layers, beauty)
    assert adjusted_rand_index(dominant(layers)[lit], truth[lit]) >= 0.9


def test_a_layer_already_in_the_stack_is_not_offered_again(compartments):
    """Compared as the path classes it cuts, not as text: the green light by its prim name."""
    name, index, *_ = compartments
    suggestion = suggest([index], 3, exclude=["C<RD>.*", "C.*<L.'green'>"])
    assert set(suggestion.layers) == {"red", "blue"} and suggestion.already == {"green": "C.*<L.'green'>"}
    assert set(suggest([index], 3, exclude=["C.*<L.'green'>L"]).layers) == {"red", "green", "blue"}


def test_light_groups_are_suggested_by_name(light_groups):
    """Two lights of group "rim" light the left boards, the key (group "front") the right one:
    the render records the groups in the index, and suggest, with K = 2 or by the elbow,
    gives the two groups, each one layer ending at its lights (ARI and the sum: above)."""
    name, index, truth, lit, beauty = light_groups
    assert index.manifest["light_groups"] == {"/World/key": "front", "/World/rim_a": "rim", "/World/rim_b": "rim"}
    for k in (2, None):
        suggestion = suggest([index], k)
        assert suggestion.layers == {"front": "C<L.'/World/key'>|C<[RTV].>.*<L.'/World/key'>",
                                     "rim": "C<L.['/World/rim_a''/World/rim_b']>|C<[RTV].>.*<L.['/World/rim_a''/World/rim_b']>"}, k
        assert suggestion.explanations == {"front": "the front group's light", "rim": "the rim group's light"}
        layers = extract(index, suggestion.layers).layers
        assert adjusted_rand_index(dominant(layers)[lit], truth[lit]) >= 0.9
        assert_sums_to_beauty(layers, beauty)


def test_assets_are_touched_by_name(assets):
    """Two component models of two meshes each: the render records the models, the atoms
    touch each model as an asset, and the two suggested layers are the chair's and the
    table's (by way of the chair, or never touching it: every path is camera, mesh, lamp)."""
    name, index, truth, lit, beauty = assets
    assert index.manifest["model_paths"] == ["/World/chair", "/World/table"]
    atoms = gather([index])
    assert {atoms.names["asset:/World/chair"], atoms.names["asset:/World/table"]} == {"chair", "table"}
    assert atoms.labels["asset:/World/chair"] == "/World/chair/*"
    suggestion = suggest([index], 2)
    assert any("chair" in layer or "table" in layer for layer in suggestion.layers), suggestion.layers
    assert any("by way of the chair" in text or "by way of the table" in text
               for text in suggestion.explanations.values()), suggestion.explanations
