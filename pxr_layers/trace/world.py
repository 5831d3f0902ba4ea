"""SceneData as the tracer's world: per-triangle tables, and the instances of shared surfaces.

The tables' rows, in this order:

* the flat rows: meshes in world space (those that are not instanced), then the tessellated
  shapes of the area lights (rect, disk, sphere, cylinder), so a ray that reaches a light
  hits real geometry and the same triangles are sampled for next-event estimation. Light
  triangles are wound so that their geometric normal points the way the light emits.
  Embree's top-level scene holds them as one mesh: a hit's primID is its row.
* the moving rows: meshes that move over the shutter (scene.Mesh.motion_points), at the
  frame's time. Embree's top-level scene holds them as one more mesh, motion-blurred over
  ``motion_steps`` time steps; a hit at a ray's time is shaded from a scratch row holding
  the row between the two steps around that time (trace/instances.py, from
  ``moving_steps``). Like the flat rows, each is its object's own.
* the strand rows: one per scene.Strands (curves, points), holding its object and material
  only. Embree draws each as curve or point geometry; a hit on it is shaded from a scratch
  row holding a small triangle in the tube's or sphere's tangent plane at the hit point, whose
  centroid the hit is (trace/instances.py).
* the prototype rows: each instanced surface (scene.Mesh.prototype) once, in its own space.
  Its placements are Embree instances of one child scene; rays never hit these rows as
  such (trace/instances.py: a hit through instance k on prototype row r is shaded from a
  scratch row holding r placed by k's transform).
* the scratch rows: ``scratch_rows`` rows written while tracing (trace/instances.py), zero
  until then, that no light samples and no table built here counts.

Material primvars (scene.Mesh.primvars) become columns of one scene-wide table,
``corner_primvars``: :func:`primvar_columns` lays them out.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import NamedTuple, get_args

import numpy as np

from ..errors import RenderSettingsError
from ..scene import FLOAT, INDEX, Light, Mesh, SceneData, StrandShape
from .curvature import triangle_curvatures

NOT_A_LIGHT = -1
DISK_SEGMENTS = 64
SPHERE_RINGS, SPHERE_SEGMENTS = 24, 48
CYLINDER_SEGMENTS = 48
CHUNK_TRIANGLES = 1 << 14  # per-chunk temporaries of about a megabyte


@dataclass(frozen=True)
class World:
    """The scene as flat arrays, t triangles over v vertices, world space in metres.

    vertices         : (v, 3) float32 (Embree's input layout)
    triangles        : (t, 3) int32
    geometric_normal : (3, t) float32 unit, right-handed from the winding
    area             : (t,) float32 square metres
    corner_positions : (3 corners, 3, t) float32
    corner_normals   : (3 corners, 3, t) float32 unit shading normals (flat where none
                       authored)
    corner_uvs       : (3 corners, 2, t) float32 (zeros where none authored)
    corner_primvars  : (3 corners, P, t) float32 material primvar values per corner, in the
                       primvars' own units (colours linear RGB as authored), P = 0 when no
                       material reads one; columns per primvar_columns
    primvar_columns  : primvar name → (offset, width): its w components are columns
                       offset .. offset + w − 1 of corner_primvars (a mesh with fewer
                       components has zeros after its own), and column offset + w is its
                       presence: 1.0 on the triangles of meshes that have the primvar, 0.0 on
                       the others and on light shapes (the reader's fallback applies there)
    curvature_k1, curvature_k2 : (t,) float32 principal curvatures, 1/m, k1 ≥ k2, from
                       the shading normals (see curvature.py; 0 on flat geometry)
    principal_direction : (3, t) float32 unit direction of k1
    gradient_s, gradient_t : (3, t) float32 world-space gradients of the texture
                       coordinates over each triangle, 1/m (in the triangle's plane; zero
                       where the uvs are degenerate): ∂(s, t)/∂(a, b) = [[∇s·a, ∇s·b],
                       [∇t·a, ∇t·b]] for any tangent axes a, b

    Per-triangle vectors are component-major (see vectors.py): gathering lanes with
    np.take(..., axis=-1) yields (3, n) rows directly.
    triangle_object  : (t,) int32 index into object_names / object_paths, -1 on prototype
                       and scratch rows (until written)
    triangle_material: (t,) int32 index into SceneData.materials, -1 on light shapes and
                       scratch rows
    triangle_light   : (t,) int32 index into SceneData.lights, -1 on surfaces
    object_instance  : (objects,) int32 per object (object_names order): the instance
                       number N of a point-instanced mesh (scene.Mesh.instance), -1 for
                       other meshes and for lights
    object_mesh      : (objects,) int32 per object: its index in SceneData.meshes, -1 for
                       strands and light shapes
    center, radius   : bounding sphere of the world-space geometry, instances placed (metres)

    vertices, triangles : the flat rows' geometry, what Embree's top-level scene holds
    prototype_vertices, prototype_triangles : per prototype, (v, 3) float32 in its own space
                       and (t, 3) int32 indices into them (its rows, in order)
    prototype_first  : (p,) int64 each prototype's first row
    instance_object  : (i,) int32 each instance's object (Embree's instance id i)
    instance_prototype : (i,) int32 its prototype
    instance_transform : (i, 3, 4) float32 its placement, own space → world metres
                       (scene.Mesh.world_from_points without the last row)
    instance_rotation : (i, 3, 3) float32 the orthogonal part R of the placement's linear
                       part s·R (det −1 for a mirror; rotation_and_scale): normals and
                       directions map by R
    instance_scale   : (i,) float32 its scale s > 0: lengths scale by s, areas s², curvatures
                       and gradients 1/s
    instance_motion_index : (i,) int32 the instance's row of instance_motion, −1 for one that
                       stands still over the shutter
    instance_motion  : (m, k, 3, 4) float32 each moving instance's placement at the k time
                       steps over the shutter (as instance_transform; the moving rows' k)
    moving_vertices  : (k, v, 3) float32 the moving rows' vertices at k = motion_steps ≥ 2
                       evenly spaced times over the shutter (its open at 0, its close at k − 1);
                       (0, 0, 3) without moving rows
    moving_triangles : (m, 3) int32 the moving rows' triangles, indices into them
    moving_first     : the first moving row (= len(triangles): the flat rows come first)
    moving_steps     : MovingSteps, the moving rows' tables at each time step
    strand_first     : the first strand row (after the moving rows)
    strands          : StrandTables of the n strands (scene.SceneData.strands), their rows in order
    strand_shapes    : (n,) their scene.Strands.shape
    scratch_first    : the first scratch row (rows before it: flat, moving, strand and prototype rows)
    """

    vertices: np.ndarray
    triangles: np.ndarray
    geometric_normal: np.ndarray
    area: np.ndarray
    corner_positions: np.ndarray
    corner_normals: np.ndarray
    corner_uvs: np.ndarray
    corner_primvars: np.ndarray
    primvar_columns: dict[str, tuple[int, int]]
    curvature_k1: np.ndarray
    curvature_k2: np.ndarray
    principal_direction: np.ndarray
    gradient_s: np.ndarray
    gradient_t: np.ndarray
    triangle_object: np.ndarray
    triangle_material: np.ndarray
    triangle_light: np.ndarray
    object_names: tuple[str, ...]
    object_paths: tuple[str, ...]
    object_instance: np.ndarray
    object_mesh: np.ndarray
    center: np.ndarray
    radius: float
    prototype_vertices: tuple[np.ndarray, ...] = ()
    prototype_triangles: tuple[np.ndarray, ...] = ()
    prototype_first: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    instance_object: np.ndarray = field(default_factory=lambda: np.zeros(0, INDEX))
    instance_prototype: np.ndarray = field(default_factory=lambda: np.zeros(0, INDEX))
    instance_transform: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 4), FLOAT))
    instance_rotation: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3), FLOAT))
    instance_scale: np.ndarray = field(default_factory=lambda: np.zeros(0, FLOAT))
    instance_motion_index: np.ndarray = field(default_factory=lambda: np.zeros(0, INDEX))
    instance_motion: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3, 4), FLOAT))
    moving_vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3), FLOAT))
    moving_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), INDEX))
    moving_first: int = 0
    moving_steps: MovingSteps | None = None
    strand_first: int = 0
    strands: StrandTables | None = None
    strand_shapes: tuple[str, ...] = ()
    scratch_first: int = -1

    @property
    def triangle_count(self) -> int:
        """Rows a ray can hit: the flat, moving and strand rows and every instanced prototype
        row (scratch rows are not geometry of their own)."""
        return (len(self.triangles) + len(self.moving_triangles) + len(self.strand_shapes)
                + sum(len(triangles) for triangles in self.prototype_triangles))

    @property
    def own_rows(self) -> int:
        """The rows each of which is one object's own (flat, moving and strand rows: the rows
        before the prototypes')."""
        return len(self.triangles) + len(self.moving_triangles) + len(self.strand_shapes)

    @property
    def needs_placing(self) -> bool:
        """Whether some hits are shaded from scratch rows (instances.py): hits through
        instances, on moving rows and on strands."""
        return len(self.instance_object) > 0 or len(self.moving_triangles) > 0 or len(self.strand_shapes) > 0


STRAND_SHAPES = get_args(StrandShape)
"""A strand's basis code is its shape's index here: linear, bezier, bspline, catmullRom, sphere."""
LINEAR, BEZIER, BSPLINE, CATMULL_ROM, SPHERE = range(len(STRAND_SHAPES))


class StrandTables(NamedTuple):
    """The strands (curves, points) of a World, n of them, their vertices and segments
    concatenated.

    vertices      : (v, 4) float32 x, y, z, radius, metres (scene.Strands.vertices)
    segments      : (s,) int32 each segment's first vertex, an index into vertices
    segment_first : (n,) int64 each strand's first segment
    vertex_first  : (n,) int64 each strand's first vertex
    span          : (n,) int32 vertices from a segment's first to its last (scene.Strands.span)
    basis         : (n,) int32 each strand's shape, an index into STRAND_SHAPES
    ribbon        : (n,) bool flat ribbons facing their normals (else round tubes or spheres)
    normals       : (v, 3) float32 the ribbons' normals at their vertices (zero elsewhere)
    motion        : (k, m, 4) float32 the moving strands' vertices at the k time steps
                    (scene.Strands.motion_vertices, concatenated); (1, 0, 4) when none moves
    motion_first  : (n,) int64 each strand's first vertex in ``motion``, −1: it stands still
    """

    vertices: np.ndarray
    segments: np.ndarray
    segment_first: np.ndarray
    vertex_first: np.ndarray
    span: np.ndarray
    basis: np.ndarray
    ribbon: np.ndarray
    normals: np.ndarray
    motion: np.ndarray
    motion_first: np.ndarray

    @classmethod
    def of(cls, strands) -> StrandTables:
        vertex_counts = np.array([len(s.vertices) for s in strands], np.int64)
        segment_counts = np.array([len(s.segments) for s in strands], np.int64)
        vertex_first = np.concatenate([[0], np.cumsum(vertex_counts)[:-1]]).astype(np.int64)
        moving = [s.motion_vertices for s in strands if s.motion_vertices is not None]
        motion = np.concatenate(moving, axis=1).astype(FLOAT) if moving else np.zeros((1, 0, 4), FLOAT)
        moving_counts = [len(s.vertices) if s.motion_vertices is not None else 0 for s in strands]
        motion_first = np.where([s.motion_vertices is not None for s in strands],
                                np.concatenate([[0], np.cumsum(moving_counts)[:-1]]), -1).astype(np.int64)
        return cls(np.concatenate([s.vertices for s in strands] or [np.zeros((0, 4))]).astype(FLOAT),
                   np.concatenate([s.segments + first for s, first in zip(strands, vertex_first)]
                                  or [np.zeros(0)]).astype(INDEX),
                   np.concatenate([[0], np.cumsum(segment_counts)[:-1]]).astype(np.int64), vertex_first,
                   np.array([s.span for s in strands], np.int32),
                   np.array([STRAND_SHAPES.index(s.shape) for s in strands], np.int32),
                   np.array([s.normals is not None for s in strands]),
                   np.concatenate([s.normals if s.normals is not None else np.zeros((len(s.vertices), 3))
                                   for s in strands] or [np.zeros((0, 3))]).astype(FLOAT), motion,
                   motion_first.reshape(len(strands)))


class MovingSteps(NamedTuple):
    """The moving rows' tables at each of the k time steps over the shutter, triangle-major
    (m moving rows, local row r is World row moving_first + r), in World units.

    corner_positions, corner_normals : (k, m, 3 corners, 3) float32
    geometric_normal, principal_direction, gradient_s, gradient_t : (k, m, 3) float32
    area, curvature_k1, curvature_k2 : (k, m) float32
    """

    corner_positions: np.ndarray
    corner_normals: np.ndarray
    geometric_normal: np.ndarray
    principal_direction: np.ndarray
    gradient_s: np.ndarray
    gradient_t: np.ndarray
    area: np.ndarray
    curvature_k1: np.ndarray
    curvature_k2: np.ndarray

    @classmethod
    def empty(cls) -> MovingSteps:
        vectors, scalars = np.zeros((2, 0, 3), FLOAT), np.zeros((2, 0), FLOAT)
        corners = np.zeros((2, 0, 3, 3), FLOAT)
        return cls(corners, corners, vectors, vectors, vectors, vectors, scalars, scalars, scalars)


class GeometryArrays(NamedTuple):
    """The World's per-triangle tables triangle-major, as kernels read them lane by lane
    (one hit's corners are then adjacent in memory).

    corner_positions, corner_normals : (t, 3 corners, 3) float32
    corner_uvs       : (t, 3 corners, 2) float32
    geometric_normal : (t, 3) float32
    area, triangle_material, triangle_light : (t,) as in World
    corner_primvars  : (t, 3 corners, P) float32, World.corner_primvars triangle-major (columns
                       and presence per World.primvar_columns); (t, 3, 0) when P = 0, so that
                       kernels see the same array type either way
    thickness        : (t,) float32 metres, how far the object reaches behind a hit along its
                       normal: a placed strand row's diameter (instances.py), 0 for surfaces
    """

    corner_positions: np.ndarray
    corner_normals: np.ndarray
    corner_uvs: np.ndarray
    geometric_normal: np.ndarray
    area: np.ndarray
    triangle_material: np.ndarray
    triangle_light: np.ndarray
    corner_primvars: np.ndarray
    thickness: np.ndarray


def geometry_arrays(world: World) -> GeometryArrays:
    rows = world.scratch_first if world.scratch_first >= 0 else len(world.area)

    def triangle_major(table: np.ndarray) -> np.ndarray:
        # the scratch rows stay zero pages, untouched until a hit is placed in them
        major = np.zeros((table.shape[-1], *table.shape[:-1]), table.dtype)
        major[:rows] = np.moveaxis(table[..., :rows], -1, 0)
        return major

    return GeometryArrays(triangle_major(world.corner_positions), triangle_major(world.corner_normals),
                          triangle_major(world.corner_uvs), triangle_major(world.geometric_normal), world.area,
                          world.triangle_material, world.triangle_light, triangle_major(world.corner_primvars),
                          np.zeros(len(world.area), np.float32))


def primvar_columns(meshes) -> dict[str, tuple[int, int]]:
    """name → (offset, width) of every primvar of ``meshes`` (scene.Mesh) in corner_primvars:
    names in sorted order, each its largest width over the meshes plus one presence column."""
    widths: dict[str, int] = {}
    for mesh in meshes:
        for name, values in mesh.primvars.items():
            widths[name] = max(widths.get(name, 0), values.shape[2])
    columns, offset = {}, 0
    for name in sorted(widths):
        columns[name] = (offset, widths[name])
        offset += widths[name] + 1
    return columns


def build_world(scene: SceneData, scratch_rows: int = 0) -> World:
    """Every mesh and area-light shape of `scene` as one World (rows: see the module
    docstring), with `scratch_rows` scratch rows after them.

    The per-triangle tables are filled chunk by chunk (CHUNK_TRIANGLES): temporaries the size
    of the whole scene would cost more in fresh pages than in arithmetic.
    """
    # objects (name, path, instance, mesh index) in order: the meshes, the strands, then the light shapes
    objects: list[tuple[str, str, int, int]] = []
    flat: list[tuple[Mesh, int, int]] = []  # (mesh or light shape, its light or NOT_A_LIGHT, object)
    instanced: list[tuple[Mesh, int]] = []  # (placement of a shared surface, object)
    moving: list[tuple[Mesh, int]] = []  # (a mesh that moves over the shutter, object)
    for index, mesh in enumerate(scene.meshes):
        if not len(mesh.triangles):
            continue
        if mesh.prototype >= 0:
            instanced.append((mesh, len(objects)))
        elif mesh.motion_points is not None:
            moving.append((mesh, len(objects)))
        else:
            flat.append((mesh, NOT_A_LIGHT, len(objects)))
        objects.append((mesh.name, mesh.path, mesh.instance, index))
    strand_objects = []
    for strands in scene.strands:
        strand_objects.append(len(objects))
        objects.append((strands.name, strands.path, -1, -1))
    for light_index, light in enumerate(scene.lights):
        shape = light_shape(light)
        if shape is not None:
            points, triangles = shape
            flat.append((Mesh(light.name, light.path, points, triangles, None, None, None,
                              np.full(len(triangles), -1, dtype=INDEX)), light_index, len(objects)))
            objects.append((light.name, light.path, -1, -1))
    if not objects and not scene.lights:
        raise RenderSettingsError(f"{scene.stage_path}: nothing to render (no geometry and no lights)")
    if not objects:
        # A sky alone (dome or distant lights, no geometry): every camera ray escapes. One empty
        # piece keeps every table below well formed, with zero rows.
        flat.append((Mesh("", "", np.zeros((0, 3), FLOAT), np.zeros((0, 3), INDEX), None, None, None,
                          np.zeros(0, INDEX)), NOT_A_LIGHT, 0))
        objects.append(("", "", -1, -1))
    # each prototype once, as its first placement's geometry (all of them share it)
    first_placement: dict[int, Mesh] = {}
    for mesh, _ in instanced:
        first_placement.setdefault(mesh.prototype, mesh)
    prototypes = list(first_placement.values())
    prototype_of = {number: order for order, number in enumerate(first_placement)}
    pieces = [piece for piece, _, _ in flat] + [mesh for mesh, _ in moving] + prototypes

    flat_count = sum(len(piece.triangles) for piece, _, _ in flat)
    count = sum(len(piece.triangles) for piece in pieces) + len(scene.strands) + scratch_rows
    geometric_normal = np.zeros((3, count), FLOAT)
    area = np.zeros(count, FLOAT)
    corner_positions = np.zeros((3, 3, count), FLOAT)
    corner_normals = np.zeros((3, 3, count), FLOAT)
    corner_uvs = np.zeros((3, 2, count), FLOAT)
    columns = primvar_columns(pieces)
    column_count = sum(width + 1 for _, width in columns.values())
    corner_primvars = np.zeros((3, column_count, count), FLOAT)  # absent: values and presence 0
    triangle_object = np.full(count, -1, INDEX)
    triangle_material = np.full(count, -1, INDEX)
    triangle_light = np.full(count, NOT_A_LIGHT, INDEX)
    tables = (geometric_normal, area, corner_positions, corner_normals, corner_uvs, corner_primvars, columns)

    vertices = np.empty((sum(len(piece.points) for piece, _, _ in flat), 3), FLOAT)
    triangles = np.empty((flat_count, 3), INDEX)
    vertex_offset = row = 0
    for piece, light_index, object_index in flat:
        points = np.asarray(piece.points, dtype=FLOAT)
        vertices[vertex_offset:vertex_offset + len(points)] = points
        own = slice(row, row + len(piece.triangles))
        np.add(piece.triangles, vertex_offset, out=triangles[own], casting="unsafe")
        triangle_object[own], triangle_material[own], triangle_light[own] = object_index, piece.triangle_material, light_index
        _fill_rows(piece, row, *tables)
        vertex_offset += len(points)
        row += len(piece.triangles)
    moving_vertices, moving_triangles, moving_steps = _moving_rows(moving, row, triangle_object, triangle_material,
                                                                   tables)
    row += len(moving_triangles)
    strand_first = row
    for strands, object_index in zip(scene.strands, strand_objects):
        triangle_object[row], triangle_material[row] = object_index, strands.material
        row += 1
    prototype_first = np.zeros(len(prototypes), np.int64)
    for order, piece in enumerate(prototypes):
        prototype_first[order] = row
        triangle_material[row:row + len(piece.triangles)] = piece.triangle_material
        _fill_rows(piece, row, *tables)
        row += len(piece.triangles)

    # per-row tables of the rows before the scratch rows, which stay zero pages until written
    real = count - scratch_rows
    k1, k2, principal_direction = (np.zeros((3, count), FLOAT) if axis else np.zeros(count, FLOAT)
                                   for axis in (0, 0, 1))
    gradient_s, gradient_t = np.zeros((3, count), FLOAT), np.zeros((3, count), FLOAT)
    k1[:real], k2[:real], principal_direction[:, :real] = triangle_curvatures(corner_positions[..., :real],
                                                                             corner_normals[..., :real])
    gradient_s[:, :real], gradient_t[:, :real] = uv_gradients(corner_positions[..., :real], corner_uvs[..., :real])
    placements = np.array([mesh.world_from_points for mesh, _ in instanced], np.float64).reshape(-1, 4, 4)
    rotation, scale = rotation_and_scale(placements[:, :3, :3])
    instance_prototype = [prototype_of[mesh.prototype] for mesh, _ in instanced]
    motions = [(number, mesh.motion_world_from_points) for number, (mesh, _) in enumerate(instanced)
               if mesh.motion_world_from_points is not None]
    if len({len(motion) for _, motion in motions} | ({len(moving_vertices)} if len(moving_triangles) else set())) > 1:
        raise ValueError("moving meshes and instances need one count of time steps")
    instance_motion_index = np.full(len(instanced), -1, INDEX)
    instance_motion_index[[number for number, _ in motions]] = np.arange(len(motions))
    instance_motion = (np.stack([motion for _, motion in motions]) if motions else np.zeros((0, 2, 4, 4)))
    swept = [instance_prototype[number] for number, motion in motions for _ in motion]  # every step's box too
    strand_tables = StrandTables.of(scene.strands)
    swollen = [strand_tables.vertices[:, :3] + sign * strand_tables.vertices[:, 3:] for sign in (-1, 1)]
    low, high = _bounds(np.concatenate([vertices, moving_vertices.reshape(-1, 3), *swollen]).astype(FLOAT), prototypes,
                        instance_prototype + swept,
                        np.concatenate([placements, instance_motion.reshape(-1, 4, 4)]))
    center = (low + high) / 2
    return World(
        vertices=vertices,
        triangles=triangles,
        geometric_normal=geometric_normal,
        area=area,
        corner_positions=corner_positions,
        corner_normals=corner_normals,
        corner_uvs=corner_uvs,
        corner_primvars=corner_primvars,
        primvar_columns=columns,
        curvature_k1=k1,
        curvature_k2=k2,
        principal_direction=principal_direction,
        gradient_s=gradient_s,
        gradient_t=gradient_t,
        triangle_object=triangle_object,
        triangle_material=triangle_material,
        triangle_light=triangle_light,
        object_names=tuple(name for name, _, _, _ in objects),
        object_paths=tuple(path for _, path, _, _ in objects),
        object_instance=np.asarray([instance for _, _, instance, _ in objects], dtype=INDEX),
        object_mesh=np.asarray([mesh for _, _, _, mesh in objects], dtype=INDEX),
        center=center.astype(np.float64),
        radius=float(np.linalg.norm(high - low) / 2) or 1.0,
        prototype_vertices=tuple(np.ascontiguousarray(piece.points, FLOAT) for piece in prototypes),
        prototype_triangles=tuple(np.ascontiguousarray(piece.triangles, INDEX) for piece in prototypes),
        prototype_first=prototype_first,
        instance_object=np.array([object_index for _, object_index in instanced], INDEX),
        instance_prototype=np.array(instance_prototype, INDEX),
        instance_transform=np.ascontiguousarray(placements[:, :3], FLOAT),
        instance_rotation=np.ascontiguousarray(rotation, FLOAT),
        instance_scale=scale.astype(FLOAT),
        instance_motion_index=instance_motion_index,
        instance_motion=np.ascontiguousarray(instance_motion[:, :, :3], FLOAT),
        moving_vertices=moving_vertices,
        moving_triangles=moving_triangles,
        moving_first=flat_count,
        moving_steps=moving_steps,
        strand_first=strand_first,
        strands=strand_tables,
        strand_shapes=tuple(strands.shape for strands in scene.strands),
        scratch_first=count - scratch_rows,
    )


def _moving_rows(moving: list[tuple[Mesh, int]], first_row: int, triangle_object: np.ndarray,
                 triangle_material: np.ndarray, tables: tuple) -> tuple[np.ndarray, np.ndarray, MovingSteps]:
    """Write the moving meshes' rows (at the frame's time) from `first_row` on; returns their
    vertices (k, v, 3) and triangles (m, 3) for Embree and their tables at each time step."""
    if not moving:
        return np.zeros((0, 0, 3), FLOAT), np.zeros((0, 3), INDEX), MovingSteps.empty()
    steps = {len(mesh.motion_points) for mesh, _ in moving}
    if len(steps) != 1 or min(steps) < 2:
        raise ValueError(f"moving meshes need one count of time steps, 2 or more, not {sorted(steps)}")
    step_count = steps.pop()
    vertices = np.concatenate([mesh.motion_points for mesh, _ in moving], axis=1).astype(FLOAT)
    offsets = np.cumsum([0] + [mesh.motion_points.shape[1] for mesh, _ in moving])
    triangles = np.concatenate([mesh.triangles + offset for (mesh, _), offset in zip(moving, offsets)]).astype(INDEX)
    row = first_row
    for mesh, object_index in moving:
        own = slice(row, row + len(mesh.triangles))
        triangle_object[own], triangle_material[own] = object_index, mesh.triangle_material
        _fill_rows(mesh, row, *tables)
        row += len(mesh.triangles)
    count, columns = len(triangles), tables[-1]
    per_step: list[list[np.ndarray]] = [[] for _ in MovingSteps._fields]
    for step in range(step_count):
        geometric_normal, area = np.zeros((3, count), FLOAT), np.zeros(count, FLOAT)
        positions, normals = np.zeros((3, 3, count), FLOAT), np.zeros((3, 3, count), FLOAT)
        uvs = np.zeros((3, 2, count), FLOAT)
        primvars = np.zeros((3, tables[5].shape[1], count), FLOAT)
        start = 0
        for mesh, _ in moving:
            posed = dataclasses.replace(mesh, points=mesh.motion_points[step],
                                        normal_values=None if mesh.motion_normals is None else mesh.motion_normals[step])
            _fill_rows(posed, start, geometric_normal, area, positions, normals, uvs, primvars, columns)
            start += len(mesh.triangles)
        k1, k2, principal = triangle_curvatures(positions, normals)
        gradient_s, gradient_t = uv_gradients(positions, uvs)
        tables_at_step = {"corner_positions": positions, "corner_normals": normals,
                          "geometric_normal": geometric_normal, "principal_direction": principal,
                          "gradient_s": gradient_s, "gradient_t": gradient_t, "area": area, "curvature_k1": k1,
                          "curvature_k2": k2}
        for field_index, name in enumerate(MovingSteps._fields):
            per_step[field_index].append(np.moveaxis(tables_at_step[name], -1, 0))
    return vertices, triangles, MovingSteps(*(np.ascontiguousarray(np.stack(tables), FLOAT) for tables in per_step))


def flatten_instances(scene: SceneData) -> SceneData:
    """`scene` with every instanced mesh (scene.Mesh.prototype) as a flat mesh of its own:
    its points and normals placed in world metres, corners 1 and 2 swapped under a mirror
    (the winding stays counter-clockwise seen from the front, as stage/placement.py does)."""
    if all(mesh.prototype < 0 for mesh in scene.meshes):
        return scene
    return dataclasses.replace(scene, meshes=tuple(_flattened(mesh) if mesh.prototype >= 0 else mesh
                                                   for mesh in scene.meshes))


def rotation_and_scale(linear: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The placements' (n, 3, 3) linear parts A ≈ s·R as (R (n, 3, 3) the nearest orthogonal
    matrix (polar decomposition; det −1 for a mirror), s (n,) = |det A|^(1/3)): USD composes
    point instances from unnormalised, often half-precision quaternions, a little off a
    similarity (stage/placement.is_instanceable)."""
    if not len(linear):
        return np.zeros((0, 3, 3)), np.zeros(0)
    left, _, right = np.linalg.svd(linear)
    return left @ right, np.cbrt(np.abs(np.linalg.det(linear)))


def _flattened(mesh: Mesh) -> Mesh:
    """`mesh`'s placement as a flat mesh (a moving instance: a moving mesh, its points and
    normals placed at each time step)."""

    def placed(placement: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        linear = placement[:3, :3]
        points = (np.asarray(mesh.points, np.float64) @ linear.T + placement[:3, 3]).astype(FLOAT)
        if mesh.normal_values is None:
            return points, None
        rotation = rotation_and_scale(linear[None])[0][0]
        return points, (np.asarray(mesh.normal_values, np.float64) @ rotation.T).astype(FLOAT)

    points, normal_values = placed(np.asarray(mesh.world_from_points, np.float64))
    motion_points = motion_normals = None
    if mesh.motion_world_from_points is not None:
        steps = [placed(placement) for placement in np.asarray(mesh.motion_world_from_points, np.float64)]
        motion_points = np.stack([step_points for step_points, _ in steps])
        motion_normals = None if normal_values is None else np.stack([normals for _, normals in steps])
    corners = [0, 2, 1] if np.linalg.det(np.asarray(mesh.world_from_points)[:3, :3]) < 0 else [0, 1, 2]

    def wound(per_corner):
        return None if per_corner is None else np.ascontiguousarray(np.asarray(per_corner)[:, corners])

    return dataclasses.replace(mesh, points=points, triangles=wound(mesh.triangles), normal_values=normal_values,
                               normal_indices=wound(mesh.normal_indices), uvs=wound(mesh.uvs),
                               primvars={name: wound(values) for name, values in mesh.primvars.items()},
                               prototype=-1, world_from_points=None, motion_points=motion_points,
                               motion_normals=motion_normals, motion_world_from_points=None)


def _fill_rows(piece: Mesh, first_row: int, geometric_normal, area, corner_positions, corner_normals, corner_uvs,
               corner_primvars, columns) -> None:
    """Write `piece`'s rows of the geometry tables, from `first_row` on (in its own space)."""
    # Gathers one component at a time (contiguous (n,) rows in, contiguous rows out) fill the
    # component-major tables without a transposed copy.
    point_components = _components(np.asarray(piece.points, dtype=FLOAT))
    normal_components = None if piece.normal_values is None else _components(piece.normal_values)
    size = len(piece.triangles)
    for start in range(0, size, CHUNK_TRIANGLES):
        rows = slice(start, min(start + CHUNK_TRIANGLES, size))
        out = slice(first_row + rows.start, first_row + rows.stop)
        tris = np.asarray(piece.triangles[rows], dtype=INDEX)
        positions = corner_positions[:, :, out]
        _gather_corners(point_components, tris, positions)
        unit_normal, double_area = _unit_cross(positions[1] - positions[0], positions[2] - positions[0])
        geometric_normal[:, out] = unit_normal
        np.divide(double_area, 2, out=area[out])
        if normal_components is None:
            corner_normals[:, :, out] = unit_normal  # flat: the geometric normal at each corner
        else:
            _gather_corners(normal_components, piece.normal_indices[rows], corner_normals[:, :, out])
        if piece.uvs is not None:
            corner_uvs[:, :, out] = np.moveaxis(piece.uvs[rows], 0, -1)
        for name, values in piece.primvars.items():
            offset, width = columns[name]
            own_width = values.shape[2]
            # (n, 3, w) → (3, w, n); slices of broadcast (constant) values stay views
            corner_primvars[:, offset:offset + own_width, out] = np.transpose(values[rows], (1, 2, 0))
            corner_primvars[:, offset + width, out] = 1.0


def _bounds(vertices: np.ndarray, prototypes: list[Mesh], instance_prototype: list[int], placements: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) (3,) float64 corners of the box around the flat `vertices` and every
    instance's placed prototype box (zeros for no geometry)."""
    lows, highs = ([vertices.min(axis=0)], [vertices.max(axis=0)]) if len(vertices) else ([], [])
    if len(placements):
        boxes = np.array([[piece.points.min(axis=0), piece.points.max(axis=0)] for piece in prototypes], np.float64)
        corners = boxes[:, [[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 1], [1, 0, 0], [1, 0, 1], [1, 1, 0], [1, 1, 1]],
                        [0, 1, 2]]  # (p, 8, 3)
        placed = np.einsum("kij,kcj->kci", placements[:, :3, :3], corners[instance_prototype]) + placements[:, None, :3, 3]
        lows.append(placed.min(axis=(0, 1)))
        highs.append(placed.max(axis=(0, 1)))
    if not lows:
        return np.zeros(3), np.zeros(3)
    return np.min(lows, axis=0).astype(np.float64), np.max(highs, axis=0).astype(np.float64)


def uv_gradients(corner_positions: np.ndarray, corner_uvs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of s and t over each triangle: (3, t) float32 each, in 1/m.

    Each gradient g lies in the triangle's plane with g·(p_k − p_0) = uv_k − uv_0 for the
    two edges from corner 0; degenerate triangles get zero. Computed in float64 by chunks.
    """
    count = corner_positions.shape[2]
    gradient_s, gradient_t = np.empty((3, count), FLOAT), np.empty((3, count), FLOAT)
    for start in range(0, count, CHUNK_TRIANGLES):
        rows = slice(start, min(start + CHUNK_TRIANGLES, count))
        gradient_s[:, rows], gradient_t[:, rows] = _chunk_uv_gradients(corner_positions[:, :, rows], corner_uvs[:, :, rows])
    return gradient_s, gradient_t


def _chunk_uv_gradients(corner_positions: np.ndarray, corner_uvs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = corner_positions.astype(np.float64)
    uv = corner_uvs.astype(np.float64)
    edge_1, edge_2 = p[1] - p[0], p[2] - p[0]
    g11 = np.sum(edge_1 * edge_1, axis=0)
    g12 = np.sum(edge_1 * edge_2, axis=0)
    g22 = np.sum(edge_2 * edge_2, axis=0)
    determinant = g11 * g22 - g12 * g12
    regular = determinant > 1e-12 * np.maximum(g11 * g22, 1e-300)
    inverse = np.where(regular, 1.0 / np.where(regular, determinant, 1.0), 0.0)
    gradients = []
    for component in (0, 1):
        d1 = uv[1, component] - uv[0, component]
        d2 = uv[2, component] - uv[0, component]
        alpha = (g22 * d1 - g12 * d2) * inverse
        beta = (g11 * d2 - g12 * d1) * inverse
        gradients.append(alpha * edge_1 + beta * edge_2)
    return gradients[0], gradients[1]


def _components(vectors: np.ndarray) -> list[np.ndarray]:
    """(n, 3) → its three (n,) float32 columns, each contiguous."""
    return [np.ascontiguousarray(vectors[:, axis], dtype=FLOAT) for axis in range(3)]


def _gather_corners(components: list[np.ndarray], corners: np.ndarray, out: np.ndarray) -> None:
    """out[corner, axis] = components[axis][corners[:, corner]]: (3 corners, 3, n) from (t, 3)
    indices (validated upstream, hence mode="clip": no bounds check, no buffering)."""
    for corner in range(3):
        index = corners[:, corner]
        for axis, component in enumerate(components):
            np.take(component, index, out=out[corner, axis], mode="clip")


def _unit_cross(edge_a: np.ndarray, edge_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, n) float32 unit edge_a × edge_b and its (n,) length, for (3, n) float32 edges
    (the arithmetic of np.cross and np.linalg.norm, component by component)."""
    cross = np.empty_like(edge_a)
    np.subtract(edge_a[1] * edge_b[2], edge_a[2] * edge_b[1], out=cross[0])
    np.subtract(edge_a[2] * edge_b[0], edge_a[0] * edge_b[2], out=cross[1])
    np.subtract(edge_a[0] * edge_b[1], edge_a[1] * edge_b[0], out=cross[2])
    length = np.sqrt(cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2])
    cross /= np.maximum(length, 1e-30)
    return cross, length


def light_shape(light: Light) -> tuple[np.ndarray, np.ndarray] | None:
    """World-space triangles of an area light, wound so the normal is the emitting side.

    Returns (points (v, 3) float32 metres, triangles (t, 3) int32), or None for lights with
    no shape (distant, dome, and the point and line a treatAsPoint/treatAsLine light is).
    """
    if light.kind == "rect":
        w, h = light.width / 2, light.height / 2
        local = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], dtype=np.float64)
        # Counter-clockwise seen from +Z gives a +Z normal; rect lights emit along -Z.
        triangles = np.array([[0, 2, 1], [0, 3, 2]])
    elif light.kind == "disk":
        angles = np.linspace(0, 2 * np.pi, DISK_SEGMENTS, endpoint=False)
        rim = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1) * light.radius
        local = np.vstack([[0.0, 0.0, 0.0], rim])
        nxt = np.roll(np.arange(DISK_SEGMENTS), -1) + 1
        triangles = np.stack([np.zeros(DISK_SEGMENTS, int), nxt, np.arange(DISK_SEGMENTS) + 1], axis=1)
    elif light.kind == "sphere":
        local, triangles = _uv_sphere(light.radius)
    elif light.kind == "cylinder":
        local, triangles = _open_cylinder(light.radius, light.length)
    else:
        return None
    homogeneous = np.hstack([local, np.ones((len(local), 1))])
    world = (homogeneous @ np.asarray(light.world_from_light, dtype=np.float64).T)[:, :3]
    if np.linalg.det(np.asarray(light.world_from_light)[:3, :3]) < 0:
        triangles = triangles[:, ::-1]  # a mirroring transform flips the winding
    return world.astype(FLOAT), np.ascontiguousarray(triangles, dtype=INDEX)


def _uv_sphere(radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Outward-facing UV sphere: (points, triangles)."""
    theta = np.linspace(0, np.pi, SPHERE_RINGS + 1)
    phi = np.linspace(0, 2 * np.pi, SPHERE_SEGMENTS, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    points = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3) * radius
    ring = lambda i, j: i * SPHERE_SEGMENTS + (j % SPHERE_SEGMENTS)
    triangles = []
    for i in range(SPHERE_RINGS):
        for j in range(SPHERE_SEGMENTS):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j), ring(i + 1, j + 1)
            if i > 0:
                triangles.append([a, b, c])
            if i < SPHERE_RINGS - 1:
                triangles.append([b, d, c])
    return points, np.array(triangles)


def _open_cylinder(radius: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Outward-facing tube along local X (UsdLux CylinderLight): (points, triangles)."""
    phi = np.linspace(0, 2 * np.pi, CYLINDER_SEGMENTS, endpoint=False)
    ring = np.stack([np.zeros_like(phi), np.cos(phi) * radius, np.sin(phi) * radius], axis=1)
    points = np.vstack([ring + [-length / 2, 0, 0], ring + [length / 2, 0, 0]])
    j = np.arange(CYLINDER_SEGMENTS)
    k = (j + 1) % CYLINDER_SEGMENTS
    n = CYLINDER_SEGMENTS
    triangles = np.vstack([np.stack([j, k, j + n], 1), np.stack([k, k + n, j + n], 1)])
    return points, triangles
