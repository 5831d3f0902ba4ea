"""``read_scene``: a composed stage at one time code → SceneData.

Subdivision levels are chosen before any mesh is read (:class:`_SubdivisionLevels`): each
subdividing mesh wants the level its size on the image asks for (subdivision.PixelFootprint)
or the request's uniform one; meshes that share a surface (one prototype, one asset) share
the highest level their placements want; then the highest levels are lowered first until
the scene's refined triangles fit request.MAX_SUBDIVISION_TRIANGLES (one warning naming them).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections import Counter
from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom, UsdShade

from pxr_layers.errors import StageError
from pxr_layers.request import MAX_SUBDIVISION_TRIANGLES
from pxr_layers.scene import INDEX, Mesh, SceneData, Strands

from .budgets import fit_subdivision_levels
from .context import ReadContext
from .defaults import DEFAULT_UV_SET
from .diagnostics import Diagnostics
from .draw_modes import author_draw_mode_cards
from .implicit import tessellate
from .lights import read_lights
from .materials import MaterialLibrary, ResolvedMaterial, display_color
from .motion import MAX_MOTION_STEPS, GprimMotion
from .placement import (
    PreparedSurface,
    SharedSurface,
    is_instanceable,
    place_instance,
    place_surface,
    prepare_surface,
    shared_surface,
)
from .skinning import SkinnedPoser
from .strands import read_strands
from .subdivision import PixelFootprint
from .surfaces import (
    LocalSurface,
    SubdivisionCage,
    find_primvar,
    geometry_opinions,
    mesh_opinions,
    read_cage,
    read_mesh,
    with_constant_primvars,
)
from .transforms import column_matrix, to_metres
from .textures import TextureLibrary
from .values import integer_array
from .walk import GprimPlacement, InstancerLink, walk_stage

logger = logging.getLogger(__name__)


def read_scene(
    context: ReadContext,
    frame_value: float,
    material_binding_purposes: tuple[str, ...],
    footprint: PixelFootprint,
    subdiv_level: int | None = None,
    earlier_warnings: tuple[str, ...] = (),
) -> SceneData:
    """Read everything the tracer needs from ``context``'s stage at its time code.

    frame_value       : SceneData.frame (NaN for "the earliest sample")
    footprint         : what the render camera sees, which subdivision levels follow
    subdiv_level      : one refinement level for every subdivision surface; None: a level
                        per surface from ``footprint`` (see the module docstring); either
                        way lowered to fit the scene's subdivision budget
    earlier_warnings  : warnings already logged for this stage (its opening), kept in
                        SceneData.warnings but not logged again

    Raises StageError (naming the file, the prim and the attribute) for values that are
    wrong wherever they are read: attributes of another type than the schema's, broken
    topology, sizes of implicit shapes and camera values no shape or lens has. Computed data
    gone bad (NaN or infinite transforms, instance data or mesh points; geometry placed out
    of float32's reach) skips its prim, or its instances, with a warning naming them (see
    walk.py). Everything else the tracer cannot honour but can render around is a warning,
    logged once and kept in SceneData.warnings.
    """
    diagnostics, file = context.diagnostics, context.file
    author_draw_mode_cards(context.stage, context.time, diagnostics)  # before the walk, which prunes their models
    textures = TextureLibrary(diagnostics)
    materials = MaterialLibrary(context, textures, material_binding_purposes)
    contents = walk_stage(context)

    levels = _SubdivisionLevels(context, contents.gprims, footprint, subdiv_level)
    builder = _MeshBuilder(context, materials, levels)
    meshes = builder.build_all(contents.gprims)
    strands = _read_strands(context, materials, contents.strands)
    lights = read_lights(context, contents.lights, textures, [mesh.path for mesh in meshes])
    if not meshes and not strands:
        diagnostics.warn(f"{file} has no geometry that renders: the image holds its lights alone")
    logger.info(
        "%s: %d meshes, %d triangles, %d materials, %d lights, %d textures",
        file,
        len(meshes),
        sum(len(mesh.triangles) for mesh in meshes),
        len(materials.materials),
        len(lights),
        len(textures.images),
    )
    textures.remember()  # the next frame's read takes them as they are
    return SceneData(
        stage_path=os.path.abspath(file),
        frame=frame_value,
        meshes=tuple(meshes),
        strands=tuple(strands),
        materials=tuple(materials.materials),
        lights=tuple(lights),
        textures=tuple(textures.images),
        meters_per_unit=context.meters_per_unit,
        up_axis=context.up_axis,
        warnings=(*earlier_warnings, *diagnostics.finish()),
    )


def _read_strands(context: ReadContext, materials: MaterialLibrary, placements: list[GprimPlacement]) -> list[Strands]:
    """The BasisCurves and Points of the walk (strands.py), each with its bound material;
    emissive ones are skipped with a note (their light would not be sampled). Strands that
    move over the shutter (as meshes do: motion.py) carry their vertices at k evenly spaced
    times, one k for them all (Strands.motion_vertices); their curves must keep their counts."""
    found: list[tuple[GprimPlacement, Strands, int]] = []
    motion = GprimMotion(context) if context.shutter is not None else None
    for placement in placements:
        prim = placement.prim
        material = materials.resolve(materials.bound_material(prim), display_color(prim, context.time, context.file))
        if materials.materials[material.index].emits:
            context.diagnostics.note("emissive-strands", "emissive curves and points skipped (not rendered yet): {prims}",
                                     placement.path)
            continue
        strands = read_strands(context, prim, placement.world_from_local, placement.path, placement.name,
                               material.index)
        if strands is not None:
            steps = motion.steps(prim, placement.instancer, placement.instance) if motion is not None else 1
            found.append((placement, strands, steps))
    step_count = max((steps for _, _, steps in found), default=1)
    if step_count == 1:
        return [strands for _, strands, _ in found]
    times = context.shutter.times(step_count)
    moved = []
    for placement, strands, steps in found:
        if steps > 1:
            prim = placement.prim
            points = motion.points_at(prim, times) if motion.deforms(prim) else [None] * step_count
            worlds = motion.placements(prim, placement.instancer, placement.instance, times)
            at_times = [read_strands(context, prim, world, placement.path, placement.name, strands.material, points=p)
                        for world, p in zip(worlds, points)]
            if any(step is None or step.vertices.shape != strands.vertices.shape
                   or not np.array_equal(step.segments, strands.segments) for step in at_times):
                raise StageError("its curves change in number or length over the shutter: motion blur interpolates "
                                 "one set of curves", file=context.file, prim=placement.path)
            strands = dataclasses.replace(strands, motion_vertices=np.stack([step.vertices for step in at_times]))
        moved.append(strands)
    return moved


INSTANCING_SAVES = 1 << 16
"""A surface is instanced when flat copies of its placements would hold at least this many
triangles more than one copy does: below, copies cost little memory and shade a little
faster (an instanced hit is placed first, trace/instances.py)."""


@dataclass(frozen=True, eq=False)
class _Resolved:
    """A placement before it becomes a Mesh: its prim, surface (posed: skinned for this prim
    alone) and the primvars it was read with, per-triangle materials, transform (stage units)
    and names."""

    prim: Usd.Prim
    uv_primvar: str
    primvars: tuple[str, ...]
    instancer: InstancerLink | None
    surface: PreparedSurface
    triangle_material: np.ndarray
    world_from_local: np.ndarray
    name: str
    path: str
    instance: int
    posed: bool

    @property
    def instanceable(self) -> bool:
        return not self.posed and is_instanceable(self.world_from_local)

    @property
    def sharing_key(self) -> tuple:
        """Placements with equal keys may be instances of one prototype (the reader gives
        placements of equal bindings one triangle_material array)."""
        return id(self.surface), id(self.triangle_material)


class _MeshBuilder:
    """Builds scene.Mesh objects, triangulating each distinct surface only once.

    Gprims share a triangulation (and its PreparedSurface) when they are the same prototype
    gprim (native instances, point-instanced copies) or, for meshes, when every value the
    surface is read from comes from the same opinions (surfaces.mesh_opinions: prims that
    reference one asset). A prim that shares a surface read for another still gets the
    read's warnings under its own path, as if it had been read itself.
    """

    def __init__(self, context: ReadContext, materials: MaterialLibrary, levels: _SubdivisionLevels) -> None:
        self._context = context
        self._materials = materials
        self._levels = levels
        self._poser = SkinnedPoser(context.stage, context.time, context.diagnostics, xform_cache=context.xform_cache)
        # (prototype prim path, uv primvar, material primvars, where they are found: see
        # _primvar_owners) → surface, and mesh_opinions key → (surface, the path it was read
        # under, the notes of its read).
        # None: a surface read_mesh skipped.
        self._surfaces: dict[tuple, PreparedSurface | None] = {}
        self._triangle_materials: dict[tuple, np.ndarray] = {}  # (surface, bindings) → (t,) material per triangle
        self._by_opinions: dict[tuple, tuple[PreparedSurface | None, str, list[tuple]]] = {}

    def build_all(self, placements: list[GprimPlacement]) -> list[Mesh]:
        """The meshes of `placements`, in their order. A surface placed often enough that
        copies would cost INSTANCING_SAVES triangles or more, bound to the same materials in
        every placement, none of which emits, is shared: its similarity placements become
        instances of it (scene.Mesh.prototype); every other placement is a copy in the world,
        and one that moves over the shutter carries its motion (scene.Mesh.motion_points)."""
        resolved = [self._resolve(placement) for placement in placements]
        motion = GprimMotion(self._context) if self._context.shutter is not None else None
        steps = [self._motion_steps(motion, item) for item in resolved]
        step_count = max(steps, default=1)
        groups: dict[tuple, list[int]] = {}
        for index, item in enumerate(resolved):
            # a moving placement shares its surface when only its transform moves
            if item is not None and item.instanceable and (steps[index] == 1 or not motion.deforms(item.prim)):
                groups.setdefault(item.sharing_key, []).append(index)
        prototype_of: dict[int, SharedSurface] = {}  # placement index → the surface it instances
        prototypes = 0
        for members in groups.values():
            first = resolved[members[0]]
            triangles = len(first.surface.surface.triangles)
            if (len(members) - 1) * triangles < INSTANCING_SAVES or self._materials.emit(first.triangle_material):
                continue
            # the shared triangles count once against the scene's budget
            self._context.budget.take_triangles(triangles, f"the {triangles:,} triangles of its surface",
                                                file=self._context.file, prim=first.path)
            prototype_of.update(dict.fromkeys(members, shared_surface(first.surface, first.triangle_material, prototypes)))
            prototypes += 1
        meshes = []
        for index, item in enumerate(resolved):
            if item is None:
                continue
            mesh = None
            if index in prototype_of:
                mesh = self._instance(item, prototype_of[index], motion, step_count if steps[index] > 1 else 1)
            if mesh is None:
                mesh = self._copy(item)
                if mesh is not None and steps[index] > 1:
                    mesh = self._moving(motion, item, mesh, step_count)
            if mesh is not None:
                meshes.append(mesh)
        if prototypes:
            logger.info("%s: %d placements are instances of %d shared surfaces", self._context.file,
                        len(prototype_of), prototypes)
        return meshes

    def _motion_steps(self, motion: GprimMotion | None, item: _Resolved | None) -> int:
        """The time steps the placement needs over the shutter (motion.py): 1 when it stands
        still, or when its motion is not read: emissive surfaces stay where they are at the
        frame's time (a note names them). A skinned mesh takes a step per sample of what poses
        it (SkinnedPoser.motion_times), 1 when its pose is the same at both ends of the
        shutter and nothing is sampled between them."""
        if motion is None or item is None:
            return 1
        if item.posed:
            times = self._poser.motion_times(item.prim, motion.interval)
            if len(times) > 2:
                return min(len(times), MAX_MOTION_STEPS)
            ends = [self._poser.posed(item.prim, time) for time in times]
            moves = not any(pose is None for pose in ends) and not (
                np.array_equal(ends[0].points, ends[-1].points)
                and np.array_equal(ends[0].world_from_points, ends[-1].world_from_points))
            steps = 2 if moves else 1
        else:
            steps = motion.steps(item.prim, item.instancer, item.instance)
        if steps > 1 and self._materials.emit(item.triangle_material):
            self._context.diagnostics.note(
                "unread-motion", "gprims rendered where they are at the frame's time, without motion blur "
                "(emissive surfaces do not move over the shutter yet): {prims}", item.path)
            return 1
        return steps

    def _moving(self, motion: GprimMotion, item: _Resolved, mesh: Mesh, step_count: int) -> Mesh:
        """`mesh` with its points (and normals) at `step_count` times over the shutter. A
        deforming mesh is read again at each (its points, or points moved by its velocities);
        its topology must stay the mesh's, or StageError names the prim."""
        context = self._context
        times = context.shutter.times(step_count)
        if item.posed:
            return self._moving_skinned(item, mesh, times)
        surfaces = [item.surface] * step_count
        if motion.deforms(item.prim):
            changed = motion.topology_change(item.prim)
            if changed:
                raise StageError(f"{changed}: motion blur interpolates one mesh", file=context.file, prim=item.path)
            surfaces = [self._surface_at(item, points) for points in motion.points_at(item.prim, times)]
        placements = motion.placements(item.prim, item.instancer, item.instance, times)
        placed = [place_surface(surface, world_from_local, context.meters_per_unit, item.triangle_material, item.name,
                                item.path, Diagnostics(), instance=item.instance)
                  for surface, world_from_local in zip(surfaces, placements)]
        return self._with_steps(placed[0] if surfaces[0] is not item.surface else mesh, placed, item.path)

    def _with_steps(self, base: Mesh, placed: list[Mesh | None], path: str) -> Mesh:
        """`base` carrying the points (and normals) of `placed`, the mesh at each time step."""
        if any(step is None or len(step.points) != len(placed[0].points) for step in placed):
            raise StageError("its placed points over the shutter are out of reach or change in number",
                             file=self._context.file, prim=path)
        same_normals = all(step.normal_values is not None and np.array_equal(step.normal_indices, base.normal_indices)
                           and len(step.normal_values) == len(placed[0].normal_values) for step in placed)
        return dataclasses.replace(
            base, motion_points=np.stack([step.points for step in placed]),
            motion_normals=np.stack([step.normal_values for step in placed]) if same_normals else None)

    def _moving_skinned(self, item: _Resolved, mesh: Mesh, times: np.ndarray) -> Mesh:
        """`mesh`, a skinned placement, posed at each of `times` (its Skeleton's or its own
        place in the world at each; a point instance's placement stays the frame's)."""
        context = self._context
        poses = [self._poser.posed(item.prim, time) for time in times]
        at_frame = self._poser.posed(item.prim)
        if at_frame is None or any(pose is None for pose in poses):
            raise StageError("its skinning fails at a time over the shutter (see the skinning warnings)",
                             file=context.file, prim=item.path)
        placement = item.world_from_local @ np.linalg.inv(at_frame.world_from_points)
        placed = [place_surface(self._surface_at(item, pose.points), placement @ pose.world_from_points,
                                context.meters_per_unit, item.triangle_material, item.name, item.path, Diagnostics(),
                                instance=item.instance) for pose in poses]
        return self._with_steps(mesh, placed, item.path)

    def _surface_at(self, item: _Resolved, points: np.ndarray) -> PreparedSurface:
        """The placement's surface read again with `points` (a step of its motion); StageError
        naming the prim when they give another mesh than at the frame."""
        context = self._context
        local = read_mesh(item.prim, context.time, item.uv_primvar, Diagnostics(), context.file,
                          subdiv_level=self._levels.level(item.prim), points=points, primvars=item.primvars)
        if local is None or not np.array_equal(local.triangles, item.surface.surface.triangles):
            raise StageError("its points over the shutter give another mesh than at the frame: motion blur "
                             "interpolates one mesh", file=context.file, prim=item.path)
        return prepare_surface(local)

    def _copy(self, item: _Resolved) -> Mesh | None:
        """The placement as a copy of its surface in the world."""
        context = self._context
        local = item.surface.surface
        # Each copy of a surface's triangles in the world counts.
        context.budget.take_triangles(len(local.triangles), f"its {len(local.triangles):,} triangles",
                                      file=context.file, prim=item.path)
        return place_surface(item.surface, item.world_from_local, context.meters_per_unit, item.triangle_material,
                             item.name, item.path, context.diagnostics, instance=item.instance)

    def _instance(self, item: _Resolved, shared: SharedSurface, motion: GprimMotion | None,
                  step_count: int) -> Mesh | None:
        """The placement as an instance of `shared`, moving over `step_count` time steps when
        more than 1; None when it moves through placements other than similarities (it is
        then a copy of its own)."""
        context = self._context
        motion_placements = None
        if step_count > 1:
            placements = motion.placements(item.prim, item.instancer, item.instance, context.shutter.times(step_count))
            if not all(is_instanceable(placement) for placement in placements):
                return None
            motion_placements = np.stack([to_metres(placement, context.meters_per_unit) for placement in placements])
        mesh = place_instance(shared, item.world_from_local, context.meters_per_unit, item.name, item.path,
                              context.diagnostics, instance=item.instance)
        if mesh is None or motion_placements is None:
            return mesh
        return dataclasses.replace(mesh, motion_world_from_points=motion_placements)

    def _resolve(self, placement: GprimPlacement) -> _Resolved | None:
        """The placement's surface, materials and transform (None: read_mesh skipped it)."""
        context = self._context
        prim = placement.prim
        color = display_color(prim, context.time, context.file)
        mesh_material = self._materials.resolve(self._materials.bound_material(prim), color)
        subset_materials = self._subset_materials(prim, color)
        uv_sets = list(dict.fromkeys(resolved.uv_primvar for resolved in [mesh_material, *(m for _, m in subset_materials)]
                                     if resolved.uv_primvar))
        uv_primvar = uv_sets[0] if uv_sets else DEFAULT_UV_SET
        if len(uv_sets) > 1:
            context.diagnostics.note(
                "several-uv-sets",
                "meshes whose materials read several uv sets as texture coordinates (the first is used for "
                "all): {prims}",
                f"{prim.GetPath()} ({', '.join(uv_sets)})",
            )
        # What the primvar readers of the mesh's materials read, in one order whatever the
        # order of the materials (the surface cache's key).
        primvars = tuple(sorted({
            name for resolved in [mesh_material, *(m for _, m in subset_materials)] for name in resolved.primvars
        }))
        world_from_local = placement.world_from_local
        posed = self._poser.posed(prim) if prim.IsA(UsdGeom.Mesh) else None
        if posed is None:
            surface = self._surface(prim, uv_primvar, primvars)
        else:
            local = self._read_mesh(prim, uv_primvar, primvars, posed.points, context.diagnostics)
            surface = None if local is None else prepare_surface(local)
            # The skinned points sit in the skeleton's space: replace the prim's own world
            # transform by it (and keep a point instance's placement of the prim, if any).
            prim_world = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
            world_from_local = world_from_local @ np.linalg.inv(prim_world) @ posed.world_from_points
        if surface is None:  # skipped by read_mesh, which said why
            return None

        # One array per distinct (surface, bindings): the placements of a surface (a point
        # instancer's thousands) share it, and with it a sharing key that is cheap to hash.
        bindings = (id(surface), mesh_material.index,
                    tuple((resolved.index, faces.tobytes()) for faces, resolved in subset_materials))
        if bindings not in self._triangle_materials:
            local = surface.surface
            face_material = np.full(local.face_count, mesh_material.index, dtype=INDEX)
            # Reversed so that, where subsets overlap, the first subset listed wins.
            for faces, resolved in reversed(subset_materials):
                faces = faces[(faces >= 0) & (faces < local.face_count)]
                face_material[faces] = resolved.index
            self._triangle_materials[bindings] = face_material[local.triangle_face]
        return _Resolved(prim, uv_primvar, primvars, placement.instancer, surface, self._triangle_materials[bindings],
                         world_from_local, placement.name, placement.path, placement.instance, posed=posed is not None)

    def _read_mesh(
        self,
        prim: Usd.Prim,
        uv_primvar: str,
        primvars: tuple[str, ...],
        points: np.ndarray | None,
        diagnostics: Diagnostics,
    ) -> LocalSurface | None:
        context = self._context
        return read_mesh(prim, context.time, uv_primvar, diagnostics, context.file,
                         subdiv_level=self._levels.level(prim), points=points, primvars=primvars,
                         budget=context.budget)

    def _subset_materials(
        self, prim: Usd.Prim, color: tuple[float, float, float] | None
    ) -> list[tuple[np.ndarray, ResolvedMaterial]]:
        if not prim.IsA(UsdGeom.Mesh):
            return []
        subsets = []
        for subset in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets():
            if subset.GetElementTypeAttr().Get() != UsdGeom.Tokens.face:
                continue
            faces = integer_array(subset.GetIndicesAttr(), self._context.time, self._context.file)
            material = self._materials.bound_material(subset.GetPrim())
            subsets.append((faces, self._materials.resolve(material, color)))
        return subsets

    def _surface(self, prim: Usd.Prim, uv_primvar: str, primvars: tuple[str, ...]) -> PreparedSurface | None:
        key = (_source_path(prim), uv_primvar, primvars, _primvar_owners(prim, primvars))
        if key in self._surfaces:
            return self._surfaces[key]
        context = self._context
        if not prim.IsA(UsdGeom.Mesh):
            shape = tessellate(prim, context.time)
            if primvars:
                shape = with_constant_primvars(shape, prim, context.time, primvars, context.diagnostics)
            surface = prepare_surface(shape)
        else:
            opinions = mesh_opinions(prim, context.time, uv_primvar, primvars)
            path = str(prim.GetPath())
            if opinions in self._by_opinions:
                surface, read_path, notes = self._by_opinions[opinions]
                for kind, template, noted, count in notes:
                    if noted.startswith(read_path):  # the read names its prim first
                        noted = path + noted[len(read_path):]
                    context.diagnostics.note(kind, template, noted, count)
            else:
                recorder = _NoteRecorder(context.diagnostics)
                local = self._read_mesh(prim, uv_primvar, primvars, None, recorder)
                surface = None if local is None else prepare_surface(local)
                if opinions is not None:
                    self._by_opinions[opinions] = (surface, path, recorder.notes)
        self._surfaces[key] = surface
        return surface


def _primvar_owners(prim: Usd.Prim, primvars: tuple[str, ...]) -> tuple[str, ...]:
    """For each primvar, the path of the prim it is found on (surfaces.find_primvar; "" when
    missing), in prototype terms inside a native instance's prototype: the instances of a
    prototype share a surface only when they also inherit their constant primvars from the
    same prims (a displayColor on each instance's root gives each its own)."""
    owners = []
    for name in primvars:
        primvar = find_primvar(prim, name)
        if primvar is None:
            owners.append("")
            continue
        owner = primvar.GetAttr().GetPrim()
        owners.append(str((owner.GetPrimInPrototype() if owner.IsInstanceProxy() else owner).GetPath()))
    return tuple(owners)


class _SubdivisionLevels:
    """The refinement level of every subdividing mesh of a scene, chosen before any is read.

    A mesh's level is keyed by its cage (:meth:`key`): the prims that share a surface in
    _MeshBuilder (one prototype gprim; equal opinions) have equal keys, so a shared surface
    is refined once, at the highest level its placements want (the nearest copy decides).
    A skinned mesh is sized by its rest pose under its prim's transform.
    """

    def __init__(self, context: ReadContext, gprims: list[GprimPlacement], footprint: PixelFootprint,
                 subdiv_level: int | None) -> None:
        self._context = context
        self._key_of: dict[str, tuple | None] = {}  # source prim path → key (None: no subdivision)
        cages: dict[tuple, SubdivisionCage] = {}
        first_path: dict[tuple, str] = {}
        copies: dict[tuple, int] = {}
        wanted: dict[tuple, int] = {}
        for placement in gprims:
            key = self.key(placement.prim)
            if key is None:
                continue
            if key not in cages:
                cage = read_cage(placement.prim, context.time, context.file, measure_edges=subdiv_level is None)
                if cage is None:  # nothing to refine: the key goes
                    self._key_of[_source_path(placement.prim)] = None
                    continue
                cages[key], first_path[key] = cage, placement.path
            cage = cages[key]
            copies[key] = copies.get(key, 0) + 1
            level = subdiv_level if subdiv_level is not None else footprint.level(
                to_metres(placement.world_from_local, context.meters_per_unit), cage.edge_length,
                cage.lower, cage.upper)
            wanted[key] = max(wanted.get(key, 0), level)
        triangles = {key: [copies[key] * count for count in cages[key].triangles] for key in wanted}
        self._levels = fit_subdivision_levels(wanted, triangles)
        asked = "their size on the image asks for" if subdiv_level is None else f"the {subdiv_level} asked"
        for key in wanted:
            if self._levels[key] < wanted[key]:
                context.diagnostics.note(
                    "subdivision-budget",
                    f"subdivision surfaces refined to fewer levels than {asked}, the highest first, to keep the "
                    f"scene's within {MAX_SUBDIVISION_TRIANGLES:,} triangles: {{prims}}",
                    f"{first_path[key]} (level {wanted[key]} → {self._levels[key]})",
                )
        if wanted:
            histogram = Counter(self._levels.values())
            logger.info("%s: subdivision levels (%s): %s surfaces; %d refined triangles", context.file,
                        "automatic" if subdiv_level is None else f"{subdiv_level} asked",
                        ", ".join(f"level {level}: {count}" for level, count in sorted(histogram.items())),
                        sum(triangles[key][level] for key, level in self._levels.items()))

    def key(self, prim: Usd.Prim) -> tuple | None:
        """What identifies ``prim``'s cage: its geometry's opinions (surfaces.geometry_opinions),
        else (animated) its prototype gprim's path; None for a gprim that does not subdivide."""
        source = _source_path(prim)
        if source not in self._key_of:
            key = None
            if prim.IsA(UsdGeom.Mesh) and (
                    UsdGeom.Mesh(prim).GetSubdivisionSchemeAttr().Get(self._context.time) != UsdGeom.Tokens.none):
                opinions = geometry_opinions(prim, self._context.time)
                key = ("opinions", opinions) if opinions is not None else ("prim", source)
            self._key_of[source] = key
        return self._key_of[source]

    def level(self, prim: Usd.Prim) -> int:
        """The level chosen for ``prim`` (0 for one that does not subdivide)."""
        key = self.key(prim)
        return 0 if key is None else self._levels.get(key, 0)


def _source_path(prim: Usd.Prim) -> str:
    """The path of the gprim ``prim`` reads: its prototype's for an instance proxy."""
    return str((prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim).GetPath())


class _NoteRecorder:
    """Diagnostics for one read_mesh call: passes notes on and keeps them, so that prims
    sharing the surface can be noted alike."""

    def __init__(self, diagnostics: Diagnostics) -> None:
        self._diagnostics = diagnostics
        self.notes: list[tuple[str, str, str, int]] = []

    def note(self, kind: str, template: str, prim_path: str, count: int = 1) -> None:
        self.notes.append((kind, template, prim_path, count))
        self._diagnostics.note(kind, template, prim_path, count)

    def warn(self, message: str, *, once_key: str | None = None) -> None:
        self._diagnostics.warn(message, once_key=once_key)
