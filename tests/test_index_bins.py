"""The merged index's bins: the norm and rgb codes, and conditional layers on a merged index
against the same render's per-contribution (records) index, which keeps full-precision
light and float16 norms (which the merged codes are made from): a threshold at 0 or a power
of two is exact, any other one changes only the light whose value lies in its octave; and
every layer is within the rgb rule (paths/format.py) of the records index's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.paths.format import NormBins, RgbBins
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

RESOLUTION = (48, 36)


def test_powers_of_two_have_their_own_codes_and_octaves_the_others():
    exponents = np.arange(NormBins.LOWEST_EXPONENT, NormBins.LOWEST_EXPONENT + NormBins.EDGES)
    powers = 2.0 ** exponents
    codes = NormBins.code(powers)
    assert (codes % 2 == 0).all() and (np.diff(codes.astype(int)) == 2).all()
    assert (NormBins.decoded(codes) == powers.astype(np.float32)).all()  # read as themselves
    for factor in (1 + 2**-20, 1.3, 1.9999):  # strictly inside each octave
        inside = NormBins.code(powers[:-1] * factor)
        assert (inside == codes[:-1] + 1).all()
        read = NormBins.decoded(inside).astype(np.float64)
        assert (read > powers[:-1]).all() and (read < 2 * powers[:-1]).all()
        assert np.allclose(read / (powers[:-1] * factor), 1, rtol=math.sqrt(2) - 1)
    values = np.concatenate([[0.0], 10.0 ** np.linspace(-18, 18, 20001)])
    assert (np.diff(NormBins.code(values).astype(int)) >= 0).all()  # monotone
    for code in range(1, NormBins.CODES):
        low, high = NormBins.edges(code)
        centre = float(NormBins.centres()[code])
        assert (centre == low == high) if low == high else (low <= centre <= high)


def test_codes_saturate_and_keep_signs():
    assert NormBins.code(np.array([1e30, np.inf, np.nan])).tolist() == [255, 255, 255]
    assert NormBins.code(np.array([1e-30, 0.0])).tolist() == [1, 0]
    assert NormBins.code(np.array([2.0**-63, 2.0**63], np.float64)).tolist() == [2, 254]
    signed = NormBins.signed_code(np.array([-3.0, 0.0, 3.0, -1e-30]))
    assert signed.dtype == np.int16 and signed[0] == -signed[2] and signed[1] == 0 and signed[3] == -1
    read = NormBins.decoded(signed)
    assert read[0] == -read[2] and abs(read[2] / 3.0 - 1) < math.sqrt(NormBins.WIDTH) - 1


def test_rgb_codes_are_within_one_bin_and_the_brightest_within_half():
    rng = np.random.default_rng(5)
    rgb = 10.0 ** rng.uniform(-12, 8, (20000, 3))
    rgb[::7, 1] = 0.0
    codes = RgbBins.code(rgb)
    read = RgbBins.table()[codes].astype(np.float64)
    assert (read[rgb == 0] == 0).all()
    bins = np.abs(np.log2(read[rgb > 0] / rgb[rgb > 0])) * RgbBins.BINS_PER_OCTAVE
    assert bins.max() <= 1 + 1e-4  # the float32 of each code's value: 1e-5 of a bin
    brightest = rgb.argmax(axis=1)
    rows = np.arange(len(rgb))
    assert (np.abs(np.log2(read[rows, brightest] / rgb[rows, brightest])) * RgbBins.BINS_PER_OCTAVE).max() <= 0.5 + 1e-4
    assert (RgbBins.code(np.array([[-1.0, np.nan, np.inf], [1e-30, 1e30, 1.0]])) == RgbBins.EXACT).tolist() == [
        [True, True, True], [True, True, False]]


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


def rgb_rule(index: PathIndex) -> np.ndarray:
    """(h, w, 3): how far any layer of a merged index may be from full precision by the rgb
    rule, (WIDTH − 1) × the pixel's light (of `index`, a records index of the same render),
    plus float32 rounding."""
    width, height = index.manifest["resolution"]
    beauty = extract(index, {"all": "C.*"}).layers["all"].astype(np.float64)
    return (RgbBins.WIDTH - 1) * np.abs(beauty) + 1e-6 * np.abs(beauty).max()


def thresholds(values: np.ndarray) -> tuple[list[float], list[float]]:
    """Thresholds inside the octaves the values occupy (the median of each one's values),
    and thresholds in empty octaves between and around them (each such octave's centre)."""
    codes = NormBins.code(values)
    occupied = [code for code in np.unique(codes).tolist() if code % 2]  # the open octaves
    inside = [float(np.median(values[codes == code])) for code in occupied]
    empty = [float(NormBins.centres()[code]) for code in range(occupied[0] - 2, occupied[-1] + 4, 2)
             if code not in occupied]
    return inside, empty


@pytest.mark.parametrize("norm, column, scatter", [("T", 1, "D"), ("R", 2, "G"), ("C", 0, ".")])
def test_a_threshold_changes_only_the_light_of_its_own_octave(both_modes, norm, column, scatter):
    """|merged − records| per pixel is at most the light of the records (full precision)
    whose value lies in the open octave holding the threshold, plus the rgb rule; with a
    threshold in an octave no value falls in, the merged layer is the full-precision one
    within the rgb rule."""
    merged, records = both_modes["merged"], both_modes["records"]
    values = first_bounce_values(records, column)
    assert len(values) > 100, f"the showcase has no {norm} to threshold"
    inside, empty = thresholds(values)
    rule = rgb_rule(records)
    selected = []
    for threshold in inside + empty:
        low, high = NormBins.edges(int(NormBins.code(np.array([threshold]))[0]))
        layers = {"above": f"C<R{scatter}>@(|S_{norm}| > {threshold!r}).*",
                  "in_bin": f"C<R{scatter}>@(|S_{norm}| > {low!r} and |S_{norm}| < {high!r}).*"}
        on_records = extract(records, layers).layers
        on_merged = extract(merged, {"above": layers["above"]}).layers["above"].astype(np.float64)
        difference = np.abs(on_merged - on_records["above"])
        assert (difference <= on_records["in_bin"] + rule).all(), threshold
        if threshold in empty:
            assert on_records["in_bin"].max() == 0
            assert (difference <= rule).all(), threshold
        selected.append(on_records["above"].sum())
    assert max(selected) > 0 and min(selected) < max(selected)  # the thresholds cut somewhere


@pytest.mark.parametrize("norm, column, scatter", [("T", 1, "D"), ("R", 2, "G")])
def test_a_threshold_on_a_power_of_two_is_exact(both_modes, norm, column, scatter):
    """Thresholds at the powers of two around the values present: every comparison gives
    the records index's layer, within the rgb rule only, though values lie on both sides."""
    merged, records = both_modes["merged"], both_modes["records"]
    values = first_bounce_values(records, column)
    rule = rgb_rule(records)
    exponents = np.unique(np.floor(np.log2(values)).astype(int))
    cut = 0
    for exponent in exponents.tolist():
        edge = 2.0 ** exponent
        for comparison in (">", ">=", "<", "<=", "="):
            layer = f"C<R{scatter}>@(|S_{norm}| {comparison} {edge!r}).*"
            on_records = extract(records, {"layer": layer}).layers["layer"].astype(np.float64)
            on_merged = extract(merged, {"layer": layer}).layers["layer"].astype(np.float64)
            assert (np.abs(on_merged - on_records) <= rule).all(), layer
            cut += comparison == ">" and 0 < on_records.sum()
    assert cut >= 2  # thresholds with light on both sides


@pytest.mark.parametrize("layer", ["C<RD>@(|S_T| = 0).*", "C<R.>@(|S_C| = 0).*", "C<RD>@(|S_R| = 0).*L"])
def test_zero_is_exact(both_modes, layer):
    """Zero has its own code: `= 0` conditions give the full-precision layer (within the rgb rule)."""
    merged = extract(both_modes["merged"], {"layer": layer}).layers["layer"].astype(np.float64)
    records = extract(both_modes["records"], {"layer": layer}).layers["layer"].astype(np.float64)
    assert (np.abs(merged - records) <= rgb_rule(both_modes["records"])).all()
    assert records.sum() > 0


def test_layers_of_a_partition_sum_to_the_beauty_exactly(both_modes):
    """The carriers hold each pixel's rest: the standard passes, the per-light layers and a
    layer with its complement each sum to the beauty to float32 rounding, however far each
    layer is from full precision; and each is within the rgb rule of the records index's."""
    from pxr_layers import lpe
    from pxr_layers.lpe.passes import per_light_passes

    merged, records = both_modes["merged"], both_modes["records"]
    beauty = extract(records, {"all": "C.*"}).layers["all"].astype(np.float64)
    lights = [event.name for event in merged.events if event.type == "L"]
    partitions = {
        "passes": lpe.STANDARD_PASSES,
        "lights": per_light_passes(lights),
        "complement": {"flat": "C<R.>@(|S_C| = 0).*", "curved": "C<R.>@(|S_C| > 0).*", "direct": "C[^R].*"},
    }
    rule = rgb_rule(records)
    for name, layers in partitions.items():
        cut = extract(merged, layers).layers
        total = np.sum([image.astype(np.float64) for image in cut.values()], axis=0)
        np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-6 * beauty.max(), err_msg=name)
        full = extract(records, layers).layers
        for layer, image in cut.items():
            assert (np.abs(image - full[layer].astype(np.float64)) <= rule).all(), (name, layer)
