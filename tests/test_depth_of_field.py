"""Depth of field against the thin-lens circle of confusion.

An emissive square on the optical axis, seen by a camera with a lens (UsdGeomCamera
fStop, focusDistance; focalLength in tenths of a scene unit). Out of focus, a point images
to a uniform disc of radius R·|d − F| / (d·F) at unit distance (R = focalLength / (2·fStop)
the aperture radius, d the point's distance, F the focus distance): the thin-lens circle of
confusion. A uniform disc of radius r has the second moment r²/2 about its centre, and
second moments of independent blurs add, so the blur radius is measured as
sqrt(2·(M_lens − M_pinhole)), M the image's second moment about its centroid in pixels²:
the square's own size and the pixel filter cancel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.errors import StageError
from pxr_layers.stage import load_stage

from camera_scenes import APERTURE, FOCAL, GLOW, beauty, centimetre_stage, quad

RESOLUTION = 96


def stage(tmp_path, *, distance: float, f_stop: float = 0.0, focus: float = 0.0, disable: bool = False) -> str:
    """A centimetre stage: an emissive square `distance` cm down the camera's −Z, 4 % of
    the distance wide (5 pixels: its own blur, which the pinhole's moment removes)."""
    half = 0.02 * distance
    settings = f"""
    def RenderSettings "Settings"
    {{
        rel camera = </World/Camera>
        int2 resolution = ({RESOLUTION}, {RESOLUTION})
        uniform bool disableDepthOfField = true
    }}""" if disable else ""
    return centimetre_stage(
        tmp_path / f"lens_{distance}_{f_stop}_{focus}_{disable}.usda",
        f"""{GLOW}{quad("square", half, half, distance)}{settings}""",
        metadata='renderSettingsPrimPath = "/World/Settings"' if disable else "",
        camera=f"""float fStop = {f_stop}
        float focusDistance = {focus}""")


def render(path, spp: int = 64) -> np.ndarray:
    return beauty(path, RESOLUTION, spp)


def second_moment(image: np.ndarray) -> float:
    """Σ I·|p − c|² / Σ I in pixels², about the centroid c."""
    y, x = np.mgrid[:image.shape[0], :image.shape[1]] + 0.5
    total = image.sum()
    cx, cy = (image * x).sum() / total, (image * y).sum() / total
    return float((image * ((x - cx) ** 2 + (y - cy) ** 2)).sum() / total)


def circle_of_confusion(distance: float, f_stop: float, focus: float) -> float:
    """The thin lens's blur radius in pixels for a point `distance` cm away (module docstring)."""
    lens_radius = FOCAL / 10 / (2 * f_stop)  # cm: focalLength is in tenths of a scene unit
    at_unit_distance = lens_radius * abs(distance - focus) / (distance * focus)
    return at_unit_distance / (APERTURE / FOCAL) * RESOLUTION


@pytest.mark.parametrize("distance, focus", [(100.0, 500.0), (400.0, 100.0)])
def test_blur_radius_is_the_thin_lens_circle_of_confusion(tmp_path, distance, focus):
    f_stop = 0.5
    pinhole = second_moment(render(stage(tmp_path, distance=distance), spp=128))
    lens = second_moment(render(stage(tmp_path, distance=distance, f_stop=f_stop, focus=focus), spp=128))
    expected = circle_of_confusion(distance, f_stop, focus)
    assert 4 < expected < RESOLUTION / 4  # a blur well resolved and inside the frame
    # Noise: over seeds the measured radius spreads ±1.5 % at 64 spp (4.84 to 4.97 for 5.0)
    assert math.sqrt(2 * (lens - pinhole)) == pytest.approx(expected, rel=0.04)


def test_a_point_at_the_focus_distance_stays_sharp(tmp_path):
    pinhole = render(stage(tmp_path, distance=200.0))
    lens = render(stage(tmp_path, distance=200.0, f_stop=0.5, focus=200.0))
    assert circle_of_confusion(100.0, 0.5, 200.0) > 3  # the same lens blurs a point at half the distance
    assert math.sqrt(2 * abs(second_moment(lens) - second_moment(pinhole))) < 0.25
    assert lens.sum() == pytest.approx(pinhole.sum(), rel=0.02)  # the lens gathers the same light


def test_disable_depth_of_field_renders_the_pinhole_image(tmp_path):
    pinhole = render(stage(tmp_path, distance=100.0), spp=4)
    disabled = render(stage(tmp_path, distance=100.0, f_stop=0.5, focus=500.0, disable=True), spp=4)
    np.testing.assert_array_equal(disabled, pinhole)


def test_the_lens_is_read_in_metres(tmp_path):
    _, spec = load_stage(stage(tmp_path, distance=100.0, f_stop=2.0, focus=300.0))
    assert spec.camera.lens_radius == pytest.approx(0.05 / 2 / 2)  # 50 mm at f/2: a 25 mm aperture
    assert spec.camera.focus_distance == pytest.approx(3.0)
    assert spec.depth_of_field


def test_an_f_stop_without_a_focus_distance_is_a_pinhole_with_a_warning(tmp_path, caplog):
    _, spec = load_stage(stage(tmp_path, distance=100.0, f_stop=2.0))
    assert spec.camera.lens_radius == 0.0
    assert "fStop 2 but focusDistance 0" in caplog.text and "/World/Camera" in caplog.text


def test_a_negative_f_stop_is_refused_naming_the_camera(tmp_path):
    with pytest.raises(StageError, match="fStop is -1.*0 .no depth of field. or more") as error:
        load_stage(stage(tmp_path, distance=100.0, f_stop=-1.0, focus=300.0))
    assert "/World/Camera" in str(error.value)


@pytest.mark.parametrize("f_stop, focus, attribute", [("nan", 300.0, "fStop"), (2.0, "inf", "focusDistance")])
def test_a_lens_that_is_not_a_number_is_refused_naming_it(tmp_path, f_stop, focus, attribute):
    with pytest.raises(StageError, match=f"{attribute} is .*: it must be a finite number") as error:
        load_stage(stage(tmp_path, distance=100.0, f_stop=f_stop, focus=focus))
    assert "/World/Camera" in str(error.value)


def test_the_ray_cone_widens_by_the_lens_defocus_away_from_the_focus():
    """The footprint that filters textures (and sets T): a pinhole's pixel cone, plus the
    width 2R·|1 − t/F| of the bundle of lens rays that meet on the plane in focus."""
    from pxr_layers.trace.sigma import RayCone

    pixel, radius, focus = 1e-3, 0.01, 2.0
    travelled, cos_out = np.array([0.0, 1.0, 2.0, 4.0], np.float32), np.ones(4, np.float32)
    pinhole = RayCone(pixel).footprint(travelled, cos_out)
    lens = RayCone(pixel, radius, focus).footprint(travelled, cos_out)
    np.testing.assert_allclose(pinhole, pixel * travelled, rtol=1e-6)
    np.testing.assert_allclose(lens - pinhole, [2 * radius, radius, 0.0, 2 * radius], rtol=1e-5, atol=1e-9)
