"""Material primvars: read per triangle corner (stage/surfaces.py), placed (placement.py),
gathered into the World's column table (trace/world.py).

Expected values are written out from the authored ones (values exact in float32), never
taken from the reader's own output.
"""

from __future__ import annotations

import dataclasses
import textwrap

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from pxr_layers.scene import INDEX, Light, Mesh, SceneData
from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.placement import place_surface, prepare_surface
from pxr_layers.stage.surfaces import mesh_opinions, read_mesh, with_constant_primvars
from pxr_layers.trace.world import build_world, geometry_arrays

TIME = Usd.TimeCode.Default()


class RecordingDiagnostics(Diagnostics):
    """Diagnostics that also keep (kind, noted) pairs, to check what was noted."""

    def __init__(self) -> None:
        super().__init__()
        self.notes: list[tuple[str, str]] = []

    def note(self, kind: str, template: str, prim_path: str, count: int = 1) -> None:
        self.notes.append((kind, prim_path))
        super().note(kind, template, prim_path, count)

    def kinds(self) -> set[str]:
        return {kind for kind, _ in self.notes}


def open_stage(tmp_path, body: str, name: str = "scene.usda") -> Usd.Stage:
    path = tmp_path / name
    path.write_text("#usda 1.0\n" + textwrap.dedent(body))
    stage = Usd.Stage.Open(str(path))
    assert stage, path
    return stage


def read(stage: Usd.Stage, path: str, primvars: tuple[str, ...], *, level: int = 0, diagnostics=None):
    return read_mesh(stage.GetPrimAtPath(path), TIME, "st", diagnostics or RecordingDiagnostics(),
                     "scene.usda", subdiv_level=level, primvars=primvars)


# A quad (points 0 1 2 3) and a triangle (points 1 4 2): fanned into the triangles
# (0 1 2), (0 2 3) of face 0 (face corners 0 1 2, 0 2 3) and (1 4 2) of face 1 (corners 4 5 6).
POLYGON_MESH = """
def Mesh "mesh"
{
    int[] faceVertexCounts = [4, 3]
    int[] faceVertexIndices = [0, 1, 2, 3, 1, 4, 2]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0.5, 0)]
    uniform token subdivisionScheme = "none"
    %s
}
"""
POLYGON_TRIANGLE_POINTS = [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
POLYGON_TRIANGLE_CORNERS = [[0, 1, 2], [0, 2, 3], [4, 5, 6]]
POLYGON_TRIANGLE_FACE = [0, 0, 1]


def polygon_stage(tmp_path, primvars: str) -> Usd.Stage:
    return open_stage(tmp_path, POLYGON_MESH % primvars)


def test_constant_displaycolor_reaches_every_corner_as_a_broadcast_view(tmp_path):
    stage = polygon_stage(tmp_path, 'color3f[] primvars:displayColor = [(0.25, 0.5, 0.75)] (interpolation = "constant")')
    values = read(stage, "/mesh", ("displayColor",)).primvars["displayColor"]
    assert values.shape == (3, 3, 3) and values.dtype == np.float32
    np.testing.assert_array_equal(values, np.full((3, 3, 3), [0.25, 0.5, 0.75], np.float32))
    # one value, no per-corner memory, read-only
    assert values.strides[:2] == (0, 0) and not values.flags.writeable


def test_non_array_constant_primvar_is_one_value(tmp_path):
    stage = polygon_stage(tmp_path, "float primvars:coverage = 0.5")
    values = read(stage, "/mesh", ("coverage",)).primvars["coverage"]
    np.testing.assert_array_equal(values, np.full((3, 3, 1), 0.5, np.float32))


def test_uniform_displaycolor_follows_each_triangles_face(tmp_path):
    colors = [(1, 0, 0), (0, 0.5, 1)]
    stage = polygon_stage(tmp_path, 'color3f[] primvars:displayColor = [(1, 0, 0), (0, 0.5, 1)] (interpolation = "uniform")')
    values = read(stage, "/mesh", ("displayColor",)).primvars["displayColor"]
    expected = [[colors[face]] * 3 for face in POLYGON_TRIANGLE_FACE]
    np.testing.assert_array_equal(values, np.asarray(expected, np.float32))
    assert values.strides[1] == 0  # one row per triangle


def test_vertex_displaycolor_follows_the_points(tmp_path):
    colors = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.25, 1)]
    authored = ", ".join(str(c) for c in colors)
    stage = polygon_stage(tmp_path, f'color3f[] primvars:displayColor = [{authored}] (interpolation = "vertex")')
    values = read(stage, "/mesh", ("displayColor",)).primvars["displayColor"]
    expected = [[colors[p] for p in triangle] for triangle in POLYGON_TRIANGLE_POINTS]
    np.testing.assert_array_equal(values, np.asarray(expected, np.float32))


def test_indexed_face_varying_displaycolor_follows_the_face_corners(tmp_path):
    palette = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    indices = [0, 1, 2, 1, 2, 2, 0]  # one per face corner
    stage = polygon_stage(tmp_path, textwrap.dedent('''
        color3f[] primvars:displayColor = [(1, 0, 0), (0, 1, 0), (0, 0, 1)] (interpolation = "faceVarying")
        int[] primvars:displayColor:indices = [0, 1, 2, 1, 2, 2, 0]
    '''))
    values = read(stage, "/mesh", ("displayColor",)).primvars["displayColor"]
    expected = [[palette[indices[c]] for c in corners] for corners in POLYGON_TRIANGLE_CORNERS]
    np.testing.assert_array_equal(values, np.asarray(expected, np.float32))


def test_varying_primvar_is_read_per_point(tmp_path):
    weights = [0.0, 0.25, 0.5, 0.75, 1.0]
    stage = polygon_stage(tmp_path, 'float[] primvars:weight = [0, 0.25, 0.5, 0.75, 1] (interpolation = "varying")')
    values = read(stage, "/mesh", ("weight",)).primvars["weight"]
    expected = [[[weights[p]] for p in triangle] for triangle in POLYGON_TRIANGLE_POINTS]
    np.testing.assert_array_equal(values, np.asarray(expected, np.float32))


def test_widths_follow_the_type_and_ints_and_bools_read_as_floats(tmp_path):
    stage = polygon_stage(tmp_path, textwrap.dedent('''
        float[] primvars:rough = [0.25, 0.75] (interpolation = "uniform")
        float2[] primvars:offset = [(0.5, -1)] (interpolation = "constant")
        color4f[] primvars:tint = [(0.5, 0.25, 1, 0.75)] (interpolation = "constant")
        int[] primvars:id = [3, 7] (interpolation = "uniform")
        bool[] primvars:flag = [1, 0, 0, 1, 1] (interpolation = "vertex")
    '''))
    surface = read(stage, "/mesh", ("rough", "offset", "tint", "id", "flag"))
    assert {name: values.shape[2] for name, values in surface.primvars.items()} == {
        "rough": 1, "offset": 2, "tint": 4, "id": 1, "flag": 1}
    assert all(values.dtype == np.float32 for values in surface.primvars.values())
    np.testing.assert_array_equal(surface.primvars["rough"][:, :, 0], [[0.25] * 3, [0.25] * 3, [0.75] * 3])
    np.testing.assert_array_equal(surface.primvars["offset"], np.full((3, 3, 2), [0.5, -1.0], np.float32))
    np.testing.assert_array_equal(surface.primvars["tint"], np.full((3, 3, 4), [0.5, 0.25, 1.0, 0.75], np.float32))
    np.testing.assert_array_equal(surface.primvars["id"][:, :, 0], [[3] * 3, [3] * 3, [7] * 3])
    flag = [1, 0, 0, 1, 1]
    np.testing.assert_array_equal(surface.primvars["flag"][:, :, 0],
                                  [[flag[p] for p in triangle] for triangle in POLYGON_TRIANGLE_POINTS])


def test_missing_primvar_is_left_out_without_a_note(tmp_path):
    stage = polygon_stage(tmp_path, 'color3f[] primvars:displayColor = [(1, 0, 0)] (interpolation = "constant")')
    diagnostics = RecordingDiagnostics()
    surface = read(stage, "/mesh", ("displayColor", "nowhere"), diagnostics=diagnostics)
    assert set(surface.primvars) == {"displayColor"}
    assert diagnostics.notes == []
    assert read(stage, "/mesh", ()).primvars == {}


def test_primvars_of_other_types_or_too_few_values_are_noted_and_left_out(tmp_path):
    stage = polygon_stage(tmp_path, textwrap.dedent('''
        string[] primvars:label = ["a"] (interpolation = "constant")
        matrix4d[] primvars:frame = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1))] (interpolation = "constant")
        color3f[] primvars:displayColor = [(1, 0, 0)] (interpolation = "uniform")
        float[] primvars:empty = [] (interpolation = "constant")
    '''))
    diagnostics = RecordingDiagnostics()
    surface = read(stage, "/mesh", ("label", "frame", "displayColor", "empty"), diagnostics=diagnostics)
    assert surface.primvars == {}
    assert sorted(diagnostics.notes) == [
        ("primvar-size", "/mesh (displayColor: 1 values, uniform)"),
        ("primvar-size", "/mesh (empty: 0 values, constant)"),
        ("primvar-type", "/mesh.primvars:frame (matrix4d[])"),
        ("primvar-type", "/mesh.primvars:label (string[])"),
    ]


INHERITING = """
def Xform "Root"
{
    color3f[] primvars:displayColor = [(0.5, 0.25, 0.125)] (interpolation = "constant")
    float primvars:gloss = 0.75
    def Xform "Group"
    {
        def Mesh "plain"
        {
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
            point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
            uniform token subdivisionScheme = "none"
        }
        def Mesh "own"
        {
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
            point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
            uniform token subdivisionScheme = "none"
            color3f[] primvars:displayColor = [(1, 0, 0), (0, 1, 0), (0, 0, 1)] (interpolation = "vertex")
        }
    }
    def Cube "cube"
    {
        float[] primvars:gloss = [0.25] (interpolation = "uniform")
    }
}
"""


def test_constant_primvars_of_ancestors_apply_unless_the_mesh_has_its_own(tmp_path):
    stage = open_stage(tmp_path, INHERITING)
    plain = read(stage, "/Root/Group/plain", ("displayColor", "gloss")).primvars
    np.testing.assert_array_equal(plain["displayColor"], np.full((1, 3, 3), [0.5, 0.25, 0.125], np.float32))
    np.testing.assert_array_equal(plain["gloss"], np.full((1, 3, 1), 0.75, np.float32))
    own = read(stage, "/Root/Group/own", ("displayColor",)).primvars
    np.testing.assert_array_equal(own["displayColor"], [[(1, 0, 0), (0, 1, 0), (0, 0, 1)]])


def test_implicit_shapes_take_constant_primvars_only(tmp_path):
    from pxr_layers.stage.implicit import tessellate

    stage = open_stage(tmp_path, INHERITING)
    prim = stage.GetPrimAtPath("/Root/cube")
    shape = tessellate(prim, TIME)
    diagnostics = RecordingDiagnostics()
    surface = with_constant_primvars(shape, prim, TIME, ("displayColor", "gloss", "nowhere"), diagnostics)
    assert set(surface.primvars) == {"displayColor"}  # inherited; its own gloss is uniform
    values = surface.primvars["displayColor"]
    assert values.shape == (len(shape.triangles), 3, 3) and values.strides[:2] == (0, 0)
    np.testing.assert_array_equal(values[0, 0], [0.5, 0.25, 0.125])
    assert diagnostics.notes == [("implicit-primvar", "/Root/cube (gloss: uniform)")]


def test_mesh_opinions_tell_apart_meshes_that_inherit_different_primvars(tmp_path):
    (tmp_path / "asset.usda").write_text(textwrap.dedent("""\
        #usda 1.0
        (defaultPrim = "Asset")
        def Xform "Asset"
        {
            def Mesh "mesh"
            {
                int[] faceVertexCounts = [3]
                int[] faceVertexIndices = [0, 1, 2]
                point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
            }
        }
    """))
    stage = open_stage(tmp_path, """
        def Xform "Red"
        {
            color3f[] primvars:displayColor = [(1, 0, 0)]
            def "A" (
                references = @./asset.usda@
            )
            {
            }
        }
        def Xform "Blue"
        {
            color3f[] primvars:displayColor = [(0, 0, 1)]
            def "A" (
                references = @./asset.usda@
            )
            {
            }
        }
        def "Plain" (
            references = @./asset.usda@
        )
        {
        }
        def "AlsoPlain" (
            references = @./asset.usda@
        )
        {
        }
    """)
    key = {name: mesh_opinions(stage.GetPrimAtPath(f"/{name}/mesh" if "Plain" in name else f"/{name}/A/mesh"),
                               TIME, "st", ("displayColor",))
           for name in ("Red", "Blue", "Plain", "AlsoPlain")}
    assert key["Red"] != key["Blue"] and key["Red"] != key["Plain"]
    assert key["Plain"] == key["AlsoPlain"]
    # Without the primvar asked for, all four read the same surface.
    assert len({mesh_opinions(stage.GetPrimAtPath(p), TIME, "st")
                for p in ("/Red/A/mesh", "/Blue/A/mesh", "/Plain/mesh")}) == 1


# --- subdivision meshes -----------------------------------------------------------------------

# Two quads side by side, x in [0, 2], y in [0, 1].
SUBDIVISION_MESH = """
def Mesh "mesh"
{
    int[] faceVertexCounts = [4, 4]
    int[] faceVertexIndices = [0, 1, 4, 3, 1, 2, 5, 4]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)]
    uniform token subdivisionScheme = "catmullClark"
    color3f[] primvars:displayColor = [(1, 0, 0), (0, 0.5, 1)] (interpolation = "uniform")
    point3f[] primvars:rest = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)] (interpolation = "vertex")
    float[] primvars:side = [0, 0, 0, 0, 1, 1, 1, 1] (interpolation = "faceVarying")
    float primvars:gloss = 0.25
    %s
}
"""


def test_subdivision_mesh_refines_uniform_vertex_face_varying_and_constant_primvars(tmp_path):
    stage = open_stage(tmp_path, SUBDIVISION_MESH % "")
    names = ("displayColor", "rest", "side", "gloss")
    surface = read(stage, "/mesh", names, level=2)
    assert len(surface.triangles) == 2 * 16 * 2
    primvars = surface.primvars
    assert all(primvars[name].shape[:2] == (len(surface.triangles), 3) for name in names)
    # uniform: the authored face's colour on every refined triangle of it
    colors = np.asarray([(1, 0, 0), (0, 0.5, 1)], np.float32)
    np.testing.assert_array_equal(primvars["displayColor"], np.repeat(colors[surface.triangle_face][:, None], 3, axis=1))
    assert np.bincount(surface.triangle_face).tolist() == [32, 32]
    # vertex: refined and limited like the points (the rest position is the points)
    np.testing.assert_allclose(primvars["rest"], surface.points[surface.triangles], atol=1e-6)
    # faceVarying: each face's own value throughout it (a seam between them)
    np.testing.assert_allclose(primvars["side"][:, :, 0],
                               np.repeat(surface.triangle_face[:, None].astype(float), 3, axis=1), atol=1e-6)
    np.testing.assert_array_equal(primvars["gloss"], np.full((64, 3, 1), 0.25, np.float32))
    assert primvars["gloss"].strides[:2] == (0, 0)


def test_left_handed_subdivision_mesh_keeps_its_primvars_on_their_faces(tmp_path):
    stage = open_stage(tmp_path, SUBDIVISION_MESH % 'uniform token orientation = "leftHanded"')
    surface = read(stage, "/mesh", ("displayColor", "rest", "side"), level=1)
    colors = np.asarray([(1, 0, 0), (0, 0.5, 1)], np.float32)
    np.testing.assert_array_equal(surface.primvars["displayColor"][:, 0], colors[surface.triangle_face])
    np.testing.assert_allclose(surface.primvars["rest"], surface.points[surface.triangles], atol=1e-6)
    np.testing.assert_allclose(surface.primvars["side"][:, :, 0],
                               np.repeat(surface.triangle_face[:, None].astype(float), 3, axis=1), atol=1e-6)


def test_subdivision_mesh_read_with_its_uvs_and_primvars_refines_both(tmp_path):
    stage = open_stage(tmp_path, SUBDIVISION_MESH % '''
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1)] (interpolation = "vertex")
    ''')
    surface = read(stage, "/mesh", ("rest",), level=1)
    np.testing.assert_allclose(surface.uvs, surface.points[surface.triangles][:, :, :2], atol=1e-9)
    assert surface.uvs.dtype == np.float64
    np.testing.assert_allclose(surface.primvars["rest"], surface.points[surface.triangles], atol=1e-6)


def test_pyramid_uniform_displaycolor_reaches_the_refined_triangles_of_each_face(shared_scenes):
    asset = shared_scenes / "usd-wg/full_assets/SubdivisionSurfaces/Pyramid/Pyramid.usd"
    stage = Usd.Stage.Open(str(asset))
    prim = stage.GetPrimAtPath("/Pyramid/geo/shape")
    assert prim.GetAttribute("subdivisionScheme").Get() == "catmullClark"
    authored = np.asarray(UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor").ComputeFlattened(TIME), np.float32)
    assert authored.shape == (24, 3)
    diagnostics = RecordingDiagnostics()
    surface = read_mesh(prim, TIME, "st", diagnostics, str(asset), subdiv_level=2, primvars=("displayColor",))
    values = surface.primvars["displayColor"]
    assert len(surface.triangles) == 24 * 16 * 2 and values.shape == (24 * 32, 3, 3)
    for face in range(24):
        mine = values[surface.triangle_face == face]
        assert len(mine) == 32
        np.testing.assert_array_equal(mine, np.broadcast_to(authored[face], mine.shape))


# --- placement --------------------------------------------------------------------------------


def test_placement_shares_primvars_between_instances_and_keeps_constants_views(tmp_path):
    colors = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.25, 1)]
    authored = ", ".join(str(c) for c in colors)
    stage = polygon_stage(tmp_path, f'''
        color3f[] primvars:displayColor = [{authored}] (interpolation = "vertex")
        float primvars:gloss = 0.5
        float[] primvars:rough = [0.25, 0.75] (interpolation = "uniform")
    ''')
    prepared = prepare_surface(read(stage, "/mesh", ("displayColor", "gloss", "rough")))
    material = np.zeros(3, INDEX)
    first = place_surface(prepared, np.eye(4), 1.0, material, "a", "/a", Diagnostics())
    shifted = np.eye(4)
    shifted[:3, 3] = (5, 0, 0)
    second = place_surface(prepared, shifted, 1.0, material, "b", "/b", Diagnostics(), instance=1)
    for name in ("displayColor", "gloss", "rough"):
        assert first.primvars[name] is second.primvars[name]
        assert not first.primvars[name].flags.writeable
    assert first.primvars["gloss"].strides[:2] == (0, 0)
    np.testing.assert_array_equal(first.primvars["gloss"], np.full((3, 3, 1), 0.5))
    np.testing.assert_array_equal(first.primvars["rough"][:, :, 0], [[0.25] * 3, [0.25] * 3, [0.75] * 3])
    expected = [[colors[p] for p in triangle] for triangle in POLYGON_TRIANGLE_POINTS]
    np.testing.assert_array_equal(first.primvars["displayColor"], np.asarray(expected, np.float32))

    # A mirror swaps corners 1 and 2 of the triangles: the primvars go with their points.
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirrored = place_surface(prepared, mirror, 1.0, material, "m", "/m", Diagnostics())
    np.testing.assert_array_equal(mirrored.primvars["displayColor"],
                                  np.asarray(colors, np.float32)[mirrored.triangles])
    assert mirrored.primvars["gloss"].strides[:2] == (0, 0)


def test_placement_drops_the_primvars_of_degenerate_triangles(tmp_path):
    # Face 1 collapses to a line once y is squashed to 0 (a non-similarity: tested in world space).
    stage = open_stage(tmp_path, """
    def Mesh "mesh"
    {
        int[] faceVertexCounts = [3, 3]
        int[] faceVertexIndices = [0, 1, 2, 0, 1, 3]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 0, 1), (0.5, 1, 0)]
        uniform token subdivisionScheme = "none"
        float[] primvars:rough = [0.25, 0.75] (interpolation = "uniform")
        float[] primvars:weight = [0, 0.25, 0.5, 0.75] (interpolation = "vertex")
        float primvars:gloss = 0.5
    }
    """)
    surface = read(stage, "/mesh", ("rough", "weight", "gloss"))
    squash = np.diag([1.0, 0.0, 1.0, 1.0])
    mesh = place_surface(surface, squash, 1.0, np.zeros(2, INDEX), "m", "/m", Diagnostics())
    assert mesh.triangles.tolist() == [[0, 1, 2]]
    np.testing.assert_array_equal(mesh.primvars["rough"], [[[0.25]] * 3])
    np.testing.assert_array_equal(mesh.primvars["weight"][0, :, 0], [0, 0.25, 0.5])
    assert mesh.primvars["gloss"].shape == (1, 3, 1) and mesh.primvars["gloss"].strides[:2] == (0, 0)


# --- the World's column table -----------------------------------------------------------------


def _triangle_mesh(name: str, primvars: dict, offset: float = 0.0) -> Mesh:
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32) + offset
    triangles = np.array([[0, 1, 2], [1, 3, 2]], INDEX)
    return Mesh(name, f"/{name}", points, triangles, None, None, None, np.zeros(2, INDEX), primvars=primvars)


def test_world_gathers_primvars_into_columns_with_presence():
    tint_a = np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2)  # 2 components here
    tint_b = np.broadcast_to(np.float32([0.5, 0.25, 0.125]), (2, 3, 3))  # 3 there (constant)
    gloss_b = np.full((2, 3, 1), 0.75, np.float32)
    rect = Light("rect", "/rect", "rect", np.eye(4), np.ones(3))
    scene = SceneData("x.usda", 0.0, (
        _triangle_mesh("a", {"tint": tint_a}),
        _triangle_mesh("b", {"tint": tint_b, "gloss": gloss_b}, 2.0),
        _triangle_mesh("c", {}, 4.0),
    ), (), (rect,))
    world = build_world(scene)
    # sorted names; each its widest width, then a presence column
    assert world.primvar_columns == {"gloss": (0, 1), "tint": (2, 3)}
    table = world.corner_primvars
    assert table.shape == (3, 6, world.triangle_count) and table.dtype == np.float32
    assert world.triangle_count == 8  # three meshes, then the rect light's two triangles
    a, b, c, light = slice(0, 2), slice(2, 4), slice(4, 6), slice(6, 8)
    np.testing.assert_array_equal(table[:, 2:4, a], np.transpose(tint_a, (1, 2, 0)))
    np.testing.assert_array_equal(table[:, 4, a], 0.0)  # padding of the narrower tint
    np.testing.assert_array_equal(table[:, 5, a], 1.0)
    np.testing.assert_array_equal(table[:, 0:2, a], 0.0)  # no gloss: value and presence 0
    np.testing.assert_array_equal(table[:, 2:5, b], np.broadcast_to(np.float32([0.5, 0.25, 0.125])[None, :, None], (3, 3, 2)))
    np.testing.assert_array_equal(table[:, 0, b], 0.75)
    np.testing.assert_array_equal(table[:, [1, 5], b], 1.0)
    np.testing.assert_array_equal(table[:, :, c], 0.0)
    np.testing.assert_array_equal(table[:, :, light], 0.0)
    assert (world.triangle_light[light] == 0).all()

    geometry = geometry_arrays(world)
    assert geometry.corner_primvars.shape == (8, 3, 6) and geometry.corner_primvars.flags.c_contiguous
    np.testing.assert_array_equal(geometry.corner_primvars, np.moveaxis(table, -1, 0))
    np.testing.assert_array_equal(geometry.corner_primvars[0, :, 2:4], tint_a[0])


def test_world_without_primvars_keeps_an_empty_column_table():
    world = build_world(SceneData("x.usda", 0.0, (_triangle_mesh("a", {}),), (), ()))
    assert world.primvar_columns == {}
    assert world.corner_primvars.shape == (3, 0, 2) and world.corner_primvars.dtype == np.float32
    geometry = geometry_arrays(world)
    assert geometry.corner_primvars.shape == (2, 3, 0) and geometry.corner_primvars.dtype == np.float32


# --- through the reader -----------------------------------------------------------------------


@pytest.fixture
def materials_read_displaycolor(monkeypatch):
    """Every material read as if its primvar readers read displayColor (the material reader
    fills ResolvedMaterial.primvars; the mesh side is what is tested here)."""
    from pxr_layers.stage.materials import MaterialLibrary

    resolve = MaterialLibrary.resolve

    def resolve_with_primvars(self, *args, **kwargs):
        return dataclasses.replace(resolve(self, *args, **kwargs), primvars=("displayColor",))

    monkeypatch.setattr(MaterialLibrary, "resolve", resolve_with_primvars)


def test_native_instances_keep_the_displaycolor_of_their_own_root(tmp_path, materials_read_displaycolor):
    from pxr_layers.stage import load_stage

    stage = open_stage(tmp_path, """
    def Camera "Camera" {}
    class "Proto"
    {
        def Mesh "mesh"
        {
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
            point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
            uniform token subdivisionScheme = "none"
        }
    }
    def Xform "Red" (
        instanceable = true
        inherits = </Proto>
    )
    {
        color3f[] primvars:displayColor = [(1, 0, 0)]
    }
    def Xform "Blue" (
        instanceable = true
        inherits = </Proto>
    )
    {
        color3f[] primvars:displayColor = [(0, 0, 1)]
    }
    def Xform "Plain" (
        instanceable = true
        inherits = </Proto>
    )
    {
    }
    """)
    scene, _ = load_stage(stage.GetRootLayer().realPath)
    by_path = {mesh.path: mesh for mesh in scene.meshes}
    assert set(by_path) == {"/Red/mesh", "/Blue/mesh", "/Plain/mesh"}
    np.testing.assert_array_equal(by_path["/Red/mesh"].primvars["displayColor"], np.full((1, 3, 3), (1, 0, 0)))
    np.testing.assert_array_equal(by_path["/Blue/mesh"].primvars["displayColor"], np.full((1, 3, 3), (0, 0, 1)))
    assert "displayColor" not in by_path["/Plain/mesh"].primvars
