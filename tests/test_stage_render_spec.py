"""stage/: RenderSettings, camera selection and the time code → RenderSpec / SceneData.frame."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdRender

from pxr_layers.errors import PxrLayersError
from pxr_layers.request import AUTO_CAMERA_VIEWS, RenderRequest
from pxr_layers.stage import load_stage
from pxr_layers.stage.defaults import AUTO_CAMERA_MARGIN


def new_stage(tmp_path, *, meters_per_unit=1.0) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(tmp_path / "scene.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    return stage


def load(stage: Usd.Stage, **kwargs):
    stage.GetRootLayer().Save()
    return load_stage(stage.GetRootLayer().realPath, **kwargs)


def settings_with_camera(stage, path, camera_path):
    settings = UsdRender.Settings.Define(stage, path)
    settings.CreateCameraRel().SetTargets([camera_path])
    return settings


def test_stage_render_settings_give_camera_resolution_and_purposes(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Camera.Define(stage, "/Cameras/wide")
    UsdGeom.Camera.Define(stage, "/Cameras/close")
    settings = settings_with_camera(stage, "/Render/Final", "/Cameras/close")
    settings.CreateResolutionAttr(Gf.Vec2i(640, 360))
    settings.CreatePixelAspectRatioAttr(2.0)
    settings.CreateAspectRatioConformPolicyAttr(UsdRender.Tokens.cropAperture)
    settings.CreateMaterialBindingPurposesAttr(["preview", "allPurpose"])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Final")
    _, spec = load(stage)
    assert spec.camera.path == "/Cameras/close" and spec.camera.name == "close"
    assert spec.resolution == (640, 360)
    assert spec.pixel_aspect_ratio == 2.0
    assert spec.aspect_ratio_conform_policy == "cropAperture"
    assert spec.settings_path == "/Render/Final"
    assert spec.material_binding_purposes == ("preview", "")


def test_settings_argument_overrides_the_stage_default(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Camera.Define(stage, "/a")
    UsdGeom.Camera.Define(stage, "/b")
    settings_with_camera(stage, "/Render/Default", "/a")
    settings_with_camera(stage, "/Render/Other", "/b").CreateResolutionAttr(Gf.Vec2i(10, 20))
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Default")
    _, spec = load(stage, settings="/Render/Other")
    assert (spec.camera.path, spec.resolution, spec.settings_path) == ("/b", (10, 20),
                                                                      "/Render/Other")
    # unauthored purposes: full, then allPurpose
    assert spec.material_binding_purposes == ("full", "")


def test_camera_argument_overrides_the_settings_camera(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Camera.Define(stage, "/a")
    UsdGeom.Camera.Define(stage, "/b")
    settings_with_camera(stage, "/Render/Default", "/a")
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Default")
    _, spec = load(stage, camera="/b")
    assert spec.camera.path == "/b" and spec.settings_path == "/Render/Default"


def test_without_settings_the_first_camera_in_traversal_order_is_used(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Xform.Define(stage, "/A")
    UsdGeom.Camera.Define(stage, "/A/first")
    UsdGeom.Camera.Define(stage, "/B/second")
    _, spec = load(stage)
    assert spec.camera.path == "/A/first"
    assert spec.settings_path is None and spec.resolution == (512, 512)


def test_camera_attributes_and_rigid_transform_in_metres(tmp_path):
    stage = new_stage(tmp_path, meters_per_unit=0.01)
    rig = UsdGeom.Xform.Define(stage, "/Rig")
    rig.AddTranslateOp().Set(Gf.Vec3d(100, 0, 500))
    rig.AddRotateYOp().Set(30.0)
    rig.AddScaleOp().Set(Gf.Vec3f(3, 3, 3))
    camera = UsdGeom.Camera.Define(stage, "/Rig/cam")
    camera.CreateFocalLengthAttr(35.0)
    camera.CreateHorizontalApertureAttr(36.0)
    camera.CreateVerticalApertureAttr(24.0)
    camera.CreateHorizontalApertureOffsetAttr(1.0)
    camera.CreateVerticalApertureOffsetAttr(-2.0)
    camera.CreateClippingRangeAttr(Gf.Vec2f(10, 10000))
    camera.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    _, spec = load(stage)
    got = spec.camera
    assert (got.focal_length, got.horizontal_aperture, got.vertical_aperture) == (35, 36, 24)
    assert (got.horizontal_aperture_offset, got.vertical_aperture_offset) == (1, -2)
    assert got.projection == "orthographic"
    assert got.clipping == pytest.approx((0.1, 100.0))
    matrix = got.world_from_camera
    np.testing.assert_allclose(matrix[:3, 3], [1.0, 0.0, 5.0])
    np.testing.assert_allclose(matrix[:3, :3] @ matrix[:3, :3].T, np.eye(3), atol=1e-12)
    angle = math.radians(30.0)
    # the camera looks down its local −Z: after rotateY(30°) that is (−sin, 0, −cos)
    np.testing.assert_allclose(-matrix[:3, 2], [-math.sin(angle), 0, -math.cos(angle)],
                               atol=1e-12)


def _animated_triangle(stage):
    xform = UsdGeom.Xform.Define(stage, "/Anim")
    translate = xform.AddTranslateOp()
    translate.Set(Gf.Vec3d(1, 0, 0), 1.0)
    translate.Set(Gf.Vec3d(11, 0, 0), 11.0)
    mesh = UsdGeom.Mesh.Define(stage, "/Anim/tri")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    UsdGeom.Camera.Define(stage, "/cam")


def test_frame_argument_selects_the_time_code(tmp_path):
    stage = new_stage(tmp_path)
    _animated_triangle(stage)
    scene, _ = load(stage, frame=6.0)
    assert scene.frame == 6.0
    np.testing.assert_allclose(scene.meshes[0].points[0], [6, 0, 0])


def test_default_frame_is_the_authored_start_time_code(tmp_path):
    stage = new_stage(tmp_path)
    _animated_triangle(stage)
    stage.SetStartTimeCode(3.0)
    stage.SetEndTimeCode(11.0)
    scene, _ = load(stage)
    assert scene.frame == 3.0
    np.testing.assert_allclose(scene.meshes[0].points[0], [3, 0, 0])


def test_without_start_time_code_the_earliest_sample_is_read(tmp_path):
    stage = new_stage(tmp_path)
    _animated_triangle(stage)
    scene, _ = load(stage)
    assert math.isnan(scene.frame)
    np.testing.assert_allclose(scene.meshes[0].points[0], [1, 0, 0])


def test_missing_or_wrong_settings_prim_is_an_error(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Camera.Define(stage, "/cam")
    with pytest.raises(PxrLayersError, match="/Render/Nope"):
        load(stage, settings="/Render/Nope")
    with pytest.raises(PxrLayersError, match="not RenderSettings"):
        load(stage, settings="/cam")


def test_missing_or_wrong_camera_prim_is_an_error(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Camera.Define(stage, "/cam")
    UsdGeom.Xform.Define(stage, "/group")
    with pytest.raises(PxrLayersError, match="/nowhere"):
        load(stage, camera="/nowhere")
    with pytest.raises(PxrLayersError, match="not a Camera"):
        load(stage, camera="/group")
    settings_with_camera(stage, "/Render/Broken", "/gone")
    with pytest.raises(PxrLayersError, match="/gone"):
        load(stage, settings="/Render/Broken")


def test_included_purposes_of_the_settings_select_what_renders(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Camera.Define(stage, "/cam")
    for purpose in ("default", "render", "proxy"):
        mesh = UsdGeom.Mesh.Define(stage, f"/{purpose}")
        mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
        mesh.CreateFaceVertexCountsAttr([3])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
        mesh.CreatePurposeAttr(purpose)
    settings = UsdRender.Settings.Define(stage, "/Render/Preview")
    settings.CreateIncludedPurposesAttr(["default", "proxy"])
    scene, _ = load(stage, settings="/Render/Preview")
    assert sorted(mesh.path for mesh in scene.meshes) == ["/default", "/proxy"]


@pytest.mark.parametrize("up_axis", ["Y", "Z"])
@pytest.mark.parametrize("resolution", [(64, 48), (48, 64), (96, 24)])
@pytest.mark.parametrize("view", AUTO_CAMERA_VIEWS)
def test_a_stage_without_camera_is_framed_tightly_at_the_render_aspect(tmp_path, up_axis, resolution, view):
    from pxr_layers.trace.camera import ThinLensCamera

    stage = new_stage(tmp_path, meters_per_unit=0.01)
    UsdGeom.SetStageUpAxis(stage, up_axis)
    cube = UsdGeom.Cube.Define(stage, "/World/box")
    cube.CreateSizeAttr(200.0)  # 2 m in centimetres
    cube.AddTranslateOp().Set(Gf.Vec3d(300, -100, 50))
    stage.GetRootLayer().Save()
    request = RenderRequest("x", resolution=resolution, auto_camera=view)
    scene, spec = load_stage(stage.GetRootLayer().realPath, request=request)
    assert spec.camera.path == "/pxrLayers/autoCamera"
    camera = ThinLensCamera.from_spec(spec)
    assert camera.half_width / camera.half_height == pytest.approx(resolution[0] / resolution[1])  # no conform crop
    centre = np.array([3.0, -1.0, 0.5])
    corners = centre + np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    # Every corner of the box projects inside the film window, the centre on its middle, and
    # the box spans 1/AUTO_CAMERA_MARGIN of the dimension that binds: a tight fit.
    local = (corners - camera.position) @ camera.world_from_camera
    assert (local[:, 2] < 0).all()
    film = local[:, :2] / -local[:, 2:3] / [camera.half_width, camera.half_height]
    assert np.abs(film).max() == pytest.approx(1.0 / AUTO_CAMERA_MARGIN)
    view_axis = (centre - camera.position) @ camera.world_from_camera
    assert np.allclose(view_axis[:2] / -view_axis[2], 0.0, atol=1e-9)
    # Seen from the front (+Z for Y-up, −Y for Z-up), up the stage's up; three-quarter: also
    # from the right and from above.
    up = np.array([0, 0, 1.0]) if up_axis == "Z" else np.array([0, 1.0, 0])
    front = np.array([0, -1.0, 0]) if up_axis == "Z" else np.array([0, 0, 1.0])
    eye = (camera.position - centre) / np.linalg.norm(camera.position - centre)
    if view == "front":
        assert eye @ front == pytest.approx(1.0)
        assert camera.world_from_camera[:, 1] @ up == pytest.approx(1.0)
    else:
        assert eye @ up > 0.3 and eye @ front > 0.5 and eye[0] > 0.3
    near, far = spec.camera.clipping
    distances = np.linalg.norm(corners - camera.position, axis=1)
    assert near < distances.min() and distances.max() < far


@pytest.mark.parametrize("up_axis", ["Y", "Z"])
def test_a_flat_subject_is_seen_from_above_not_edge_on(tmp_path, up_axis):
    """A ground with decals seen from the front would be a line of pixels: the automatic
    camera looks at a flat subject from AUTO_CAMERA_FLAT_ELEVATION above; a tall one stays front."""
    from pxr_layers.stage.defaults import AUTO_CAMERA_FLAT_ELEVATION
    from pxr_layers.trace.camera import ThinLensCamera

    up = np.array([0, 0, 1.0]) if up_axis == "Z" else np.array([0, 1.0, 0])
    elevations = {}
    for name, height in (("ground", 0.05), ("wall", 1.0)):
        (tmp_path / name).mkdir()
        stage = new_stage(tmp_path / name)
        UsdGeom.SetStageUpAxis(stage, up_axis)
        cube = UsdGeom.Cube.Define(stage, "/World/subject")
        cube.AddScaleOp().Set(Gf.Vec3d(*(np.ones(3) + (height - 1) * up)))
        stage.GetRootLayer().Save()
        _, spec = load_stage(stage.GetRootLayer().realPath, request=RenderRequest("x", resolution=(32, 32)))
        camera = ThinLensCamera.from_spec(spec)
        eye = camera.position / np.linalg.norm(camera.position)  # the subject sits at the origin
        elevations[name] = np.degrees(np.arcsin(eye @ up))
    assert elevations == pytest.approx({"ground": AUTO_CAMERA_FLAT_ELEVATION, "wall": 0.0}, abs=1e-6)
