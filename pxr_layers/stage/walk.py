"""Find what renders on a stage: gprim placements (instances expanded) and lights.

The walk visits instance proxies (native instances appear at their own paths), prunes
invisible subtrees, purposes the render settings do not include (all but default and
render unless they say otherwise) and models whose draw mode replaces them (draw_modes.py:
cards models are drawn as the cards authored beforehand, bounds and origin models are
guides and render nothing), and stops at gprims, cameras, point instancers and lights
(UsdGeom forbids gprims under gprims; a light's children are not lit geometry).
PointInstancers are expanded here into one placement per instance and prototype gprim.

Bad data follows one rule (see reader.read_scene). A value that is wrong wherever it is
read, an implicit shape's size that is negative, NaN or infinite, an attribute of another
type than its schema's (values.py), is an error naming the prim and the attribute: one
edit fixes it. Data that goes bad by being computed (a simulation, a constraint, a
scatter) is skipped, with one warning per kind of problem naming the prims and what is at
fault, so that one bad element among thousands does not stop a render (``--strict`` makes
the warnings fatal): gprims, lights and instancers whose world transform is not finite
(the xformOp named), and, one by one, point instances whose data is unusable (counted by
cause: NaN or infinite positions, orientations or scales, protoIndices out of range,
arrays too short; the rest of their instancer renders). Implicit gprims of size 0, which
describe a shape that is not there, are skipped with a warning too.

Every placement counts against the scene's mesh budget (budgets.MAX_SCENE_MESHES), a
PointInstancer's as soon as its protoIndices are read, before its other arrays and its
transforms: a StageError naming the instancer, not minutes of expansion.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom, UsdLux, UsdRender, UsdShade, UsdVol

from . import values
from .context import ReadContext
from .draw_modes import applied_draw_mode, cards_pass_models, is_guide_mode
from .implicit import is_implicit, unusable_dimension
from .lights import is_supported_light
from .transforms import column_matrix, transform_errors_name

_PREDICATE = Usd.TraverseInstanceProxies(
    Usd.PrimIsActive & Usd.PrimIsDefined & Usd.PrimIsLoaded & ~Usd.PrimIsAbstract
)
# Point instancers nested inside prototypes of point instancers are expanded this deep;
# deeper nesting is almost certainly a reference cycle in the data.
_MAX_INSTANCER_DEPTH = 8
# Typed prims that never hold renderable descendants.
_OPAQUE_TYPES = (
    UsdShade.NodeGraph,  # Material is a NodeGraph
    UsdShade.Shader,
    UsdGeom.Subset,
    UsdRender.SettingsBase,
    UsdRender.Product,
    UsdRender.Var,
    UsdRender.Pass,
    UsdLux.LightFilter,
)


@dataclass(frozen=True)
class GprimPlacement:
    """One gprim to turn into a scene.Mesh.

    world_from_local : (4, 4) float64, column convention, stage units
    path             : Mesh.path: the prim path, or for a point-instanced gprim
                       ``<instancer path>/instance_<N>/<prototype name>/<path below it>``
                       where N is the instance's position in the instancer's arrays
    instance         : that N as data (Mesh.instance), of the innermost instancer when
                       instancers nest; -1 for a gprim that is not point-instanced
                       (native instances included)
    instancer        : how a point instance is placed (its motion is read from it), None
                       for a gprim that is not point-instanced
    """

    prim: Usd.Prim
    world_from_local: np.ndarray
    path: str
    name: str
    instance: int = -1
    instancer: InstancerLink | None = None


@dataclass(frozen=True, eq=False)
class InstancerLink:
    """A point instance's placement, world_from_local = world_from_instancer ·
    instancer_from_instance · proto_from_prim (column convention, stage units).

    prim                 : the innermost UsdGeom.PointInstancer
    world_from_instancer : (4, 4) at the frame for an instancer nested in another's
                           prototype (it is placed by an instance: it stands still over the
                           shutter); None for a top-level instancer, whose own world
                           transform is read at any time
    proto_from_prim      : (4, 4) the gprim relative to its prototype's root
    """

    prim: Usd.Prim
    world_from_instancer: np.ndarray | None
    proto_from_prim: np.ndarray


@dataclass
class StageContents:
    gprims: list[GprimPlacement] = field(default_factory=list)
    strands: list[GprimPlacement] = field(default_factory=list)  # BasisCurves and Points
    lights: list[Usd.Prim] = field(default_factory=list)


@dataclass(frozen=True)
class _PrototypeItem:
    prim: Usd.Prim
    proto_from_prim: np.ndarray  # (4, 4) column convention, relative to the prototype root
    sub_path: str  # path from the prototype root's parent, e.g. "Tree/Trunk"
    is_instancer: bool


def walk_stage(context: ReadContext) -> StageContents:
    contents = StageContents()
    models_with_cards = cards_pass_models(context.stage)
    iterator = iter(Usd.PrimRange(context.stage.GetPseudoRoot(), _PREDICATE))
    for prim in iterator:
        if prim.IsPseudoRoot():
            continue
        if not _is_rendered(context, prim) or _is_replaced_by_draw_mode(
            context, prim, models_with_cards
        ):
            iterator.PruneChildren()
            continue
        if prim.IsA(UsdGeom.PointInstancer):
            iterator.PruneChildren()
            world = _finite_world_transform(context, prim)
            if world is not None:
                _expand_instancer(context, prim, world, str(prim.GetPath()), 0, contents)
        elif _is_gprim(prim):
            iterator.PruneChildren()
            if not _has_surface(context, prim):
                continue
            world = _finite_world_transform(context, prim)
            if world is not None:
                context.budget.take_meshes(1, "one more gprim", file=context.file, prim=str(prim.GetPath()))
                contents.gprims.append(
                    GprimPlacement(prim, world, str(prim.GetPath()), prim.GetName())
                )
        elif _is_strands(prim):
            iterator.PruneChildren()
            world = _finite_world_transform(context, prim)
            if world is not None:
                context.budget.take_meshes(1, "one more gprim", file=context.file, prim=str(prim.GetPath()))
                contents.strands.append(GprimPlacement(prim, world, str(prim.GetPath()), prim.GetName()))
        elif is_supported_light(prim):
            # A dome's children can only be portals (reported below); other lights stop here.
            if not (prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1)):
                iterator.PruneChildren()
            if _finite_world_transform(context, prim) is not None:
                contents.lights.append(prim)
        elif prim.HasAPI(UsdLux.LightAPI):
            _note_unsupported_light(context, prim)
        elif prim.IsA(UsdGeom.Camera) or _is_unsupported_geometry(context, prim):
            iterator.PruneChildren()
    return contents


# Schema type (Tf.Type, fallback types resolved) → (opaque, imageable): IsA depends on the
# type alone, so each type is asked once per process, not nine times per prim visited.
_TYPE_KINDS: dict[object, tuple[bool, bool]] = {}


def _type_kind(prim: Usd.Prim) -> tuple[bool, bool]:
    """(one of _OPAQUE_TYPES, a UsdGeom.Imageable) for ``prim``'s type."""
    schema_type = prim.GetPrimTypeInfo().GetSchemaType()
    kind = _TYPE_KINDS.get(schema_type)
    if kind is None:
        kind = _TYPE_KINDS[schema_type] = (any(prim.IsA(schema) for schema in _OPAQUE_TYPES),
                                           prim.IsA(UsdGeom.Imageable))
    return kind


def _is_rendered(context: ReadContext, prim: Usd.Prim) -> bool:
    """False for subtrees that never render: shading networks, invisible prims, guides."""
    opaque, is_imageable = _type_kind(prim)
    if opaque:
        return False
    if not is_imageable:
        return True  # typeless and unknown-typed prims are plain containers
    imageable = UsdGeom.Imageable(prim)
    # Ancestors were checked on the way down (invisible ones pruned), so the prim's own
    # opinion is enough for visibility; purpose inheritance is subtler, so ask USD.
    if imageable.GetVisibilityAttr().Get(context.time) == UsdGeom.Tokens.invisible:
        return False
    return imageable.ComputePurpose() in context.rendered_purposes


def _is_replaced_by_draw_mode(
    context: ReadContext,
    prim: Usd.Prim,
    models_with_cards: frozenset[str] = frozenset(),
    in_prototype: bool = False,
) -> bool:
    """Whether a model's draw mode (UsdGeomModelAPI) replaces its subtree, which is then
    pruned: cards models render as the cards draw_modes.author_draw_mode_cards wrote, bounds
    and origin models not at all.

    models_with_cards : the models the cards pass handled (cards_pass_models)
    in_prototype      : inside a PointInstancer prototype, where no cards are authored: a
                        cards model there renders its full geometry instead
    """
    mode = applied_draw_mode(prim)
    if mode is None:
        return False
    path = str(prim.GetPath())
    diagnostics = context.diagnostics
    if is_guide_mode(mode):
        diagnostics.note(
            "draw-mode-guide",
            "models in bounds or origin draw mode render nothing (those stand-ins are "
            "wireframe guides, with no surface): {prims}",
            f"{path} ({mode})",
        )
        return True
    if mode != UsdGeom.Tokens.cards:
        diagnostics.note(
            "draw-mode-unknown", "unknown model:drawMode values treated as default: {prims}",
            f"{path} ({mode})",
        )
        return False
    if in_prototype:
        diagnostics.note(
            "draw-mode-prototype",
            "models in cards draw mode inside PointInstancer prototypes render their full "
            "geometry (cards are drawn only for models placed on the stage itself): {prims}",
            path,
        )
        return False
    if path not in models_with_cards:
        diagnostics.note(
            "draw-mode-no-cards",
            "models in cards draw mode render nothing: their cards were not authored "
            "(draw_modes.author_draw_mode_cards did not run on this stage): {prims}",
            path,
        )
    return True


def _is_gprim(prim: Usd.Prim) -> bool:
    """A gprim the reader triangulates (Mesh, or an implicit shape)."""
    return prim.IsA(UsdGeom.Mesh) or is_implicit(prim)


def _is_strands(prim: Usd.Prim) -> bool:
    """Curves or points, which Embree draws as they are (strands.py)."""
    return prim.IsA(UsdGeom.BasisCurves) or prim.IsA(UsdGeom.Points)


def _has_surface(context: ReadContext, prim: Usd.Prim) -> bool:
    """False (with a warning) for an implicit gprim whose sizes make no surface (a size of 0);
    StageError for sizes no shape has (implicit.unusable_dimension)."""
    if prim.HasAPI(UsdLux.LightAPI):
        _note_unsupported_light(context, prim)
    if is_implicit(prim):
        reason = unusable_dimension(prim, context.time, context.file)
        if reason is not None:
            context.diagnostics.note(
                "implicit-size",
                "implicit gprims whose sizes make no surface skipped: {prims}",
                f"{prim.GetPath()} ({reason})",
            )
            return False
    return True


def _finite_world_transform(context: ReadContext, prim: Usd.Prim) -> np.ndarray | None:
    """(4, 4) float64 world_from_local (column convention, stage units), or None (with a
    warning) when it holds NaN or infinity: everything placed by it would be NaN."""
    with transform_errors_name(prim, context.file):
        world = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
    if np.isfinite(world).all():
        return world
    _note_non_finite_transform(context, prim)
    return None


def _note_non_finite_transform(context: ReadContext, prim: Usd.Prim, below: Usd.Prim | None = None) -> None:
    """Note ``prim`` as skipped for a non-finite transform, naming the xformOp at fault
    (see _non_finite_op); ``below``: the ancestor the transform is relative to (a prototype
    root), whose own ops are not part of it."""
    context.diagnostics.note(
        "non-finite-transform",
        "prims with NaN or infinite transforms skipped (the xformOp at fault in brackets): {prims}",
        f"{prim.GetPath()} ({_non_finite_op(prim, context.time, below)})",
    )


def _non_finite_op(prim: Usd.Prim, time: Usd.TimeCode, below: Usd.Prim | None = None) -> str:
    """The first xformOp of ``prim`` or its ancestors (below ``below``, and up to a
    resetXformStack) whose transform is not finite: its name on ``prim`` itself, its property
    path on an ancestor; when every op is finite, their product overflows."""
    current = prim
    while current and not current.IsPseudoRoot() and current != below:
        if current.IsA(UsdGeom.Xformable):
            xformable = UsdGeom.Xformable(current)
            for op in xformable.GetOrderedXformOps():
                if not np.isfinite(np.asarray(op.GetOpTransform(time))).all():
                    return op.GetName() if current == prim else f"{current.GetPath()}.{op.GetName()}"
            if xformable.GetResetXformStack():
                break
        current = current.GetParent()
    return "finite xformOps whose product overflows"


def _is_unsupported_geometry(context: ReadContext, prim: Usd.Prim) -> bool:
    if prim.IsA(UsdGeom.Gprim) or prim.IsA(UsdVol.Volume):
        context.diagnostics.note(
            "unsupported-gprim",
            "unsupported geometry skipped (not rendered): {prims}",
            f"{prim.GetPath()} ({prim.GetTypeName()})",
        )
        return True
    return False


def _note_unsupported_light(context: ReadContext, prim: Usd.Prim) -> None:
    schemas = [name for name in prim.GetAppliedSchemas() if "Light" in name]
    kind = prim.GetTypeName() if "Light" in prim.GetTypeName() else ", ".join(schemas)
    context.diagnostics.note(
        "unsupported-light",
        "unsupported lights skipped (mesh lights, portals, plugin lights, ...): {prims}",
        f"{prim.GetPath()} ({kind or 'LightAPI'})",
    )


def _expand_instancer(
    context: ReadContext,
    prim: Usd.Prim,
    world_from_instancer: np.ndarray,
    instancer_path: str,
    depth: int,
    contents: StageContents,
) -> None:
    """world_from_instancer : (4, 4) float64, column convention, stage units (finite)."""
    diagnostics = context.diagnostics
    if depth >= _MAX_INSTANCER_DEPTH:
        diagnostics.note(
            "instancer-depth",
            f"PointInstancers nested deeper than {_MAX_INSTANCER_DEPTH} levels skipped: {{prims}}",
            instancer_path,
        )
        return
    time = context.time
    instancer = UsdGeom.PointInstancer(prim)
    prototype_paths = instancer.GetPrototypesRel().GetForwardedTargets()
    proto_indices = values.integer_array(instancer.GetProtoIndicesAttr(), time, context.file)
    if not prototype_paths or not len(proto_indices):
        return
    # Before the other arrays are read and the transforms computed (128 bytes an instance):
    # every instance places at least one mesh.
    context.budget.check_meshes(len(proto_indices), f"protoIndices lists {len(proto_indices):,} instances",
                                file=context.file, prim=instancer_path)
    prototype_roots = [context.stage.GetPrimAtPath(path) for path in prototype_paths]
    instancer_from_instances, usable = _instance_transforms(
        context, instancer, proto_indices, prototype_roots, instancer_path
    )
    # invisibleIds and inactiveIds, as one flag per instance (empty = all shown).
    mask = np.asarray(instancer.ComputeMaskAtTime(time), dtype=bool)
    shown = usable & mask if len(mask) == len(usable) else usable
    prototypes = [_prototype_items(context, root, instancer_path) for root in prototype_roots]
    shown_instances = np.flatnonzero(shown)
    # The gprims the shown instances place (nested instancers count theirs when expanded).
    gprims_per_prototype = np.array([sum(not item.is_instancer for item in items) for items in prototypes])
    placed = int(gprims_per_prototype[proto_indices[shown_instances]].sum())
    context.budget.take_meshes(placed, f"its {len(shown_instances):,} instances place {placed:,} gprims",
                               file=context.file, prim=instancer_path)
    # Finite transforms can still overflow in these products: the placement skips what
    # lands out of reach (placement.MAX_WORLD_COORDINATE), without numpy's warnings here.
    with np.errstate(over="ignore", invalid="ignore"):
        world_from_instances = world_from_instancer @ instancer_from_instances[shown_instances]
    for world_from_instance, instance in zip(world_from_instances, shown_instances.tolist()):
        for item in prototypes[proto_indices[instance]]:
            with np.errstate(over="ignore", invalid="ignore"):
                world = world_from_instance @ item.proto_from_prim
            path = f"{instancer_path}/instance_{instance}/{item.sub_path}"
            if item.is_instancer:
                _expand_instancer(context, item.prim, world, path, depth + 1, contents)
            else:  # strands: a copy per instance
                link = InstancerLink(prim, world_from_instancer if depth else None, item.proto_from_prim)
                found = contents.strands if _is_strands(item.prim) else contents.gprims
                found.append(GprimPlacement(item.prim, world, path, item.prim.GetName(), instance, link))


def _instance_transforms(
    context: ReadContext,
    instancer: UsdGeom.PointInstancer,
    proto_indices: np.ndarray,
    prototype_roots: list[Usd.Prim],
    instancer_path: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Each instance's transform and whether its data can be used.

    proto_indices : (n,) int64
    Returns instancer_from_instance, (n, 4, 4) float64 column convention (the prototype
    root's own transform included), and usable, (n,) bool. An instance is unusable when its
    protoIndex is out of range, an authored array (positions, orientations, scales) is too
    short to reach it, or its transform is not finite; those instances are dropped with one
    warning per instancer, or, when none is usable, the whole instancer is.

    USD computes the transforms (velocities, accelerations and angular velocities included)
    whenever the arrays agree, which is always for valid data; otherwise the usable
    instances are composed here from positions, orientations and scales alone.
    """
    time, file = context.time, context.file
    count = len(proto_indices)
    positions = values.real_array(instancer.GetPositionsAttr(), time, 3, file, "point3f[]")
    orientations = values.real_array(instancer.GetOrientationsfAttr(), time, 4, file, "quatf[]")
    if not len(orientations):  # orientationsf wins over orientations, as in USD
        orientations = values.real_array(instancer.GetOrientationsAttr(), time, 4, file, "quath[]")
    scales = values.real_array(instancer.GetScalesAttr(), time, 3, file, "float3[]")
    arrays = {"positions": positions, "orientations": orientations, "scales": scales}
    # Orientations and scales are optional: unauthored (empty) ones do not limit anything.
    lengths = {name: len(array) for name, array in arrays.items() if len(array) or name == "positions"}
    reached = np.arange(count) < min(lengths.values())
    in_range = (proto_indices >= 0) & (proto_indices < len(prototype_roots))
    if max(lengths.values()) > count:
        context.diagnostics.note(
            "instancer-long-arrays",
            "PointInstancers with more positions, orientations or scales than protoIndices "
            "(the extra values are ignored): {prims}",
            instancer_path,
        )
    transforms = None
    if in_range.all() and all(length == count for length in lengths.values()):
        computed = instancer.ComputeInstanceTransformsAtTime(
            time, time, UsdGeom.PointInstancer.IncludeProtoXform,
            UsdGeom.PointInstancer.IgnoreMask,
        )
        if len(computed) == count:
            transforms = np.asarray(computed).transpose(0, 2, 1)  # row → column convention
    if transforms is None:
        usable_rows = reached & in_range
        root_transforms = np.stack([_local_transform(root, time) for root in prototype_roots])
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite rows are dropped just below
            transforms = compose_instance_transforms(
                positions, orientations, scales, root_transforms, proto_indices, usable_rows
            )
    usable = reached & in_range & np.isfinite(transforms).all(axis=(1, 2))
    dropped = int(count - usable.sum())
    if dropped:
        why = _why_instances_unusable(arrays, lengths, in_range, usable, count)
        context.diagnostics.note(
            "instancer-unusable" if dropped == count else "instancer-dropped",
            "PointInstancers none of whose instances has usable data skipped: {prims}" if dropped == count
            else "dropped {count} point instances with unusable data from: {prims}",
            f"{instancer_path} ({dropped} of {count} instances: {why})",
            dropped,
        )
    return transforms, usable


def _why_instances_unusable(
    arrays: dict[str, np.ndarray], lengths: dict[str, int], in_range: np.ndarray, usable: np.ndarray, count: int
) -> str:
    """What made the instances that are not ``usable`` so, for the warning: how many have a
    protoIndex out of range, lie past the end of an array, or have NaN or infinite values in
    one, and, for the rest, a transform that is not finite all the same (velocities,
    accelerations, a prototype root's own transform, or an overflowing product).

    arrays  : name → (m, w) float64 authored values; lengths: name → m of those that limit
              the instances (positions, and the optional arrays when authored)
    """
    reasons = []
    explained = ~in_range
    if not in_range.all():
        reasons.append(f"{int((~in_range).sum())} with protoIndices out of range")
    for name, length in lengths.items():
        if length < count:
            reasons.append(f"{count - length} past the {length} {name}")
            explained[length:] = True
        shared = min(count, length)
        bad = ~np.isfinite(arrays[name][:shared]).all(axis=1)
        if bad.any():
            reasons.append(f"{int(bad.sum())} with NaN or infinite {name}")
            explained[:shared] |= bad
    rest = int((~usable & ~explained).sum())
    if rest:
        reasons.append(f"{rest} whose transform is not finite")
    return ", ".join(reasons)


def _local_transform(prim: Usd.Prim, time: Usd.TimeCode) -> np.ndarray:
    """(4, 4) column-convention local transform of a prototype root (identity if none)."""
    if prim and prim.IsA(UsdGeom.Xformable):
        return column_matrix(UsdGeom.Xformable(prim).GetLocalTransformation(time))
    return np.eye(4)


def compose_instance_transforms(
    positions: np.ndarray,
    orientations: np.ndarray,
    scales: np.ndarray,
    root_transforms: np.ndarray,
    proto_indices: np.ndarray,
    usable_rows: np.ndarray,
) -> np.ndarray:
    """instancer_from_instance = translate · rotate · scale · prototype root transform, as
    UsdGeomPointInstancer composes it (velocities and accelerations aside).

    positions       : (p, 3) float64, stage units
    orientations    : (q, 4) float64 quaternions as Gf stores them, (i, j, k, real), used
                      unnormalised as USD does; q = 0: no rotation
    scales          : (s, 3) float64; s = 0: unit scale
    root_transforms : (r, 4, 4) float64, column convention, one per prototype
    proto_indices   : (n,) int64
    usable_rows     : (n,) bool, the instances every array reaches with a valid protoIndex
    Returns (n, 4, 4) float64, column convention; NaN where not usable_rows.
    """
    count = len(proto_indices)
    transforms = np.full((count, 4, 4), np.nan)
    rows = np.flatnonzero(usable_rows)
    local = np.tile(np.eye(4), (len(rows), 1, 1))
    if len(scales):
        local[:, :3, :3] *= scales[rows][:, None, :]  # columns scaled: R · S
    if len(orientations):
        local[:, :3, :3] = _rotation_matrices(orientations[rows]) @ local[:, :3, :3]
    local[:, :3, 3] = positions[rows]
    transforms[rows] = local @ root_transforms[proto_indices[rows]]
    return transforms


def _rotation_matrices(quaternions: np.ndarray) -> np.ndarray:
    """(n, 3, 3) column-convention matrices of (n, 4) quaternions (i, j, k, real), taken as
    they are, like GfMatrix4d.SetRotate: USD does not normalise instance orientations."""
    x, y, z, w = quaternions.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def _prototype_items(
    context: ReadContext, root: Usd.Prim, instancer_path: str
) -> list[_PrototypeItem]:
    """Gprims (strands too) and nested instancers under one prototype root, relative to it."""
    if not root or not root.IsActive():
        return []
    items = []
    parent_path = root.GetPath().GetParentPath()
    iterator = iter(Usd.PrimRange(root, _PREDICATE))
    for prim in iterator:
        if not _is_rendered(context, prim) or _is_replaced_by_draw_mode(
            context, prim, in_prototype=True
        ):
            iterator.PruneChildren()
            continue
        is_instancer = prim.IsA(UsdGeom.PointInstancer)
        if is_instancer or _is_gprim(prim) or _is_strands(prim):
            iterator.PruneChildren()
            if not is_instancer and not _has_surface(context, prim):
                continue
            if prim == root:
                proto_from_prim = np.eye(4)
            else:
                with transform_errors_name(prim, context.file):
                    relative, _ = context.xform_cache.ComputeRelativeTransform(prim, root)
                proto_from_prim = column_matrix(relative)
            if not np.isfinite(proto_from_prim).all():
                _note_non_finite_transform(context, prim, below=root)
                continue
            sub_path = str(prim.GetPath().MakeRelativePath(parent_path))
            items.append(_PrototypeItem(prim, proto_from_prim, sub_path, is_instancer))
        elif is_supported_light(prim) or prim.HasAPI(UsdLux.LightAPI):
            context.diagnostics.note(
                "instanced-light",
                "lights inside PointInstancer prototypes are not instanced (skipped): {prims}",
                str(prim.GetPath()),
            )
            iterator.PruneChildren()
        elif prim.IsA(UsdGeom.Camera) or _is_unsupported_geometry(context, prim):
            iterator.PruneChildren()
    return items
