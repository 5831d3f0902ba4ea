"""Overlapping layers (layers.overlaps) against a per-record brute force, and exclusive +
remainder layers (set differences) extracted from a real index: they sum to the beauty."""

from __future__ import annotations

import numpy as np
import pytest

from pxr_layers import lpe
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract, extract_reference
from pxr_layers.layers.overlaps import overlaps
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest
from pxr_layers.scene import REC709_LUMINANCE

STACK = {
    "diffuse": "C<RD>.*",
    "key": "C<RD>.*<L.'ceilingLight'>",
    "red": "C.*'redWall'.*",
    "flat_diffuse": "C<RD>@(|S_C| = 0).*",
    "curved_bounce": "C.+D@(|S_C| > 0).*",
    "direct": "C.L",
}


@pytest.fixture(scope="module")
def indexed(shipped_scene, tmp_path_factory):
    request = RenderRequest(stage=shipped_scene("cornell.usda"), resolution=(40, 30), spp=8, max_depth=5, seed=5,
                            norm_bounces=5, index_mode="merged", index_covariance="norms", previews=False)
    result = render_frame(request, output=tmp_path_factory.mktemp("overlaps"), threads=2)
    return result, PathIndex(result.index_path)


def brute_force(index: PathIndex, expressions: dict[str, str]) -> tuple[np.ndarray, np.ndarray]:
    """(records, layers) bool membership from the reference matcher, (records,) luminance."""
    trees = [lpe.parse(text) for text in expressions.values()]
    events = [path_class.events for path_class in index.classes]
    members, luminance = [], []
    for chunk in index.records():
        for record in range(len(chunk.class_id)):
            path = events[chunk.class_id[record]]
            members.append([lpe.reference_match(tree, path, chunk.norms[record]) for tree in trees])
        luminance.append(chunk.rgb.astype(np.float64) @ np.asarray(REC709_LUMINANCE))
    return np.array(members, bool), np.concatenate(luminance)


def test_overlaps_are_what_each_record_says(indexed):
    result, index = indexed
    found = overlaps(index, STACK, threads=2)
    members, luminance = brute_force(index, STACK)
    total = luminance.sum()
    names = list(STACK)
    expected_pairs = {(names[a], names[b]): (luminance * (members[:, a] & members[:, b])).sum() / total
                      for a in range(len(names)) for b in range(a + 1, len(names))}
    assert set(found.pairs) == {pair for pair, share in expected_pairs.items() if share > 0}
    for pair, share in found.pairs.items():
        assert share == pytest.approx(expected_pairs[pair], rel=1e-9), pair
    counts = members.sum(axis=1)
    assert found.double_counted == pytest.approx((luminance * np.maximum(counts - 1, 0)).sum() / total, rel=1e-9)
    assert found.remainder == pytest.approx((luminance * (counts == 0)).sum() / total, rel=1e-9, abs=1e-12)
    assert found.claimed + found.remainder == pytest.approx(1.0)
    assert 0 < found.remainder < 1 and found.double_counted > 0  # the light seen directly: no layer takes it
    # the beauty's energy from the image: the same shares, within the image's float32 rounding
    with_image = overlaps(index, STACK, result.rgba, threads=1)
    assert with_image.pairs.keys() == found.pairs.keys()
    assert with_image.double_counted == pytest.approx(found.double_counted, rel=1e-5)


def test_overlaps_do_not_depend_on_threads(indexed):
    _, index = indexed
    one, two = overlaps(index, STACK, threads=1), overlaps(index, STACK, threads=2)
    assert one.pairs == two.pairs and one.double_counted == two.double_counted and one.remainder == two.remainder


def test_a_partition_has_no_overlap_and_no_remainder(indexed):
    _, index = indexed
    found = overlaps(index, lpe.STANDARD_PASSES)
    assert found.pairs == {} and found.double_counted == 0.0 and found.remainder == 0.0


def test_exclusive_layers_and_the_remainder_sum_to_the_beauty(indexed):
    result, index = indexed
    names = list(STACK)
    layers = {name: lpe.exclusive(STACK[name], [STACK[other] for other in names[:number]])
              for number, name in enumerate(names)}
    layers["remainder"] = lpe.remainder(list(STACK.values()))
    found = overlaps(index, layers)
    assert found.pairs == {} and found.double_counted == 0.0 and found.remainder == 0.0
    images = extract(index, layers).layers
    total = np.sum([image.astype(np.float64) for image in images.values()], axis=0)
    beauty = extract(index, {"beauty": lpe.BEAUTY}).layers["beauty"].astype(np.float64)
    # every record lands in one layer: the float64 sums are the same records', so the sum of
    # the float32 images is the beauty within their rounding (one float32 ulp per layer)
    assert np.abs(total - beauty).max() <= len(images) * np.finfo(np.float32).eps * beauty.max()
    np.testing.assert_allclose(total, result.rgba[..., :3], rtol=1e-5, atol=1e-6 * beauty.max())
    # the fast extraction of differences is the reference's
    slow = extract_reference(index, {name: layers[name] for name in ("key", "curved_bounce", "remainder")})
    for name, image in slow.items():
        np.testing.assert_allclose(images[name], image, rtol=1e-6, atol=1e-7)
