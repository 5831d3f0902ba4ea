"""stage/skinning: UsdSkel-posed points against UsdSkel's own reference, UsdSkel.BakeSkinning.

The reference bakes a copy of the stage (a new stage on the same root layer, writing into its
session layer, so the stage under test is untouched) and reads the baked points through the
ordinary UsdGeom path: XformCache local-to-world @ baked points. The poser must put the same
points in the same place: world_from_points @ posed.points.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.skinning import PosedPoints, SkinnedPoser

logger = logging.getLogger(__name__)

ELEPHANT_THUMBNAIL = "usd-wg/full_assets/ElephantWithMonochord/SoC-ElephantWithMonochord_thumbnail.usda"
# Agreement with the bake, relative to the size of the posed mesh: both run UsdSkel's float32
# kernels, so what is left is the float32 rounding of points and transforms.
RELATIVE_TOLERANCE = 1e-5
MESH_PATH = "/Char/Mesh"


def skinned_stage(
    method: str = "classicLinear",
    *,
    blend_shapes: bool = False,
    rigid: bool = False,
    mesh_joint_order: bool = False,
    joint_influences: bool = True,
) -> Usd.Stage:
    """A SkelRoot (translated) with a 2-joint Skeleton (rotating over time) and a 2x5-point
    strip bound to it; the mesh's own translate must be ignored by skinning. The animation has
    samples at 0, 5, 10; frames 0..10 are the playback frames UsdSkel.BakeSkinning bakes."""
    stage = Usd.Stage.CreateInMemory()
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(10)
    root = UsdSkel.Root.Define(stage, "/Char")
    root.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    skeleton = UsdSkel.Skeleton.Define(stage, "/Char/Skel")
    rotate = skeleton.AddRotateYOp()
    rotate.Set(0.0, 0)
    rotate.Set(30.0, 10)  # the Skeleton's own transform moves too: world_from_points follows
    joints = ["Hip", "Hip/Knee"]
    knee_offset = Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 1, 0))
    skeleton.CreateJointsAttr(joints)
    skeleton.CreateBindTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1), knee_offset]))
    skeleton.CreateRestTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1), knee_offset]))

    animation = UsdSkel.Animation.Define(stage, "/Char/Skel/Anim")
    animation.CreateJointsAttr(joints)
    for frame in (0, 5, 10):
        half_angle = np.radians(9.0 * frame) / 2
        animation.CreateTranslationsAttr().Set(Vt.Vec3fArray([(0.1 * frame, 0, 0), (0, 1, 0)]), frame)
        knee = Gf.Quatf(float(np.cos(half_angle)), 0, 0, float(np.sin(half_angle)))
        animation.CreateRotationsAttr().Set(Vt.QuatfArray([Gf.Quatf(1), knee]), frame)
        animation.CreateScalesAttr().Set(Vt.Vec3hArray([(1, 1, 1), (1, 1, 1)]), frame)
    UsdSkel.BindingAPI.Apply(skeleton.GetPrim()).CreateAnimationSourceRel().SetTargets([animation.GetPath()])

    mesh = UsdGeom.Mesh.Define(stage, MESH_PATH)
    mesh.AddTranslateOp().Set(Gf.Vec3d(5, 5, 5))
    points = [(x, y, 0.0) for y in (0.0, 0.5, 1.0, 1.5, 2.0) for x in (-0.2, 0.2)]
    mesh.CreatePointsAttr(Vt.Vec3fArray(points))
    mesh.CreateFaceVertexCountsAttr([4] * 4)
    mesh.CreateFaceVertexIndicesAttr([i for row in range(4) for i in (2 * row, 2 * row + 1, 2 * row + 3, 2 * row + 2)])
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skeleton.GetPath()])
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0.1, 0)))
    binding.CreateSkinningMethodAttr(method)
    if joint_influences:
        if rigid:
            binding.CreateJointIndicesPrimvar(constant=True, elementSize=2).Set([0, 1])
            binding.CreateJointWeightsPrimvar(constant=True, elementSize=2).Set([0.5, 0.5])
        else:
            knee_weights = [min(max(y - 0.5, 0.0), 1.0) for _, y, _ in points]
            indices = [0, 1] * len(points)
            if mesh_joint_order:  # the mesh lists the joints the other way round
                binding.CreateJointsAttr(["Hip/Knee", "Hip"])
                indices = [1, 0] * len(points)
            binding.CreateJointIndicesPrimvar(constant=False, elementSize=2).Set(indices)
            binding.CreateJointWeightsPrimvar(constant=False, elementSize=2).Set(
                [w for knee in knee_weights for w in (1.0 - knee, knee)]
            )
    if blend_shapes:
        shape = UsdSkel.BlendShape.Define(stage, f"{MESH_PATH}/Tip")
        shape.CreateOffsetsAttr(Vt.Vec3fArray([(0, 0, 0.3), (0, 0, -0.3)]))
        shape.CreatePointIndicesAttr(Vt.IntArray([8, 9]))
        halfway = shape.CreateInbetween("halfway")
        halfway.SetWeight(0.5)
        halfway.SetOffsets(Vt.Vec3fArray([(0.1, 0, 0), (-0.1, 0, 0)]))
        binding.CreateBlendShapesAttr(["tip"])
        binding.CreateBlendShapeTargetsRel().SetTargets([shape.GetPath()])
        animation.CreateBlendShapesAttr(["tip"])
        for frame, weight in ((0, 0.0), (5, 0.3), (10, 1.0)):
            animation.CreateBlendShapeWeightsAttr().Set(Vt.FloatArray([weight]), frame)
    return stage


def homogeneous(points: np.ndarray) -> np.ndarray:
    return np.c_[points, np.ones(len(points))]


def posed_world_points(posed: PosedPoints) -> np.ndarray:
    """(n, 3) world positions of the posed points, stage units."""
    return (posed.world_from_points @ homogeneous(posed.points).T).T[:, :3]


def baked_world_points(stage: Usd.Stage, prim_paths: list[str], times: list[float]) -> dict:
    """{(path, time): (n, 3) world points} from UsdSkel.BakeSkinning on a copy of ``stage``."""
    reference = Usd.Stage.Open(stage.GetRootLayer())  # its own session layer: the original is untouched
    session = reference.GetSessionLayer()
    # An anonymous layer says 24 time codes per second; on a stage with another rate, samples
    # authored in it would be rescaled on reading (e.g. by 60/24 on the Elephant).
    session.timeCodesPerSecond = reference.GetTimeCodesPerSecond()
    reference.SetEditTarget(session)
    assert UsdSkel.BakeSkinning(reference.Traverse())
    baked = {}
    for frame in times:
        xform_cache = UsdGeom.XformCache(Usd.TimeCode(frame))
        for path in prim_paths:
            prim = reference.GetPrimAtPath(path)
            points = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(frame), dtype=np.float64)
            # Row-vector Gf matrix: p_world = p @ M.
            world = homogeneous(points) @ np.array(xform_cache.GetLocalToWorldTransform(prim))
            baked[path, frame] = world[:, :3]
    return baked


def assert_matches_bake(stage: Usd.Stage, prim_paths: list[str], times: list[float]) -> None:
    baked = baked_world_points(stage, prim_paths, times)
    for frame in times:
        diagnostics = Diagnostics()
        poser = SkinnedPoser(stage, Usd.TimeCode(frame), diagnostics)
        for path in prim_paths:
            prim = stage.GetPrimAtPath(path)
            posed = poser.posed(prim)
            assert posed is not None, path
            assert posed.points.dtype == np.float64 and posed.points.shape[1] == 3
            assert posed.world_from_points.shape == (4, 4)
            expected = baked[path, frame]
            size = np.abs(expected).max()
            error = np.abs(posed_world_points(posed) - expected).max()
            assert error <= RELATIVE_TOLERANCE * size, (path, frame, error, size)
            rest = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(frame), dtype=np.float64)
            assert posed.points.shape == rest.shape
        assert diagnostics.finish() == ()


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"method": "dualQuaternion"},
        {"blend_shapes": True},
        {"rigid": True},
        {"mesh_joint_order": True},
        {"blend_shapes": True, "joint_influences": False},
    ],
    ids=["linear", "dual-quaternion", "blend-shapes", "rigid", "mesh-joint-order", "blend-shapes-only"],
)
def test_posed_points_match_usdskel_bake(options):
    assert_matches_bake(skinned_stage(**options), [MESH_PATH], [3.0, 10.0])


def test_pose_moves_the_mesh_and_ignores_its_own_transform():
    """Not vacuous: the pose differs from rest, and from rest placed by the mesh's transform."""
    stage = skinned_stage()
    prim = stage.GetPrimAtPath(MESH_PATH)
    posed = SkinnedPoser(stage, Usd.TimeCode(10), Diagnostics()).posed(prim)
    rest = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(10), dtype=np.float64)
    assert np.abs(posed.points - rest).max() > 0.1
    # The skeleton sits under the SkelRoot's (1, 2, 3) and turns with its own rotateY.
    expected = UsdGeom.XformCache(Usd.TimeCode(10)).GetLocalToWorldTransform(stage.GetPrimAtPath("/Char/Skel"))
    np.testing.assert_allclose(posed.world_from_points, np.array(expected).T)


def test_skinning_method_is_honoured():
    linear = skinned_stage("classicLinear")
    dual = skinned_stage("dualQuaternion")
    pose = [SkinnedPoser(s, Usd.TimeCode(10), Diagnostics()).posed(s.GetPrimAtPath(MESH_PATH)) for s in (linear, dual)]
    assert np.abs(pose[0].points - pose[1].points).max() > 1e-3


def test_native_instances_are_posed_in_their_own_place():
    stage = skinned_stage()
    for name, offset in (("A", (0, 0, 0)), ("B", (10, 0, 0))):
        instance = stage.DefinePrim(f"/Crowd/{name}")
        instance.GetReferences().AddInternalReference("/Char")
        instance.SetInstanceable(True)
        instance.GetAttribute("xformOp:translate").Set(Gf.Vec3d(*offset))
    poser = SkinnedPoser(stage, Usd.TimeCode(5), Diagnostics())
    first, second = (poser.posed(stage.GetPrimAtPath(f"/Crowd/{name}/Mesh")) for name in "AB")
    assert stage.GetPrimAtPath("/Crowd/A/Mesh").IsInstanceProxy()
    np.testing.assert_allclose(posed_world_points(second) - posed_world_points(first), [[10, 0, 0]] * 10, atol=1e-6)


def test_prims_that_are_not_skinned_give_none_quietly():
    stage = skinned_stage()
    outside = UsdGeom.Mesh.Define(stage, "/Loose")  # no SkelRoot above it
    outside.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    inside = UsdGeom.Mesh.Define(stage, "/Char/Prop")  # under the SkelRoot, no binding
    inside.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    diagnostics = Diagnostics()
    poser = SkinnedPoser(stage, Usd.TimeCode(5), diagnostics)
    assert poser.posed(outside.GetPrim()) is None
    assert poser.posed(inside.GetPrim()) is None
    assert poser.posed(stage.GetPrimAtPath("/Char/Skel")) is None
    assert poser.posed(stage.GetPrimAtPath(MESH_PATH)) is not None
    assert diagnostics.finish() == ()


def _out_of_range_index(stage):
    indices = UsdSkel.BindingAPI(stage.GetPrimAtPath(MESH_PATH)).GetJointIndicesPrimvar()
    values = list(indices.Get())
    values[3] = 7  # the skeleton has 2 joints
    indices.Set(values)


def _too_few_influences(stage):
    binding = UsdSkel.BindingAPI(stage.GetPrimAtPath(MESH_PATH))
    binding.GetJointIndicesPrimvar().Set([0, 1] * 3)
    binding.GetJointWeightsPrimvar().Set([0.5, 0.5] * 3)


def _weights_count(stage):
    UsdSkel.BindingAPI(stage.GetPrimAtPath(MESH_PATH)).GetJointWeightsPrimvar().Set([1.0] * 4)


def _missing_skeleton(stage):
    UsdSkel.BindingAPI(stage.GetPrimAtPath(MESH_PATH)).GetSkeletonRel().SetTargets(["/Char/Nowhere"])


def _no_skeleton(stage):
    UsdSkel.BindingAPI(stage.GetPrimAtPath(MESH_PATH)).GetSkeletonRel().SetTargets([])


def _no_bind_transforms(stage):
    UsdSkel.Skeleton(stage.GetPrimAtPath("/Char/Skel")).GetBindTransformsAttr().Clear()


def _misordered_joints(stage):
    UsdSkel.Skeleton(stage.GetPrimAtPath("/Char/Skel")).GetJointsAttr().Set(["Hip/Knee", "Hip"])


def _blend_shape_past_the_points(stage):
    UsdSkel.BlendShape(stage.GetPrimAtPath(f"{MESH_PATH}/Tip")).GetPointIndicesAttr().Set(Vt.IntArray([8, 99]))


def _nan_pose(stage):
    translations = UsdSkel.Animation(stage.GetPrimAtPath("/Char/Skel/Anim")).GetTranslationsAttr()
    translations.Set(Vt.Vec3fArray([(float("nan"), 0, 0), (0, 1, 0)]), 5)


@pytest.mark.parametrize(
    "break_it, kind_words",
    [
        (_out_of_range_index, "joint indices or weights"),
        (_too_few_influences, "joint indices or weights"),
        (_weights_count, "joint indices or weights"),
        (_missing_skeleton, "no valid Skeleton is bound"),
        (_no_skeleton, "no valid Skeleton is bound"),
        (_no_bind_transforms, "the bound Skeleton cannot be posed"),
        (_misordered_joints, "the bound Skeleton cannot be posed"),
        (_blend_shape_past_the_points, "blend shapes"),
        (_nan_pose, "NaN"),
    ],
)
def test_broken_skinning_warns_and_leaves_rest_pose(break_it, kind_words):
    stage = skinned_stage(blend_shapes=True)
    break_it(stage)
    diagnostics = Diagnostics()
    poser = SkinnedPoser(stage, Usd.TimeCode(5), diagnostics)
    assert poser.posed(stage.GetPrimAtPath(MESH_PATH)) is None
    warnings = diagnostics.finish()
    assert len(warnings) == 1
    assert kind_words in warnings[0] and MESH_PATH in warnings[0] and "rest pose" in warnings[0]


@pytest.fixture(scope="module")
def elephant_stage(shared_scenes):
    """The USD-WG Elephant with Monochord (two SkelRoots, 60 time codes per second)."""
    return Usd.Stage.Open(str(shared_scenes / ELEPHANT_THUMBNAIL))


ELEPHANT_MESHES = [
    "/Elephant/Object/Elefant/Elefant1",
    "/Elephant/Object/Elefant_Monochord_Play/Monochord_Vibrator",
]


def test_elephant_matches_usdskel_bake(elephant_stage):
    # Frames on the stage's playback grid (every 2.5 time codes), which the bake samples exactly.
    assert_matches_bake(elephant_stage, ELEPHANT_MESHES, [100.0, 1000.0])


def test_elephant_unskinned_parts_and_timing(elephant_stage):
    """The monochord's base inherits empty influences from its SkelRoot: rest pose, no warning.
    Posing the whole asset (both SkelRoots populated) stays well below a frame's read time."""
    meshes = [prim for prim in elephant_stage.Traverse() if prim.IsA(UsdGeom.Mesh)]
    start = time.perf_counter()
    diagnostics = Diagnostics()
    poser = SkinnedPoser(elephant_stage, Usd.TimeCode(500), diagnostics)
    posed = {str(prim.GetPath()): poser.posed(prim) for prim in meshes}
    elapsed = time.perf_counter() - start
    logger.info("posing the Elephant's %d meshes took %.1f ms", len(meshes), elapsed * 1e3)
    assert sorted(path for path, pose in posed.items() if pose is not None) == ELEPHANT_MESHES
    assert diagnostics.finish() == ()
    assert elapsed < 0.5
