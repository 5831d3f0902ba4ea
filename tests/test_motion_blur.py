"""Camera motion blur against its analytic shape.

A tall emissive strip of width w (pixels on the image) seen by a camera that slides
sideways by d pixels' worth over the shutter (shutter:open 0, shutter:close 1, the
camera's translate keyed at the frame and the next): every sample opens at a time drawn
uniformly in the shutter, so each image row is the strip's box convolved with a box of
width d, a trapezoid of extent w + d whose plateau is (w/d)·E for d > w (E the static
strip's value), and whose integral is the static strip's w·E (motion moves light, it does
not make or lose it). The same for a camera that turns (slerp between its keyed rotations).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.errors import StageError
from pxr_layers.stage import load_stage

from camera_scenes import APERTURE, FOCAL, GLOW, beauty, centimetre_stage, quad

RESOLUTION = 96
DISTANCE = 100.0  # cm from the camera to the strip
PIXELS_PER_CM = RESOLUTION / (APERTURE / FOCAL) / DISTANCE  # at the strip's distance


def stage(tmp_path, *, slide: float = 0.0, turn: float = 0.0, shutter=(0.0, 1.0), settings: str = "") -> str:
    """A centimetre stage: a 4 cm wide, 40 cm tall emissive strip 100 cm down −Z; the camera
    keyed at frames 1 and 2, sliding `slide` cm along +X and turning `turn` degrees about +Y."""
    return centimetre_stage(
        tmp_path / f"moving_{slide}_{turn}_{shutter[0]}_{shutter[1]}_{len(settings)}.usda",
        f"""{GLOW}{quad("strip", 2, 20, DISTANCE)}
    {settings}""",
        metadata=f"""startTimeCode = 1
    endTimeCode = 2
    {'renderSettingsPrimPath = "/World/Settings"' if settings else ""}""",
        camera=f"""double shutter:open = {shutter[0]}
        double shutter:close = {shutter[1]}
        double3 xformOp:translate.timeSamples = {{1: (0, 0, 0), 2: ({slide}, 0, 0)}}
        float xformOp:rotateY.timeSamples = {{1: 0, 2: {turn}}}
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]""")


def render(path, spp: int = 64) -> np.ndarray:
    """The beauty (h, w) at frame 1."""
    return beauty(path, RESOLUTION, spp, 1.0)


def profile(image: np.ndarray) -> np.ndarray:
    """(w,) the mean of the middle rows (the strip spans them all)."""
    middle = RESOLUTION // 2
    return image[middle - 8:middle + 8].mean(axis=0)


def test_a_sliding_camera_smears_a_strip_into_its_trapezoid(tmp_path):
    width, slide = 4 * PIXELS_PER_CM, 12 * PIXELS_PER_CM  # 5.3 and 16 pixels
    still = profile(render(stage(tmp_path)))
    moving = profile(render(stage(tmp_path, slide=12.0)))
    assert moving.sum() == pytest.approx(still.sum(), rel=0.01)  # the light is moved, not made or lost
    assert still.sum() == pytest.approx(width, rel=0.01)
    centre = RESOLUTION / 2 - slide / 2  # the camera slides right: the strip's image slides left
    plateau = moving[int(centre) - 3:int(centre) + 3]
    assert plateau.mean() == pytest.approx(width / slide, rel=0.03)
    assert (moving > 0.02).sum() == pytest.approx(width + slide, abs=1.5)
    assert np.argmax(np.cumsum(moving) >= moving.sum() / 2) == pytest.approx(centre, abs=1)


def test_a_turning_camera_moves_light_without_making_any(tmp_path):
    turn = math.degrees(math.atan(12 / DISTANCE))  # the strip's centre moves 16 pixels again
    still = profile(render(stage(tmp_path)))
    moving = profile(render(stage(tmp_path, turn=turn)))
    assert moving.sum() == pytest.approx(still.sum(), rel=0.01)
    assert (moving > 0.02).sum() == pytest.approx(4 * PIXELS_PER_CM + 12 * PIXELS_PER_CM, abs=2)
    centre = np.argmax(np.cumsum(moving) >= moving.sum() / 2)
    assert centre == pytest.approx(RESOLUTION / 2 + 8, abs=1)  # turning left, the strip slides right
    # the plateau: the image moves at θ'·(1 + x²) in tan units, within 0.4 % of uniform here
    assert moving[centre - 3:centre + 3].mean() == pytest.approx(4 / 12, rel=0.03)


def render_settings(attribute: str = "") -> str:
    """A RenderSettings prim /World/Settings of the camera, with `attribute` authored."""
    return f'def RenderSettings "Settings"\n    {{\n        rel camera = </World/Camera>\n        {attribute}\n    }}'


@pytest.mark.parametrize("closing", ["uniform bool disableMotionBlur = true", "uniform bool instantaneousShutter = true"])
def test_settings_that_close_the_shutter_render_the_frame_still(tmp_path, closing):
    still = render(stage(tmp_path, settings=render_settings()), spp=4)
    closed = render(stage(tmp_path, slide=12.0, settings=render_settings(closing)), spp=4)
    np.testing.assert_array_equal(closed, still)


def test_the_camera_motion_is_read_over_the_shutter(tmp_path):
    _, spec = load_stage(stage(tmp_path, slide=12.0, shutter=(-0.5, 0.5)), frame=1.0)
    np.testing.assert_allclose(spec.camera.motion_times, [-0.5, 0.0, 0.5])  # the key at frame 1 inside
    np.testing.assert_allclose(spec.camera.motion_transforms[:, 0, 3], [0.0, 0.0, 0.06])  # metres, held before 1
    _, spec = load_stage(stage(tmp_path, slide=12.0, shutter=(0.0, 0.0)), frame=1.0)
    assert len(spec.camera.motion_times) == 0  # an instant: no motion


def test_a_shutter_that_closes_before_it_opens_is_refused(tmp_path):
    with pytest.raises(StageError, match=r"shutter:close \(0\) is before shutter:open \(0.5\)") as error:
        load_stage(stage(tmp_path, slide=12.0, shutter=(0.5, 0.0)), frame=1.0)
    assert "/World/Camera" in str(error.value)


def test_a_shutter_that_is_not_a_number_is_refused_naming_it(tmp_path):
    with pytest.raises(StageError, match="shutter:open is nan: it must be a finite number") as error:
        load_stage(stage(tmp_path, slide=12.0, shutter=("nan", 1.0)), frame=1.0)
    assert "/World/Camera" in str(error.value)
