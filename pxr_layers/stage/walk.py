"""Find what renders on a stage: gprim placements (instances expanded) and lights.

The walk visits instance proxies (native instances appear at their own paths), prunes
invisible subtrees and purposes the render settings do not include (all but default and
render unless they say otherwise), and stops at gprims, cameras,
point instancers and lights (UsdGeom forbids gprims under gprims; a light's children are
not lit geometry). PointInstancers are expanded here into one placement per instance and
prototype gprim.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom, UsdLux, UsdRender, UsdShade, UsdSkel, UsdVol

from .context import ReadContext
from .implicit import is_implicit
from .lights import is_supported_light
from .transforms import column_matrix

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
    """

    prim: Usd.Prim
    world_from_local: np.ndarray
    path: str
    name: str
    instance: int = -1


@dataclass
class StageContents:
    gprims: list[GprimPlacement] = field(default_factory=list)
    lights: list[Usd.Prim] = field(default_factory=list)


@dataclass(frozen=True)
class _PrototypeItem:
    prim: Usd.Prim
    proto_from_prim: np.ndarray  # (4, 4) column convention, relative to the prototype root
    sub_path: str  # path from the prototype root's parent, e.g. "Tree/Trunk"
    is_instancer: bool


def walk_stage(context: ReadContext) -> StageContents:
    contents = StageContents()
    iterator = iter(Usd.PrimRange(context.stage.GetPseudoRoot(), _PREDICATE))
    for prim in iterator:
        if prim.IsPseudoRoot():
            continue
        if not _is_rendered(context, prim):
            iterator.PruneChildren()
            continue
        if prim.IsA(UsdGeom.PointInstancer):
            world = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
            _expand_instancer(context, prim, world, str(prim.GetPath()), 0, contents)
            iterator.PruneChildren()
        elif _is_supported_gprim(context, prim):
            world = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
            contents.gprims.append(
                GprimPlacement(prim, world, str(prim.GetPath()), prim.GetName())
            )
            iterator.PruneChildren()
        elif is_supported_light(prim):
            contents.lights.append(prim)
            # A dome's children can only be portals (reported below); other lights stop here.
            if not (prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1)):
                iterator.PruneChildren()
        elif prim.HasAPI(UsdLux.LightAPI):
            _note_unsupported_light(context, prim)
        elif prim.IsA(UsdGeom.Camera) or _is_unsupported_geometry(context, prim):
            iterator.PruneChildren()
    return contents


def _is_rendered(context: ReadContext, prim: Usd.Prim) -> bool:
    """False for subtrees that never render: shading networks, invisible prims, guides."""
    if any(prim.IsA(schema) for schema in _OPAQUE_TYPES):
        return False
    if not prim.IsA(UsdGeom.Imageable):
        return True  # typeless and unknown-typed prims are plain containers
    imageable = UsdGeom.Imageable(prim)
    # Ancestors were checked on the way down (invisible ones pruned), so the prim's own
    # opinion is enough for visibility; purpose inheritance is subtler, so ask USD.
    if imageable.GetVisibilityAttr().Get(context.time) == UsdGeom.Tokens.invisible:
        return False
    return imageable.ComputePurpose() in context.rendered_purposes


def _is_supported_gprim(context: ReadContext, prim: Usd.Prim) -> bool:
    if not (prim.IsA(UsdGeom.Mesh) or is_implicit(prim)):
        return False
    path = str(prim.GetPath())
    if prim.HasAPI(UsdLux.LightAPI):
        _note_unsupported_light(context, prim)
    if prim.HasAPI(UsdSkel.BindingAPI) and prim.GetAttribute("primvars:skel:jointIndices"):
        context.diagnostics.note(
            "skinning", "skinned meshes are rendered in their rest pose: {prims}", path
        )
    return True


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
    proto_indices = instancer.GetProtoIndicesAttr().Get(time)
    if not prototype_paths or not proto_indices:
        return
    instance_transforms = instancer.ComputeInstanceTransformsAtTime(
        time, time, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask
    )
    if len(instance_transforms) != len(proto_indices):
        diagnostics.note(
            "instancer-invalid",
            "PointInstancers with inconsistent data (positions, protoIndices, prototypes) "
            "skipped: {prims}",
            instancer_path,
        )
        return
    # invisibleIds and inactiveIds, as one flag per instance (empty = all shown).
    mask = instancer.ComputeMaskAtTime(time)
    prototypes = [
        _prototype_items(context, context.stage.GetPrimAtPath(path), instancer_path)
        for path in prototype_paths
    ]
    for instance, (proto_index, transform) in enumerate(zip(proto_indices, instance_transforms)):
        if len(mask) and not mask[instance]:
            continue
        world_from_instance = world_from_instancer @ column_matrix(transform)
        for item in prototypes[proto_index]:
            world = world_from_instance @ item.proto_from_prim
            path = f"{instancer_path}/instance_{instance}/{item.sub_path}"
            if item.is_instancer:
                _expand_instancer(context, item.prim, world, path, depth + 1, contents)
            else:
                contents.gprims.append(
                    GprimPlacement(item.prim, world, path, item.prim.GetName(), instance)
                )


def _prototype_items(
    context: ReadContext, root: Usd.Prim, instancer_path: str
) -> list[_PrototypeItem]:
    """Gprims and nested instancers under one prototype root, relative to it."""
    if not root or not root.IsActive():
        return []
    items = []
    parent_path = root.GetPath().GetParentPath()
    iterator = iter(Usd.PrimRange(root, _PREDICATE))
    for prim in iterator:
        if not _is_rendered(context, prim):
            iterator.PruneChildren()
            continue
        is_instancer = prim.IsA(UsdGeom.PointInstancer)
        if is_instancer or _is_supported_gprim(context, prim):
            if prim == root:
                proto_from_prim = np.eye(4)
            else:
                relative, _ = context.xform_cache.ComputeRelativeTransform(prim, root)
                proto_from_prim = column_matrix(relative)
            sub_path = str(prim.GetPath().MakeRelativePath(parent_path))
            items.append(_PrototypeItem(prim, proto_from_prim, sub_path, is_instancer))
            iterator.PruneChildren()
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
