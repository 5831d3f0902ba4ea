"""Data AOVs (depth, normal, Neye, Peye, primId, instanceId) checked against the geometry
authored in the scenes, not against the tracer's own output.

Tolerances: depths and positions to 1e-4 m (float32 hits at ~1 m), unit vectors to 1e-5.
"""

import dataclasses

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from pxr_layers.errors import RenderSettingsError
from pxr_layers.stage import load_stage
from pxr_layers.trace import DATA_AOVS, TraceSettings, render_data_aovs
from pxr_layers.trace.render import prepare

# render/cornell.usda, in millimetres: camera at (278, 273, −800), rotateY 180 (looks along
# world +Z, +Y up, so camera +X is world −X), focal length 35, square aperture 25.000036.
CAMERA = np.array([278.0, 273.0, -800.0])
HALF = 25.000036 / 2 / 35  # tangent of half the field of view
BACK_WALL_Z = 559.2  # the back wall is the plane z = 559.2, x 0..549.6 (bottom), 0..556 (top)
CEILING_Y = 548.8
TALL_BOX_TOP = 330.0
TALL_FRONT = ((423.0, 247.0), (265.0, 296.0))  # (x, z) ends of the tall box's face seen head-on
WORLD_FROM_CAMERA = np.diag([-1.0, 1.0, -1.0])  # rotateY 180
SIZE = 33  # odd: the centre pixel's ray is the view axis


def _aovs(path, resolution, names=DATA_AOVS, **load):
    scene, spec = load_stage(path, **load)
    spec = dataclasses.replace(spec, resolution=resolution)
    integrator = prepare(scene, spec, TraceSettings(spp=1, max_depth=1, seed=0))
    return integrator.world.object_paths, render_data_aovs(integrator, names)


def _camera_direction(column, row, width, height, half_width, half_height):
    """Unnormalised camera-space direction (x, y, −1) through a pixel centre."""
    return np.array([(2 * (column + 0.5) / width - 1) * half_width, (1 - 2 * (row + 0.5) / height) * half_height, -1.0])


@pytest.fixture(scope="module")
def cornell(shipped_scene):
    return _aovs(shipped_scene("cornell.usda"), (SIZE, SIZE))


def test_cornell_shapes_and_dtypes(cornell):
    _, aovs = cornell
    assert list(aovs) == list(DATA_AOVS)
    for name, array in aovs.items():
        assert array.dtype == np.float32
        assert array.shape == ((SIZE, SIZE, 3) if name in ("normal", "Neye", "Peye") else (SIZE, SIZE))


def test_cornell_back_wall_depth_is_the_distance_along_the_view_axis(cornell):
    paths, aovs = cornell
    row = 8
    direction = WORLD_FROM_CAMERA @ _camera_direction(0, row, SIZE, SIZE, HALF, HALF)
    # Above the boxes: the ray is higher than the tall box's top before reaching it.
    assert CAMERA[1] + direction[1] * (TALL_FRONT[0][1] - CAMERA[2]) > TALL_BOX_TOP
    checked = 0
    for column in range(SIZE):
        d = WORLD_FROM_CAMERA @ _camera_direction(column, row, SIZE, SIZE, HALF, HALF)
        t = (BACK_WALL_Z - CAMERA[2]) / d[2]
        x, y = CAMERA[0] + t * d[0], CAMERA[1] + t * d[1]
        if not (5 < x < 545 and 5 < y < CEILING_Y - 5):
            continue
        checked += 1
        # A plane perpendicular to the view axis has one camera-space depth: constant along the row.
        assert aovs["depth"][row, column] == pytest.approx((BACK_WALL_Z - CAMERA[2]) / 1000, abs=1e-4)
        assert paths[int(aovs["primId"][row, column])] == "/World/Geometry/backWall"
        np.testing.assert_allclose(aovs["normal"][row, column], [0, 0, -1], atol=1e-5)  # into the room
        np.testing.assert_allclose(aovs["Neye"][row, column], [0, 0, 1], atol=1e-5)  # towards the camera
    assert checked >= SIZE // 2


def test_cornell_centre_sees_the_tall_box_head_on(cornell):
    paths, aovs = cornell
    centre = SIZE // 2
    (x0, z0), (x1, z1) = TALL_FRONT
    z = z0 + (CAMERA[0] - x0) / (x1 - x0) * (z1 - z0)  # the face's plane at the view axis
    assert paths[int(aovs["primId"][centre, centre])] == "/World/Geometry/tallBox"
    assert aovs["depth"][centre, centre] == pytest.approx((z - CAMERA[2]) / 1000, abs=1e-4)
    np.testing.assert_allclose(aovs["Peye"][centre, centre], [0, 0, -(z - CAMERA[2]) / 1000], atol=1e-4)
    # the face's outward normal, horizontal, perpendicular to the (x, z) edge, towards −z
    normal = np.array([-(z1 - z0), 0.0, x1 - x0])
    normal /= np.linalg.norm(normal)
    np.testing.assert_allclose(aovs["normal"][centre, centre], normal, atol=1e-5)


def test_cornell_floor_near_the_bottom(cornell):
    paths, aovs = cornell
    row, column = SIZE - 2, SIZE // 2
    direction = _camera_direction(column, row, SIZE, SIZE, HALF, HALF)  # camera x = 0 here
    depth = CAMERA[1] / -direction[1]  # mm along the view axis to reach y = 0
    assert 0 < depth + CAMERA[2] < 65  # on the floor in front of the short box (z ≥ 65)
    assert paths[int(aovs["primId"][row, column])] == "/World/Geometry/floor"
    assert aovs["depth"][row, column] == pytest.approx(depth / 1000, abs=1e-4)
    np.testing.assert_allclose(aovs["normal"][row, column], [0, 1, 0], atol=1e-5)
    np.testing.assert_allclose(aovs["Neye"][row, column], [0, 1, 0], atol=1e-5)


def test_cornell_camera_space_is_the_camera_rotation(cornell):
    _, aovs = cornell
    hit = np.isfinite(aovs["depth"])
    assert hit.sum() > SIZE * SIZE // 2
    lengths = np.linalg.norm(aovs["normal"][hit], axis=1)
    np.testing.assert_allclose(lengths, 1.0, atol=1e-5)
    camera_from_world = WORLD_FROM_CAMERA.T
    np.testing.assert_allclose(aovs["Neye"][hit], aovs["normal"][hit] @ camera_from_world.T, atol=1e-5)
    np.testing.assert_allclose(aovs["Peye"][..., 2][hit], -aovs["depth"][hit], rtol=1e-6)
    # Peye lies on the pixel's ray: (x, y) = depth · the film position at unit distance
    rows, columns = np.nonzero(hit)
    direction = np.stack([_camera_direction(c, r, SIZE, SIZE, HALF, HALF) for r, c in zip(rows, columns)])
    np.testing.assert_allclose(aovs["Peye"][hit], direction * aovs["depth"][hit][:, None], atol=1e-4)
    # the normal faces the camera: against the direction from the camera to the hit
    assert (np.sum(aovs["Neye"][hit] * aovs["Peye"][hit], axis=1) < 0).all()


def test_cornell_top_row_sees_nothing(cornell):
    _, aovs = cornell
    direction = _camera_direction(SIZE // 2, 0, SIZE, SIZE, HALF, HALF)
    # At the box's open front (z = 0) the ray is already above the ceiling, and climbing.
    assert CAMERA[1] + direction[1] * -CAMERA[2] > CEILING_Y
    background = ~np.isfinite(aovs["depth"])
    assert background[0].all()
    assert np.isposinf(aovs["depth"][background]).all()
    assert (aovs["primId"][background] == -1).all() and (aovs["instanceId"][background] == -1).all()
    assert (aovs["normal"][background] == 0).all() and (aovs["Neye"][background] == 0).all()
    assert (aovs["Peye"][background] == 0).all()
    assert (aovs["primId"][~background] >= 0).all()
    assert (aovs["instanceId"] == -1).all()  # nothing is point-instanced


# -- a tiny stage: a PointInstancer of three quads and a plain quad below them


def _quad(stage, path, size=1.0, z=0.0):
    mesh = UsdGeom.Mesh.Define(stage, path)
    h = size / 2
    mesh.CreatePointsAttr([(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)])  # facing +Z
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateSubdivisionSchemeAttr("none")
    return mesh


def _camera(stage, focal=10.0, aperture=20.0):
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    camera = UsdGeom.Camera.Define(stage, "/Camera")  # at the origin, looking along −Z
    camera.CreateFocalLengthAttr(focal)
    camera.CreateHorizontalApertureAttr(aperture)
    camera.CreateVerticalApertureAttr(aperture)
    return aperture / 2 / focal


INSTANCE_X = (-2.0, 0.0, 2.0)
ROW_Y, PLAIN_Y, DISTANCE = 1.0, -1.5, 5.0


def _pixel(x, y, size, half):
    """The pixel whose centre ray is closest to world (x, y, −DISTANCE)."""
    column = int((x / DISTANCE / half + 1) / 2 * size)
    row = int((1 - y / DISTANCE / half) / 2 * size)
    return row, column


def test_instance_ids_of_a_point_instancer(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "instances.usda"))
    half = _camera(stage)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    _quad(stage, "/World/Scatter/Prototypes/card")
    instancer.CreatePrototypesRel().SetTargets(["/World/Scatter/Prototypes/card"])
    instancer.CreateProtoIndicesAttr([0, 0, 0])
    instancer.CreatePositionsAttr([(x, ROW_Y, -DISTANCE) for x in INSTANCE_X])
    _quad(stage, "/World/Plain", z=-DISTANCE).AddTranslateOp().Set(Gf.Vec3d(0, PLAIN_Y, 0))
    stage.Save()

    size = 48
    paths, aovs = _aovs(tmp_path / "instances.usda", (size, size), camera="/Camera")
    prim_ids = []
    for n, x in enumerate(INSTANCE_X):
        row, column = _pixel(x, ROW_Y, size, half)
        assert aovs["instanceId"][row, column] == n
        assert paths[int(aovs["primId"][row, column])] == f"/World/Scatter/instance_{n}/card"
        assert aovs["depth"][row, column] == pytest.approx(DISTANCE, abs=1e-4)
        np.testing.assert_allclose(aovs["normal"][row, column], [0, 0, 1], atol=1e-5)
        prim_ids.append(aovs["primId"][row, column])
    row, column = _pixel(0.0, PLAIN_Y, size, half)
    assert aovs["instanceId"][row, column] == -1
    assert paths[int(aovs["primId"][row, column])] == "/World/Plain"
    prim_ids.append(aovs["primId"][row, column])
    assert len(set(prim_ids)) == 4
    # between the cards: background
    row, column = _pixel(1.0, ROW_Y, size, half)
    assert np.isposinf(aovs["depth"][row, column])
    assert aovs["primId"][row, column] == -1 and aovs["instanceId"][row, column] == -1
    # ids are exact integers, each card covers its own pixels only
    for name in ("primId", "instanceId"):
        assert (aovs[name] == np.round(aovs[name])).all()
    covered = [(aovs["instanceId"] == n).sum() for n in range(3)]
    assert min(covered) > 0 and max(covered) - min(covered) <= 2 * size // 10


def test_nested_and_native_instances_in_scene_data(tmp_path):
    """Nested instancers keep the innermost N; native instances are not point instances."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "nested.usda"))
    _camera(stage)
    outer = UsdGeom.PointInstancer.Define(stage, "/World/Outer")
    inner = UsdGeom.PointInstancer.Define(stage, "/World/Outer/Prototypes/group")
    _quad(stage, "/World/Outer/Prototypes/group/Prototypes/card")
    inner.CreatePrototypesRel().SetTargets(["/World/Outer/Prototypes/group/Prototypes/card"])
    inner.CreateProtoIndicesAttr([0, 0])
    inner.CreatePositionsAttr([(0, 0, 0), (2, 0, 0)])
    outer.CreatePrototypesRel().SetTargets(["/World/Outer/Prototypes/group"])
    outer.CreateProtoIndicesAttr([0, 0, 0])
    outer.CreatePositionsAttr([(0, 0, -5), (0, 2, -5), (0, 4, -5)])
    _quad(stage, "/Asset/card")
    for name in ("a", "b"):
        native = stage.DefinePrim(f"/World/{name}")
        native.GetReferences().AddInternalReference(Sdf.Path("/Asset"))
        native.SetInstanceable(True)
    stage.Save()

    scene, _ = load_stage(tmp_path / "nested.usda", camera="/Camera")
    instance = {mesh.path: mesh.instance for mesh in scene.meshes}
    assert instance["/World/Outer/instance_2/group/instance_1/card"] == 1
    assert instance["/World/Outer/instance_1/group/instance_0/card"] == 0
    assert len([p for p in instance if p.startswith("/World/Outer/")]) == 6
    assert instance["/World/a/card"] == -1 and instance["/World/b/card"] == -1


def test_cut_out_surfaces_are_passed_through(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "cutout.usda"))
    _camera(stage)
    _quad(stage, "/World/Back", size=4, z=-DISTANCE)
    front = _quad(stage, "/World/Front", size=4, z=-DISTANCE + 1)
    material = UsdShade.Material.Define(stage, "/Materials/hole")
    shader = UsdShade.Shader.Define(stage, "/Materials/hole/surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(0.0)
    shader.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(front.GetPrim()).Bind(material)
    stage.Save()

    paths, aovs = _aovs(tmp_path / "cutout.usda", (9, 9), names=("primId", "depth", "depth"), camera="/Camera")
    assert list(aovs) == ["primId", "depth"]
    assert paths[int(aovs["primId"][4, 4])] == "/World/Back"
    assert aovs["depth"][4, 4] == pytest.approx(DISTANCE, abs=1e-4)


def test_unknown_aov_names_the_known_ones(shipped_scene):
    scene, spec = load_stage(shipped_scene("cornell.usda"))
    spec = dataclasses.replace(spec, resolution=(4, 4))
    integrator = prepare(scene, spec, TraceSettings(spp=1, max_depth=1, seed=0))
    with pytest.raises(RenderSettingsError) as error:
        render_data_aovs(integrator, ["depth", "elementId"])
    message = str(error.value)
    assert "elementId" in message
    assert all(name in message for name in DATA_AOVS)
