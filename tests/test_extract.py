"""Layers cut from a path index: partitions of the beauty, the reference, covariance conditions."""

from __future__ import annotations

import numpy as np
import pytest

from pxr_layers import lpe
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers import extract as extract_module
from pxr_layers.layers.extract import extract, extract_reference
from pxr_layers.lpe import testing as lpe_testing
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

RESOLUTION = (64, 48)


def indexed_render(stage, folder, resolution=RESOLUTION, spp=8, max_depth=5):
    """render_frame's result and its merged index (seed 5, the norms of 5 events)."""
    request = RenderRequest(stage=stage, resolution=resolution, spp=spp, max_depth=max_depth, seed=5, norm_bounces=5,
                            index_mode="merged", index_covariance="norms", previews=False)
    result = render_frame(request, output=folder, threads=2)
    return result, PathIndex(result.index_path)


@pytest.fixture(scope="module")
def stages(shipped_scene):
    return {name: shipped_scene(f"{name}.usda") for name in ("cornell", "showcase")}


@pytest.fixture(scope="module", params=["cornell", "showcase"])
def indexed(request, stages, tmp_path_factory):
    result, index = indexed_render(stages[request.param], tmp_path_factory.mktemp("extract"))
    return request.param, result.vocabulary.light_names, result, index


def assert_sums_to_beauty(layers: dict[str, np.ndarray], beauty: np.ndarray) -> None:
    total = np.sum([image.astype(np.float64) for image in layers.values()], axis=0)
    scale = np.maximum(np.abs(beauty), 1e-3 * beauty.max())
    assert np.max(np.abs(total - beauty) / scale) <= 1e-5


def test_standard_passes_partition_the_beauty(indexed):
    _, _, result, index = indexed
    layers = extract(index, lpe.STANDARD_PASSES).layers
    assert_sums_to_beauty(layers, result.rgba[..., :3].astype(np.float64))
    assert layers["diffuse_direct"].sum() > 0 and layers["diffuse_indirect"].sum() > 0
    beauty = extract(index, {"beauty": lpe.BEAUTY}).layers["beauty"]
    np.testing.assert_allclose(beauty, result.rgba[..., :3], rtol=1e-5, atol=1e-7)


def test_per_light_layers_partition_the_beauty(indexed):
    _, lights, result, index = indexed
    layers = extract(index, lpe.per_light_passes(list(lights))).layers
    assert_sums_to_beauty(layers, result.rgba[..., :3].astype(np.float64))
    assert all(layers[f"light_{light}"].sum() > 0 for light in lights)


def test_only_the_classes_a_layer_can_match_are_read(indexed):
    _, lights, _, index = indexed
    light = lights[0]
    narrow = extract(index, {"direct": f"C<RD>'{light}'"})
    assert narrow.classes_matched < len(index.classes) / 4
    assert narrow.records_read < index.record_count


def test_fast_extraction_matches_the_reference_on_random_expressions(stages, tmp_path, rng):
    _, index = indexed_render(stages["showcase"], tmp_path, resolution=(12, 10), spp=2)
    labels = sorted(index.labels)
    expressions = {}
    for number in range(24):
        tree = lpe_testing.random_tree(rng, depth=3, condition_rate=0.3)
        text = lpe.canonical(tree)
        pool = lpe_testing.LABEL_POOL + lpe_testing.PATTERN_POOL
        for position, pool_label in enumerate(pool):  # swap the generator's names for the scene's
            text = text.replace(f"'{pool_label}'", f"'{labels[(7 * position + number) % len(labels)]}'")
        expressions[f"random{number}"] = "C" + text if not text.startswith("C") else text
    expressions.update(lpe.STANDARD_PASSES)
    fast = extract(index, expressions).layers
    slow = extract_reference(index, expressions)
    for name, expression in expressions.items():
        np.testing.assert_allclose(fast[name], slow[name], rtol=1e-6, atol=1e-9, err_msg=f"{name}: {expression}")


@pytest.mark.parametrize("max_sets", [64, 2])
def test_many_conditional_layers_match_the_reference(stages, tmp_path, monkeypatch, max_sets):
    """More conditional layers than a record's int64 key has bits for, and (max_sets=2)
    more distinct layer sets per chunk than one bincount per set: both fall back, same sums."""
    monkeypatch.setattr(extract_module.LayerSums, "MAX_SETS", max_sets)
    _, index = indexed_render(stages["showcase"], tmp_path, resolution=(16, 12), spp=2)
    expressions = {f"texture{number}": f"C<R.>@(|S_T| > {number / 10:g}).*" for number in range(70)}
    expressions.update({f"reflectance{number}": f"C.*<R.>@(|S_R| > {2 ** number:g}) L" for number in range(12)})
    expressions.update(lpe.STANDARD_PASSES)
    fast = extract(index, expressions).layers
    slow = extract_reference(index, expressions)
    assert sum(fast[name].sum() > 0 for name in expressions) > 20
    for name, expression in expressions.items():
        np.testing.assert_allclose(fast[name], slow[name], rtol=1e-6, atol=1e-9, err_msg=f"{name}: {expression}")


@pytest.fixture(scope="module")
def showcase_index(stages, tmp_path_factory):
    return indexed_render(stages["showcase"], tmp_path_factory.mktemp("conditions"), resolution=(96, 96), spp=4,
                          max_depth=3)[1]


def test_a_texture_threshold_selects_the_high_frequency_stripes(showcase_index):
    layers = extract(showcase_index, {
        "panel": "C<R.'texturedPanel'>.*",
        "high_frequency": "C<R.'texturedPanel'>@(|S_T| > 4.5).*",  # 5 cycles/m gives T ≈ 3.3, 10 cycles/m ≈ 6.2
    }).layers
    panel, high = layers["panel"].sum(axis=2), layers["high_frequency"].sum(axis=2)
    columns = np.flatnonzero(panel.sum(axis=0) > 0)
    left_edge, right_edge = columns.min(), columns.max()
    quarter = (right_edge - left_edge) // 4
    low_half = slice(left_edge + 2, left_edge + 2 * quarter - 2)
    high_half = slice(right_edge - 2 * quarter + 3, right_edge - 1)
    assert high[:, low_half].sum() == 0 and panel[:, low_half].sum() > 0
    np.testing.assert_allclose(high[:, high_half], panel[:, high_half], rtol=1e-6)


def test_a_reflectance_threshold_selects_the_near_mirror_only(showcase_index):
    layers = extract(showcase_index, {
        "sharp": "C<R.>@(|S_R| > 100).*",  # mirrorPanel: 1/(2π·0.02²) ≈ 398; glossyBox ≈ 4; diffuse 0
        "mirror_specular": "C<RG'mirrorPanel'>.*",
        "diffuse_first": "C<RD>.*",
        "glossy_box": "C<R.'glossyBox'>.*",
    }).layers
    np.testing.assert_allclose(layers["sharp"], layers["mirror_specular"], rtol=1e-6, atol=1e-9)
    assert layers["sharp"].sum() > 0
    assert not np.any((layers["sharp"] > 0) & (layers["glossy_box"] > 0) & (layers["mirror_specular"] == 0))


def test_flat_condition_excludes_the_sphere(showcase_index):
    layers = extract(showcase_index, {
        "flat": "C<R.>@(|S_C| = 0).*",
        "sphere": "C<R.'curvedSphere'>.*",
        "all": "C<R.>.*",
    }).layers
    assert layers["sphere"].sum() > 0
    np.testing.assert_allclose(layers["flat"] + layers["sphere"], layers["all"], rtol=1e-5, atol=1e-8)
    assert not np.any((layers["flat"] > 0) & (layers["sphere"] > 0) & (layers["all"] == layers["sphere"]))


def test_an_unknown_label_warns_with_the_closest_names(showcase_index, caplog):
    extract(showcase_index, {"typo": "C<R.'curvedSpher'>.*"})
    assert "curvedSpher" in caplog.text and "'curvedSphere'" in caplog.text


def test_the_luminance_weights_extract_imports_are_the_renderers():
    """pxr_layers.colour holds the Rec.709 weights for the tools that must not import the
    renderer; scene.py keeps its own copy until it imports them from there."""
    from pxr_layers.colour import REC709_LUMINANCE
    from pxr_layers.scene import REC709_LUMINANCE as SCENE_LUMINANCE

    assert REC709_LUMINANCE == SCENE_LUMINANCE


def test_extract_imports_no_compiled_kernel_nor_the_renderer():
    """`pxr-layers extract` starts without numba, the tracer or USD (a fifth of a second and more)."""
    import subprocess
    import sys

    code = ("import sys; from pxr_layers.cli.main import build_parser; build_parser(['extract']); "
            "import pxr_layers.layers.deliver, pxr_layers.layers.extract, pxr_layers.paths.reader; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'pxr', 'embree') "
            "or m.startswith(('pxr_layers.trace', 'pxr_layers.stage', 'pxr_layers.scene'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "[]"
