"""`pxr-layers suggest`: known light touches recovered, lights split first where they share
pixels, partitions exact, names stable, recipes that round-trip through `extract
--recipe` (and that `render --recipe` takes), one layer set for a shot's frames. The
subcommand runs in-process through its module's add_arguments / run (the console script
reaches it once main.py lists it)."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from pxr_layers import lpe
from pxr_layers.cli import suggest as suggest_command
from pxr_layers.layers.extract import extract
from pxr_layers.paths.reader import PathIndex
from pxr_layers.suggest import STRATEGIES, SuggestError, check_partition, suggest
from pxr_layers.suggest.atoms import gather
from pxr_layers.suggest.layers import Node

RENDER_DIR = Path(__file__).resolve().parents[1] / "render"
TOUCHES = ("key", "fill", "rim")
"""The lights of render/touches.usda, each light-linked to one object."""


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", *args], capture_output=True, text=True)


def render(stage: Path, folder: Path, *flags: str) -> None:
    result = cli("render", str(stage), "-o", str(folder), "-q", *flags)
    assert result.returncode == 0, result.stderr


@pytest.fixture(scope="module")
def touches(tmp_path_factory) -> PathIndex:
    folder = tmp_path_factory.mktemp("touches")
    render(RENDER_DIR / "touches.usda", folder, "--resolution", "72", "48", "--spp", "8", "--max-depth", "4")
    return PathIndex(folder / "touches.pxlidx")


@pytest.fixture(scope="module")
def shot(tmp_path_factory) -> list[PathIndex]:
    """Three tiny frames of the animated showcase, in one folder."""
    folder = tmp_path_factory.mktemp("shot")
    for frame in ("1", "12", "24"):
        render(RENDER_DIR / "showcase_animated.usda", folder, "--frame", frame, "--resolution", "40", "40",
               "--spp", "4", "--max-depth", "3", "--no-previews")
    return [PathIndex(path) for path in sorted(folder.glob("*.pxlidx"))]


@pytest.fixture(scope="module")
def showcase(tmp_path_factory) -> PathIndex:
    """The showcase (key, fill, sky lighting the same objects) at a tiny resolution."""
    folder = tmp_path_factory.mktemp("showcase")
    render(RENDER_DIR / "showcase.usda", folder, "--resolution", "48", "28", "--spp", "4", "--max-depth", "3",
           "--no-previews")
    return PathIndex(folder / "showcase.pxlidx")


def adjusted_rand_index(a: np.ndarray, b: np.ndarray) -> float:
    """Hubert & Arabie's adjusted Rand index of two labellings of the same items."""
    _, a = np.unique(a, return_inverse=True)
    _, b = np.unique(b, return_inverse=True)
    table = np.zeros((a.max() + 1, b.max() + 1))
    np.add.at(table, (a, b), 1)

    def pairs(counts):
        return float((counts * (counts - 1) / 2).sum())

    index, rows, columns, total = pairs(table), pairs(table.sum(1)), pairs(table.sum(0)), pairs(np.array([len(a)]))
    expected = rows * columns / total
    return (index - expected) / ((rows + columns) / 2 - expected)


def dominant(layers: dict[str, np.ndarray]) -> np.ndarray:
    """(h, w) index of the layer with the most luminance at each pixel."""
    return np.argmax(np.stack([image @ np.array([0.2126, 0.7152, 0.0722]) for image in layers.values()]), axis=0)


def test_three_layers_recover_the_three_light_touches(touches):
    # The construction, independently of suggest: which light lights each pixel most.
    truth = extract(touches, lpe.per_light_passes(TOUCHES)).layers
    del truth["light_other"]
    beauty = extract(touches, {"beauty": lpe.BEAUTY}).layers["beauty"]
    lit = beauty @ np.array([0.2126, 0.7152, 0.0722]) > 0.02 * beauty.max()
    scores = {}
    for strategy in STRATEGIES:
        suggestion = suggest([touches], 3, strategy=strategy)
        assert len(suggestion.layers) == 3
        layers = extract(touches, suggestion.layers).layers
        scores[strategy] = (adjusted_rand_index(dominant(layers)[lit], dominant(truth)[lit]), suggestion.objective)
    print("ARI, objective per strategy:", scores)
    assert all(ari >= 0.9 for ari, _ in scores.values())
    assert scores["beam"][1] >= scores["greedy"][1] - 1e-12


def assert_sums_to_beauty(layers: dict[str, np.ndarray], beauty: np.ndarray) -> None:
    total = np.sum([image.astype(np.float64) for image in layers.values()], axis=0)
    scale = np.maximum(np.abs(beauty), 1e-3 * beauty.max())
    assert np.max(np.abs(total - beauty) / scale) <= 1e-5


@pytest.mark.parametrize("k", [2, 5, 9])
def test_the_layers_partition_the_beauty(touches, k):
    suggestion = suggest([touches], k)
    assert len(suggestion.layers) == k and abs(sum(suggestion.shares.values()) - 1) < 1e-9
    layers = extract(touches, suggestion.layers).layers
    assert_sums_to_beauty(layers, extract(touches, {"beauty": lpe.BEAUTY}).layers["beauty"].astype(np.float64))


def test_covariance_splits_partition_every_record(touches):
    """Complementary covariance conditions (= 0 / != 0) on the first bounce, and the check
    that finds a layer set that is not a partition."""
    atoms = gather([touches])
    curved, flat = Node().split("curved", "1")
    textured, plain = flat.split("textured", "1")
    layers = {"curved": curved.expression(atoms.labels), "textured": textured.expression(atoms.labels),
              "plain": plain.expression(atoms.labels)}
    assert "@(|S_C| != 0)" in layers["curved"] and "|S_T| = 0" in layers["plain"]
    assert check_partition(touches, layers) > 0
    images = extract(touches, layers).layers
    assert_sums_to_beauty(images, extract(touches, {"beauty": lpe.BEAUTY}).layers["beauty"].astype(np.float64))
    assert images["curved"][:, :24].sum() > 0.9 * images["curved"].sum()  # the ball is on the left
    with pytest.raises(SuggestError, match="matched by 2 layers"):
        check_partition(touches, {"all": "C.*", "diffuse": "C<RD>.*"})
    with pytest.raises(SuggestError, match="matched by no layer"):
        check_partition(touches, {"curved": layers["curved"]})


def test_names_are_readable_and_stable(touches):
    first, again = suggest([touches], 6), suggest([touches], 6)
    assert first.layers == again.layers and first.shares == again.shares
    assert all(name.isidentifier() for name in first.layers)
    assert any(name.startswith(("on_", *TOUCHES)) for name in first.layers)


def test_one_layer_set_for_a_shot_whatever_the_frame_order(shot):
    forward, backward = suggest(shot, 5), suggest(shot[::-1], 5)
    assert forward.layers == backward.layers and forward.objective == backward.objective
    assert len(forward.checked) == 3  # the partition was checked on every frame
    for index in shot:
        layers = extract(index, forward.layers).layers
        assert_sums_to_beauty(layers, extract(index, {"beauty": lpe.BEAUTY}).layers["beauty"].astype(np.float64))


def test_lights_that_share_pixels_are_split_first(showcase):
    """What an ID matte cannot do: where lights light the same objects, the first split is
    by light (the objective without its unmatted term splits by object, as a matte would).
    Asked for two layers, where the first split is the whole answer: which split the search
    puts at the root of three layers is within the noise of this tiny render (depth and
    light score within 0.3 % of each other), that of two is not (tried over seeds and sizes)."""
    for strategy in STRATEGIES:
        suggestion = suggest([showcase], 2, strategy=strategy)
        assert suggestion.splits == ("light = L:/World/Lights/key",), suggestion.splits
        assert set(suggestion.layers) == {"key", "fill_sky"}  # the rest, named after the lights it is left with
        for k in (2, 3):
            layers = extract(showcase, suggest([showcase], k, strategy=strategy).layers).layers
            assert_sums_to_beauty(layers, extract(showcase, {"beauty": lpe.BEAUTY}).layers["beauty"].astype(np.float64))
    matte_only = suggest([showcase], 2, unmatted_weight=0)
    assert matte_only.splits[0].startswith(("object = ", "material = ")), matte_only.splits


def run_suggest(*args: str) -> int:
    parser = argparse.ArgumentParser()
    parser.set_defaults(show_progress=False)
    suggest_command.add_arguments(parser)
    return suggest_command.run(parser.parse_args(list(args)))


def test_the_recipe_round_trips_through_extract_bit_for_bit(touches, tmp_path, capsys):
    recipe = tmp_path / "touch_layers.usda"
    assert run_suggest(str(touches.path), "-k", "4", "-o", str(recipe)) == 0
    printed = capsys.readouterr().out
    assert "objective" in printed and str(recipe) in printed
    written = tmp_path / "touch_layers.exr"
    assert (tmp_path / "touch_layers.contact.png").exists()
    extracted = cli("extract", str(touches.path), "--recipe", str(recipe), "-o", str(tmp_path / "again"), "-q")
    assert extracted.returncode == 0, extracted.stderr
    first, second = OpenEXR.File(str(written)).parts, OpenEXR.File(str(tmp_path / "again" / "touch_layers.exr")).parts
    assert [part.name() for part in first] == [part.name() for part in second] and len(first) == 5
    for one, other in zip(first, second):
        for name, channel in one.channels.items():
            assert channel.pixels.tobytes() == other.channels[name].pixels.tobytes()
    rendered = cli("render", str(RENDER_DIR / "touches.usda"), "--recipe", str(recipe), "-o", str(tmp_path / "render"),
                   "-q", "--resolution", "24", "16", "--spp", "2", "--no-previews")
    assert rendered.returncode == 0, rendered.stderr
    parts = OpenEXR.File(str(tmp_path / "render" / "touch_layers.exr")).parts
    assert [part.name() for part in parts] == [part.name() for part in first]


def test_without_k_the_elbow_chooses_and_the_recipe_carries_the_explanations(touches, tmp_path, capsys):
    """No -k: K at the objective's elbow, said so; each layer's one-line explanation printed
    under it and kept in the recipe as its RenderVar's USD documentation."""
    from pxr import Usd

    recipe = tmp_path / "explained.usda"
    assert run_suggest(str(touches.path), "-o", str(recipe), "--no-exr") == 0
    printed = capsys.readouterr().out
    expected = suggest([touches])
    assert expected.chosen_k == "elbow" and "at the elbow of" in printed
    stage = Usd.Stage.Open(str(recipe))
    documented = {prim.GetName(): prim.GetDocumentation() for prim in stage.Traverse()
                  if prim.GetTypeName() == "RenderVar"}
    assert documented == expected.explanations
    assert all(f"  {text}" in printed for text in expected.explanations.values())
