"""stage/: broken geometry is skipped with a warning naming the prim, or is an error naming
the prim and attribute (never NaN points or a traceback), and model draw modes
(UsdGeomModelAPI) replace what they should.

The walk (walk.py) is tested directly through a ReadContext; the points of what it finds are
placed with implicit.tessellate and placement.place_surface, as the reader does.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel, Vt

from pxr_layers.errors import StageError
from pxr_layers.stage.context import ReadContext
from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.draw_modes import (
    CARDS_ROOT,
    applied_draw_mode,
    author_draw_mode_cards,
    cards_pass_models,
)
from pxr_layers.shader_nodes import ShaderNode

from test_stage_materials import texture_input
from pxr_layers.stage.implicit import is_implicit, tessellate, unusable_dimension
from pxr_layers.stage.materials import MaterialLibrary
from pxr_layers.stage.placement import place_surface
from pxr_layers.stage.surfaces import read_mesh
from pxr_layers.stage.textures import TextureLibrary
from pxr_layers.stage.walk import compose_instance_transforms, walk_stage

TIME = Usd.TimeCode.Default()
NAN, INF = float("nan"), float("inf")
TEAPOT = "usd-wg/full_assets/Teapot"  # under ../shared/scenes (the shared_scenes fixture)


def new_stage() -> Usd.Stage:
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    return stage


def read_context(stage: Usd.Stage, time: Usd.TimeCode = TIME) -> ReadContext:
    return ReadContext(stage=stage, time=time, meters_per_unit=1.0, up_axis="Y",
                       xform_cache=UsdGeom.XformCache(time), diagnostics=Diagnostics(),
                       file="test.usda")


def walk(stage: Usd.Stage, time: Usd.TimeCode = TIME):
    """(StageContents, warnings) of one walk."""
    context = read_context(stage, time)
    contents = walk_stage(context)
    return contents, context.diagnostics.finish()


def placed_points(placement, time: Usd.TimeCode = TIME) -> np.ndarray:
    """(v, 3) world points of one placement, as the reader places them."""
    prim = placement.prim
    if is_implicit(prim):
        surface = tessellate(prim, time)
        mesh = place_surface(surface, placement.world_from_local, 1.0,
                             np.zeros(len(surface.triangles), np.int64), placement.name,
                             placement.path, Diagnostics())
        return mesh.points
    local = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(time), dtype=np.float64)
    return local @ placement.world_from_local[:3, :3].T + placement.world_from_local[:3, 3]


def paths(contents) -> list[str]:
    return sorted(placement.path for placement in contents.gprims)


def one_warning(warnings, fragment: str) -> str:
    matching = [warning for warning in warnings if fragment in warning]
    assert len(matching) == 1, warnings
    return matching[0]


# --- implicit gprims whose sizes make no surface --------------------------------------------


# Sizes of 0: a shape that is not there, skipped with a warning.
EMPTY_SIZES = [
    ("Sphere", "radius", 0.0, "radius is 0"),
    ("Cube", "size", 0.0, "size is 0"),
    ("Cylinder", "height", 0.0, "height is 0"),
    ("Cone", "radius", 0.0, "radius is 0"),
    ("Plane", "width", 0.0, "width is 0"),
]
# Sizes no shape has: an error naming the prim and the attribute.
INVALID_SIZES = [
    ("Sphere", "radius", -1.0, "radius is -1"),
    ("Sphere", "radius", NAN, "radius is nan"),
    ("Sphere", "radius", INF, "radius is inf"),
    ("Cube", "size", -2.0, "size is -2"),
    ("Cube", "size", NAN, "size is nan"),
    ("Cylinder", "radius", -1.0, "radius is -1"),
    ("Cylinder", "height", INF, "height is inf"),
    ("Cone", "height", -1.0, "height is -1"),
    ("Capsule", "radius", NAN, "radius is nan"),
    ("Capsule", "height", -1.0, "height is -1"),
    ("Plane", "length", -1.0, "length is -1"),
    ("Cylinder_1", "radiusBottom", -1.0, "radiusBottom is -1"),
    ("Capsule_1", "height", NAN, "height is nan"),
]


@pytest.mark.parametrize("type_name, attribute, value, reason", EMPTY_SIZES)
def test_implicit_gprim_of_size_zero_is_skipped_with_a_warning(type_name, attribute, value, reason):
    stage = new_stage()
    bad = stage.DefinePrim("/World/bad", type_name)
    bad.GetAttribute(attribute).Set(value)
    UsdGeom.Sphere.Define(stage, "/World/good")
    contents, warnings = walk(stage)
    assert paths(contents) == ["/World/good"]
    warning = one_warning(warnings, "/World/bad")
    assert f"/World/bad ({reason})" in warning and "skipped" in warning
    assert unusable_dimension(bad, TIME) == reason
    with pytest.raises(ValueError, match=reason):
        tessellate(bad, TIME)  # never collapsed triangles, even when called without the check
    assert np.isfinite(placed_points(contents.gprims[0])).all()


@pytest.mark.parametrize("type_name, attribute, value, reason", INVALID_SIZES)
def test_implicit_gprim_of_invalid_size_is_an_error_naming_prim_and_attribute(type_name, attribute, value, reason):
    stage = new_stage()
    bad = stage.DefinePrim("/World/bad", type_name)
    bad.GetAttribute(attribute).Set(value)
    with pytest.raises(StageError, match=f"test.usda, prim /World/bad: {reason}: a size must be") as raised:
        walk(stage)
    assert raised.value.prim == "/World/bad"
    with pytest.raises(ValueError, match=reason):
        tessellate(bad, TIME)  # never NaN points, even when called without the check


def test_tapered_shapes_need_one_radius_and_a_blocked_size_has_no_value():
    stage = new_stage()
    pointless = stage.DefinePrim("/pointless", "Cylinder_1")
    pointless.GetAttribute("radiusBottom").Set(0.0)
    pointless.GetAttribute("radiusTop").Set(0.0)
    blocked = UsdGeom.Sphere.Define(stage, "/blocked")
    blocked.CreateRadiusAttr().Block()
    contents, warnings = walk(stage)
    assert contents.gprims == []
    assert "/pointless (radiusBottom and radiusTop are 0)" in one_warning(warnings, "/pointless")
    assert "/blocked (radius has no value)" in one_warning(warnings, "/blocked")


def test_degenerate_but_valid_implicit_shapes_still_render():
    """A capsule of height 0 is a sphere; a tapered cylinder with one radius 0 is a cone."""
    stage = new_stage()
    UsdGeom.Capsule.Define(stage, "/ball").CreateHeightAttr(0.0)
    cone = stage.DefinePrim("/cone", "Cylinder_1")
    cone.GetAttribute("radiusTop").Set(0.0)
    contents, warnings = walk(stage)
    assert paths(contents) == ["/ball", "/cone"] and warnings == ()
    for placement in contents.gprims:
        points = placed_points(placement)
        assert np.isfinite(points).all() and np.ptp(points, axis=0).min() > 0.5


@pytest.mark.parametrize("bad_value", [NAN, INF])
def test_a_mesh_with_non_finite_points_is_skipped_with_a_warning_naming_it(bad_value):
    stage = new_stage()
    mesh = UsdGeom.Mesh.Define(stage, "/World/broken")
    mesh.CreatePointsAttr([(0, 0, 0), (bad_value, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    diagnostics = Diagnostics()
    assert read_mesh(mesh.GetPrim(), TIME, "st", diagnostics, "test.usda", subdiv_level=0) is None
    (warning,) = diagnostics.finish()
    assert "NaN or infinite points skipped: /World/broken (1 of 3 points)" in warning


# --- non-finite transforms ------------------------------------------------------------------


@pytest.mark.parametrize("bad_value", [NAN, INF])
def test_gprims_lights_and_instancers_under_a_non_finite_transform_are_skipped(bad_value):
    stage = new_stage()
    broken = UsdGeom.Xform.Define(stage, "/Broken")
    broken.AddTranslateOp().Set(Gf.Vec3d(bad_value, 0, 0))
    UsdGeom.Cube.Define(stage, "/Broken/cube")
    UsdLux.SphereLight.Define(stage, "/Broken/lamp")
    instancer = UsdGeom.PointInstancer.Define(stage, "/Broken/scatter")
    UsdGeom.Cube.Define(stage, "/Broken/scatter/proto")
    instancer.CreatePrototypesRel().SetTargets(["/Broken/scatter/proto"])
    instancer.CreateProtoIndicesAttr([0])
    instancer.CreatePositionsAttr([(0, 0, 0)])
    scaled = UsdGeom.Sphere.Define(stage, "/scaled")
    scaled.AddScaleOp().Set(Gf.Vec3f(1, bad_value, 1))
    UsdGeom.Sphere.Define(stage, "/fine")
    UsdLux.SphereLight.Define(stage, "/fineLamp")
    contents, warnings = walk(stage)
    assert paths(contents) == ["/fine"]
    assert [str(light.GetPath()) for light in contents.lights] == ["/fineLamp"]
    warning = one_warning(warnings, "NaN or infinite transforms")
    for path in ("/Broken/cube", "/Broken/lamp", "/Broken/scatter"):
        assert f"{path} (/Broken.xformOp:translate)" in warning  # the op at fault, on an ancestor
    assert "/scaled (xformOp:scale)" in warning  # on the prim itself
    assert np.isfinite(placed_points(contents.gprims[0])).all()


def test_prototype_part_with_a_non_finite_transform_is_skipped():
    stage = new_stage()
    instancer = UsdGeom.PointInstancer.Define(stage, "/scatter")
    UsdGeom.Xform.Define(stage, "/scatter/proto")
    UsdGeom.Cube.Define(stage, "/scatter/proto/body")
    UsdGeom.Cube.Define(stage, "/scatter/proto/arm").AddTranslateOp().Set(Gf.Vec3d(0, NAN, 0))
    instancer.CreatePrototypesRel().SetTargets(["/scatter/proto"])
    instancer.CreateProtoIndicesAttr([0, 0])
    instancer.CreatePositionsAttr([(0, 0, 0), (5, 0, 0)])
    contents, warnings = walk(stage)
    assert paths(contents) == ["/scatter/instance_0/proto/body", "/scatter/instance_1/proto/body"]
    assert "/scatter/proto/arm (xformOp:translate)" in one_warning(warnings, "NaN or infinite transforms")


# --- point instancers: unusable instances are dropped, not the instancer ---------------------


def scatter(stage, count: int = 4, prototypes: int = 1) -> UsdGeom.PointInstancer:
    """An instancer of ``count`` unit cubes 10 apart along X."""
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/scatter")
    targets = []
    for index in range(prototypes):
        UsdGeom.Cube.Define(stage, f"/World/scatter/protos/p{index}")
        targets.append(f"/World/scatter/protos/p{index}")
    instancer.CreatePrototypesRel().SetTargets(targets)
    instancer.CreateProtoIndicesAttr([0] * count)
    instancer.CreatePositionsAttr([(10 * n, 0, 0) for n in range(count)])
    return instancer


def instance_numbers(contents) -> list[int]:
    return sorted(placement.instance for placement in contents.gprims)


# breakage → (how to break instance 1, what the warning says of it)
BAD_INSTANCE_DATA = {
    "nan position": (lambda i: i.GetPositionsAttr().Set([(0, 0, 0), (NAN, 0, 0), (20, 0, 0), (30, 0, 0)]),
                     "1 with NaN or infinite positions"),
    "inf orientation": (lambda i: i.CreateOrientationsAttr(
        [Gf.Quath(1, 0, 0, 0), Gf.Quath(INF, 0, 0, 0), Gf.Quath(1, 0, 0, 0), Gf.Quath(1, 0, 0, 0)]),
        "1 with NaN or infinite orientations"),
    "nan scale": (lambda i: i.CreateScalesAttr([(1, 1, 1), (1, NAN, 1), (1, 1, 1), (1, 1, 1)]),
                  "1 with NaN or infinite scales"),
    "protoIndex too large": (lambda i: i.GetProtoIndicesAttr().Set([0, 5, 0, 0]), "1 with protoIndices out of range"),
    "negative protoIndex": (lambda i: i.GetProtoIndicesAttr().Set([0, -1, 0, 0]), "1 with protoIndices out of range"),
}


@pytest.mark.parametrize("breakage", sorted(BAD_INSTANCE_DATA))
def test_one_bad_instance_is_dropped_and_the_rest_render(breakage):
    stage = new_stage()
    breaking, said = BAD_INSTANCE_DATA[breakage]
    breaking(scatter(stage))
    contents, warnings = walk(stage)
    assert instance_numbers(contents) == [0, 2, 3]
    warning = one_warning(warnings, "/World/scatter")
    assert warning.startswith("dropped 1 point instances") and f"/World/scatter (1 of 4 instances: {said})" in warning
    for placement in contents.gprims:
        points = placed_points(placement)
        assert np.isfinite(points).all()
        assert points[:, 0].mean() == pytest.approx(10 * placement.instance, abs=1e-6)


def test_arrays_shorter_than_proto_indices_drop_the_instances_they_do_not_reach():
    stage = new_stage()
    instancer = scatter(stage, count=5)
    instancer.GetPositionsAttr().Set([(10 * n, 0, 0) for n in range(4)])
    quarter_turn = Gf.Quath(math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4))
    instancer.CreateOrientationsAttr([quarter_turn] * 3)
    instancer.CreateScalesAttr([(2, 2, 2)] * 5)
    contents, warnings = walk(stage)
    assert instance_numbers(contents) == [0, 1, 2]
    warning = one_warning(warnings, "/World/scatter")
    assert warning.startswith("dropped 2 point instances")
    assert "(2 of 5 instances: 1 past the 4 positions, 2 past the 3 orientations)" in warning
    by_instance = {placement.instance: placement for placement in contents.gprims}
    # the survivors keep their rotation and scale (composed here: USD refuses ragged arrays)
    np.testing.assert_allclose(by_instance[1].world_from_local[:3, :3],
                               [[0, -2, 0], [2, 0, 0], [0, 0, 2]], atol=1e-3)
    np.testing.assert_allclose(by_instance[1].world_from_local[:3, 3], [10, 0, 0])


def test_arrays_longer_than_proto_indices_are_cut_with_a_warning():
    stage = new_stage()
    instancer = scatter(stage, count=2)
    instancer.GetPositionsAttr().Set([(0, 0, 0), (10, 0, 0), (20, 0, 0)])
    contents, warnings = walk(stage)
    assert instance_numbers(contents) == [0, 1]
    assert "/World/scatter" in one_warning(warnings, "more positions, orientations or scales")


def test_an_instancer_without_any_usable_instance_is_skipped_with_its_own_warning():
    stage = new_stage()
    instancer = scatter(stage, count=3)
    instancer.GetPositionsAttr().Set([(NAN, 0, 0)] * 3)
    UsdGeom.Sphere.Define(stage, "/World/fine")
    contents, warnings = walk(stage)
    assert paths(contents) == ["/World/fine"]
    warning = one_warning(warnings, "/World/scatter")
    assert "none of whose instances has usable data" in warning
    assert not any(warning.startswith("dropped") for warning in warnings)


def test_invisible_instances_are_not_counted_as_dropped():
    stage = new_stage()
    instancer = scatter(stage, count=3)
    instancer.CreateInvisibleIdsAttr([2])
    contents, warnings = walk(stage)
    assert instance_numbers(contents) == [0, 1] and warnings == ()


def test_composed_instance_transforms_match_usd(rng):
    """The fallback composition (ragged data) against USD's own, on valid data."""
    stage = new_stage()
    count = 16
    instancer = scatter(stage, count=count, prototypes=2)
    root = UsdGeom.Xformable(stage.GetPrimAtPath("/World/scatter/protos/p1"))
    root.AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    root.AddRotateXYZOp().Set(Gf.Vec3f(10, 20, 30))
    proto_indices = rng.integers(0, 2, count)
    positions = rng.normal(size=(count, 3)) * 5
    quaternions = rng.normal(size=(count, 4))  # (i, j, k, real), not normalised (nor by USD)
    scales = rng.uniform(0.5, 2.0, size=(count, 3))
    instancer.GetProtoIndicesAttr().Set(Vt.IntArray(proto_indices.tolist()))
    instancer.GetPositionsAttr().Set(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    instancer.CreateOrientationsfAttr(Vt.QuatfArray([Gf.Quatf(float(q[3]), *map(float, q[:3]))
                                                     for q in quaternions]))
    instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(scales.astype(np.float32)))
    expected = np.asarray(instancer.ComputeInstanceTransformsAtTime(
        TIME, TIME, UsdGeom.PointInstancer.IncludeProtoXform)).transpose(0, 2, 1)
    roots = np.stack([np.eye(4), np.array(root.GetLocalTransformation(TIME)).T])
    composed = compose_instance_transforms(
        positions.astype(np.float32).astype(np.float64),
        np.asarray(instancer.GetOrientationsfAttr().Get(TIME), dtype=np.float64),
        scales.astype(np.float32).astype(np.float64), roots, proto_indices,
        np.ones(count, dtype=bool))
    np.testing.assert_allclose(composed, expected, atol=1e-5)


# --- skinning is another module's business now ------------------------------------------------


def test_skinned_meshes_get_no_rest_pose_warning_from_the_walk():
    stage = new_stage()
    mesh = UsdGeom.Mesh.Define(stage, "/skinned")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateJointIndicesPrimvar(constant=True).Set([0])
    binding.CreateJointWeightsPrimvar(constant=True).Set([1.0])
    contents, warnings = walk(stage)
    assert paths(contents) == ["/skinned"] and warnings == ()


# --- draw modes -------------------------------------------------------------------------------


def model(stage, path: str, kind: str = Kind.Tokens.component, mode: str | None = None,
          **attributes) -> Usd.Prim:
    """An Xform model with GeomModelAPI; ``attributes`` by their name after ``model:``."""
    prim = UsdGeom.Xform.Define(stage, path).GetPrim()
    Usd.ModelAPI(prim).SetKind(kind)
    api = UsdGeom.ModelAPI.Apply(prim)
    if mode is not None:
        api.CreateModelDrawModeAttr(mode)
    for name, value in attributes.items():
        prim.GetAttribute(f"model:{name}").Set(value)
    return prim


def teapot_stage(mode: str, **attributes) -> Usd.Stage:
    """/World (group) > /World/pot (component, ``mode``) > a 2 × 1 × 4 box mesh at z = 5."""
    stage = new_stage()
    model(stage, "/World", Kind.Tokens.group)
    pot = model(stage, "/World/pot", mode=mode, **attributes)
    UsdGeom.Xformable(pot).AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    box = UsdGeom.Mesh.Define(stage, "/World/pot/geo")
    box.CreatePointsAttr([(-1, 0, -2), (1, 0, -2), (1, 1, 2), (-1, 1, 2)])
    box.CreateFaceVertexCountsAttr([4])
    box.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    box.CreateExtentAttr([(-1, 0, -2), (1, 1, 2)])
    return stage


def card_mesh(stage, model_name: str = "pot") -> UsdGeom.Mesh:
    return UsdGeom.Mesh(stage.GetPrimAtPath(CARDS_ROOT.AppendPath(f"{model_name}/cards")))


def world_card_quads(stage, model_name: str = "pot") -> np.ndarray:
    """(f, 4, 3) world corners of a model's cards."""
    mesh = card_mesh(stage, model_name)
    world = np.array(UsdGeom.XformCache(TIME).GetLocalToWorldTransform(mesh.GetPrim())).T
    local = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
    return (local @ world[:3, :3].T + world[:3, 3]).reshape(-1, 4, 3)


def face_materials(stage, model_name: str = "pot") -> list[str]:
    """The name of the material each card face is bound to, in face order."""
    mesh = card_mesh(stage, model_name)
    bound = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()[0]
    names = [bound.GetPrim().GetName() if bound else None] * len(mesh.GetFaceVertexCountsAttr().Get())
    for subset in UsdShade.MaterialBindingAPI(mesh.GetPrim()).GetMaterialBindSubsets():
        material = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
        for face in subset.GetIndicesAttr().Get():
            names[face] = material.GetPrim().GetName()
    return names


def texture_of(stage, material_name: str, model_name: str = "pot") -> str | None:
    material = UsdShade.Material(stage.GetPrimAtPath(
        CARDS_ROOT.AppendPath(f"{model_name}/Materials/{material_name}")))
    surface, _, _ = material.ComputeSurfaceSource()
    source = surface.GetInput("diffuseColor").GetConnectedSources()[0]
    if not source:
        return None
    return source[0].source.GetInput("file").Get().path


def test_draw_mode_applies_to_components_and_to_models_asking_for_it():
    stage = new_stage()
    world = model(stage, "/World", Kind.Tokens.group, mode="cards")
    component = model(stage, "/World/component")  # inherits cards
    declined = model(stage, "/World/declined", applyDrawMode=False)
    assembly = model(stage, "/World/assembly", Kind.Tokens.assembly, mode="bounds",
                     applyDrawMode=True)
    shown = model(stage, "/World/shown", mode="default")
    plain = UsdGeom.Xform.Define(stage, "/World/shown/notAModel").GetPrim()
    assert applied_draw_mode(world) is None  # a group: its children decide
    assert applied_draw_mode(component) == "cards"
    assert applied_draw_mode(declined) is None
    assert applied_draw_mode(assembly) == "bounds"
    assert applied_draw_mode(shown) is None
    assert applied_draw_mode(plain) is None


def test_bounds_and_origin_models_render_nothing_and_say_so():
    for mode in ("bounds", "origin"):
        stage = teapot_stage(mode)
        UsdGeom.Sphere.Define(stage, "/elsewhere")
        contents, warnings = walk(stage)
        assert paths(contents) == ["/elsewhere"]
        assert f"/World/pot ({mode})" in one_warning(warnings, "wireframe guides")


def test_default_draw_mode_renders_the_geometry():
    contents, warnings = walk(teapot_stage("default"))
    assert paths(contents) == ["/World/pot/geo"] and warnings == ()


def test_cards_without_textures_are_the_six_faces_of_the_box_in_the_draw_mode_colour():
    stage = teapot_stage("cards", cardGeometry="box", drawModeColor=Gf.Vec3f(0.2, 0.4, 0.6))
    assert author_draw_mode_cards(stage, TIME) == ("/World/pot",)
    contents, warnings = walk(stage)
    assert paths(contents) == [f"{CARDS_ROOT}/pot/cards"] and warnings == ()
    quads = world_card_quads(stage)
    assert quads.shape == (6, 4, 3)
    np.testing.assert_allclose(quads.reshape(-1, 3).min(axis=0), [-1, 0, 3])
    np.testing.assert_allclose(quads.reshape(-1, 3).max(axis=0), [1, 1, 7])
    # each face on a side of the box, facing out
    centre = np.array([0.0, 0.5, 5.0])
    for quad in quads:
        normal = np.cross(quad[1] - quad[0], quad[2] - quad[0])
        assert np.dot(normal, quad.mean(axis=0) - centre) > 0
    assert face_materials(stage) == ["color"] * 6
    material = UsdShade.Material(stage.GetPrimAtPath(f"{CARDS_ROOT}/pot/Materials/color"))
    surface, _, _ = material.ComputeSurfaceSource()
    assert tuple(surface.GetInput("diffuseColor").Get()) == pytest.approx((0.2, 0.4, 0.6))


def test_cross_cards_with_one_texture_draw_only_that_axis(tmp_path):
    image = tmp_path / "side.png"
    write_image(image)
    stage = teapot_stage("cards", cardTextureXPos=Sdf.AssetPath(str(image)))
    author_draw_mode_cards(stage, TIME)
    quads = world_card_quads(stage)
    assert quads.shape == (2, 4, 3)  # XPos and XNeg, back to back through the centre
    xs = quads[:, :, 0]
    assert np.ptp(xs, axis=1) == pytest.approx([0, 0])
    assert xs[0, 0] > 0 > xs[1, 0] and xs[0, 0] - xs[1, 0] < 0.01
    np.testing.assert_allclose(quads[0, :, 1:].min(axis=0), [0, 3], atol=1e-6)
    np.testing.assert_allclose(quads[0, :, 1:].max(axis=0), [1, 7], atol=1e-6)
    # XNeg has no texture of its own: it shows XPos's, mirrored (Storm's u flip)
    assert face_materials(stage) == ["XPos", "XPos"]
    assert texture_of(stage, "XPos") == str(image)
    st = np.asarray(UsdGeom.PrimvarsAPI(card_mesh(stage)).GetPrimvar("st").Get()).reshape(2, 4, 2)
    np.testing.assert_allclose(st[0], [(1, 1), (0, 1), (0, 0), (1, 0)])
    np.testing.assert_allclose(st[1], [(0, 1), (1, 1), (1, 0), (0, 0)])


def test_cards_are_authored_again_per_call_and_copy_purpose_and_skip_invisible_models():
    stage = teapot_stage("cards")
    author_draw_mode_cards(stage, TIME)
    hidden = model(stage, "/World/hidden", mode="cards")
    UsdGeom.Imageable(hidden).MakeInvisible()
    proxy = model(stage, "/World/proxyPot", mode="cards")
    UsdGeom.Imageable(proxy).CreatePurposeAttr(UsdGeom.Tokens.proxy)
    UsdGeom.Cube.Define(stage, "/World/proxyPot/geo")
    pot = stage.GetPrimAtPath("/World/pot")
    UsdGeom.Xformable(pot).GetOrderedXformOps()[0].Set(Gf.Vec3d(0, 0, -5))
    assert author_draw_mode_cards(stage, TIME) == ("/World/pot", "/World/proxyPot")
    assert world_card_quads(stage)[:, :, 2].max() == pytest.approx(-3)  # moved with the model
    assert [child.GetName() for child in stage.GetPrimAtPath(CARDS_ROOT).GetChildren()] == [
        "pot", "proxyPot"]
    assert UsdGeom.Imageable(stage.GetPrimAtPath(f"{CARDS_ROOT}/proxyPot")).ComputePurpose() == \
        UsdGeom.Tokens.proxy
    contents, _ = walk(stage)
    assert paths(contents) == [f"{CARDS_ROOT}/pot/cards"]  # proxy purpose does not render
    # the cards are not themselves models in a non-default draw mode
    for prim in Usd.PrimRange(stage.GetPrimAtPath(CARDS_ROOT)):
        assert applied_draw_mode(prim) is None


def test_cards_models_with_the_same_name_get_their_own_cards():
    stage = new_stage()
    model(stage, "/World", Kind.Tokens.group)
    for group in ("A", "B"):
        model(stage, f"/World/{group}", Kind.Tokens.group)
        model(stage, f"/World/{group}/tree", mode="cards")
        UsdGeom.Cube.Define(stage, f"/World/{group}/tree/geo")
    author_draw_mode_cards(stage, TIME)
    contents, _ = walk(stage)
    assert paths(contents) == [f"{CARDS_ROOT}/tree/cards", f"{CARDS_ROOT}/tree_2/cards"]


def test_cards_model_without_extent_renders_nothing_with_one_warning():
    stage = new_stage()
    model(stage, "/World", Kind.Tokens.group)
    model(stage, "/World/empty", mode="cards")
    diagnostics = Diagnostics()
    assert author_draw_mode_cards(stage, TIME, diagnostics) == ()
    assert "/World/empty" in one_warning(diagnostics.finish(), "without an extent")
    assert cards_pass_models(stage) == {"/World/empty"}
    contents, warnings = walk(stage)
    assert contents.gprims == [] and warnings == ()  # already said, not said again


def test_cards_model_whose_cards_were_never_authored_is_reported():
    contents, warnings = walk(teapot_stage("cards"))
    assert contents.gprims == []
    assert "/World/pot" in one_warning(warnings, "their cards were not authored")


def test_cards_inside_point_instancer_prototypes_render_the_full_geometry():
    stage = new_stage()
    model(stage, "/World", Kind.Tokens.group)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/scatter")
    Usd.ModelAPI(instancer.GetPrim()).SetKind(Kind.Tokens.group)
    model(stage, "/World/scatter/tree", mode="cards")
    UsdGeom.Cube.Define(stage, "/World/scatter/tree/geo")
    instancer.CreatePrototypesRel().SetTargets(["/World/scatter/tree"])
    instancer.CreateProtoIndicesAttr([0, 0])
    instancer.CreatePositionsAttr([(0, 0, 0), (3, 0, 0)])
    assert author_draw_mode_cards(stage, TIME) == ()
    contents, warnings = walk(stage)
    assert paths(contents) == [f"/World/scatter/instance_{n}/tree/geo" for n in range(2)]
    assert "/World/scatter/tree" in one_warning(warnings, "inside PointInstancer prototypes")


def write_image(path: Path, world_to_screen=None) -> None:
    """A 4 × 4 RGBA image, optionally with ``worldtoscreen`` metadata (a Gf.Matrix4d)."""
    spec = oiio.ImageSpec(4, 4, 4, oiio.FLOAT)
    if world_to_screen is not None:
        values = tuple(float(value) for row in world_to_screen for value in row)
        spec.attribute("worldtoscreen", oiio.TypeDesc("matrix"), values)
    output = oiio.ImageOutput.create(str(path))
    assert output.open(str(path), spec)
    output.write_image(np.ones((4, 4, 4), dtype=np.float32))
    output.close()


def test_from_texture_cards_are_placed_by_the_worldtoscreen_matrix(tmp_path):
    image = tmp_path / "front.exr"
    # screen = model scaled by 1/2 in x and y: the screen's corners are (±2, ±2, 0)
    write_image(image, Gf.Matrix4d().SetScale(Gf.Vec3d(0.5, 0.5, 1.0)))
    stage = teapot_stage("cards", cardGeometry="fromTexture",
                         cardTextureZPos=Sdf.AssetPath(str(image)))
    diagnostics = Diagnostics()
    author_draw_mode_cards(stage, TIME, diagnostics)
    assert diagnostics.finish() == ()
    quads = world_card_quads(stage)
    assert quads.shape == (1, 4, 3)
    np.testing.assert_allclose(quads[0], [(2, -2, 5), (-2, -2, 5), (-2, 2, 5), (2, 2, 5)], atol=1e-6)
    assert face_materials(stage) == ["ZPos"]


def test_from_texture_without_metadata_falls_back_to_box_cards(tmp_path):
    image = tmp_path / "plain.png"
    write_image(image)
    stage = teapot_stage("cards", cardGeometry="fromTexture",
                         cardTextureZPos=Sdf.AssetPath(str(image)))
    diagnostics = Diagnostics()
    author_draw_mode_cards(stage, TIME, diagnostics)
    assert "/World/pot" in one_warning(diagnostics.finish(), "drawn as box cards")
    quads = world_card_quads(stage)
    assert quads.shape == (2, 4, 3)  # ZPos and ZNeg faces of the box
    assert sorted(quads[:, 0, 2]) == pytest.approx([3, 7])


# --- the usd-wg Teapot DrawModes asset ----------------------------------------------------------


@pytest.fixture(scope="module")
def draw_modes_asset(shared_scenes):
    """The DrawModes stage with its cards authored, walked at its start time."""
    path = shared_scenes / TEAPOT / "DrawModes.usd"
    stage = Usd.Stage.Open(str(path))
    time = Usd.TimeCode(stage.GetStartTimeCode())
    diagnostics = Diagnostics()
    represented = author_draw_mode_cards(stage, time, diagnostics)
    assert diagnostics.finish() == ()
    contents, warnings = walk(stage, time)
    return stage, time, represented, contents, warnings


TEAPOTS = ["FancyTeapot"] + [f"UtahTeapot_Ceramic{colour}" for colour in
                             ("Black", "Blue", "LimeGreen", "Orange", "Red", "White")]


def test_asset_default_models_render_their_meshes(draw_modes_asset):
    _, time, _, contents, _ = draw_modes_asset
    meshes = [placement for placement in contents.gprims
              if not placement.path.startswith(str(CARDS_ROOT))]
    assert sorted(placement.path for placement in meshes) == sorted(
        f"/World/{teapot}_0/Geometry" for teapot in TEAPOTS)
    for placement in meshes:
        assert np.isfinite(placed_points(placement, time)).all()


def test_asset_cards_models_render_textured_card_quads(draw_modes_asset, shared_scenes):
    stage, time, represented, contents, _ = draw_modes_asset
    assert sorted(represented) == sorted(f"/World/{teapot}_{n}" for teapot in TEAPOTS for n in (1, 2))
    cards = sorted(placement.path for placement in contents.gprims
                   if placement.path.startswith(str(CARDS_ROOT)))
    assert cards == sorted(f"{CARDS_ROOT}/{teapot}_{n}/cards" for teapot in TEAPOTS for n in (1, 2))
    for teapot in TEAPOTS:
        variant = "Fancy" if teapot.startswith("Fancy") else "Utah"
        for n in (1, 2):
            name = f"{teapot}_{n}"
            # all six textures: three back-to-back pairs (cross) or the six box faces
            assert card_mesh(stage, name).GetFaceVertexCountsAttr().Get() == Vt.IntArray([4] * 6)
            assert face_materials(stage, name) == ["XPos", "XNeg", "YPos", "YNeg", "ZPos", "ZNeg"]
            for face in ("XPos", "XNeg", "YPos", "YNeg", "ZPos", "ZNeg"):
                assert texture_of(stage, face, name) == str(shared_scenes / TEAPOT / "cards" / variant / f"{face}.png")
    # the cards stand where the model would: the box of cards is the model's world bound
    bounds = UsdGeom.BBoxCache(time, [UsdGeom.Tokens.default_], useExtentsHint=True)
    for name in ("FancyTeapot_2", "UtahTeapot_CeramicRed_2"):
        expected = bounds.ComputeWorldBound(stage.GetPrimAtPath(f"/World/{name}")).ComputeAlignedRange()
        corners = world_card_quads(stage, name).reshape(-1, 3)
        np.testing.assert_allclose(corners.min(axis=0), expected.GetMin(), atol=1e-5)
        np.testing.assert_allclose(corners.max(axis=0), expected.GetMax(), atol=1e-5)


def test_asset_cards_read_as_textured_materials_by_the_reader(draw_modes_asset):
    """The reader's own material conversion sees the cards' materials as any other."""
    stage, time, _, _, _ = draw_modes_asset
    context = read_context(stage, time)
    materials = MaterialLibrary(context, TextureLibrary(context.diagnostics), ("full", ""))
    mesh = card_mesh(stage, "UtahTeapot_CeramicRed_1").GetPrim()
    for subset in UsdShade.MaterialBindingAPI(mesh).GetMaterialBindSubsets():
        resolved = materials.resolve(materials.bound_material(subset.GetPrim()), None)
        material = materials.materials[resolved.index]
        assert resolved.uv_primvar == "st"
        assert isinstance(material.diffuse_color, ShaderNode)
        assert texture_input(material.opacity, 1).channels == (3,)
        assert material.opacity_threshold == pytest.approx(0.1)
    assert context.diagnostics.finish() == ()


def test_asset_bounds_and_origin_models_render_nothing_and_are_listed(draw_modes_asset):
    _, _, _, contents, warnings = draw_modes_asset
    assert not any(placement.path.endswith(("_3", "_4")) or "_3/" in placement.path
                   or "_4/" in placement.path for placement in contents.gprims)
    warning = one_warning(warnings, "wireframe guides")
    assert "/World/FancyTeapot_3 (bounds)" in warning and "/World/FancyTeapot_4 (origin)" in warning
    assert warning.endswith("and 6 more")  # 14 models, 8 listed
    assert len(warnings) == 1
