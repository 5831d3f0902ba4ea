"""The merged index's covariance bins: the codes, and conditional layers on a merged index
against the same render's per-contribution (records) index, which keeps full-precision
norms: equal except for contributions whose value lies in the bin holding a threshold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.paths.format import NormBins
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

RESOLUTION = (48, 36)


def test_codes_split_values_into_bins_of_the_stated_width():
    values = np.concatenate([[0.0], 10.0 ** np.linspace(-9, 9, 20001)])
    codes = NormBins.code(values)
    assert codes[0] == 0 and (codes[1:] >= 1).all()
    assert (np.diff(codes.astype(int)) >= 0).all()  # monotone
    for code in np.unique(codes[1:]).tolist()[1:-1]:
        low, high = NormBins.edges(code)
        held = values[codes == code]
        assert (held >= low).all() and (held < high).all()
        assert math.isclose(high / low, NormBins.WIDTH, rel_tol=1e-12)
    read = NormBins.decoded(codes)
    inside = (values > NormBins.LOWEST * NormBins.WIDTH) & (values < NormBins.edges(NormBins.CODES - 1)[0])
    ratio = read[inside] / values[inside]
    assert ratio.max() <= math.sqrt(NormBins.WIDTH) * (1 + 1e-6) and ratio.min() >= 1 / math.sqrt(NormBins.WIDTH) - 1e-6
    assert read[0] == 0


def test_codes_saturate_and_keep_signs():
    assert NormBins.code(np.array([1e30, np.inf, np.nan])).tolist() == [255, 255, 255]
    assert NormBins.code(np.array([1e-30])).tolist() == [1]
    signed = NormBins.signed_code(np.array([-3.0, 0.0, 3.0, -1e-30]))
    assert signed.dtype == np.int16 and signed[0] == -signed[2] and signed[1] == 0 and signed[3] == -1
    read = NormBins.decoded(signed)
    assert read[0] == -read[2] and abs(read[2] / 3.0 - 1) < math.sqrt(NormBins.WIDTH) - 1


@pytest.fixture(scope="module")
def both_modes(shipped_scene, tmp_path_factory):
    """The showcase (textured, glossy, curved) rendered once per mode, same seed."""
    folder = tmp_path_factory.mktemp("bins")
    indexes = {}
    for mode in ("merged", "records"):
        request = RenderRequest(stage=shipped_scene("showcase.usda"), resolution=RESOLUTION, spp=8, max_depth=4,
                                seed=3, norm_bounces=3, index_mode=mode, index_covariance="norms", previews=False)
        indexes[mode] = PathIndex(render_frame(request, output=folder / mode, threads=2).index_path)
    return indexes


def first_bounce_values(index: PathIndex, column: int) -> np.ndarray:
    """The nonzero values of one norm at the first event, over all records."""
    values = np.concatenate([chunk.norms[:, 0, column] for chunk in index.records()])
    return values[values > 0]


def test_the_merged_index_is_smaller_and_holds_every_contribution(both_modes):
    merged, records = both_modes["merged"], both_modes["records"]
    assert merged.manifest["contributions"] == records.record_count
    assert merged.record_count < records.record_count / 2 and merged.size < records.size


def thresholds(values: np.ndarray) -> tuple[list[float], list[float]]:
    """Thresholds inside the bins the values occupy (the median of each bin's values), and
    thresholds in empty bins between and around them (each such bin's centre)."""
    codes = NormBins.code(values)
    occupied = np.unique(codes).tolist()
    inside = [float(np.median(values[codes == code])) for code in occupied]
    empty = [float(NormBins.centres()[code]) for code in range(occupied[0] - 1, occupied[-1] + 2)
             if code not in occupied]
    return inside, empty


@pytest.mark.parametrize("norm, column, scatter", [("T", 1, "D"), ("R", 2, "G"), ("C", 0, ".")])
def test_a_threshold_changes_only_the_light_of_its_own_bin(both_modes, norm, column, scatter):
    """|merged − records| per pixel is at most the light of the records (full precision)
    whose value lies in the bin holding the threshold; with a threshold in a bin no value
    falls in, the merged layer is the full-precision one."""
    merged, records = both_modes["merged"], both_modes["records"]
    values = first_bounce_values(records, column)
    assert len(values) > 100, f"the showcase has no {norm} to threshold"
    inside, empty = thresholds(values)
    selected = []
    for threshold in inside + empty:
        low, high = NormBins.edges(int(NormBins.code(np.array([threshold]))[0]))
        layers = {"above": f"C<R{scatter}>@(|S_{norm}| > {threshold!r}).*",
                  "in_bin": f"C<R{scatter}>@(|S_{norm}| >= {low!r} and |S_{norm}| < {high!r}).*"}
        on_records = extract(records, layers).layers
        on_merged = extract(merged, {"above": layers["above"]}).layers["above"].astype(np.float64)
        tolerance = 1e-6 * max(float(on_records["above"].max()), float(on_records["in_bin"].max()),
                               float(on_merged.max()), 1e-30)  # float32 rounding of sums in another order
        difference = np.abs(on_merged - on_records["above"])
        assert (difference <= on_records["in_bin"] + tolerance).all(), threshold
        if threshold in empty:
            assert on_records["in_bin"].max() == 0
            assert difference.max() <= tolerance, threshold
        selected.append(on_records["above"].sum())
    assert max(selected) > 0 and min(selected) < max(selected)  # the thresholds cut somewhere


@pytest.mark.parametrize("layer", ["C<RD>@(|S_T| = 0).*", "C<R.>@(|S_C| = 0).*", "C<RD>@(|S_R| = 0).*L"])
def test_zero_is_exact(both_modes, layer):
    """Zero has its own code: `= 0` conditions give the full-precision layer."""
    merged = extract(both_modes["merged"], {"layer": layer}).layers["layer"]
    records = extract(both_modes["records"], {"layer": layer}).layers["layer"]
    np.testing.assert_allclose(merged, records, rtol=1e-6, atol=1e-7 * max(records.max(), 1e-30))
    assert records.sum() > 0
