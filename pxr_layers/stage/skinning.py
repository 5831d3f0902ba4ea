"""UsdSkel: skinned point-based prims posed at the read's time code.

UsdSkel deforms a skinned prim in this order (UsdSkel "Schemas In-Depth", BindingAPI):

1. blend shapes offset the rest ``points`` (weights from the bound SkelAnimation, in-betweens
   resolved by UsdSkel.BlendShapeQuery);
2. the points are taken into bind space by ``primvars:skel:geomBindTransform`` and skinned by
   the joint influences: linear blend or dual-quaternion, as ``primvars:skel:skinningMethod``
   says (UsdSkel.SkinningQuery.ComputeSkinnedPoints honours both, and remaps a prim's own
   ``skel:joints`` order);
3. the result is in the *skeleton's* space, placed in the world by the Skeleton prim's
   local-to-world transform. The skinned prim's own xformOps (and its ancestors' below the
   Skeleton's) have no effect: that avoids transforming twice when an ancestor of both moves.

A prim with blend shapes but no joint influences keeps its own space (step 2 is skipped, as
UsdSkel.BakeSkinning does). Everything that cannot be posed is a warning and the prim renders
in rest pose: a pose that cannot be trusted should not stop a shot from rendering.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from pxr import Gf, Tf, Usd, UsdGeom, UsdSkel, Vt

from .diagnostics import Diagnostics
from .motion import transform_times
from .transforms import column_matrix

logger = logging.getLogger(__name__)

# The walk (walk.py) visits instance proxies, so skinned prims inside native instances must be
# found by the cache too.
_POPULATE_PREDICATE = Usd.TraverseInstanceProxies()

_JOINT_INDICES_ATTR = "primvars:skel:jointIndices"

# Each kind of broken skinning, as the start of the one warning that lists all its prims.
_BROKEN_SKINNING = {
    "skel-unbound": "no valid Skeleton is bound (skel:skeleton, SkelBindingAPI) to",
    "skel-not-points": "only point-based prims (meshes) are skinned, not",
    "skel-skeleton": "the bound Skeleton cannot be posed (its joints, bindTransforms or "
    "restTransforms) for",
    "skel-blend-shapes": "blend shapes (skel:blendShapes, skel:blendShapeTargets) do not fit "
    "the points of",
    "skel-influences": "joint indices or weights do not match the points or the Skeleton's "
    "joints of",
    "skel-not-finite": "the pose gives NaN or infinite points for",
    "skel-error": "UsdSkel failed to pose",
}


@dataclass(frozen=True)
class PosedPoints:
    """A skinned prim's points at the read's time and where they sit in the world.

    points            : (n, 3) float64, stage units, in the space ``world_from_points`` leaves
                        (the Skeleton's space once joints deform the prim); same order and count
                        as the prim's ``points``, so topology and primvars still apply
    world_from_points : (4, 4) float64, column convention (p_world = M @ p), stage units: the
                        bound Skeleton's local-to-world, or the prim's own for a prim deformed
                        by blend shapes only. Use it *instead of* the prim's world transform.
                        It is the stage's own transform (UsdGeom.XformCache): a prim inside a
                        PointInstancer prototype still needs its instance's placement.
    """

    points: np.ndarray
    world_from_points: np.ndarray


@dataclass(frozen=True)
class _SkinnedPrim:
    """How one prim is skinned: its skinning query and the Skeleton driving it."""

    skinning_query: UsdSkel.SkinningQuery
    skeleton: UsdSkel.Skeleton


class SkinnedPoser:
    """Skinned prims of one stage posed at one time code (UsdSkel.Cache + skinning queries).

    Built once per stage read. Each SkelRoot is populated into the cache, and its bindings
    resolved, the first time a prim under it is asked for (so a stage without skeletons pays
    one ancestor walk per prim and nothing else); each Skeleton's skinning transforms are
    computed once and shared by the prims it drives.
    """

    def __init__(
        self,
        stage: Usd.Stage,
        time: Usd.TimeCode,
        diagnostics: Diagnostics,
        *,
        xform_cache: UsdGeom.XformCache | None = None,
    ) -> None:
        """stage       : the stage the prims given to ``posed`` belong to (their SkelRoots are
                         found from the prims themselves, when first needed)
        xform_cache : world transforms at ``time`` to share with the caller (ReadContext's);
                      None makes a private one
        """
        del stage  # nothing to read up front: see the class docstring
        self._time = time
        self._diagnostics = diagnostics
        # world transforms per time code: the read's (shared with the caller), and the
        # shutter's steps of skinned prims that move
        self._xform_caches = {time: xform_cache if xform_cache is not None else UsdGeom.XformCache(time)}
        self._cache = UsdSkel.Cache()
        self._populated_roots: set[str] = set()
        self._skinned: dict[str, _SkinnedPrim] = {}  # prim path → binding, for populated roots
        # (Skeleton path, time code) → its skinning transforms (Vt.Matrix4dArray), None when
        # it cannot pose.
        self._skinning_transforms: dict[tuple[str, float], Vt.Matrix4dArray | None] = {}

    def posed(self, prim: Usd.Prim, time: float | None = None) -> PosedPoints | None:
        """The skinned points of ``prim`` at the read's time (or at time code `time`: a step
        of its motion over the shutter), or None to use its rest points.

        None without a warning for a prim that is not skinned (no enclosing SkelRoot, or no
        Skeleton and joint influences reach it); None after a warning (grouped per kind by
        Diagnostics) for a prim whose skinning is broken.
        """
        root = UsdSkel.Root.Find(prim)
        if not root:
            return None  # UsdSkel: bindings outside a SkelRoot have no meaning
        at = self._time if time is None else Usd.TimeCode(time)
        with Tf.DiagnosticTrap() as trap:
            try:
                self._populate(root)
                return self._pose(prim, at)
            except Tf.ErrorException as error:
                logger.debug("UsdSkel failed on %s: %s", prim.GetPath(), error)
                self._note_broken(prim, "skel-error")
                return None
            finally:
                # UsdSkel explains its refusals as Tf warnings; the grouped notes above say what
                # happened to which prim, so keep USD's wording for debugging.
                for warning in trap.GetWarnings():
                    logger.debug("UsdSkel: %s", warning.commentary)
                trap.Clear()

    def _populate(self, root: UsdSkel.Root) -> None:
        root_path = str(root.GetPath())
        if root_path in self._populated_roots:
            return
        self._populated_roots.add(root_path)
        self._cache.Populate(root, _POPULATE_PREDICATE)
        for binding in self._cache.ComputeSkelBindings(root, _POPULATE_PREDICATE):
            skeleton = binding.GetSkeleton()
            for skinning_query in binding.GetSkinningTargets():
                path = str(skinning_query.GetPrim().GetPath())
                self._skinned[path] = _SkinnedPrim(skinning_query, skeleton)

    def motion_times(self, prim: Usd.Prim, interval: Gf.Interval) -> list[float]:
        """The ends of `interval` (time codes) and every sample between them of what poses a
        skinned `prim` (posed before): its animation's joint transforms and blend shape
        weights, the transforms of its Skeleton and of the prim (and their ancestors)."""
        times = set(transform_times(prim, interval))
        skinned = self._skinned.get(str(prim.GetPath()))
        if skinned is not None:
            times.update(transform_times(skinned.skeleton.GetPrim(), interval))
            anim_query = self._cache.GetSkelQuery(skinned.skeleton).GetAnimQuery()
            if anim_query:
                times.update(anim_query.GetJointTransformTimeSamplesInInterval(interval))
                times.update(anim_query.GetBlendShapeWeightTimeSamplesInInterval(interval))
        return sorted(times)

    def _pose(self, prim: Usd.Prim, time: Usd.TimeCode) -> PosedPoints | None:
        path = str(prim.GetPath())
        skinned = self._skinned.get(path)
        if skinned is None:
            if self._has_unbound_influences(prim):
                self._note_broken(prim, "skel-unbound")
            return None
        query = skinned.skinning_query
        if not prim.IsA(UsdGeom.PointBased):
            self._note_broken(prim, "skel-not-points")
            return None
        transforms = self._transforms_of(skinned.skeleton, time)
        if transforms is None:
            self._note_broken(prim, "skel-skeleton")
            return None

        points = UsdGeom.PointBased(prim).GetPointsAttr().Get(time)
        if points is None or len(points) == 0:
            return None  # nothing to deform; surfaces.py reports an empty mesh its own way
        points = Vt.Vec3fArray(points)  # deformed in place by the calls below

        blend_shapes_fit = not query.HasBlendShapes() or self._apply_blend_shapes(
            prim, query, skinned.skeleton, points, time
        )
        if not blend_shapes_fit:
            self._note_broken(prim, "skel-blend-shapes")
            return None

        if query.HasJointInfluences():
            if not query.ComputeSkinnedPoints(transforms, points, time):
                self._note_broken(prim, "skel-influences")
                return None
            placed = skinned.skeleton.GetPrim()
        else:
            placed = prim
        if time not in self._xform_caches:
            self._xform_caches[time] = UsdGeom.XformCache(time)
        world_from_points = self._xform_caches[time].GetLocalToWorldTransform(placed)

        posed_points = np.array(points, dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(posed_points).all():
            self._note_broken(prim, "skel-not-finite")
            return None
        return PosedPoints(posed_points, column_matrix(world_from_points))

    def _transforms_of(self, skeleton: UsdSkel.Skeleton, time: Usd.TimeCode) -> Vt.Matrix4dArray | None:
        """The Skeleton's skinning transforms at `time` (skeleton space), or None."""
        key = (str(skeleton.GetPath()), time.GetValue())
        if key not in self._skinning_transforms:
            transforms = None
            skeleton_query = self._cache.GetSkelQuery(skeleton)
            # The Python binding returns the array even when the computation failed (no bind
            # pose: the transforms then lack the inverse bind), so check what it depends on.
            if skeleton_query and skeleton_query.HasBindPose():
                computed = skeleton_query.ComputeSkinningTransforms(time)
                if len(computed) == len(skeleton_query.GetJointOrder()) and len(computed) > 0:
                    transforms = computed
            self._skinning_transforms[key] = transforms
        return self._skinning_transforms[key]

    def _apply_blend_shapes(
        self,
        prim: Usd.Prim,
        query: UsdSkel.SkinningQuery,
        skeleton: UsdSkel.Skeleton,
        points: Vt.Vec3fArray,
        time: Usd.TimeCode,
    ) -> bool:
        """Offset ``points`` in place by the prim's blend shapes at `time`; False when they do
        not fit."""
        anim_query = self._cache.GetSkelQuery(skeleton).GetAnimQuery()
        if not anim_query:
            return True  # no animation, so every weight is 0: the rest shape
        weights = anim_query.ComputeBlendShapeWeights(time)
        if not weights:
            return True
        mapper = query.GetBlendShapeMapper()
        # From the animation's skel:blendShapes order to the prim's; unmapped shapes weigh 0.
        prim_weights = mapper.Remap(weights) if mapper and not mapper.IsNull() else weights
        if not prim_weights:
            return True
        shapes = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(prim))
        # In-betweens: each shape's weight becomes weights of its sub-shapes (UsdSkel schemas).
        sub_shape_weights, blend_shape_indices, sub_shape_indices = shapes.ComputeSubShapeWeights(
            Vt.FloatArray(prim_weights)
        )
        return shapes.ComputeDeformedPoints(
            sub_shape_weights,
            blend_shape_indices,
            sub_shape_indices,
            shapes.ComputeBlendShapePointIndices(),
            shapes.ComputeSubShapePointOffsets(),
            points,
        )

    def _has_unbound_influences(self, prim: Usd.Prim) -> bool:
        """True when ``prim`` asks to be skinned (joint influences reach it) but is in no
        binding: its skel:skeleton is missing or invalid, or SkelBindingAPI is not applied."""
        skinning_query = self._cache.GetSkinningQuery(prim)
        if skinning_query and skinning_query.HasJointInfluences():
            return True
        indices = prim.GetAttribute(_JOINT_INDICES_ATTR)
        return bool(indices and indices.HasAuthoredValue() and len(indices.Get(self._time) or []))

    def _note_broken(self, prim: Usd.Prim, kind: str) -> None:
        template = f"{_BROKEN_SKINNING[kind]} these prims, which render in rest pose: {{prims}}"
        self._diagnostics.note(kind, template, str(prim.GetPath()))
