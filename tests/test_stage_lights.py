"""stage/: UsdLux lights → scene.Light (radiance, blackbody, normalize, transforms, dome
orientation, shaping and IES profiles, textures, treatAs hints, multipliers, camera visibility,
light and shadow linking, and what still warns)."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from pxr_layers.request import RenderRequest
from pxr_layers.scene import LightShaping
from pxr_layers.stage import load_stage
from pxr_layers.stage.lights import blackbody_rgb


def new_stage(tmp_path, *, up_axis=UsdGeom.Tokens.y, meters_per_unit=1.0) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(tmp_path / "scene.usda"))
    UsdGeom.SetStageUpAxis(stage, up_axis)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.Camera.Define(stage, "/Camera")
    return stage


def load(stage: Usd.Stage):
    stage.GetRootLayer().Save()
    scene, _ = load_stage(stage.GetRootLayer().realPath)
    return scene


def only_light(scene):
    assert len(scene.lights) == 1, [light.path for light in scene.lights]
    return scene.lights[0]


def test_intensity_exposure_and_color_fold_into_radiance(tmp_path):
    stage = new_stage(tmp_path)
    light = UsdLux.RectLight.Define(stage, "/Lights/key")
    light.CreateIntensityAttr(2.0)
    light.CreateExposureAttr(1.5)
    light.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    got = only_light(load(stage))
    assert (got.name, got.path, got.kind) == ("key", "/Lights/key", "rect")
    np.testing.assert_allclose(got.radiance, 2.0 * 2**1.5 * np.array([1.0, 0.5, 0.25]))
    assert got.radiance.shape == (3,)


def test_color_temperature_multiplies_the_blackbody_colour(tmp_path):
    stage = new_stage(tmp_path)
    light = UsdLux.SphereLight.Define(stage, "/warm")
    light.CreateIntensityAttr(3.0)
    light.CreateEnableColorTemperatureAttr(True)
    light.CreateColorTemperatureAttr(3000.0)
    UsdLux.SphereLight.Define(stage, "/off").CreateColorTemperatureAttr(3000.0)  # not enabled
    lights = {light.name: light for light in load(stage).lights}
    np.testing.assert_allclose(lights["warm"].radiance, 3.0 * blackbody_rgb(3000.0), rtol=1e-12)
    np.testing.assert_allclose(lights["off"].radiance, [1.0, 1.0, 1.0])


# Linear Rec.709 (D65) → CIE XYZ, IEC 61966-2-1.
XYZ_FROM_REC709 = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])


def kim_planckian_xy(kelvin: float) -> tuple[float, float]:
    """The Planckian locus in CIE 1931 xy by Kim et al.'s cubic splines (2002), 1667–25000 K."""
    t = kelvin
    if t <= 4000.0:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222.0:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000.0:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


@pytest.mark.parametrize("kelvin", [2000.0, 4250.0, 6500.0, 8750.0, 11000.0])
def test_blackbody_lies_on_the_planckian_locus_with_luminance_one(kelvin):
    rgb = blackbody_rgb(kelvin)
    xyz = XYZ_FROM_REC709 @ rgb
    assert xyz[1] == pytest.approx(1.0, abs=1e-4)
    np.testing.assert_allclose(xyz[:2] / xyz.sum(), kim_planckian_xy(kelvin), atol=2e-3)


def test_blackbody_agrees_with_usdlux_table_inside_the_rec709_gamut():
    # Within 0.5 % of each channel, or of the luminance (1) for the small ones, up to the
    # table's 10000 K clamp. Below ~1900 K the locus leaves the Rec.709 gamut, where the two
    # approximations part (8 % at 1000 K) and the blue is clipped to 0.
    for kelvin in np.arange(2000.0, 10001.0, 50.0):
        table = np.array(UsdLux.BlackbodyTemperatureAsRgb(kelvin))
        assert (abs(blackbody_rgb(kelvin) - table) <= 5e-3 * np.maximum(table, 1.0)).all(), kelvin
    for kelvin in (1000.0, 1500.0):
        rgb = blackbody_rgb(kelvin)
        assert rgb.min() == 0.0 and rgb[0] > rgb[1] and rgb @ [0.2126, 0.7152, 0.0722] == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize(
    "schema, sizes, area",
    [
        (UsdLux.RectLight, {"width": 2.0, "height": 3.0}, 6.0),
        (UsdLux.DiskLight, {"radius": 0.5}, math.pi * 0.25),
        (UsdLux.SphereLight, {"radius": 2.0}, 4 * math.pi * 4.0),
        (UsdLux.CylinderLight, {"radius": 1.0, "length": 4.0}, 2 * math.pi * 4.0),
    ],
    ids=["rect", "disk", "sphere", "cylinder"],
)
def test_normalize_divides_area_lights_by_their_stage_unit_area(tmp_path, schema, sizes, area):
    # centimetre stage, light scaled ×2 by its parent: the area counts the scale, not the units
    stage = new_stage(tmp_path, meters_per_unit=0.01)
    UsdGeom.Xform.Define(stage, "/Rig").AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    light = schema.Define(stage, "/Rig/light")
    light.CreateNormalizeAttr(True)
    light.CreateIntensityAttr(10.0)
    for name, value in sizes.items():
        light.GetPrim().GetAttribute(f"inputs:{name}").Set(value)
    got = only_light(load(stage))
    scaled_area = area * 4.0
    np.testing.assert_allclose(got.radiance, [10.0 / scaled_area] * 3, rtol=2e-3)
    for name, value in sizes.items():
        assert getattr(got, name) == pytest.approx(value)  # sizes stay in local units


def test_scaled_sphere_light_uses_the_ellipsoid_area(tmp_path):
    stage = new_stage(tmp_path)
    light = UsdLux.SphereLight.Define(stage, "/egg")
    light.AddScaleOp().Set(Gf.Vec3f(1, 1, 3))
    light.CreateRadiusAttr(1.0)
    light.CreateNormalizeAttr(True)
    # the surface area of a prolate spheroid with a = 1, c = 3
    eccentricity = math.sqrt(1 - 1 / 9)
    area = 2 * math.pi * (1 + 3 / eccentricity * math.asin(eccentricity))
    np.testing.assert_allclose(only_light(load(stage)).radiance, [1 / area] * 3, rtol=0.011)


@pytest.mark.parametrize(
    "angle, size_factor",
    [
        (0.0, 1.0),
        (10.0, math.pi * math.sin(math.radians(5.0)) ** 2),
        (180.0, math.pi),
        (270.0, (2 - math.sin(math.radians(135.0)) ** 2) * math.pi),
    ],
)
def test_normalize_distant_light_by_its_cone(tmp_path, angle, size_factor):
    stage = new_stage(tmp_path)
    light = UsdLux.DistantLight.Define(stage, "/sun")
    light.CreateAngleAttr(angle)
    light.CreateIntensityAttr(100.0)
    light.CreateNormalizeAttr(True)
    got = only_light(load(stage))
    assert got.kind == "distant" and got.angle == pytest.approx(angle)
    np.testing.assert_allclose(got.radiance, [100.0 / size_factor] * 3, rtol=1e-6)


def test_distant_light_default_intensity_without_normalize(tmp_path):
    stage = new_stage(tmp_path)
    UsdLux.DistantLight.Define(stage, "/sun")
    np.testing.assert_allclose(only_light(load(stage)).radiance, [50000.0] * 3)


def test_light_transform_keeps_scale_and_converts_to_metres(tmp_path):
    stage = new_stage(tmp_path, meters_per_unit=0.01)
    rig = UsdGeom.Xform.Define(stage, "/Rig")
    rig.AddTranslateOp().Set(Gf.Vec3d(100, 200, 300))
    rig.AddRotateYOp().Set(90.0)
    light = UsdLux.RectLight.Define(stage, "/Rig/panel")
    light.AddScaleOp().Set(Gf.Vec3f(2, 1, 1))
    light.CreateWidthAttr(50.0)
    got = only_light(load(stage))
    matrix = got.world_from_light
    assert matrix.shape == (4, 4) and matrix.dtype == np.float64
    np.testing.assert_allclose(matrix[:3, 3], [1.0, 2.0, 3.0])
    # column convention: local +X (scaled ×2, in cm) ends up along world −Z (rotateY 90°)
    np.testing.assert_allclose(matrix[:3, 0], [0, 0, -0.02], atol=1e-12)
    np.testing.assert_allclose(matrix[:3, 2], [0.01, 0, 0], atol=1e-12)
    # the tracer's world width: local width times the matrix
    assert np.linalg.norm(matrix[:3, 0] * got.width) == pytest.approx(1.0)


def write_exr(path, pixels: np.ndarray) -> None:
    output = oiio.ImageOutput.create(str(path))
    output.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], oiio.FLOAT))
    output.write_image(pixels)
    output.close()


def test_dome_ignores_normalize_and_reads_its_texture_raw(tmp_path):
    pixels = np.array([[[4.0, 2.0, 1.0], [0.5, 0.25, 0.125]]], dtype=np.float32)
    write_exr(tmp_path / "sky.exr", pixels)
    stage = new_stage(tmp_path)
    dome = UsdLux.DomeLight.Define(stage, "/sky")
    dome.CreateTextureFileAttr(Sdf.AssetPath("sky.exr"))
    dome.CreateIntensityAttr(0.5)
    dome.CreateNormalizeAttr(True)
    scene = load(stage)
    got = only_light(scene)
    assert got.kind == "dome"
    np.testing.assert_allclose(got.radiance, [0.5] * 3)
    texture = scene.textures[got.texture]
    np.testing.assert_allclose(texture.pixels[0, :, :3], pixels[0])


def test_missing_dome_texture_warns_and_leaves_a_constant_dome(tmp_path):
    stage = new_stage(tmp_path)
    UsdLux.DomeLight.Define(stage, "/sky").CreateTextureFileAttr(Sdf.AssetPath("./nope.exr"))
    scene = load(stage)
    assert only_light(scene).texture is None
    assert any("nope.exr" in warning and "/sky" in warning for warning in scene.warnings)


@pytest.mark.parametrize(
    "schema, pole_axis, up_axis, y_goes_to",
    [
        (UsdLux.DomeLight, None, "Y", (0, 1, 0)),
        (UsdLux.DomeLight, None, "Z", (0, 1, 0)),  # the plain DomeLight is always Y-up
        (UsdLux.DomeLight_1, "scene", "Z", (0, 0, 1)),
        (UsdLux.DomeLight_1, "scene", "Y", (0, 1, 0)),
        (UsdLux.DomeLight_1, "Z", "Y", (0, 0, 1)),
        (UsdLux.DomeLight_1, "Y", "Z", (0, 1, 0)),
    ],
)
def test_dome_frame_follows_the_pole_axis(tmp_path, schema, pole_axis, up_axis, y_goes_to):
    stage = new_stage(tmp_path, up_axis=up_axis)
    dome = schema.Define(stage, "/sky")
    if pole_axis is not None:
        dome.CreatePoleAxisAttr(pole_axis)
    matrix = only_light(load(stage)).world_from_light
    np.testing.assert_allclose(matrix[:3, 1], y_goes_to, atol=1e-12)
    np.testing.assert_allclose(matrix[:3, :3] @ matrix[:3, :3].T, np.eye(3), atol=1e-12)
    if y_goes_to == (0, 0, 1):
        # UsdLux: on a Z-up dome, longitude 0 (EXR +Z) points to −Y
        np.testing.assert_allclose(matrix[:3, 2], [0, -1, 0], atol=1e-12)


def test_dome_keeps_its_rotation_but_not_scale_or_translation(tmp_path):
    stage = new_stage(tmp_path)
    dome = UsdLux.DomeLight.Define(stage, "/sky")
    dome.AddTranslateOp().Set(Gf.Vec3d(5, 5, 5))
    dome.AddRotateYOp().Set(90.0)
    dome.AddScaleOp().Set(Gf.Vec3f(3, 3, 3))
    matrix = only_light(load(stage)).world_from_light
    np.testing.assert_allclose(matrix[:3, 3], [0, 0, 0])
    np.testing.assert_allclose(matrix[:3, 2], [1, 0, 0], atol=1e-12)  # +Z turned to +X


def tri(stage: Usd.Stage, path: str) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    return mesh


def test_unsupported_lights_warn_once_per_kind(tmp_path):
    stage = new_stage(tmp_path)
    UsdLux.MeshLightAPI.Apply(tri(stage, "/glowing").GetPrim())
    UsdLux.PortalLight.Define(stage, "/portal")
    UsdLux.SphereLight.Define(stage, "/a")
    scene = load(stage)
    assert [mesh.path for mesh in scene.meshes] == ["/glowing"]  # still rendered as geometry
    assert [light.path for light in scene.lights] == ["/a"]
    unsupported = [w for w in scene.warnings if "unsupported lights" in w]
    assert len(unsupported) == 1 and "/glowing" in unsupported[0] and "/portal" in unsupported[0]
    assert len(scene.warnings) == 1


def test_filters_shadow_controls_and_portals_warn_once_per_kind(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    UsdLux.LightFilter.Define(stage, "/filter")
    for name in ("a", "b"):
        light = UsdLux.SphereLight.Define(stage, f"/{name}")
        light.GetFiltersRel().AddTarget("/filter")
        UsdLux.ShadowAPI.Apply(light.GetPrim()).CreateShadowColorAttr(Gf.Vec3f(1, 0, 0))
    UsdLux.ShadowAPI.Apply(UsdLux.SphereLight.Define(stage, "/defaults").GetPrim())  # nothing authored
    UsdLux.DomeLight.Define(stage, "/sky").GetPortalsRel().AddTarget("/portal")
    warnings = load(stage).warnings
    assert len(warnings) == 3, warnings
    for word in ("filters", "ShadowAPI"):
        [warning] = [w for w in warnings if word in w]
        assert "/a" in warning and "/b" in warning and "/defaults" not in warning
    assert any("portals" in w and "/sky" in w for w in warnings)


def test_invisible_lights_are_skipped(tmp_path):
    stage = new_stage(tmp_path)
    UsdLux.SphereLight.Define(stage, "/on")
    UsdLux.SphereLight.Define(stage, "/off").MakeInvisible()
    assert [light.path for light in load(stage).lights] == ["/on"]


def test_a_stage_nothing_lights_gets_the_default_rig_with_one_warning(tmp_path):
    stage = new_stage(tmp_path)
    scene = load(stage)
    names = ["defaultDome", "defaultKey", "defaultFill", "defaultRim"]
    assert [(light.name, light.kind) for light in scene.lights] == [
        (name, "dome" if name == "defaultDome" else "distant") for name in names]
    assert [light.path for light in scene.lights] == [f"/pxrLayers/defaultLights/{name}" for name in names]
    assert len([warning for warning in scene.warnings if "default rig" in warning]) == 1


def test_without_default_lights_an_unlit_stage_warns_the_image_will_be_black(tmp_path):
    stage = new_stage(tmp_path)
    stage.GetRootLayer().Save()
    scene, _ = load_stage(stage.GetRootLayer().realPath, request=RenderRequest("x", default_lights=False))
    assert scene.lights == () and any("black" in warning for warning in scene.warnings)


def test_an_emissive_material_counts_as_light(tmp_path):
    stage = new_stage(tmp_path)
    mesh = tri(stage, "/panel")
    material = UsdShade.Material.Define(stage, "/Looks/glow")
    shader = UsdShade.Shader.Define(stage, "/Looks/glow/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set((5, 5, 5))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    assert not any("black" in warning for warning in load(stage).warnings)


# ---------------------------------------------------------------------------------------
# ShapingAPI


def shaped(stage: Usd.Stage, schema, path: str, **values) -> UsdLux.ShapingAPI:
    """A light of ``schema`` with ShapingAPI applied and ``values`` authored (UsdLux names
    after ``inputs:shaping:``, with ``:`` as ``_``)."""
    prim = schema.Define(stage, path).GetPrim()
    shaping = UsdLux.ShapingAPI.Apply(prim)
    for name, value in values.items():
        attribute = prim.GetAttribute("inputs:shaping:" + name.replace("_", ":"))
        attribute.Set(value)
    return shaping


def test_a_rect_with_default_shaping_or_a_sphere_with_a_half_cone_has_no_shaping_and_no_warning(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.RectLight, "/rect")  # the fallback 90° cone: a rect emits within 90° anyway
    shaped(stage, UsdLux.DiskLight, "/disk", cone_angle=100.0, cone_softness=0.1)  # starts fading at 90°
    shaped(stage, UsdLux.SphereLight, "/sphere", cone_angle=180.0, focus=3.0, focusTint=Gf.Vec3f(1, 1, 1))
    shaped(stage, UsdLux.CylinderLight, "/cylinder", cone_angle=180.0, focus=-2.0, focusTint=Gf.Vec3f(0.5, 0, 0))
    UsdLux.SphereLight.Define(stage, "/plain")
    scene = load(stage)
    assert [light.shaping for light in scene.lights] == [None] * 5
    assert scene.warnings == ()


def test_the_schema_fallback_cone_shapes_a_sphere(tmp_path):
    stage = new_stage(tmp_path)
    shaped(stage, UsdLux.SphereLight, "/bulb")
    assert only_light(load(stage)).shaping == LightShaping(cone_angle=90.0)


FLOAT32_0_2 = float(np.float32(0.2))  # what a float attribute holds for 0.2


@pytest.mark.parametrize(
    "values, expected",
    [
        ({"cone_angle": 30.0, "cone_softness": 0.25}, LightShaping(cone_angle=30.0, cone_softness=0.25)),
        ({"cone_angle": 100.0, "cone_softness": 0.2}, LightShaping(cone_angle=100.0, cone_softness=FLOAT32_0_2)),
        ({"cone_angle": 45.0, "cone_softness": 1.5}, LightShaping(cone_angle=45.0, cone_softness=1.0)),
        ({"cone_angle": 45.0, "cone_softness": -1.0}, LightShaping(cone_angle=45.0)),
        ({"focus": 2.0}, LightShaping(focus=2.0)),
        ({"focus": 2.0, "focusTint": Gf.Vec3f(0.5, 0.25, 1)}, LightShaping(focus=2.0, focus_tint=(0.5, 0.25, 1.0))),
        ({"cone_angle": 60.0, "focus": 1.0}, LightShaping(cone_angle=60.0, focus=1.0)),
    ],
    ids=["cone", "just-below-90", "softness-clamped-high", "softness-clamped-low", "focus", "focus-tint",
         "cone-and-focus"],
)
def test_shaping_that_changes_a_rect_is_read(tmp_path, values, expected):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.RectLight, "/key", **values)
    scene = load(stage)
    assert only_light(scene).shaping == expected
    assert scene.warnings == ()


def test_shaping_is_time_sampled(tmp_path):
    stage = new_stage(tmp_path)
    attribute = shaped(stage, UsdLux.RectLight, "/key").GetShapingConeAngleAttr()
    attribute.Set(30.0, 1.0)
    attribute.Set(90.0, 2.0)
    stage.GetRootLayer().Save()
    path = stage.GetRootLayer().realPath
    cones = [load_stage(path, frame=frame)[0].lights[0].shaping for frame in (1, 2)]
    assert cones == [LightShaping(cone_angle=30.0), None]


def test_shaping_on_distant_and_dome_lights_warns_only_when_it_would_change_them(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.DistantLight, "/sun", cone_angle=180.0)  # as McUsd authors it: changes nothing
    shaped(stage, UsdLux.DomeLight, "/sky", cone_angle=180.0)
    shaped(stage, UsdLux.DistantLight, "/houdini")  # the API applied, its 90° fallback cone not authored
    shaped(stage, UsdLux.DistantLight, "/narrow", cone_angle=30.0)
    shaped(stage, UsdLux.DomeLight_1, "/focused", cone_angle=180.0, focus=2.0)
    scene = load(stage)
    assert all(light.shaping is None for light in scene.lights)
    [warning] = scene.warnings
    assert "distant and dome" in warning and "/narrow" in warning and "/focused" in warning
    assert "/sun" not in warning and "/sky" not in warning and "/houdini" not in warning


# ---------------------------------------------------------------------------------------
# IES profiles


def write_ies(path, candela=(100.0, 50.0, 0.0), tilt="NONE") -> str:
    vertical = np.linspace(0.0, 180.0, len(candela))
    path.write_text("\n".join([
        "IESNA:LM-63-2002", f"TILT={tilt}", f"1 -1 1 {len(candela)} 1 1 2 0 0 0", "1 1 10",
        " ".join(f"{v:g}" for v in vertical), "0", " ".join(f"{c:g}" for c in candela), "",
    ]))
    return str(path)


def test_an_ies_profile_is_read_once_per_read_with_its_scale_and_normalisation(tmp_path):
    profile_path = write_ies(tmp_path / "spot.ies")
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.SphereLight, "/a", cone_angle=180.0, ies_file=Sdf.AssetPath("spot.ies"),
           ies_angleScale=0.5, ies_normalize=True)
    shaped(stage, UsdLux.RectLight, "/b", ies_file=Sdf.AssetPath("./spot.ies"))
    scene = load(stage)
    a, b = scene.lights
    assert a.shaping.ies is b.shaping.ies  # parsed once
    assert a.shaping.ies.path == profile_path
    np.testing.assert_allclose(a.shaping.ies.candela[0], [100.0, 50.0, 0.0])
    assert (a.shaping.ies_angle_scale, a.shaping.ies_normalize) == (0.5, True)
    assert (a.shaping.cone_angle, b.shaping.cone_angle) == (180.0, 180.0)  # the rect's 90° cone is no cone
    assert (b.shaping.ies_angle_scale, b.shaping.ies_normalize) == (0.0, False)
    assert scene.warnings == ()


def test_an_ies_profile_inside_a_usdz_package_is_read_through_the_resolver(tmp_path):
    write_ies(tmp_path / "spot.ies")
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.RectLight, "/key", ies_file=Sdf.AssetPath("spot.ies"))
    stage.GetRootLayer().Save()
    package = tmp_path / "shot.usdz"
    writer = Sdf.ZipFileWriter.CreateNew(str(package))
    for name in ("scene.usda", "spot.ies"):
        writer.AddFile(str(tmp_path / name), name)
    writer.Save()
    (tmp_path / "spot.ies").unlink()
    scene, _ = load_stage(str(package))
    assert only_light(scene).shaping.ies.path == f"{package}[spot.ies]" and scene.warnings == ()


def test_an_empty_ies_path_is_no_profile_and_no_warning(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.RectLight, "/key", ies_file=Sdf.AssetPath(""), ies_normalize=True)
    scene = load(stage)
    assert only_light(scene).shaping is None and scene.warnings == ()


def test_a_profile_of_no_power_is_not_normalised(tmp_path):
    write_ies(tmp_path / "black.ies", candela=(0.0, 0.0, 0.0))
    stage = new_stage(tmp_path)
    shaped(stage, UsdLux.RectLight, "/key", ies_file=Sdf.AssetPath("black.ies"), ies_normalize=True)
    shaping = only_light(load(stage)).shaping
    assert shaping.ies.power == 0.0 and shaping.ies_normalize is False


@pytest.mark.parametrize(
    "contents, message",
    [(None, "IES profile not found: {file} (/key)"),
     ("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 3 2 0 0 0\n1 1 10\n0 90 180\n0\n1 2 3\n",
      "IES profile unusable (/key; the light keeps the rest of its shaping): {file}: photometric type A")],
    ids=["missing", "malformed"],
)
def test_an_unusable_ies_file_warns_once_and_the_light_keeps_its_cone(tmp_path, contents, message):
    file = tmp_path / "profile.ies"
    if contents is not None:
        file.write_text(contents)
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.SphereLight, "/key", cone_angle=60.0, ies_file=Sdf.AssetPath("profile.ies"))
    shaped(stage, UsdLux.SphereLight, "/fill", cone_angle=180.0, ies_file=Sdf.AssetPath("profile.ies"))
    scene = load(stage)
    assert [light.shaping for light in scene.lights] == [LightShaping(cone_angle=60.0), None]
    [warning] = scene.warnings
    assert warning.startswith(message.format(file=file))


def test_a_tilt_file_warns_and_the_profile_is_used(tmp_path):
    write_ies(tmp_path / "tilted.ies", tilt="lamp.tlt")
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    shaped(stage, UsdLux.RectLight, "/key", ies_file=Sdf.AssetPath("tilted.ies"))
    scene = load(stage)
    assert only_light(scene).shaping.ies is not None
    [warning] = scene.warnings
    assert "tilted.ies" in warning and "/key" in warning and "lamp.tlt" in warning


def test_the_luxtest_rect_reads_its_shaping_frames(shared_data):
    # light_descriptions.json: frames 41–45 vary the focus of a 60° red-tinted cone, 51–60 the
    # angleScale of an IES profile, normalised from frame 56
    path = str(shared_data / "luxtest" / "usd" / "rect.usda")
    shapings = {frame: load_stage(path, frame=frame)[0].lights[0].shaping for frame in (1, 45, 53, 58)}
    assert shapings[1] is None
    assert (shapings[45].cone_angle, shapings[45].focus_tint, shapings[45].ies) == (60.0, (1.0, 0.0, 0.0), None)
    for frame, normalize in ((53, False), (58, True)):
        shaping = shapings[frame]
        assert shaping.ies.path.endswith("bega_omni002_4777lm.ies") and shaping.ies_normalize is normalize
        assert (shaping.cone_angle, shaping.focus) == (180.0, 0.0)


# ---------------------------------------------------------------------------------------
# RectLight colour maps, treatAsPoint / treatAsLine, multipliers


def test_a_rect_light_reads_its_colour_map(tmp_path):
    pixels = np.array([[[4.0, 2.0, 1.0], [0.5, 0.25, 0.125]]], dtype=np.float32)
    write_exr(tmp_path / "panel.exr", pixels)
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    UsdLux.RectLight.Define(stage, "/panel").CreateTextureFileAttr(Sdf.AssetPath("panel.exr"))
    UsdLux.RectLight.Define(stage, "/plain").CreateTextureFileAttr(Sdf.AssetPath(""))  # @@: no texture
    scene = load(stage)
    panel, plain = scene.lights
    np.testing.assert_allclose(scene.textures[panel.texture].pixels, pixels)
    assert plain.texture is None and scene.warnings == ()


def test_a_missing_rect_texture_warns_and_the_light_is_constant(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    UsdLux.RectLight.Define(stage, "/panel").CreateTextureFileAttr(Sdf.AssetPath("nope.exr"))
    scene = load(stage)
    assert only_light(scene).texture is None
    [warning] = scene.warnings
    assert f"{tmp_path / 'nope.exr'} (/panel)" in warning


@pytest.mark.parametrize(
    "schema, hint, kind, area",
    [(UsdLux.SphereLight, "CreateTreatAsPointAttr", "point", 4 * math.pi * 0.25),
     (UsdLux.CylinderLight, "CreateTreatAsLineAttr", "line", 2 * math.pi * 0.5 * 3.0)],
    ids=["point", "line"],
)
def test_treat_as_point_and_line_keep_the_shape_and_its_power(tmp_path, schema, hint, kind, area):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    light = schema.Define(stage, "/bulb")
    getattr(light, hint)(True)
    light.CreateRadiusAttr(0.5)
    if schema is UsdLux.CylinderLight:
        light.CreateLengthAttr(3.0)
    light.CreateNormalizeAttr(True)
    scene = load(stage)
    got = only_light(scene)
    assert got.kind == kind and got.radius == 0.5
    np.testing.assert_allclose(got.radiance, [1.0 / area] * 3, rtol=1e-3)
    assert scene.warnings == ()


def test_diffuse_and_specular_multipliers_are_read(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    light = UsdLux.RectLight.Define(stage, "/key")
    light.CreateDiffuseAttr(0.25)
    light.CreateSpecularAttr(2.0)
    UsdLux.RectLight.Define(stage, "/fill")
    scene = load(stage)
    assert [(light.diffuse, light.specular) for light in scene.lights] == [(0.25, 2.0), (1.0, 1.0)]
    assert scene.warnings == ()


# ---------------------------------------------------------------------------------------
# Camera visibility


def author(prim: Usd.Prim, name: str, value) -> None:
    """``name`` = ``value`` on ``prim``: a constant primvar for ``primvars:`` names, else a
    custom attribute, typed after the value."""
    value_type = {bool: Sdf.ValueTypeNames.Bool, int: Sdf.ValueTypeNames.Int, float: Sdf.ValueTypeNames.Float,
                  str: Sdf.ValueTypeNames.String}[type(value)]
    if name.startswith("primvars:"):
        UsdGeom.PrimvarsAPI(prim).CreatePrimvar(name.removeprefix("primvars:"), value_type).Set(value)
    else:
        prim.CreateAttribute(name, value_type, custom=True).Set(value)


@pytest.mark.parametrize(
    "name, hidden, shown",
    [
        ("inputs:visibility:camera", False, True),
        ("visibleInPrimaryRay", False, True),
        ("primvars:ri:attributes:visibility:camera", 0, 1),
        ("primvars:arnold:visibility:camera", False, True),
        ("primvars:arnold:camera", 0.0, 1.0),
        ("primvars:karma:object:rendervisibility", "-primary", "*"),
        ("karma:light:renderlightgeo", False, True),
    ],
)
def test_camera_visibility_from_each_renderers_attribute(tmp_path, name, hidden, shown):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    author(UsdLux.RectLight.Define(stage, "/hidden").GetPrim(), name, hidden)
    author(UsdLux.RectLight.Define(stage, "/shown").GetPrim(), name, shown)
    UsdLux.RectLight.Define(stage, "/plain")
    scene = load(stage)
    assert [light.camera_visible for light in scene.lights] == [False, True, True]
    assert scene.warnings == ()


@pytest.mark.parametrize(
    "rule, seen",
    [("*", True), ("primary", True), ("-primary", False), ("* -primary", False), ("^primary", False),
     ("-shadow", True), ("shadow diffuse", False), ("", False), ("-* primary", True)],
)
def test_karma_render_visibility_rules(tmp_path, rule, seen):
    stage = new_stage(tmp_path)
    author(UsdLux.SphereLight.Define(stage, "/bulb").GetPrim(), "primvars:karma:object:rendervisibility", rule)
    assert only_light(load(stage)).camera_visible is seen


def test_camera_visibility_is_inherited_as_primvars_are_and_applies_to_domes(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    author(UsdGeom.Xform.Define(stage, "/Lights").GetPrim(), "primvars:arnold:visibility:camera", False)
    UsdLux.RectLight.Define(stage, "/Lights/key")
    author(UsdLux.DomeLight.Define(stage, "/sky").GetPrim(), "visibleInPrimaryRay", False)
    assert [light.camera_visible for light in load(stage).lights] == [False, False]


def test_disagreeing_camera_visibility_attributes_warn_and_the_first_wins(tmp_path):
    stage = new_stage(tmp_path)
    tri(stage, "/ground")
    key = UsdLux.RectLight.Define(stage, "/key").GetPrim()
    author(key, "primvars:arnold:visibility:camera", False)
    author(key, "inputs:visibility:camera", True)
    agreeing = UsdLux.RectLight.Define(stage, "/fill").GetPrim()
    author(agreeing, "primvars:arnold:visibility:camera", False)
    author(agreeing, "primvars:karma:object:rendervisibility", "-primary")
    scene = load(stage)
    assert [light.camera_visible for light in scene.lights] == [True, False]
    [warning] = scene.warnings
    assert "/key (inputs:visibility:camera = True, primvars:arnold:visibility:camera = False)" in warning
    assert "/fill" not in warning


def test_the_luxtest_stages_hide_their_lights_from_the_camera_but_visible_rect(shared_data):
    folder = shared_data / "luxtest" / "usd"
    for name, seen in (("rect", False), ("sphere", False), ("disk", False), ("visibleRect", True)):
        scene, _ = load_stage(str(folder / f"{name}.usda"))
        assert [light.camera_visible for light in scene.lights] == [seen], name
        assert not any("camera visibility" in warning for warning in scene.warnings), name


# ---------------------------------------------------------------------------------------
# Light and shadow linking


@pytest.fixture
def linked_stage(tmp_path):
    """A stage with plain meshes, a native instance and a point instancer of two instances."""
    stage = new_stage(tmp_path)
    tri(stage, "/World/A/a")
    tri(stage, "/World/B/b")
    stage.CreateClassPrim("/_thing")
    tri(stage, "/_thing/m")
    instance = UsdGeom.Xform.Define(stage, "/World/Inst").GetPrim()
    instance.GetReferences().AddInternalReference("/_thing")
    instance.SetInstanceable(True)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/PI")
    tri(stage, "/World/PI/Protos/p")
    instancer.CreatePrototypesRel().AddTarget("/World/PI/Protos/p")
    instancer.CreateProtoIndicesAttr([0, 0])
    instancer.CreatePositionsAttr([(0, 0, 0), (2, 0, 0)])
    return stage


MESHES = ["/World/A/a", "/World/B/b", "/World/Inst/m", "/World/PI/instance_0/p", "/World/PI/instance_1/p"]


def linked(scene, indices) -> list[str] | None:
    return None if indices is None else [scene.meshes[index].path for index in indices]


@pytest.mark.parametrize(
    "include_root, includes, excludes, rule, members",
    [
        (None, [], [], None, None),
        (False, ["/World/A"], [], None, ["/World/A/a"]),
        (True, [], ["/World/B"], None, ["/World/A/a", "/World/Inst/m", "/World/PI/instance_0/p",
                                        "/World/PI/instance_1/p"]),
        (False, ["/World/PI"], [], None, ["/World/PI/instance_0/p", "/World/PI/instance_1/p"]),
        (False, ["/World/Inst"], [], None, ["/World/Inst/m"]),
        (False, ["/World/Inst/m", "/World/B/b"], [], None, ["/World/B/b", "/World/Inst/m"]),
        (False, ["/World"], ["/World/PI", "/World/A/a"], None, ["/World/B/b", "/World/Inst/m"]),
        (False, ["/World/A"], [], "explicitOnly", []),
        (False, ["/World/A/a"], [], "explicitOnly", ["/World/A/a"]),
        (False, [], [], None, []),
    ],
    ids=["default", "include", "exclude", "instancer", "native-instance", "inside-instance", "include-exclude",
         "explicit-only-ancestor", "explicit-only", "nothing"],
)
def test_light_and_shadow_links_follow_the_collections(linked_stage, include_root, includes, excludes, rule,
                                                       members):
    light = UsdLux.LightAPI(UsdLux.SphereLight.Define(linked_stage, "/key").GetPrim())
    other = UsdLux.LightAPI(UsdLux.SphereLight.Define(linked_stage, "/fill").GetPrim())
    for collection in (light.GetLightLinkCollectionAPI(), other.GetShadowLinkCollectionAPI()):
        if include_root is not None:
            collection.CreateIncludeRootAttr(include_root)
        for path in includes:
            collection.GetIncludesRel().AddTarget(path)
        for path in excludes:
            collection.GetExcludesRel().AddTarget(path)
        if rule is not None:
            collection.CreateExpansionRuleAttr(rule)
    scene = load(linked_stage)
    assert [mesh.path for mesh in scene.meshes] == MESHES
    key, fill = scene.lights
    assert (linked(scene, key.light_link), key.shadow_link) == (members, None)
    assert (fill.light_link, linked(scene, fill.shadow_link)) == (None, members)
    assert scene.warnings == ()
