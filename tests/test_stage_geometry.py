"""stage/: gprims → scene.Mesh (triangulation, primvars, transforms, instancing, pruning)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdVol, Vt

from pxr_layers.stage import load_stage

QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]


def new_stage(tmp_path, *, meters_per_unit: float = 1.0) -> Usd.Stage:
    """A saved-on-load stage with a camera, so load_stage does not fail for want of one."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "scene.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Camera.Define(stage, "/Camera")
    return stage


def load(stage: Usd.Stage, **kwargs):
    stage.GetRootLayer().Save()
    scene, _ = load_stage(stage.GetRootLayer().realPath, **kwargs)
    return scene


def define_mesh(stage, path, points, counts, indices, *, scheme="none", **attributes):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateSubdivisionSchemeAttr(scheme)
    for name, value in attributes.items():
        mesh.GetPrim().GetAttribute(name).Set(value)
    return mesh


def geometric_normals(mesh) -> np.ndarray:
    corners = mesh.points[mesh.triangles].astype(np.float64)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def only_mesh(scene):
    assert len(scene.meshes) == 1, [mesh.path for mesh in scene.meshes]
    return scene.meshes[0]


# --- triangulation -------------------------------------------------------------------------


def test_quad_becomes_two_counter_clockwise_triangles(tmp_path):
    stage = new_stage(tmp_path)
    define_mesh(stage, "/World/quad", QUAD, [4], [0, 1, 2, 3])
    mesh = only_mesh(load(stage))
    assert mesh.name == "quad" and mesh.path == "/World/quad"
    assert mesh.triangles.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert mesh.points.dtype == np.float32 and mesh.triangles.dtype == np.int32
    np.testing.assert_allclose(geometric_normals(mesh), [[0, 0, 1], [0, 0, 1]])
    assert mesh.normals is None  # subdivisionScheme none, no authored normals: flat
    assert mesh.triangle_material.tolist() == [0, 0]


def test_pentagon_is_fanned_from_its_first_vertex(tmp_path):
    stage = new_stage(tmp_path)
    pentagon = [(math.cos(a), math.sin(a), 0) for a in np.linspace(0, 2 * math.pi, 6)[:5]]
    define_mesh(stage, "/pentagon", pentagon, [5], [0, 1, 2, 3, 4])
    mesh = only_mesh(load(stage))
    assert mesh.triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4]]


def test_short_faces_and_holes_produce_no_triangles(tmp_path):
    stage = new_stage(tmp_path)
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)]
    # faces: triangle, degenerate 2-gon, quad, triangle (a hole)
    define_mesh(
        stage, "/m", points, [3, 2, 4, 3], [0, 1, 2, 0, 1, 1, 4, 5, 2, 0, 2, 3],
        holeIndices=Vt.IntArray([3]),
    )
    mesh = only_mesh(load(stage))
    assert mesh.triangles.tolist() == [[0, 1, 2], [1, 4, 5], [1, 5, 2]]


def test_left_handed_orientation_flips_the_winding(tmp_path):
    stage = new_stage(tmp_path)
    define_mesh(stage, "/right", QUAD, [4], [0, 1, 2, 3])
    define_mesh(stage, "/left", QUAD, [4], [0, 1, 2, 3], orientation=UsdGeom.Tokens.leftHanded)
    meshes = {mesh.name: mesh for mesh in load(stage).meshes}
    np.testing.assert_allclose(geometric_normals(meshes["right"]), [[0, 0, 1]] * 2)
    np.testing.assert_allclose(geometric_normals(meshes["left"]), [[0, 0, -1]] * 2)


def test_left_handed_keeps_authored_normals_on_the_front_side(tmp_path):
    stage = new_stage(tmp_path)
    mesh = define_mesh(
        stage, "/left", QUAD, [4], [0, 1, 2, 3], orientation=UsdGeom.Tokens.leftHanded
    )
    mesh.CreateNormalsAttr([(0, 0, -1)] * 4)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    placed = only_mesh(load(stage))
    np.testing.assert_allclose(placed.normals.reshape(-1, 3), [[0, 0, -1]] * 6)
    # the shading normals agree with the (flipped) geometric front face
    assert (np.einsum("tj,tj->t", geometric_normals(placed), placed.normals[:, 0]) > 0).all()


def test_meters_per_unit_scales_points_to_metres(tmp_path):
    stage = new_stage(tmp_path, meters_per_unit=0.001)  # millimetres
    define_mesh(stage, "/m", [(0, 0, 0), (1000, 0, 0), (0, 2000, 0)], [3], [0, 1, 2])
    scene = load(stage)
    assert scene.meters_per_unit == pytest.approx(0.001)
    np.testing.assert_allclose(only_mesh(scene).points, [[0, 0, 0], [1, 0, 0], [0, 2, 0]])


# --- primvars -----------------------------------------------------------------------------

# Two quads side by side: 6 points, 2 faces, 8 face-vertices.
STRIP_POINTS = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)]
STRIP_INDICES = [0, 1, 4, 3, 1, 2, 5, 4]
# Triangles per face (0, 1, 4), (0, 4, 3) | (1, 2, 5), (1, 5, 4), as corner indices:
STRIP_CORNERS = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]


def strip(stage, scheme="none"):
    return define_mesh(stage, "/strip", STRIP_POINTS, [4, 4], STRIP_INDICES, scheme=scheme)


def _unit(vectors):
    vectors = np.asarray(vectors, dtype=np.float64)
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


@pytest.mark.parametrize(
    "interpolation, values, indices, expected_per_corner",
    [
        ("constant", [(0, 1, 1)], None, lambda v: np.broadcast_to(v[0], (4, 3, 3))),
        ("uniform", [(0, 0, 1), (0, 1, 1)], None, lambda v: v[[0, 0, 1, 1]][:, None].repeat(3, 1)),
        ("vertex", [(i, 0, 1) for i in range(6)], None,
         lambda v: v[np.array(STRIP_INDICES)[STRIP_CORNERS]]),
        ("faceVarying", [(i, 1, 1) for i in range(8)], None, lambda v: v[STRIP_CORNERS]),
        ("faceVarying", [(0, 0, 1), (1, 0, 1)], [0, 1, 0, 1, 1, 0, 1, 0],
         lambda v: v[np.array([0, 1, 0, 1, 1, 0, 1, 0])[STRIP_CORNERS]]),
    ],
    ids=["constant", "uniform", "vertex", "faceVarying", "indexed"],
)
def test_normals_primvar_every_interpolation(tmp_path, interpolation, values, indices,
                                             expected_per_corner):
    stage = new_stage(tmp_path)
    mesh = strip(stage)
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "normals", Sdf.ValueTypeNames.Normal3fArray, interpolation
    )
    primvar.Set(values)
    if indices is not None:
        primvar.SetIndices(Vt.IntArray(indices))
    placed = only_mesh(load(stage))
    expected = _unit(expected_per_corner(np.asarray(values, dtype=np.float64)))
    np.testing.assert_allclose(placed.normals, expected, atol=1e-6)
    assert placed.normals.shape == (4, 3, 3) and placed.normals.dtype == np.float32


def test_normals_primvar_wins_over_normals_attribute(tmp_path):
    stage = new_stage(tmp_path)
    mesh = strip(stage)
    mesh.CreateNormalsAttr([(1, 0, 0)] * 6)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "normals", Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.constant
    ).Set([(0, 0, 1)])
    np.testing.assert_allclose(only_mesh(load(stage)).normals.reshape(-1, 3), [[0, 0, 1]] * 12)


def test_normals_attribute_with_uniform_interpolation(tmp_path):
    stage = new_stage(tmp_path)
    mesh = strip(stage)
    mesh.CreateNormalsAttr([(0, 0, 2), (0, 3, 0)])  # not unit length: normalised
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.uniform)
    normals = only_mesh(load(stage)).normals
    np.testing.assert_allclose(normals[:2].reshape(-1, 3), [[0, 0, 1]] * 6)
    np.testing.assert_allclose(normals[2:].reshape(-1, 3), [[0, 1, 0]] * 6)


@pytest.mark.parametrize(
    "interpolation, values, indices, expected_per_corner",
    [
        ("constant", [(0.5, 0.25)], None, lambda v: np.broadcast_to(v[0], (4, 3, 2))),
        ("uniform", [(0, 0), (1, 1)], None, lambda v: v[[0, 0, 1, 1]][:, None].repeat(3, 1)),
        ("vertex", [(i, -i) for i in range(6)], None,
         lambda v: v[np.array(STRIP_INDICES)[STRIP_CORNERS]]),
        ("varying", [(i, 2 * i) for i in range(6)], None,
         lambda v: v[np.array(STRIP_INDICES)[STRIP_CORNERS]]),
        ("faceVarying", [(i, i + 0.5) for i in range(8)], None, lambda v: v[STRIP_CORNERS]),
        ("faceVarying", [(0, 0), (1, 0), (1, 1)], [0, 1, 2, 2, 1, 0, 0, 1],
         lambda v: v[np.array([0, 1, 2, 2, 1, 0, 0, 1])[STRIP_CORNERS]]),
    ],
    ids=["constant", "uniform", "vertex", "varying", "faceVarying", "indexed"],
)
def test_st_primvar_every_interpolation(tmp_path, interpolation, values, indices,
                                        expected_per_corner):
    stage = new_stage(tmp_path)
    mesh = strip(stage)
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, interpolation
    )
    primvar.Set(values)
    if indices is not None:
        primvar.SetIndices(Vt.IntArray(indices))
    placed = only_mesh(load(stage))
    expected = expected_per_corner(np.asarray(values, dtype=np.float64))
    np.testing.assert_allclose(placed.uvs, expected)
    assert placed.uvs.shape == (4, 3, 2) and placed.uvs.dtype == np.float32


def test_uvs_absent_without_primvar(tmp_path):
    stage = new_stage(tmp_path)
    strip(stage)
    assert only_mesh(load(stage)).uvs is None


def test_primvar_with_too_few_values_is_ignored_with_a_warning(tmp_path):
    stage = new_stage(tmp_path)
    mesh = strip(stage)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    ).Set([(0, 0)] * 3)
    scene = load(stage)
    assert only_mesh(scene).uvs is None
    assert any("/strip" in warning and "st" in warning for warning in scene.warnings)


def test_subdivision_surface_without_normals_gets_smooth_area_weighted_normals(tmp_path):
    stage = new_stage(tmp_path)
    # A roof: two faces meeting at a ridge at 90°.
    points = [(0, 0, 0), (0, 0, 1), (1, 1, 0), (1, 1, 1), (2, 0, 0), (2, 0, 1)]
    define_mesh(stage, "/roof", points, [4, 4], [0, 1, 3, 2, 2, 3, 5, 4], scheme="catmullClark")
    mesh = only_mesh(load(stage))
    assert mesh.normals is not None
    ridge = np.isin(mesh.triangles, [2, 3])
    # At the ridge both faces (equal area) average to straight up, although the fan
    # triangulation gives the ridge vertices of one face two triangles and the other one.
    np.testing.assert_allclose(mesh.normals[ridge], [[0, 1, 0]] * int(ridge.sum()), atol=1e-6)
    # Away from it each vertex keeps its own face's normal.
    np.testing.assert_allclose(
        mesh.normals[mesh.triangles == 0], [_unit([-1, 1, 0])] * int((mesh.triangles == 0).sum()),
        atol=1e-6,
    )


# --- transforms ---------------------------------------------------------------------------


def test_parent_scale_and_rotation_compose_with_child_translation(tmp_path):
    stage = new_stage(tmp_path)
    parent = UsdGeom.Xform.Define(stage, "/Parent")
    parent.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    parent.AddRotateZOp().Set(90.0)
    child = UsdGeom.Xform.Define(stage, "/Parent/Child")
    child.AddTranslateOp().Set(Gf.Vec3d(1, 0, 0))
    define_mesh(stage, "/Parent/Child/tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    mesh = only_mesh(load(stage))
    # xformOpOrder [scale, rotateZ]: p' = S · Rz · (p + t); Rz(90) takes x → y.
    np.testing.assert_allclose(mesh.points, [[0, 2, 0], [0, 4, 0], [-2, 2, 0]], atol=1e-6)


def test_normals_use_the_inverse_transpose(tmp_path):
    stage = new_stage(tmp_path)
    xform = UsdGeom.Xform.Define(stage, "/Stretch")
    xform.AddScaleOp().Set(Gf.Vec3f(2, 1, 1))
    mesh = define_mesh(stage, "/Stretch/m", QUAD, [4], [0, 1, 2, 3])
    mesh.CreateNormalsAttr([(1, 1, 0)] * 4)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    normals = only_mesh(load(stage)).normals.reshape(-1, 3)
    np.testing.assert_allclose(normals, [_unit([0.5, 1, 0])] * 6, atol=1e-6)


def test_mirroring_transform_keeps_triangles_facing_front(tmp_path):
    stage = new_stage(tmp_path)
    xform = UsdGeom.Xform.Define(stage, "/Mirror")
    xform.AddScaleOp().Set(Gf.Vec3f(-1, 1, 1))
    define_mesh(stage, "/Mirror/m", QUAD, [4], [0, 1, 2, 3])
    mesh = only_mesh(load(stage))
    # Mirroring X does not change which way a face in the XY plane looks.
    np.testing.assert_allclose(geometric_normals(mesh), [[0, 0, 1]] * 2)


def test_native_instances_are_placed_at_each_instance(tmp_path):
    stage = new_stage(tmp_path)
    stage.CreateClassPrim("/Asset")
    define_mesh(stage, "/Asset/geo", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    for name, x in (("a", 10.0), ("b", -10.0)):
        instance = UsdGeom.Xform.Define(stage, f"/World/{name}")
        instance.AddTranslateOp().Set(Gf.Vec3d(x, 0, 0))
        instance.GetPrim().GetReferences().AddInternalReference("/Asset")
        instance.GetPrim().SetInstanceable(True)
    scene = load(stage)
    by_path = {mesh.path: mesh for mesh in scene.meshes}
    assert sorted(by_path) == ["/World/a/geo", "/World/b/geo"]
    np.testing.assert_allclose(by_path["/World/a/geo"].points[0], [10, 0, 0])
    np.testing.assert_allclose(by_path["/World/b/geo"].points[1], [-9, 0, 0])


def test_point_instancer_places_each_visible_instance(tmp_path):
    stage = new_stage(tmp_path)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    UsdGeom.Scope.Define(stage, "/World/Scatter/Prototypes")
    box = UsdGeom.Xform.Define(stage, "/World/Scatter/Prototypes/box")
    box.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))  # prototype root transform is included
    UsdGeom.Cube.Define(stage, "/World/Scatter/Prototypes/box/shape").CreateSizeAttr(2.0)
    instancer.CreatePrototypesRel().SetTargets(["/World/Scatter/Prototypes/box"])
    instancer.CreateProtoIndicesAttr([0, 0, 0, 0])
    instancer.CreatePositionsAttr([(0, 0, 0), (10, 0, 0), (20, 0, 0), (30, 0, 0)])
    instancer.CreateScalesAttr([(1, 1, 1), (2, 2, 2), (1, 1, 1), (1, 1, 1)])
    quarter_turn = Gf.Quath(math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4))  # 90° about Z
    instancer.CreateOrientationsAttr([Gf.Quath(1, 0, 0, 0), Gf.Quath(1, 0, 0, 0),
                                      quarter_turn, Gf.Quath(1, 0, 0, 0)])
    instancer.CreateInvisibleIdsAttr([3])  # ids default to indices
    scene = load(stage)
    by_path = {mesh.path: mesh for mesh in scene.meshes}
    assert sorted(by_path) == [f"/World/Scatter/instance_{n}/box/shape" for n in range(3)]
    assert all(mesh.name == "shape" for mesh in scene.meshes)

    def bounds(n):
        points = by_path[f"/World/Scatter/instance_{n}/box/shape"].points
        return points.min(axis=0), points.max(axis=0)

    np.testing.assert_allclose(bounds(0), [[-1, -1, 4], [1, 1, 6]], atol=1e-5)
    np.testing.assert_allclose(bounds(1), [[8, -2, 8], [12, 2, 12]], atol=1e-5)
    np.testing.assert_allclose(bounds(2), [[19, -1, 4], [21, 1, 6]], atol=1e-5)
    # the prototypes themselves are not rendered where they are authored
    assert "/World/Scatter/Prototypes/box/shape" not in by_path


def test_invisible_and_non_render_purposes_are_pruned(tmp_path):
    stage = new_stage(tmp_path)
    triangle = ([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    define_mesh(stage, "/shown", *triangle)
    define_mesh(stage, "/render", *triangle).CreatePurposeAttr(UsdGeom.Tokens.render)
    define_mesh(stage, "/guide", *triangle).CreatePurposeAttr(UsdGeom.Tokens.guide)
    define_mesh(stage, "/proxy", *triangle).CreatePurposeAttr(UsdGeom.Tokens.proxy)
    define_mesh(stage, "/hidden", *triangle).MakeInvisible()
    UsdGeom.Xform.Define(stage, "/HiddenGroup").MakeInvisible()
    define_mesh(stage, "/HiddenGroup/child", *triangle)
    UsdGeom.Xform.Define(stage, "/GuideGroup").CreatePurposeAttr(UsdGeom.Tokens.guide)
    define_mesh(stage, "/GuideGroup/child", *triangle)
    define_mesh(stage, "/inactive", *triangle).GetPrim().SetActive(False)
    assert sorted(mesh.path for mesh in load(stage).meshes) == ["/render", "/shown"]


# --- implicit gprims -----------------------------------------------------------------------


def test_sphere_points_lie_on_the_radius_with_radial_normals(tmp_path):
    stage = new_stage(tmp_path)
    sphere = UsdGeom.Sphere.Define(stage, "/ball")
    sphere.CreateRadiusAttr(2.0)
    sphere.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    mesh = only_mesh(load(stage))
    centre = np.array([1, 2, 3])
    np.testing.assert_allclose(np.linalg.norm(mesh.points - centre, axis=1), 2.0, rtol=1e-6)
    corners = mesh.points[mesh.triangles] - centre
    np.testing.assert_allclose(mesh.normals, corners / 2.0, atol=1e-5)
    assert len(mesh.triangles) >= 64 * 30  # a smooth silhouette
    assert (np.einsum("tj,tj->t", geometric_normals(mesh), corners.mean(axis=1)) > 0).all()
    assert mesh.uvs is not None and mesh.uvs.min() >= 0.0 and mesh.uvs.max() <= 1.0


def test_cube_size_and_flat_outward_normals(tmp_path):
    stage = new_stage(tmp_path)
    UsdGeom.Cube.Define(stage, "/box").CreateSizeAttr(3.0)
    mesh = only_mesh(load(stage))
    assert len(mesh.triangles) == 12
    np.testing.assert_allclose(mesh.points.min(axis=0), [-1.5] * 3)
    np.testing.assert_allclose(mesh.points.max(axis=0), [1.5] * 3)
    centres = mesh.points[mesh.triangles].mean(axis=1)
    np.testing.assert_allclose(geometric_normals(mesh), mesh.normals[:, 0], atol=1e-6)
    assert (np.einsum("tj,tj->t", geometric_normals(mesh), centres) > 0).all()


@pytest.mark.parametrize("axis, long_index", [("X", 0), ("Y", 1), ("Z", 2)])
def test_cylinder_follows_its_axis(tmp_path, axis, long_index):
    stage = new_stage(tmp_path)
    cylinder = UsdGeom.Cylinder.Define(stage, "/can")
    cylinder.CreateAxisAttr(axis)
    cylinder.CreateHeightAttr(4.0)
    cylinder.CreateRadiusAttr(1.0)
    mesh = only_mesh(load(stage))
    expected = np.ones(3)
    expected[long_index] = 2.0
    np.testing.assert_allclose(mesh.points.max(axis=0), expected, atol=1e-6)
    np.testing.assert_allclose(mesh.points.min(axis=0), -expected, atol=1e-6)
    # closed and outward facing: the signed volume is πr²h
    corners = mesh.points[mesh.triangles].astype(np.float64)
    volume = np.einsum("tj,tj->t", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6
    assert volume == pytest.approx(math.pi * 4.0, rel=0.01)


def test_cone_and_capsule_are_closed_outward_surfaces(tmp_path):
    stage = new_stage(tmp_path)
    cone = UsdGeom.Cone.Define(stage, "/cone")
    cone.CreateRadiusAttr(1.0)
    cone.CreateHeightAttr(3.0)
    capsule = UsdGeom.Capsule.Define(stage, "/capsule")
    capsule.CreateRadiusAttr(0.5)
    capsule.CreateHeightAttr(2.0)
    capsule.CreateAxisAttr("Y")
    meshes = {mesh.name: mesh for mesh in load(stage).meshes}

    def volume(mesh):
        c = mesh.points[mesh.triangles].astype(np.float64)
        return np.einsum("tj,tj->t", c[:, 0], np.cross(c[:, 1], c[:, 2])).sum() / 6

    assert volume(meshes["cone"]) == pytest.approx(math.pi * 3.0 / 3.0, rel=0.01)
    assert volume(meshes["capsule"]) == pytest.approx(
        math.pi * 0.25 * 2.0 + 4 / 3 * math.pi * 0.125, rel=0.01
    )
    np.testing.assert_allclose(meshes["capsule"].points.max(axis=0), [0.5, 1.5, 0.5], atol=1e-6)


def test_tapered_cylinder_and_capsule_schemas(tmp_path):
    stage = new_stage(tmp_path)
    frustum = UsdGeom.Cylinder_1.Define(stage, "/frustum")
    frustum.CreateRadiusBottomAttr(2.0)
    frustum.CreateRadiusTopAttr(1.0)
    frustum.CreateHeightAttr(3.0)
    pill = UsdGeom.Capsule_1.Define(stage, "/pill")
    pill.CreateRadiusBottomAttr(0.5)
    pill.CreateRadiusTopAttr(0.25)
    pill.CreateHeightAttr(2.0)
    pill.CreateAxisAttr("X")
    meshes = {mesh.name: mesh for mesh in load(stage).meshes}
    c = meshes["frustum"].points[meshes["frustum"].triangles].astype(np.float64)
    volume = np.einsum("tj,tj->t", c[:, 0], np.cross(c[:, 1], c[:, 2])).sum() / 6
    assert volume == pytest.approx(math.pi * 3.0 / 3.0 * (4 + 2 + 1), rel=0.01)
    np.testing.assert_allclose(meshes["pill"].points.min(axis=0), [-1.5, -0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(meshes["pill"].points.max(axis=0), [1.25, 0.5, 0.5], atol=1e-6)


def test_plane_faces_its_axis(tmp_path):
    stage = new_stage(tmp_path)
    plane = UsdGeom.Plane.Define(stage, "/floor")
    plane.CreateAxisAttr("Y")
    plane.CreateWidthAttr(4.0)
    plane.CreateLengthAttr(2.0)
    mesh = only_mesh(load(stage))
    np.testing.assert_allclose(geometric_normals(mesh), [[0, 1, 0]] * 2)
    np.testing.assert_allclose(mesh.points.max(axis=0), [2, 0, 1])


# --- bad data -----------------------------------------------------------------------------


def test_degenerate_triangles_are_dropped_with_one_counted_warning(tmp_path):
    stage = new_stage(tmp_path)
    points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (2, 0, 0)]
    # a good triangle, a collinear one, one repeating a vertex
    define_mesh(stage, "/a", points, [3, 3, 3], [0, 1, 2, 0, 1, 3, 2, 2, 0])
    define_mesh(stage, "/b", points, [3, 3], [0, 1, 2, 1, 1, 1])
    scene = load(stage)
    assert [len(mesh.triangles) for mesh in scene.meshes] == [1, 1]
    degenerate = [w for w in scene.warnings if "degenerate (zero-area)" in w]
    assert len(degenerate) == 1
    assert "3 degenerate" in degenerate[0] and "/a" in degenerate[0] and "/b" in degenerate[0]


def test_unsupported_geometry_is_skipped_with_one_warning(tmp_path):
    stage = new_stage(tmp_path)
    curves = UsdGeom.BasisCurves.Define(stage, "/hair")  # curves and points are drawn (test_strands.py)
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreatePointsAttr([(0, 0, 0), (0, 1, 0)])
    curves.CreateCurveVertexCountsAttr([2])
    UsdGeom.Points.Define(stage, "/dust").CreatePointsAttr([(0, 0, 0)])
    UsdGeom.NurbsPatch.Define(stage, "/panel")
    UsdVol.Volume.Define(stage, "/smoke")
    define_mesh(stage, "/ok", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    scene = load(stage)
    assert [mesh.path for mesh in scene.meshes] == ["/ok"]
    assert [strands.path for strands in scene.strands] == ["/hair", "/dust"]
    unsupported = [w for w in scene.warnings if "unsupported geometry" in w]
    assert len(unsupported) == 1
    for expected in ("/panel (NurbsPatch)", "/smoke (Volume)"):
        assert expected in unsupported[0]
    assert "BasisCurves" not in unsupported[0] and "Points" not in unsupported[0]


def test_prims_referencing_one_asset_share_its_surface_and_each_keeps_its_warnings(tmp_path):
    asset = Usd.Stage.CreateNew(str(tmp_path / "asset.usda"))
    piece = define_mesh(asset, "/Piece", QUAD, [4], [0, 1, 2, 3])
    piece.GetPrim().CreateAttribute("primvars:st", Sdf.ValueTypeNames.TexCoord2fArray).Set([(0, 0)])
    UsdGeom.Primvar(piece.GetPrim().GetAttribute("primvars:st")).SetInterpolation(UsdGeom.Tokens.vertex)
    asset.SetDefaultPrim(piece.GetPrim())
    asset.GetRootLayer().Save()
    stage = new_stage(tmp_path)
    for name, x in (("black", 0.0), ("white", 5.0)):
        prim = stage.DefinePrim(f"/World/{name}")
        prim.GetReferences().AddReference("./asset.usda")
        UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(x, 0, 0))
    scene = load(stage)
    black, white = sorted(scene.meshes, key=lambda mesh: mesh.path)
    assert np.array_equal(black.triangles, white.triangles)
    np.testing.assert_allclose(white.points - black.points, [[5.0, 0, 0]] * len(black.points))
    (warning,) = [text for text in scene.warnings if "too few values" in text]
    assert "/World/black" in warning and "/World/white" in warning
