"""Object motion blur against its analytic shape.

A black strip of width w (pixels on the image) in front of a glowing backdrop moves
sideways by d pixels' worth over the shutter (shutter:open 0, shutter:close 1 at frame 1;
the motion keyed at frames 1 and 2, or given by velocities): every sample opens at a time
drawn uniformly in the shutter, so the light each image row loses is the strip's box
convolved with a box of width d, a trapezoid of extent w + d whose plateau is (w/d)·E for
d > w (E the backdrop's value), and whose integral is the still strip's w·E — whether the
strip moves by its transform, by its points' samples, by its velocities or by the joint it
is skinned to; and a round curve of the strip's width, moved by its transform or its points.
"""

from __future__ import annotations

import numpy as np
import pytest

from pxr_layers import lpe
from pxr_layers.errors import StageError
from pxr_layers.layers.extract import extract
from pxr_layers.paths.reader import PathIndex
from pxr_layers.jobs.frame import render_frame
from pxr_layers.request import RenderRequest
from pxr_layers.stage import load_stage, reader

from camera_scenes import APERTURE, BLACK, FOCAL, GLOW, beauty, centimetre_stage, quad

RESOLUTION = 96
DISTANCE = 100.0  # cm from the camera to the strip
PIXELS_PER_CM = RESOLUTION / (APERTURE / FOCAL) / DISTANCE  # at the strip's distance
TIME_CODES_PER_SECOND = 24.0
WIDTH, SLIDE = 4.0, 12.0  # cm: the strip's width and how far it moves from frame 1 to frame 2


def strip_points(shift: float) -> str:
    x0, x1 = -WIDTH / 2 + shift, WIDTH / 2 + shift
    return f"[({x0}, -20, {-DISTANCE}), ({x1}, -20, {-DISTANCE}), ({x1}, 20, {-DISTANCE}), ({x0}, 20, {-DISTANCE})]"


def strip_instancer(velocity: str = "", angular: str = "", sampled: bool = True) -> str:
    """A PointInstancer /World/strips of the black strip (its prototype, around the origin),
    one instance 100 cm down −Z with `velocity` and `angular` (vector3f, deg/s) velocities,
    sampled at frame 1 (else default values)."""

    def value(declaration: str, array: str) -> str:
        return f"{declaration}.timeSamples = {{1: [{array}]}}" if sampled else f"{declaration} = [{array}]"

    return f"""
    def PointInstancer "strips"
    {{
        rel prototypes = </World/strips/Prototypes/strip>
        int[] protoIndices = [0]
        {value("point3f[] positions", f"(0, 0, {-DISTANCE})")}
        {value("vector3f[] velocities", velocity) if velocity else ""}
        {value("vector3f[] angularVelocities", angular) if angular else ""}
        {value("quath[] orientations", "(1, 0, 0, 0)") if angular else ""}
        def Scope "Prototypes"
        {{
            def Mesh "strip" (prepend apiSchemas = ["MaterialBindingAPI"])
            {{
                int[] faceVertexCounts = [4]
                int[] faceVertexIndices = [0, 1, 2, 3]
                point3f[] points = [(-2, -20, 0), (2, -20, 0), (2, 20, 0), (-2, 20, 0)]
                uniform token subdivisionScheme = "none"
                rel material:binding = </World/black>
            }}
        }}
    }}"""


IDENTITY = "((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))"
SKINNED = f"""def SkelRoot "rig"
    {{
        def Skeleton "skeleton" (prepend apiSchemas = ["SkelBindingAPI"])
        {{
            uniform token[] joints = ["root"]
            uniform matrix4d[] bindTransforms = [{IDENTITY}]
            uniform matrix4d[] restTransforms = [{IDENTITY}]
            rel skel:animationSource = </World/rig/skeleton/slide>
            def SkelAnimation "slide"
            {{
                uniform token[] joints = ["root"]
                float3[] translations.timeSamples = {{1: [(0, 0, 0)], 2: [({SLIDE}, 0, 0)]}}
                quatf[] rotations = [(1, 0, 0, 0)]
                half3[] scales = [(1, 1, 1)]
            }}
        }}
        def Mesh "strip" (prepend apiSchemas = ["SkelBindingAPI", "MaterialBindingAPI"])
        {{
            int[] faceVertexCounts = [4]
            int[] faceVertexIndices = [0, 1, 2, 3]
            point3f[] points = {strip_points(0)}
            int[] primvars:skel:jointIndices = [0] (interpolation = "constant"; elementSize = 1)
            float[] primvars:skel:jointWeights = [1] (interpolation = "constant"; elementSize = 1)
            matrix4d primvars:skel:geomBindTransform = {IDENTITY}
            rel skel:skeleton = </World/rig/skeleton>
            rel material:binding = </World/black>
        }}
    }}"""
"""The strip skinned to one joint that the animation slides by SLIDE from frame 1 to 2."""

def strand(points: str, transform: str = "") -> str:
    """The strip as a black round curve of its width (a tube, seen side on), through `points`."""
    return f"""def BasisCurves "strip" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        uniform token type = "linear"
        int[] curveVertexCounts = [2]
        {points}
        float[] widths = [{WIDTH}]
        {transform}
        rel material:binding = </World/black>
    }}"""


def strand_points(shift: float) -> str:
    return f"[({shift}, -20, {-DISTANCE}), ({shift}, 20, {-DISTANCE})]"


MOVES = {
    "still": f"point3f[] points = {strip_points(0)}",
    "transform": f"""point3f[] points = {strip_points(0)}
        double3 xformOp:translate.timeSamples = {{1: (0, 0, 0), 2: ({SLIDE}, 0, 0)}}
        uniform token[] xformOpOrder = ["xformOp:translate"]""",
    "deformation": f"point3f[] points.timeSamples = {{1: {strip_points(0)}, 2: {strip_points(SLIDE)}}}",
    # velocities in cm per second: SLIDE over one frame, moving a cache's sampled points (USD's
    # rule: velocities beside points without samples are ignored, with a note)
    "velocity": f"""point3f[] points.timeSamples = {{1: {strip_points(0)}}}
        vector3f[] velocities.timeSamples = {{1: [{", ".join([f"({SLIDE * TIME_CODES_PER_SECOND}, 0, 0)"] * 4)}]}}""",
    "velocity-unsampled": f"""point3f[] points = {strip_points(0)}
        vector3f[] velocities = [{", ".join([f"({SLIDE * TIME_CODES_PER_SECOND}, 0, 0)"] * 4)}]""",
    "instancer-unsampled": strip_instancer(velocity=f"({SLIDE * TIME_CODES_PER_SECOND}, 0, 0)", sampled=False),
    "instancer-velocity": strip_instancer(velocity=f"({SLIDE * TIME_CODES_PER_SECOND}, 0, 0)"),
    "instancer-turning": strip_instancer(angular=f"(0, 0, {90 * TIME_CODES_PER_SECOND})"),
    "strand-still": strand(f"point3f[] points = {strand_points(0)}"),
    "strand-transform": strand(f"point3f[] points = {strand_points(0)}",
                               f"""double3 xformOp:translate.timeSamples = {{1: (0, 0, 0), 2: ({SLIDE}, 0, 0)}}
        uniform token[] xformOpOrder = ["xformOp:translate"]"""),
    "strand-deformation": strand(f"point3f[] points.timeSamples = {{1: {strand_points(0)}, 2: {strand_points(SLIDE)}}}"),
    "mismatched": f"""point3f[] points.timeSamples = {{1: {strip_points(0)},
            2: [(0, 0, {-DISTANCE}), (1, 0, {-DISTANCE}), (1, 1, {-DISTANCE}), (0, 1, {-DISTANCE}), (2, 2, {-DISTANCE})]}}""",
}


def stage(tmp_path, move: str, settings: str = "") -> str:
    """A centimetre stage: a black strip 4 cm wide, 40 cm tall, 100 cm down −Z, moving as
    MOVES[move] says, in front of a glowing backdrop 200 cm away."""
    strip = SKINNED if move == "skinned" else MOVES[move] if move.startswith(("instancer", "strand")) else f"""def Mesh "strip" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        {MOVES[move]}
        rel material:binding = </World/black>
    }}"""
    return centimetre_stage(
        tmp_path / f"strip_{move}_{len(settings)}.usda",
        f"""{GLOW}{BLACK}{quad("backdrop", 400, 400, 2 * DISTANCE)}
    {strip}
    {settings}""",
        metadata=f"""startTimeCode = 1
    endTimeCode = 2
    timeCodesPerSecond = {TIME_CODES_PER_SECOND}
    {'renderSettingsPrimPath = "/World/Settings"' if settings else ""}""",
        camera="""double shutter:open = 0
        double shutter:close = 1""")


def occlusion(path, spp: int = 64) -> np.ndarray:
    """(w,) the light the strip takes from the backdrop, mean of the middle rows, at frame 1."""
    image = beauty(path, RESOLUTION, spp, 1.0)
    middle = RESOLUTION // 2
    return 1.0 - image[middle - 8:middle + 8].mean(axis=0)


@pytest.mark.parametrize("move", ["transform", "deformation", "velocity", "skinned", "strand-transform",
                                  "strand-deformation"])
def test_a_moving_strip_blurs_into_its_trapezoid(tmp_path, move):
    width, slide = WIDTH * PIXELS_PER_CM, SLIDE * PIXELS_PER_CM  # 5.3 and 16 pixels
    still = occlusion(stage(tmp_path, "strand-still" if move.startswith("strand") else "still"))
    moving = occlusion(stage(tmp_path, move))
    assert still.sum() == pytest.approx(width, rel=0.01)
    assert moving.sum() == pytest.approx(still.sum(), rel=0.01)  # the shadow is moved, not made or lost
    centre = RESOLUTION / 2 + slide / 2
    plateau = moving[int(centre) - 3:int(centre) + 3]
    assert plateau.mean() == pytest.approx(width / slide, rel=0.03)
    assert (moving > 0.02).sum() == pytest.approx(width + slide, abs=1.5)
    assert np.argmax(np.cumsum(moving) >= moving.sum() / 2) == pytest.approx(centre, abs=1)


@pytest.mark.parametrize("instanced", [False, True])
def test_a_point_instance_moved_by_its_velocity_blurs_into_its_trapezoid(tmp_path, monkeypatch, instanced):
    """The strip as a PointInstancer's instance with a velocity: a moving copy of the
    prototype, or, shared (every placement instanced), an Embree instance whose placement
    moves over the shutter."""
    if instanced:
        monkeypatch.setattr(reader, "INSTANCING_SAVES", 0)
    scene, _ = load_stage(stage(tmp_path, "instancer-velocity"), frame=1.0)
    strip = next(mesh for mesh in scene.meshes if mesh.name == "strip")
    assert (strip.motion_world_from_points is not None) == instanced
    width, slide = WIDTH * PIXELS_PER_CM, SLIDE * PIXELS_PER_CM
    moving = occlusion(stage(tmp_path, "instancer-velocity"))
    assert moving.sum() == pytest.approx(width, rel=0.01)
    centre = RESOLUTION / 2 + slide / 2
    assert moving[int(centre) - 3:int(centre) + 3].mean() == pytest.approx(width / slide, rel=0.03)
    assert (moving > 0.02).sum() == pytest.approx(width + slide, abs=1.5)


def test_a_turning_instance_gets_a_time_step_per_ten_degrees(tmp_path):
    """angularVelocities turn the strip 90° about the view axis over the shutter: 10 steps,
    each turning it 10°, the last one the strip turned a quarter."""
    scene, _ = load_stage(stage(tmp_path, "instancer-turning"), frame=1.0)
    strip = next(mesh for mesh in scene.meshes if mesh.name == "strip")
    assert strip.motion_points.shape[0] == 10
    corner = strip.motion_points[:, 2]  # (2, 20, 0) cm about the instance's position, in metres
    angles = np.degrees(np.arctan2(corner[:, 1], corner[:, 0]))
    np.testing.assert_allclose(np.diff(angles), 10.0, atol=1e-3)
    np.testing.assert_allclose(corner[-1, :2], [-0.2, 0.02], atol=1e-6)


@pytest.mark.parametrize("move", ["velocity-unsampled", "instancer-unsampled"])
def test_velocities_beside_unsampled_points_are_ignored_with_a_note(tmp_path, move):
    scene, _ = load_stage(stage(tmp_path, move), frame=1.0)
    strip = next(mesh for mesh in scene.meshes if mesh.name == "strip")
    assert strip.motion_points is None and strip.motion_world_from_points is None
    noted = [warning for warning in scene.warnings if "velocities ignored" in warning]
    assert len(noted) == 1 and ("/World/strips" if "instancer" in move else "/World/strip") in noted[0]


def test_settings_that_close_the_shutter_keep_a_moving_strip_still(tmp_path):
    settings = ('def RenderSettings "Settings"\n    {\n        rel camera = </World/Camera>\n'
                '        uniform bool disableMotionBlur = true\n    }')
    still = occlusion(stage(tmp_path, "still"), spp=4)
    closed = occlusion(stage(tmp_path, "transform", settings), spp=4)
    np.testing.assert_array_equal(closed, still)


def test_the_moving_meshes_carry_their_time_steps(tmp_path):
    scene, spec = load_stage(stage(tmp_path, "velocity"), frame=1.0)
    strip = next(mesh for mesh in scene.meshes if mesh.name == "strip")
    assert strip.motion_points.shape == (2, *strip.points.shape)  # the shutter's ends
    np.testing.assert_allclose(strip.motion_points[..., 0].min(axis=1), [-0.02, -0.02 + SLIDE / 100], atol=1e-6)  # m
    backdrop = next(mesh for mesh in scene.meshes if mesh.name == "backdrop")
    assert backdrop.motion_points is None


def test_points_whose_samples_change_topology_are_refused_naming_the_prim(tmp_path):
    with pytest.raises(StageError, match=r"its points change in number over the shutter \(4 at the frame, 5 at time 2\)") as error:
        load_stage(stage(tmp_path, "mismatched"), frame=1.0)
    assert "/World/strip" in str(error.value)


@pytest.mark.parametrize("move, covariance", [("transform", "norms"), ("instancer-velocity", "sigma")])
def test_moving_paths_are_indexed_and_their_layers_add_up(tmp_path, monkeypatch, move, covariance):
    """The moving strip before the glowing backdrop, two bounces, with the index: the
    standard passes cut from it add up to the beauty, which is the blurred one. With the
    whole Σ (whose index flattens instances), a moving instance becomes a moving mesh."""
    monkeypatch.setattr(reader, "INSTANCING_SAVES", 0)
    request = RenderRequest(stage=stage(tmp_path, move), resolution=(RESOLUTION, RESOLUTION), spp=16,
                            max_depth=2, default_lights=False, previews=False, index_covariance=covariance)
    result = render_frame(request, 1.0, output=tmp_path)
    beauty_rgb = result.rgba[..., :3].astype(np.float64)
    layers = extract(PathIndex(result.index_path), lpe.STANDARD_PASSES).layers
    total = np.sum([image.astype(np.float64) for image in layers.values()], axis=0)
    assert np.max(np.abs(total - beauty_rgb) / np.maximum(np.abs(beauty_rgb), 1e-3 * beauty_rgb.max())) <= 1e-5
    middle = RESOLUTION // 2
    blurred = 1.0 - beauty_rgb[middle - 8:middle + 8].mean(axis=(0, 2))
    assert (blurred > 0.02).sum() == pytest.approx((WIDTH + SLIDE) * PIXELS_PER_CM, abs=1.5)
