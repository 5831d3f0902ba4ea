"""stage/ies.py: IES LM-63 files → scene.IesProfile (symmetries, factors, power, errors)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.errors import StageError
from pxr_layers.stage.ies import parse_ies, read_ies


def ies_text(vertical, horizontal, candela, *, multiplier=1.0, ballast=1.0, photometric_type=1,
             tilt="NONE", after_tilt="") -> str:
    """An LM-63-2002 file; candela is (H, V), one row per horizontal angle."""
    candela = np.asarray(candela, dtype=float).reshape(len(horizontal), len(vertical))
    rows = "\n".join(" ".join(f"{value:g}" for value in row) for row in candela)
    return "\n".join([
        "IESNA:LM-63-2002",
        "[TEST] pxr-layers",
        "[MANUFAC] nobody",
        f"TILT={tilt}",
        *([after_tilt] if after_tilt else []),
        f"1 -1 {multiplier:g} {len(vertical)} {len(horizontal)} {photometric_type} 2 0.1 0.1 0.0",
        f"{ballast:g} 1.0 40",
        # angles split over lines and separated by commas too, as files in the wild are
        ", ".join(f"{angle:g}" for angle in vertical[: len(vertical) // 2]),
        " ".join(f"{angle:g}" for angle in vertical[len(vertical) // 2:]),
        " ".join(f"{angle:g}" for angle in horizontal),
        rows,
        "",
    ])


def parse(text: str, name: str = "test.ies"):
    profile, notes = parse_ies(text, name)
    return profile


def write(tmp_path, text: str, name: str = "test.ies") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_an_isotropic_profile_has_its_intensity_as_power_and_everywhere(tmp_path):
    vertical = np.arange(0.0, 180.1, 2.5)
    path = write(tmp_path, ies_text(vertical, [0.0], np.full(len(vertical), 100.0)))
    profile, notes = read_ies(path)
    assert notes == () and profile.path == path
    np.testing.assert_allclose(profile.vertical, np.radians(vertical))
    np.testing.assert_allclose(profile.horizontal, [0.0, 2.0 * math.pi])  # rotationally symmetric
    assert profile.candela.shape == (2, len(vertical))
    np.testing.assert_allclose(profile.candela, 100.0)
    assert profile.power == pytest.approx(100.0, rel=1e-4)


def test_a_cosine_lower_hemisphere_has_the_analytic_power():
    # I = I0 cos θ over 0–90°: ∫ I dω = π I0 over the hemisphere, whose area 2π divides it
    vertical = np.arange(0.0, 90.1, 1.0)
    profile = parse(ies_text(vertical, [0.0], 300.0 * np.cos(np.radians(vertical))))
    assert profile.power == pytest.approx(150.0, rel=1e-3)


def test_an_upper_hemisphere_keeps_its_vertical_angles_and_counts_as_a_hemisphere():
    vertical = np.arange(90.0, 180.1, 5.0)
    profile = parse(ies_text(vertical, [0.0], np.full(len(vertical), 10.0)))
    np.testing.assert_allclose(profile.vertical, np.radians(vertical))  # 0–90° left out: intensity 0 there
    assert profile.power == pytest.approx(10.0, rel=1e-3)  # a hemisphere of 10 cd over 2π


def _by_angle(profile) -> dict[float, np.ndarray]:
    """{horizontal degrees: candela row} of an unfolded profile."""
    return {round(math.degrees(angle), 6): row for angle, row in zip(profile.horizontal, profile.candela)}


def _check_closed(profile) -> None:
    assert profile.horizontal[0] == 0.0 and profile.horizontal[-1] == pytest.approx(2.0 * math.pi)
    assert (np.diff(profile.horizontal) > 0).all()
    np.testing.assert_array_equal(profile.candela[0], profile.candela[-1])


# Each horizontal plane gets its own intensity, 10 + φ (degrees), and along the vertical
# angles a slope, so mirrored rows are told apart.
VERTICAL = np.array([0.0, 45.0, 90.0, 135.0, 180.0])


def _rows(horizontal) -> np.ndarray:
    return np.array([[10.0 + phi + theta / 10.0 for theta in VERTICAL] for phi in horizontal])


@pytest.mark.parametrize(
    "horizontal, mirror_of",
    [
        # quadrant symmetric: mirrored about the 90° plane, then about the 180° plane
        ([0.0, 30.0, 60.0, 90.0], {120.0: 60.0, 150.0: 30.0, 180.0: 0.0, 210.0: 30.0, 240.0: 60.0, 270.0: 90.0,
                                   300.0: 60.0, 330.0: 30.0, 360.0: 0.0}),
        # bilateral: mirrored about the 180° plane
        ([0.0, 45.0, 90.0, 135.0, 180.0], {225.0: 135.0, 270.0: 90.0, 315.0: 45.0, 360.0: 0.0}),
        # the 90–270° half, symmetric about the 90°–270° plane: φ looks like 180° − φ
        ([90.0, 135.0, 180.0, 225.0, 270.0], {0.0: 180.0, 45.0: 135.0, 315.0: 225.0, 360.0: 180.0}),
        # as is
        ([0.0, 90.0, 180.0, 270.0, 360.0], {}),
    ],
    ids=["quadrant", "bilateral", "half-90-270", "full"],
)
def test_horizontal_symmetries_unfold_to_the_full_circle(horizontal, mirror_of):
    given = dict(zip(horizontal, _rows(horizontal)))
    if 360.0 in given:  # the same plane as 0°
        given[360.0] = given[0.0]
    profile = parse(ies_text(VERTICAL, horizontal, list(given.values())))
    _check_closed(profile)
    rows = _by_angle(profile)
    for angle, row in given.items():
        np.testing.assert_array_equal(rows[angle], row)
    for angle, source in mirror_of.items():
        np.testing.assert_array_equal(rows[angle], given[source])
    assert sorted(rows) == sorted({*given, *mirror_of, 0.0, 360.0})


def test_a_half_without_a_180_degree_plane_closes_the_circle_by_interpolation():
    horizontal = [90.0, 150.0, 210.0, 270.0]
    profile = parse(ies_text(VERTICAL, horizontal, _rows(horizontal)))
    _check_closed(profile)
    rows = _by_angle(profile)
    assert sorted(rows) == [0.0, 30.0, 90.0, 150.0, 210.0, 270.0, 330.0, 360.0]
    given = dict(zip(horizontal, _rows(horizontal)))
    np.testing.assert_array_equal(rows[30.0], given[150.0])
    np.testing.assert_array_equal(rows[330.0], given[210.0])
    # 0° lies halfway between 330° (210°'s image) and 30° (150°'s image)
    np.testing.assert_allclose(rows[0.0], (given[150.0] + given[210.0]) / 2.0)


def test_power_is_taken_over_the_unfolded_circle():
    half = [0.0, 45.0, 90.0, 135.0, 180.0]
    full = half + [225.0, 270.0, 315.0, 360.0]
    mirrored = np.concatenate([_rows(half), _rows(half)[-2::-1]])
    bilateral = parse(ies_text(VERTICAL, half, _rows(half)))
    explicit = parse(ies_text(VERTICAL, full, mirrored))
    assert bilateral.power == pytest.approx(explicit.power, rel=1e-12)
    np.testing.assert_array_equal(bilateral.candela, explicit.candela)


def test_the_candela_multiplier_and_ballast_factor_scale_the_values():
    vertical = np.arange(0.0, 180.1, 10.0)
    plain = parse(ies_text(vertical, [0.0], np.full(len(vertical), 40.0)))
    scaled = parse(ies_text(vertical, [0.0], np.full(len(vertical), 40.0), multiplier=2.0, ballast=0.75))
    np.testing.assert_allclose(scaled.candela, 60.0)
    assert scaled.power == pytest.approx(1.5 * plain.power)


def test_tilt_include_is_skipped_and_a_tilt_file_is_a_note():
    vertical = [0.0, 90.0, 180.0]
    values = [5.0, 6.0, 7.0]
    plain = parse(ies_text(vertical, [0.0], values))
    # geometry 1, three tilt angles, their three factors (the factors would halve it: not applied)
    included = parse(ies_text(vertical, [0.0], values, tilt="INCLUDE", after_tilt="1\n3\n0 45 90\n0.5 0.5 0.5"))
    np.testing.assert_array_equal(included.candela, plain.candela)
    profile, notes = parse_ies(ies_text(vertical, [0.0], values, tilt="lamp.tlt"), "x.ies")
    np.testing.assert_array_equal(profile.candela, plain.candela)
    assert len(notes) == 1 and "lamp.tlt" in notes[0]


@pytest.mark.parametrize(
    "text, message",
    [
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0]).rstrip().rsplit(" ", 1)[0],
         "the file ends in its candela values: 2 of 3 numbers"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0]) + "4 5\n",
         "2 numbers after the 1 × 3 candela values"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0], photometric_type=3), "type A (3)"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0], photometric_type=2), "type B (2)"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0], tilt=""), "line 4: TILT= names no tilt"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0]).replace("TILT=NONE", "NO TILT"), "no TILT= line"),
        ("IESNA:LM-63-1995\nTILT=INCLUDE\n1\n3\n0 45\n", "the file ends in its TILT=INCLUDE block: 2 of 6 numbers"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0], tilt="INCLUDE", after_tilt="1 2.5"),
         "line 5: the number of tilt angles must be a whole number ≥ 0, not 2.5"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, 2.0, 3.0]).replace("40\n", "40 watts\n"),
         "line 6: 'watts' is not a number"),
        (ies_text([0.0, 90.0, 180.0], [0.0, 90.0, 270.0], np.ones(9)), "horizontal angles 0…270°"),
        (ies_text([0.0, 90.0, 80.0], [0.0], [1.0, 2.0, 3.0]), "vertical angles must ascend"),
        (ies_text([0.0, 90.0, 180.0], [0.0], [1.0, -2.0, 3.0]), "negative candela"),
    ],
    ids=["too-few", "too-many", "type-A", "type-B", "empty-tilt", "no-tilt", "short-tilt", "tilt-count", "not-a-number",
         "horizontal-layout", "vertical-order", "negative"],
)
def test_malformed_files_are_one_line_errors_naming_the_file(tmp_path, text, message):
    path = write(tmp_path, text, "broken.ies")
    with pytest.raises(StageError) as raised:
        read_ies(path)
    assert str(raised.value).startswith(f"{path}: ") and message in str(raised.value)
    assert "\n" not in str(raised.value)


def test_a_missing_file_is_an_error_naming_it(tmp_path):
    with pytest.raises(StageError, match="nope.ies"):
        read_ies(str(tmp_path / "nope.ies"))


def test_the_luxtest_bega_profile(shared_data):
    path = shared_data / "luxtest" / "bega_omni002_4777lm.ies"
    profile, notes = read_ies(str(path))
    assert notes == ()
    assert profile.vertical.shape == (73,) and profile.vertical[-1] == pytest.approx(math.pi)
    # 37 planes 0–180° (bilateral) unfold to 73 over 0–360°
    assert profile.horizontal.shape == (73,) and profile.candela.shape == (73, 73)
    _check_closed(profile)
    assert profile.candela[0, 0] == pytest.approx(2628.1)
    np.testing.assert_array_equal(profile.candela[36 + 10], profile.candela[36 - 10])
    # its flux, 4π × the mean intensity, is the 4777 lm its lamp is rated for (absolute photometry)
    assert 4.0 * math.pi * profile.power == pytest.approx(4777.0, rel=0.01)
