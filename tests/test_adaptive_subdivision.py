"""Subdivision levels from the projected size: a level per mesh so that refined edges span a
few pixels through the render camera, bounded by the scene's subdivision budget.

The stages here see Catmull-Clark unit cubes through a 50 mm pinhole whose 24 × 18 mm aperture
has the image's aspect (640 × 480), so a pixel is 24 / 640 / 50 = 0.00075 of the distance
whatever the conform policy. A cube's refined mesh has 12 · 4^level triangles (6 quads, each
split in four per level, two triangles a quad): its level is read back from that count.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom

from pxr_layers.stage import budgets, open_shot, reader
from pxr_layers.stage.subdivision import OFF_VIEW_LEVEL, TARGET_EDGE_PIXELS, refine

RESOLUTION = (640, 480)
PIXEL_PER_METRE = 24.0 / RESOLUTION[0] / 50.0  # a pixel's size at 1 m, in metres
CUBE_POINTS = [(-0.5, -0.5, -0.5), (0.5, -0.5, -0.5), (-0.5, 0.5, -0.5), (0.5, 0.5, -0.5),
               (-0.5, -0.5, 0.5), (0.5, -0.5, 0.5), (-0.5, 0.5, 0.5), (0.5, 0.5, 0.5)]
CUBE_COUNTS = [4] * 6
CUBE_INDICES = [0, 4, 6, 2, 0, 1, 5, 4, 4, 5, 7, 6, 3, 7, 5, 1, 6, 7, 3, 2, 2, 3, 1, 0]


def new_stage(tmp_path) -> Usd.Stage:
    """A metre, Y-up stage with a camera at the origin looking down −Z."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "cubes.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.CreateFocalLengthAttr(50.0)
    camera.CreateHorizontalApertureAttr(24.0)
    camera.CreateVerticalApertureAttr(18.0)
    return stage


def define_cube(stage: Usd.Stage, path: str, centre: tuple[float, float, float], *, scheme: str | None = None,
                normals: str | None = None) -> UsdGeom.Mesh:
    """The Catmull-Clark unit cube cage (subdivisionScheme left to its default unless given),
    with +Z vertex normals authored as ``normals`` ("normals" or "primvars:normals") if given."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(CUBE_POINTS)
    mesh.CreateFaceVertexCountsAttr(CUBE_COUNTS)
    mesh.CreateFaceVertexIndicesAttr(CUBE_INDICES)
    if scheme is not None:
        mesh.CreateSubdivisionSchemeAttr(scheme)
    values = [(0.0, 0.0, 1.0)] * len(CUBE_POINTS)
    if normals == "normals":
        mesh.CreateNormalsAttr(values)
    elif normals == "primvars:normals":
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray,
                                                UsdGeom.Tokens.vertex).Set(values)
    UsdGeom.Xformable(mesh).AddTranslateOp().Set(Gf.Vec3d(*centre))
    return mesh


def read(stage: Usd.Stage, subdiv_level: int | None = None):
    stage.GetRootLayer().Save()
    shot = open_shot(stage.GetRootLayer().realPath)
    spec = shot.spec(None, shot.recipe(check_colour=False), resolution=RESOLUTION)
    return shot.scene(spec, subdiv_level=subdiv_level)


def cube_levels(scene) -> dict[str, int]:
    """{mesh path: its refinement level}, from 12 · 4^level triangles."""
    levels = {}
    for mesh in scene.meshes:
        level = math.log(len(mesh.triangles) / 12, 4)
        assert level == round(level), (mesh.path, len(mesh.triangles))
        levels[mesh.path] = round(level)
    return levels


def projected_edges(mesh) -> np.ndarray:
    """(3t,) pixel lengths of the triangles' edges through the pinhole (x, y)/−z."""
    points = mesh.points.astype(np.float64)
    image = points[:, :2] / -points[:, 2:3] / PIXEL_PER_METRE
    corners = image[mesh.triangles]
    return np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).reshape(-1)


def test_the_level_grows_with_the_projected_size(tmp_path):
    stage = new_stage(tmp_path)
    # The same cube at 16 m, 32 m and 64 m in front, and so far that its cage spans 3 pixels.
    for name, distance in (("near", 16.0), ("middle", 32.0), ("far", 64.0), ("tiny", 500.0)):
        define_cube(stage, f"/{name}", (0.0, 0.0, -distance))
    scene = read(stage)
    levels = cube_levels(scene)
    # Each halving of the distance doubles the projected size: one more level.
    assert levels["/near"] == levels["/middle"] + 1 == levels["/far"] + 2
    assert levels["/far"] >= 1 and levels["/tiny"] == 0
    for mesh in scene.meshes:
        if levels[mesh.path]:  # refined: the refined edges are at most the target on the image
            assert projected_edges(mesh).max() <= TARGET_EDGE_PIXELS, mesh.path


def test_a_coarse_cube_has_a_smooth_silhouette(tmp_path):
    """The refined surface (its vertices on the limit surface) misses the limit surface by
    less than a pixel between its vertices: the chord error of every refined edge, measured
    against the limit surface refined 3 levels further (its vertices 1/8 of an edge apart,
    which can overstate the error by a sixteenth of an edge, a quarter pixel)."""
    stage = new_stage(tmp_path)
    distance = 60.0  # the cage's edge spans 22 pixels
    define_cube(stage, "/cube", (0.0, 0.0, -distance))
    scene = read(stage)
    (mesh,) = scene.meshes
    (level,) = cube_levels(scene).values()
    assert level >= 2, "the cage's silhouette is a polygon at the render's resolution"
    reference = refine(np.array(CUBE_POINTS), np.array(CUBE_COUNTS), np.array(CUBE_INDICES), level + 3)
    limit = reference.points + (0.0, 0.0, -distance)
    corners = mesh.points.astype(np.float64)[mesh.triangles]
    midpoints = ((corners + np.roll(corners, 1, axis=1)) / 2).reshape(-1, 3)
    squared = (limit ** 2).sum(axis=1)
    sag = np.sqrt(np.maximum(np.concatenate([
        (chunk ** 2).sum(axis=1) + (squared[None, :] - 2 * chunk @ limit.T).min(axis=1)
        for chunk in np.array_split(midpoints, 16)]), 0.0))
    nearest = distance - 0.5
    assert sag.max() / (nearest * PIXEL_PER_METRE) < 1.0


def test_meshes_out_of_view_get_few_levels(tmp_path):
    stage = new_stage(tmp_path)
    define_cube(stage, "/front", (0.0, 0.0, -4.0))
    define_cube(stage, "/behind", (0.0, 0.0, 4.0))
    define_cube(stage, "/beside", (-4.0, 0.0, 0.0))
    levels = cube_levels(read(stage))
    assert levels["/front"] > OFF_VIEW_LEVEL
    # Still a rounded shape for reflections and shadows, not the cage.
    assert levels["/behind"] == levels["/beside"] == OFF_VIEW_LEVEL


def test_an_explicit_level_is_uniform(tmp_path):
    stage = new_stage(tmp_path)
    define_cube(stage, "/near", (0.0, 0.0, -4.0))
    define_cube(stage, "/far", (0.0, 0.0, -400.0))
    assert cube_levels(read(stage, subdiv_level=1)) == {"/near": 1, "/far": 1}


def test_copies_of_one_surface_share_the_nearest_copys_level(tmp_path):
    stage = new_stage(tmp_path)
    define_cube(stage, "/Prototypes/asset/cube", (0.0, 0.0, 0.0))
    stage.GetPrimAtPath("/Prototypes").SetSpecifier(Sdf.SpecifierClass)
    for name, distance in (("near", 16.0), ("far", 128.0)):
        copy = stage.DefinePrim(f"/{name}", "Xform")
        copy.GetReferences().AddInternalReference("/Prototypes/asset")
        copy.SetInstanceable(True)
        UsdGeom.Xformable(copy).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, -distance))
    levels = list(cube_levels(read(stage)).values())
    alone = new_stage(tmp_path / "alone")
    define_cube(alone, "/near", (0.0, 0.0, -16.0))
    assert levels == list(cube_levels(read(alone)).values()) * 2  # one surface, refined for the near copy


def test_the_budget_lowers_the_highest_levels_first():
    triangles = {"big": [100 * 4 ** level for level in range(7)], "small": [10 * 4 ** level for level in range(7)]}
    # Both fit: nothing changes.
    assert budgets.fit_subdivision_levels({"big": 2, "small": 3}, triangles, budget=10_000) == {"big": 2, "small": 3}
    # 1600 + 640 > 2000: the highest (small, 3) goes first, and that is enough.
    assert budgets.fit_subdivision_levels({"big": 2, "small": 3}, triangles, budget=2000) == {"big": 2, "small": 2}
    # At one level the one with the most triangles goes first.
    assert budgets.fit_subdivision_levels({"big": 2, "small": 2}, triangles, budget=1000) == {"big": 1, "small": 2}
    # Never below the cage, even past the budget.
    assert budgets.fit_subdivision_levels({"big": 1, "small": 1}, triangles, budget=10) == {"big": 0, "small": 0}


def test_the_scene_keeps_within_its_subdivision_budget(tmp_path, monkeypatch):
    budget = 5000
    stage = new_stage(tmp_path)
    define_cube(stage, "/near", (0.0, 0.0, -16.0))
    define_cube(stage, "/far", (0.0, 0.0, -64.0))
    wanted = cube_levels(read(stage))
    monkeypatch.setattr(reader, "fit_subdivision_levels",
                        functools.partial(budgets.fit_subdivision_levels, budget=budget))
    scene = read(stage)
    levels = cube_levels(scene)
    assert 12 * sum(4 ** level for level in wanted.values()) > budget  # the test means something
    assert sum(len(mesh.triangles) for mesh in scene.meshes) <= budget
    assert levels["/far"] == wanted["/far"] and levels["/near"] < wanted["/near"]
    (warning,) = [text for text in scene.warnings if "fewer levels" in text]
    assert "/near" in warning and "/far" not in warning


@pytest.mark.parametrize("normals", ["normals", "primvars:normals"])
def test_authored_normals_on_a_subdividing_mesh_are_warned_of(tmp_path, normals):
    stage = new_stage(tmp_path)
    define_cube(stage, "/default_scheme", (0.0, 0.0, -4.0), normals=normals)
    define_cube(stage, "/polygons", (2.0, 0.0, -4.0), scheme="none", normals=normals)
    define_cube(stage, "/no_normals", (-2.0, 0.0, -4.0))
    (warning,) = [text for text in read(stage).warnings if "authored normals are ignored" in text]
    assert "/default_scheme" in warning and 'subdivisionScheme = "none"' in warning
    assert "/polygons" not in warning and "/no_normals" not in warning


def test_the_index_records_automatic_levels_as_minus_one(tmp_path):
    from pxr_layers.jobs.frame import plan_frame
    from pxr_layers.paths.reader import AUTOMATIC_SUBDIV_LEVEL
    from pxr_layers.request import RenderRequest

    stage = new_stage(tmp_path)
    define_cube(stage, "/cube", (0.0, 0.0, -4.0))
    stage.GetRootLayer().Save()
    path = stage.GetRootLayer().realPath
    automatic = plan_frame(RenderRequest(stage=path, spp=1, resolution=(8, 8)), None, directory=tmp_path)
    explicit = plan_frame(RenderRequest(stage=path, spp=1, resolution=(8, 8), subdiv_level=3), None,
                          directory=tmp_path)
    assert automatic.manifest["subdiv_level"] == AUTOMATIC_SUBDIV_LEVEL == -1
    assert explicit.manifest["subdiv_level"] == 3
