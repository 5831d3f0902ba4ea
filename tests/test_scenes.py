"""The embedded scenes in ``render/`` (``pxr_layers.render``): structure, units, lights, camera,
materials, and the showcase texture (regenerated and compared, frequency ratio 2)."""

from __future__ import annotations

import importlib.resources
import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade

TIME = Usd.TimeCode(1)
REPO_RENDER = Path(__file__).resolve().parents[1] / "render"


def _render_dir() -> Path:
    try:
        root = importlib.resources.files("pxr_layers.render")
    except ModuleNotFoundError:
        return REPO_RENDER
    return root if isinstance(root, Path) else Path(str(root))


RENDER = _render_dir()

# Values from the Cornell box's README (Mitsuba 3 cbox-rgb equivalents).
CORNELL_RADIANCE = (18.387, 10.9873, 2.75357)
CORNELL_REFLECTANCE = {
    "white": (0.885809, 0.698859, 0.666422),
    "red": (0.570068, 0.0430135, 0.0443706),
    "green": (0.105421, 0.37798, 0.076425),
    "box": (0.45, 0.30, 0.90),
}
CORNELL_BINDINGS = {
    "floor": "white",
    "ceiling": "white",
    "backWall": "white",
    "redWall": "red",
    "greenWall": "green",
    "shortBox": "box",
    "tallBox": "box",
}
OPENING_X = (213.0, 343.0)  # the ceiling opening = the luminaire quad, mm
OPENING_Z = (227.0, 332.0)
CEILING_Y = 548.8

SHOWCASE_BINDINGS = {
    "floor": "floorMatte",
    "backdrop": "backdropMatte",
    "texturedPanel": "checkerTexture",
    "curvedSphere": "matteSphere",
    "matteBox": "matteSphere",
    "glossyBox": "glossy",
    "mirrorPanel": "nearMirror",
}
SHOWCASE_TYPES = {
    "floor": UsdGeom.Mesh,
    "backdrop": UsdGeom.Mesh,
    "texturedPanel": UsdGeom.Mesh,
    "curvedSphere": UsdGeom.Sphere,
    "matteBox": UsdGeom.Cube,
    "glossyBox": UsdGeom.Cube,
    "mirrorPanel": UsdGeom.Mesh,
}
SET_OBJECTS = ["texturedPanel", "curvedSphere", "matteBox", "glossyBox", "mirrorPanel"]


# ---------------------------------------------------------------------------- helpers


def _open(name: str) -> Usd.Stage:
    path = RENDER / name
    assert path.is_file(), path
    mark = Tf.Error.Mark()
    stage = Usd.Stage.Open(str(path))
    assert stage is not None
    assert mark.IsClean(), [e.commentary for e in mark.GetErrors()]
    assert list(stage.GetCompositionErrors()) == []
    return stage


@pytest.fixture(scope="module")
def cornell() -> Usd.Stage:
    return _open("cornell.usda")


@pytest.fixture(scope="module")
def showcase() -> Usd.Stage:
    return _open("showcase.usda")


def _surface(material: UsdShade.Material) -> UsdShade.Shader:
    shader = material.ComputeSurfaceSource()[0]
    assert shader and shader.GetIdAttr().Get() == "UsdPreviewSurface"
    return shader


def _input(shader: UsdShade.Shader, name: str):
    inp = shader.GetInput(name)
    assert inp, f"{shader.GetPath()} has no inputs:{name}"
    return inp.Get()


def _bound_material(prim: Usd.Prim, purpose: str) -> UsdShade.Material:
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(purpose)
    assert material, f"{prim.GetPath()} has no {purpose or 'allPurpose'} material"
    return material


def _mesh_faces(mesh: UsdGeom.Mesh) -> list[np.ndarray]:
    points = np.asarray(mesh.GetPointsAttr().Get(TIME), dtype=np.float64)
    counts = list(mesh.GetFaceVertexCountsAttr().Get(TIME))
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(TIME))
    assert sum(counts) == len(indices)
    faces, k = [], 0
    for c in counts:
        faces.append(points[indices[k : k + c]])
        k += c
    return faces


def _newell_normal(poly: np.ndarray) -> np.ndarray:
    n = np.zeros(3)
    for i in range(len(poly)):
        n += np.cross(poly[i], poly[(i + 1) % len(poly)])
    return n / np.linalg.norm(n)


def _world(stage: Usd.Stage, path: str) -> Gf.Matrix4d:
    return UsdGeom.XformCache(TIME).GetLocalToWorldTransform(stage.GetPrimAtPath(path))


def _frustum(stage: Usd.Stage) -> Gf.Frustum:
    return UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).GetCamera(TIME).frustum


def _ndc(frustum: Gf.Frustum, point) -> Gf.Vec3d:
    vp = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    return vp.Transform(Gf.Vec3d(*(float(v) for v in point)))


def _check_render_settings(stage: Usd.Stage, product_name: str) -> None:
    settings = UsdRender.Settings.GetStageRenderSettings(stage)
    assert settings and settings.GetPath() == Sdf.Path("/Render/Settings")
    assert settings.GetCameraRel().GetTargets() == [Sdf.Path("/World/Camera")]
    assert tuple(settings.GetResolutionAttr().Get()) == (256, 256)
    assert settings.GetPixelAspectRatioAttr().Get() == 1.0
    assert list(settings.GetMaterialBindingPurposesAttr().Get()) == ["full", ""]
    assert settings.GetProductsRel().GetTargets() == [Sdf.Path("/Render/Products/beauty")]
    product = UsdRender.Product(stage.GetPrimAtPath("/Render/Products/beauty"))
    assert product and product.GetProductNameAttr().Get() == product_name
    assert product.GetOrderedVarsRel().GetTargets() == [Sdf.Path("/Render/Vars/color")]
    var = UsdRender.Var(stage.GetPrimAtPath("/Render/Vars/color"))
    assert var
    assert var.GetSourceNameAttr().Get() == "color"
    assert var.GetSourceTypeAttr().Get() == "raw"
    assert var.GetDataTypeAttr().Get() == "color3f"


def _check_meshes_well_formed(stage: Usd.Stage, twisted: dict[str, float] | None = None) -> None:
    """Extents, subdivision, no unused points, planar faces (``twisted`` names meshes whose
    measured quads are allowed to leave their plane by up to the given distance)."""
    twisted = twisted or {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none, prim.GetPath()
        points = mesh.GetPointsAttr().Get(TIME)
        extent = mesh.GetExtentAttr().Get(TIME)
        assert extent is not None, f"{prim.GetPath()} has no extent"
        expected = UsdGeom.PointBased.ComputeExtent(points)
        assert np.allclose(np.asarray(extent), np.asarray(expected)), prim.GetPath()
        used = set(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).tolist())
        assert used == set(range(len(points))), f"{prim.GetPath()}: unused or missing points"
        tolerance = twisted.get(prim.GetName(), 1e-4)
        for face in _mesh_faces(mesh):
            n = _newell_normal(face)
            off_plane = np.abs((face - face.mean(0)) @ n).max()
            assert off_plane < tolerance, f"{prim.GetPath()}: non-planar face ({off_plane})"


def _check_asset_paths(stage: Usd.Stage) -> int:
    """Every asset path is relative (./...) and resolves inside render/."""
    seen = 0
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            if attr.GetTypeName() != Sdf.ValueTypeNames.Asset:
                continue
            value = attr.Get()
            if value is None:
                continue
            seen += 1
            assert value.path.startswith("./"), (attr.GetPath(), value.path)
            assert value.resolvedPath, f"{attr.GetPath()} does not resolve"
            assert Path(value.resolvedPath).resolve().is_relative_to(RENDER.resolve())
    text = stage.GetRootLayer().ExportToString()
    assert "/work/" not in text  # no absolute paths into a checkout or shared storage
    return seen


def _check_validators(stage: Usd.Stage) -> None:
    validation = pytest.importorskip("pxr.UsdValidation")
    registry = validation.ValidationRegistry()
    names = [
        m.name
        for m in registry.GetAllValidatorMetadata()
        if m.name.split(":")[0]
        in ("usdValidation", "usdGeomValidators", "usdShadeValidators", "usdLuxValidators")
    ]
    context = validation.ValidationContext(registry.GetOrLoadValidatorsByName(names))
    errors = context.Validate(stage)
    assert not errors, [e.GetMessage() for e in errors]


# ---------------------------------------------------------------------------- cornell


def test_cornell_stage_metadata(cornell):
    assert UsdGeom.GetStageUpAxis(cornell) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(cornell) == pytest.approx(0.001)
    assert cornell.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    assert cornell.GetMetadata("renderSettingsPrimPath") == "/Render/Settings"
    assert cornell.GetStartTimeCode() == 1 and cornell.GetEndTimeCode() == 1
    doc = cornell.GetRootLayer().documentation
    for words in ("Cornell", "Mitsuba", "cbox-rgb", "millimetres"):
        assert words in doc


def test_cornell_prims_named_and_typed(cornell):
    for name in CORNELL_BINDINGS:
        assert cornell.GetPrimAtPath(f"/World/Geometry/{name}").IsA(UsdGeom.Mesh), name
    for name in CORNELL_REFLECTANCE:
        assert cornell.GetPrimAtPath(f"/World/Materials/{name}").IsA(UsdShade.Material), name
    assert cornell.GetPrimAtPath("/World/Lights/ceilingLight").IsA(UsdLux.RectLight)
    assert cornell.GetPrimAtPath("/World/Camera").IsA(UsdGeom.Camera)
    meshes = {p.GetName() for p in cornell.Traverse() if p.IsA(UsdGeom.Mesh)}
    assert meshes == set(CORNELL_BINDINGS)  # in particular no luminaire mesh
    lights = [p for p in cornell.Traverse() if p.HasAPI(UsdLux.LightAPI)]
    assert [p.GetName() for p in lights] == ["ceilingLight"]


def test_cornell_geometry_millimetres_and_winding(cornell):
    # The measured red wall is a slightly twisted quad (0.8 mm either side of its best plane);
    # every other face is planar.
    _check_meshes_well_formed(cornell, twisted={"redWall": 1.0})
    # Coordinates are the OBJ's, in mm.
    floor = UsdGeom.Mesh(cornell.GetPrimAtPath("/World/Geometry/floor"))
    assert np.array_equal(
        np.asarray(floor.GetPointsAttr().Get()),
        np.array([[552.8, 0, 0], [0, 0, 0], [0, 0, 559.2], [549.6, 0, 559.2]], np.float32),
    )
    bbox = UsdGeom.BBoxCache(TIME, [UsdGeom.Tokens.default_]).ComputeWorldBound(
        cornell.GetPrimAtPath("/World/Geometry")
    ).ComputeAlignedRange()
    assert tuple(bbox.GetMin()) == pytest.approx((0, 0, 0))
    assert tuple(bbox.GetMax()) == pytest.approx((556, 548.8, 559.2))
    room_centre = np.array([278.0, 274.4, 279.6])
    for name in ("floor", "ceiling", "backWall", "redWall", "greenWall"):
        mesh = UsdGeom.Mesh(cornell.GetPrimAtPath(f"/World/Geometry/{name}"))
        for face in _mesh_faces(mesh):
            assert (room_centre - face.mean(0)) @ _newell_normal(face) > 0, name
            for k in range(1, len(face) - 1):  # and each fan triangle a renderer makes
                tri = face[[0, k, k + 1]]
                assert (room_centre - tri.mean(0)) @ _newell_normal(tri) > 0, name
    for name, height in (("shortBox", 165.0), ("tallBox", 330.0)):
        mesh = UsdGeom.Mesh(cornell.GetPrimAtPath(f"/World/Geometry/{name}"))
        faces = _mesh_faces(mesh)
        assert len(faces) == 6 and all(len(f) == 4 for f in faces)
        centre = np.concatenate(faces).mean(0)
        for face in faces:
            assert (face.mean(0) - centre) @ _newell_normal(face) > 0, name
        assert mesh.GetExtentAttr().Get()[1][1] == pytest.approx(height)


def _in_convex_xz(poly: np.ndarray, x: float, z: float) -> bool:
    signs = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        signs.append((b[0] - a[0]) * (z - a[2]) - (b[2] - a[2]) * (x - a[0]))
    return all(s > 0 for s in signs) or all(s < 0 for s in signs)


def test_cornell_ceiling_has_the_opening(cornell):
    ceiling = UsdGeom.Mesh(cornell.GetPrimAtPath("/World/Geometry/ceiling"))
    faces = _mesh_faces(ceiling)
    assert all(np.all(f[:, 1] == np.float32(CEILING_Y)) for f in faces)
    area = sum(0.5 * abs(np.cross(f[1:-1] - f[0], f[2:] - f[0]).sum(0)[1]) for f in faces)
    assert area == pytest.approx(556 * 559.2 - 130 * 105)
    for x in np.linspace(OPENING_X[0] + 1, OPENING_X[1] - 1, 7):
        for z in np.linspace(OPENING_Z[0] + 1, OPENING_Z[1] - 1, 7):
            assert not any(_in_convex_xz(f, x, z) for f in faces), (x, z)
    assert any(_in_convex_xz(f, 100.0, 100.0) for f in faces)


def test_cornell_light(cornell):
    light = UsdLux.RectLight(cornell.GetPrimAtPath("/World/Lights/ceilingLight"))
    assert light.GetNormalizeAttr().Get() is False
    assert light.GetExposureAttr().Get() == 0.0
    assert not light.GetEnableColorTemperatureAttr().Get()
    radiance = np.float64(light.GetIntensityAttr().Get()) * np.asarray(
        light.GetColorAttr().Get(), dtype=np.float64
    )
    assert radiance == pytest.approx(CORNELL_RADIANCE, rel=1e-6)
    assert light.GetIntensityAttr().Get() == pytest.approx(18.387, rel=1e-7)

    world = _world(cornell, "/World/Lights/ceilingLight")
    down = world.TransformDir(Gf.Vec3d(0, 0, -1)).GetNormalized()
    assert tuple(down) == pytest.approx((0, -1, 0), abs=1e-12)
    assert tuple(world.TransformDir(Gf.Vec3d(1, 0, 0)).GetNormalized()) == pytest.approx(
        (1, 0, 0), abs=1e-12
    )
    w, h = light.GetWidthAttr().Get(), light.GetHeightAttr().Get()
    assert (w, h) == (130.0, 105.0)
    corners = np.array(
        [world.Transform(Gf.Vec3d(sx * w / 2, sy * h / 2, 0)) for sx in (-1, 1) for sy in (-1, 1)]
    )
    assert corners[:, 1] == pytest.approx(548.3)
    assert corners[:, 1].max() < CEILING_Y
    assert corners[:, 0].min() == pytest.approx(OPENING_X[0])
    assert corners[:, 0].max() == pytest.approx(OPENING_X[1])
    assert corners[:, 2].min() == pytest.approx(OPENING_Z[0])
    assert corners[:, 2].max() == pytest.approx(OPENING_Z[1])
    assert tuple(world.ExtractTranslation()) == pytest.approx((278.0, 548.3, 279.5))


def test_cornell_camera(cornell):
    cam = UsdGeom.Camera(cornell.GetPrimAtPath("/World/Camera"))
    gf = cam.GetCamera(TIME)
    assert gf.GetFieldOfView(Gf.Camera.FOVVertical) == pytest.approx(39.3077, abs=1e-4)
    assert gf.GetFieldOfView(Gf.Camera.FOVHorizontal) == pytest.approx(39.3077, abs=1e-4)
    assert cam.GetFocalLengthAttr().Get() == 35.0
    assert cam.GetHorizontalApertureAttr().Get() == cam.GetVerticalApertureAttr().Get()
    assert cam.GetHorizontalApertureAttr().Get() == pytest.approx(
        2 * 35 * math.tan(math.radians(39.3077) / 2), rel=1e-7
    )
    assert cam.GetProjectionAttr().Get() == UsdGeom.Tokens.perspective
    assert tuple(cam.GetClippingRangeAttr().Get()) == (10.0, 10000.0)
    frustum = gf.frustum
    assert tuple(frustum.GetPosition()) == pytest.approx((278, 273, -800))
    assert tuple(frustum.ComputeViewDirection()) == pytest.approx((0, 0, 1), abs=1e-12)
    assert tuple(frustum.ComputeUpVector()) == pytest.approx((0, 1, 0), abs=1e-12)
    # The classic photo: red wall (large x) on the left, green wall on the right.
    assert _ndc(frustum, (553, 274.4, 279.6))[0] < -0.5
    assert _ndc(frustum, (0, 274.4, 279.6))[0] > 0.5
    # The whole back wall is in frame.
    for corner in ((0, 0, 559.2), (556, 548.8, 559.2)):
        p = _ndc(frustum, corner)
        assert abs(p[0]) < 1 and abs(p[1]) < 1


def test_cornell_materials(cornell):
    for name, colour in CORNELL_REFLECTANCE.items():
        shader = _surface(UsdShade.Material(cornell.GetPrimAtPath(f"/World/Materials/{name}")))
        assert tuple(_input(shader, "diffuseColor")) == pytest.approx(colour, rel=1e-6)
        assert _input(shader, "roughness") == 1.0
        assert tuple(_input(shader, "specularColor")) == (0.0, 0.0, 0.0)
        assert _input(shader, "useSpecularWorkflow") == 1
    for mesh, material in CORNELL_BINDINGS.items():
        prim = cornell.GetPrimAtPath(f"/World/Geometry/{mesh}")
        assert prim.HasAPI(UsdShade.MaterialBindingAPI)
        for purpose in ("full", ""):
            bound = _bound_material(prim, purpose)
            assert bound.GetPath() == Sdf.Path(f"/World/Materials/{material}")


def test_cornell_render_settings_and_validation(cornell):
    _check_render_settings(cornell, "cornell.exr")
    assert _check_asset_paths(cornell) == 0
    _check_validators(cornell)


# ---------------------------------------------------------------------------- showcase


def test_showcase_stage_metadata(showcase):
    assert UsdGeom.GetStageUpAxis(showcase) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(showcase) == 1.0
    assert showcase.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    assert showcase.GetMetadata("renderSettingsPrimPath") == "/Render/Settings"
    doc = showcase.GetRootLayer().documentation
    for words in ("5 cycles/m", "10 cycles/m", "radius exactly 0.4 m", "roughness 0.2", "roughness 0.02"):
        assert words in doc
    _check_render_settings(showcase, "showcase.exr")
    _check_validators(showcase)


def test_showcase_prims_named_and_typed(showcase):
    for name, schema in SHOWCASE_TYPES.items():
        assert showcase.GetPrimAtPath(f"/World/Geometry/{name}").IsA(schema), name
    geometry = {p.GetName() for p in showcase.GetPrimAtPath("/World/Geometry").GetChildren()}
    assert geometry == set(SHOWCASE_TYPES)
    assert showcase.GetPrimAtPath("/World/Lights/key").IsA(UsdLux.RectLight)
    assert showcase.GetPrimAtPath("/World/Lights/fill").IsA(UsdLux.SphereLight)
    assert showcase.GetPrimAtPath("/World/Lights/sky").IsA(UsdLux.DomeLight)
    assert showcase.GetPrimAtPath("/World/Camera").IsA(UsdGeom.Camera)
    _check_meshes_well_formed(showcase)


def test_showcase_geometry(showcase):
    sphere = UsdGeom.Sphere(showcase.GetPrimAtPath("/World/Geometry/curvedSphere"))
    assert sphere.GetRadiusAttr().Get() == 0.4
    bboxes = UsdGeom.BBoxCache(TIME, [UsdGeom.Tokens.default_])
    for name in ("curvedSphere", "matteBox", "glossyBox"):  # resting on the floor
        rng = bboxes.ComputeWorldBound(showcase.GetPrimAtPath(f"/World/Geometry/{name}"))
        assert rng.ComputeAlignedRange().GetMin()[1] == pytest.approx(0.0, abs=1e-6), name
    # The sphere's extent is authored and matches its radius.
    assert np.allclose(np.asarray(sphere.GetExtentAttr().Get()), [[-0.4] * 3, [0.4] * 3])
    floor = bboxes.ComputeWorldBound(showcase.GetPrimAtPath("/World/Geometry/floor"))
    size = floor.ComputeAlignedRange().GetSize()
    assert (size[0], size[1], size[2]) == pytest.approx((8, 0, 8))


def _panel_world(showcase):
    panel = UsdGeom.Mesh(showcase.GetPrimAtPath("/World/Geometry/texturedPanel"))
    world = _world(showcase, "/World/Geometry/texturedPanel")
    points = np.array([world.Transform(Gf.Vec3d(*map(float, p))) for p in panel.GetPointsAttr().Get()])
    return panel, points


def test_showcase_panel_uvs(showcase):
    panel, points = _panel_world(showcase)
    primvar = UsdGeom.PrimvarsAPI(panel).GetPrimvar("st")
    assert primvar.GetInterpolation() in (UsdGeom.Tokens.faceVarying, UsdGeom.Tokens.vertex)
    st = np.asarray(primvar.ComputeFlattened(TIME), dtype=np.float64)
    assert st.min(0) == pytest.approx((0, 0)) and st.max(0) == pytest.approx((1, 1))
    if primvar.GetInterpolation() == UsdGeom.Tokens.faceVarying:
        at = points[np.asarray(panel.GetFaceVertexIndicesAttr().Get())]
    else:
        at = points
    # 1.6 m wide along u (world x, to the camera's right), 0.8 m tall along v (world y).
    du = np.linalg.lstsq(np.c_[st, np.ones(len(st))], at, rcond=None)[0]
    assert du[0] == pytest.approx((1.6, 0, 0), abs=1e-6)
    assert du[1] == pytest.approx((0, 0.8, 0), abs=1e-6)
    normal = _newell_normal(_mesh_faces(panel)[0])
    cam = np.array(_frustum(showcase).GetPosition())
    assert (cam - at.mean(0)) @ normal > 0  # faces the camera
    right = np.array(_frustum(showcase).ComputeViewInverse().TransformDir(Gf.Vec3d(1, 0, 0)))
    assert right @ du[0] > 0  # u grows to the right in the image


def test_showcase_materials(showcase):
    for mesh, material in SHOWCASE_BINDINGS.items():
        prim = showcase.GetPrimAtPath(f"/World/Geometry/{mesh}")
        assert prim.HasAPI(UsdShade.MaterialBindingAPI)
        for purpose in ("full", ""):
            assert _bound_material(prim, purpose).GetPath() == Sdf.Path(
                f"/World/Materials/{material}"
            ), mesh
    mats = {
        n: _surface(UsdShade.Material(showcase.GetPrimAtPath(f"/World/Materials/{n}")))
        for n in set(SHOWCASE_BINDINGS.values())
    }
    glossy, mirror = mats.pop("glossy"), mats.pop("nearMirror")
    assert _input(glossy, "roughness") == pytest.approx(0.2)
    assert _input(glossy, "useSpecularWorkflow") == 1
    assert tuple(_input(glossy, "specularColor")) == pytest.approx((0.9, 0.9, 0.9))
    assert tuple(_input(glossy, "diffuseColor")) == pytest.approx((0.05, 0.05, 0.05))
    assert _input(mirror, "roughness") == pytest.approx(0.02)
    assert _input(mirror, "metallic") == 1.0
    assert tuple(_input(mirror, "diffuseColor")) == pytest.approx((0.95, 0.95, 0.95))
    for name, shader in mats.items():  # every other material is pure Lambertian
        assert _input(shader, "roughness") == 1.0, name
        assert _input(shader, "useSpecularWorkflow") == 1, name
        assert tuple(_input(shader, "specularColor")) == (0, 0, 0), name
    assert tuple(_input(mats["matteSphere"], "diffuseColor")) == pytest.approx((0.6,) * 3)


def test_showcase_texture_network(showcase):
    shader = _surface(UsdShade.Material(showcase.GetPrimAtPath("/World/Materials/checkerTexture")))
    (source,) = shader.GetInput("diffuseColor").GetConnectedSources()[0]
    texture = UsdShade.Shader(source.source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture" and source.sourceName == "rgb"
    assert _input(texture, "sourceColorSpace") == "raw"
    assert _input(texture, "wrapS") == "clamp" and _input(texture, "wrapT") == "clamp"
    asset = _input(texture, "file")
    assert asset.path == "./textures/two_frequencies.png"
    assert Path(asset.resolvedPath).resolve() == (RENDER / "textures/two_frequencies.png").resolve()
    (st_source,) = texture.GetInput("st").GetConnectedSources()[0]
    reader = UsdShade.Shader(st_source.source.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float2"
    assert _input(reader, "varname") == "st"
    assert _check_asset_paths(showcase) == 1


def test_showcase_lights(showcase):
    key = UsdLux.RectLight(showcase.GetPrimAtPath("/World/Lights/key"))
    fill = UsdLux.SphereLight(showcase.GetPrimAtPath("/World/Lights/fill"))
    sky = UsdLux.DomeLight(showcase.GetPrimAtPath("/World/Lights/sky"))
    for light in (key, fill, sky):
        assert light.GetNormalizeAttr().Get() is False
        assert light.GetExposureAttr().Get() == 0.0
    assert (key.GetWidthAttr().Get(), key.GetHeightAttr().Get()) == (1.0, 1.0)
    assert fill.GetRadiusAttr().Get() == 0.25
    assert not sky.GetTextureFileAttr().HasAuthoredValue()
    assert sky.GetIntensityAttr().Get() == pytest.approx(0.3)
    assert fill.GetIntensityAttr().Get() < key.GetIntensityAttr().Get()
    warm, cool = fill.GetColorAttr().Get(), sky.GetColorAttr().Get()
    assert warm[0] > warm[1] > warm[2] and cool[2] > cool[1] > cool[0]
    # The key's emitting -Z points at the set (the objects' bounding-box centre).
    bboxes = UsdGeom.BBoxCache(TIME, [UsdGeom.Tokens.default_])
    box = Gf.Range3d()
    for name in SET_OBJECTS:
        box.UnionWith(bboxes.ComputeWorldBound(showcase.GetPrimAtPath(f"/World/Geometry/{name}")).ComputeAlignedRange())
    world = _world(showcase, "/World/Lights/key")
    aim = np.array(world.TransformDir(Gf.Vec3d(0, 0, -1)).GetNormalized())
    to_set = np.array(box.GetMidpoint() - world.ExtractTranslation())
    assert math.degrees(math.acos(aim @ to_set / np.linalg.norm(to_set))) < 15
    # Neither lamp is seen directly by the camera.
    frustum = _frustum(showcase)
    for path in ("/World/Lights/key", "/World/Lights/fill"):
        p = _ndc(frustum, _world(showcase, path).ExtractTranslation())
        assert max(abs(p[0]), abs(p[1])) > 1.2, path


def _ray_hits_box(bound: Gf.BBox3d, origin, target) -> bool:
    inverse = bound.GetMatrix().GetInverse()
    o = np.array(inverse.Transform(Gf.Vec3d(*map(float, origin))))
    d = np.array(inverse.Transform(Gf.Vec3d(*map(float, target)))) - o
    lo, hi = np.array(bound.GetRange().GetMin()), np.array(bound.GetRange().GetMax())
    t0, t1 = 0.0, 1.0
    for k in range(3):
        if abs(d[k]) < 1e-12:
            if not lo[k] <= o[k] <= hi[k]:
                return False
            continue
        a, b = (lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return t0 <= t1


def test_showcase_camera_frames_every_object(showcase):
    cam = UsdGeom.Camera(showcase.GetPrimAtPath("/World/Camera"))
    assert cam.GetFocalLengthAttr().Get() == 35.0
    assert cam.GetHorizontalApertureAttr().Get() == 36.0
    assert cam.GetVerticalApertureAttr().Get() == 36.0
    frustum = cam.GetCamera(TIME).frustum
    eye = np.array(frustum.GetPosition())
    right = frustum.ComputeViewInverse().TransformDir(Gf.Vec3d(1, 0, 0))
    assert abs(right[1]) < 1e-9  # no roll: the image's x axis stays horizontal
    bboxes = UsdGeom.BBoxCache(TIME, [UsdGeom.Tokens.default_])
    bounds = {
        n: bboxes.ComputeWorldBound(showcase.GetPrimAtPath(f"/World/Geometry/{n}")) for n in SET_OBJECTS
    }
    group = Gf.Range3d()
    for bound in bounds.values():
        group.UnionWith(bound.ComputeAlignedRange())
    assert 4.0 <= np.linalg.norm(np.array(group.GetMidpoint()) - eye) <= 5.0
    for name, bound in bounds.items():
        centre = bound.GetMatrix().Transform(bound.GetRange().GetMidpoint())
        for i in range(8):
            p = _ndc(frustum, bound.GetMatrix().Transform(bound.GetRange().GetCorner(i)))
            assert abs(p[0]) < 0.95 and abs(p[1]) < 0.95 and -1 < p[2] < 1, name
        blockers = [o for o in SET_OBJECTS if o != name and _ray_hits_box(bounds[o], eye, centre)]
        assert not blockers, (name, blockers)


# ---------------------------------------------------------------------------- texture


def _load_generator():
    script = RENDER / "tools" / "make_showcase_textures.py"
    if not script.is_file():
        script = REPO_RENDER / "tools" / "make_showcase_textures.py"
    if not script.is_file():
        pytest.skip("render/tools is not installed with the package")
    spec = importlib.util.spec_from_file_location("make_showcase_textures", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _read_uint16(path: Path) -> np.ndarray:
    oiio = pytest.importorskip("OpenImageIO")
    buf = oiio.ImageBuf(str(path))
    assert not buf.has_error, buf.geterror()
    spec = buf.spec()
    assert spec.format == oiio.UINT16
    return np.asarray(buf.get_pixels(oiio.UINT16))


def test_texture_regenerates_identically(tmp_path):
    shipped = _read_uint16(RENDER / "textures" / "two_frequencies.png")
    generator = _load_generator()
    assert generator.main(["--out", str(tmp_path)]) == 0
    regenerated = _read_uint16(tmp_path / "two_frequencies.png")
    assert regenerated.shape == shipped.shape == (512, 1024, 3)
    assert np.array_equal(regenerated, shipped)


def test_texture_two_frequencies():
    pixels = _read_uint16(RENDER / "textures" / "two_frequencies.png").astype(np.float64) / 65535
    assert np.all(pixels == pixels[:1])  # stripes: every row the same
    assert np.all(pixels == pixels[..., :1])  # grey
    assert pixels.min() == pytest.approx(0.2, abs=0.01) and pixels.max() == pytest.approx(0.8, abs=0.01)
    row = pixels[0, :, 0]
    half = row.size // 2
    left, right = row[:half], row[half:]

    def crossings(x):
        s = np.sign(x - x.mean())
        assert np.all(s != 0)
        return int(np.count_nonzero(s[1:] != s[:-1]))

    def fft_peak(x):
        return int(np.argmax(np.abs(np.fft.rfft(x - x.mean()))[1:]) + 1)  # cycles per half

    assert fft_peak(left) == 4 and fft_peak(right) == 8
    # n cycles of a sine starting at phase 0 cross the mean 2n - 1 times inside the half.
    cycles_left, cycles_right = (crossings(left) + 1) / 2, (crossings(right) + 1) / 2
    assert (cycles_left, cycles_right) == (4, 8)
    assert cycles_right / cycles_left == 2
    # On the 1.6 m panel each half is 0.8 m: exactly 5 and 10 cycles per metre.
    assert fft_peak(left) / 0.8 == 5.0 and fft_peak(right) / 0.8 == 10.0


def test_texture_matches_panel_width(showcase):
    _, points = _panel_world(showcase)
    width = np.ptp(points[:, 0])
    assert width == pytest.approx(1.6)
    assert np.ptp(points[:, 1]) == pytest.approx(0.8)
