"""Place an object-space LocalSurface in the world: scene.Mesh in metres.

Handles what depends on the transform: the stage-units → metres scale, mirroring
transforms (a negative determinant reverses the winding, UsdGeom_WindingOrder), normals
through the cofactor matrix, and degenerate triangles (zero area once placed).

What does not depend on the transform is done once per surface by :func:`prepare_surface`
and shared by every placement of it (instances, and prims that read the same opinions):

* normals are indexed, one value per point where the corners of the point agree
  (:func:`_index_by_point`), so a placement transforms (points, 3) values, not (t, 3, 3);
* smooth normals are summed in object space: a linear map A takes a triangle's area vector
  e1 × e2 to (A e1) × (A e2) = cof(A) (e1 × e2), so the world-space sums are the cofactor
  matrix times the object-space ones (:func:`~.transforms.normal_matrix`), whatever A is;
* the degenerate-triangle test: |e1 × e2| / (longest edge)² does not change under a
  similarity (rotation, mirror, uniform scale), so for those placements the object-space
  test holds; other placements test their world-space triangles;
* the int32 and float32 arrays a scene.Mesh shares (triangles, normal indices, uvs,
  primvars), read-only. Constant and uniform primvars stay the broadcast views the reader
  made (:func:`_select_corners`): a constant one costs its placements no per-corner memory.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from pxr_layers.scene import FLOAT, INDEX, Mesh

from .diagnostics import Diagnostics
from .surfaces import LocalSurface
from .transforms import normal_matrix

logger = logging.getLogger(__name__)

# A triangle is degenerate when |e1 × e2| <= this × (longest edge)², i.e. its height is
# below float32 resolution relative to its length: its normal is noise and Embree may miss
# it, so it is as good as zero-area.
_DEGENERATE_HEIGHT_RATIO = 1e-7

# A linear map is taken for a similarity when AᵀA is s²·I to this relative tolerance: far
# below the test's own resolution, far above the rounding of composed rotations.
_SIMILARITY_TOLERANCE = 1e-9

# A placement this close to a similarity (relative, in AᵀA) may be an instance: USD composes
# point instances from unnormalised, often half-precision quaternions, up to a few 1e-3 off a
# rotation; the tracer's normals then turn by as much (a tenth of a degree or so).
INSTANCE_SIMILARITY_TOLERANCE = 1e-2

# Faces of up to this many triangles find their distinct vertices by comparing neighbouring
# triangles (fans of quads and small polygons: all but a few faces); bigger ones by np.unique.
_FACE_LOOKBACK = 8

# The winding that undoes a mirror: two corners swapped, corner 0 kept.
_MIRRORED = [0, 2, 1]

# Placed points farther than this from the origin (in metres, on any axis) skip their gprim.
# The tracer works in float32: within 1e9 m (2.6 times the Moon's distance) edges stay below
# 2e9 m, and the squared lengths of their cross products (edge⁴ = 1.6e37, trace/world.py)
# below float32's 3.4e38. A set that big would be resolved to about 100 m there anyway.
MAX_WORLD_COORDINATE = 1e9


@dataclass(frozen=True, eq=False)
class _Layout:
    """A surface's per-corner arrays in one winding, with or without its object-space
    degenerate triangles; shared read-only by the placements that use it.

    triangles      : (k, 3) int32
    normal_indices : (k, 3) int32 or None
    uvs            : (k, 3, 2) float32 or None
    kept           : (k,) int64 the surface triangles kept, or None for all of them
    primvars       : name → (k, 3, w) float32 (stride-0 views stay views: _select_corners)
    """

    triangles: np.ndarray
    normal_indices: np.ndarray | None
    uvs: np.ndarray | None
    kept: np.ndarray | None
    primvars: Mapping[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class PreparedSurface:
    """A LocalSurface with the object-space work that its placements share (see module).

    surface       : the LocalSurface (object space, stage units)
    normal_values : (n, 3) float64 object-space normal directions, not unit (smooth: the
                    area-weighted sums), or None for flat shading
    normal_indices: (t, 3) int64 index into normal_values per corner, or None
    degenerate    : (t,) bool, degenerate in object space (and under any similarity)
    """

    surface: LocalSurface
    normal_values: np.ndarray | None
    normal_indices: np.ndarray | None
    degenerate: np.ndarray
    # (mirrored, drop_degenerate) → _Layout, made on first use: a cache, not a fact.
    _layouts: dict[tuple[bool, bool], _Layout] = field(default_factory=dict, repr=False)

    def layout(self, mirrored: bool, drop_degenerate: bool) -> _Layout:
        """The corner arrays for a placement: ``mirrored`` swaps corners 1 and 2,
        ``drop_degenerate`` leaves out the object-space degenerate triangles."""
        key = (mirrored, drop_degenerate)
        if key not in self._layouts:
            self._layouts[key] = self._make_layout(mirrored, drop_degenerate)
        return self._layouts[key]

    def _make_layout(self, mirrored: bool, drop_degenerate: bool) -> _Layout:
        surface = self.surface
        kept = np.flatnonzero(~self.degenerate) if drop_degenerate and self.degenerate.any() else None

        def corners(per_triangle: np.ndarray | None, dtype) -> np.ndarray | None:
            if per_triangle is None:
                return None
            if kept is not None:
                per_triangle = np.take(per_triangle, kept, axis=0)
            if mirrored:
                per_triangle = per_triangle[:, _MIRRORED]
            return _read_only(np.ascontiguousarray(per_triangle, dtype=dtype))

        triangles = corners(surface.triangles, INDEX)
        if self.normal_indices is surface.triangles:
            normal_indices = triangles  # one normal per point: the same array
        else:
            normal_indices = corners(self.normal_indices, INDEX)
        primvars = {name: _select_corners(values, kept, mirrored) for name, values in surface.primvars.items()}
        return _Layout(triangles, normal_indices, corners(surface.uvs, FLOAT), kept, primvars)


def prepare_surface(surface: LocalSurface) -> PreparedSurface:
    """The object-space work shared by all placements of ``surface`` (see module).

    Points too big to square (a radius of 1e300) give non-finite area vectors here, without
    numpy's overflow warnings: place_surface skips such a surface, out of reach, unless its
    transform brings it back, and then falls back to geometric normals (_world_normals)."""
    with np.errstate(over="ignore", invalid="ignore"):
        area_vectors, degenerate = _triangle_geometry(surface.points, surface.triangles)
        normal_values = normal_indices = None
        if surface.normals is not None:
            normal_values, normal_indices = _index_by_point(surface.normals, surface.triangles, len(surface.points))
        elif surface.smooth:
            normal_values = _area_weighted_vertex_normals(
                area_vectors, surface.triangles, surface.triangle_face, len(surface.points)
            )
            normal_indices = surface.triangles
    return PreparedSurface(
        surface=surface, normal_values=normal_values, normal_indices=normal_indices, degenerate=degenerate
    )


def place_surface(
    surface: LocalSurface | PreparedSurface,
    world_from_local: np.ndarray,
    meters_per_unit: float,
    triangle_material: np.ndarray,
    name: str,
    path: str,
    diagnostics: Diagnostics,
    instance: int = -1,
) -> Mesh | None:
    """Transform ``surface`` to world metres; None when no triangle survives, or (with a
    warning) when the placed points are beyond MAX_WORLD_COORDINATE or not finite (finite
    inputs can overflow: a radius of 1e300, scales of 1e200 twice).

    surface           : a LocalSurface, or its PreparedSurface to share the object-space work
                        between several placements
    world_from_local  : (4, 4) float64, column convention, stage units
    triangle_material : (t,) integer material index per triangle of ``surface``
    instance          : Mesh.instance (GprimPlacement.instance), -1 if not point-instanced
    """
    prepared = surface if isinstance(surface, PreparedSurface) else prepare_surface(surface)
    local = prepared.surface
    linear = world_from_local[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is found just below
        points = local.points @ linear.T
        points += world_from_local[:3, 3]
        points *= meters_per_unit
        reach = float(np.abs(points).max(initial=0.0))
    if not reach <= MAX_WORLD_COORDINATE:  # NaN too
        _note_out_of_reach(diagnostics, path)
        return None
    # A mirror turns counter-clockwise into clockwise: two corners swapped back.
    mirrored = bool(np.linalg.det(linear) < 0.0)
    similarity = _is_similarity(linear)
    layout = prepared.layout(mirrored, drop_degenerate=similarity)
    triangles, normal_indices, uvs = layout.triangles, layout.normal_indices, layout.uvs
    primvars = layout.primvars
    if layout.kept is not None:
        triangle_material = triangle_material[layout.kept]
    if similarity:
        dropped = int(prepared.degenerate.sum())
    else:
        _, degenerate = _triangle_geometry(points, triangles)
        dropped = int(degenerate.sum())
        if dropped:
            keep = ~degenerate
            triangles, triangle_material = triangles[keep], triangle_material[keep]
            normal_indices = None if normal_indices is None else normal_indices[keep]
            uvs = None if uvs is None else uvs[keep]
            primvars = {name: _select_corners(values, np.flatnonzero(keep), False) for name, values in primvars.items()}
    if dropped:
        diagnostics.note(
            "degenerate-triangles",
            "dropped {count} degenerate (zero-area) triangles on: {prims}",
            path,
            dropped,
        )
    if len(triangles) == 0:
        logger.debug("%s has no triangles; skipped", path)
        return None

    normal_values = None
    if prepared.normal_values is not None:
        normal_values, normal_indices = _world_normals(
            prepared.normal_values @ normal_matrix(linear).T, normal_indices, points, triangles
        )
    return Mesh(
        name=name,
        path=path,
        points=np.ascontiguousarray(points, dtype=FLOAT),
        triangles=triangles,
        normal_values=normal_values,
        normal_indices=normal_indices,
        uvs=uvs,
        triangle_material=np.ascontiguousarray(triangle_material, dtype=INDEX),
        instance=int(instance),
        primvars=primvars,
    )


def _note_out_of_reach(diagnostics: Diagnostics, path: str) -> None:
    diagnostics.note(
        "out-of-reach",
        f"gprims placed beyond {MAX_WORLD_COORDINATE:g} m from the origin (or whose placed points "
        "overflow) skipped: {prims}",
        path,
    )


def is_instanceable(world_from_local: np.ndarray) -> bool:
    """Whether a placement may be an instance of its surface (scene.Mesh.prototype): a
    similarity to INSTANCE_SIMILARITY_TOLERANCE, so that the tracer maps normals by the
    nearest rotation and lengths by one scale (Embree places the points by the transform
    itself: silhouettes are exact)."""
    return _is_similarity(world_from_local[:3, :3], INSTANCE_SIMILARITY_TOLERANCE)


@dataclass(frozen=True, eq=False)
class SharedSurface:
    """A surface in its own space shared by its instanced placements (scene.Mesh.prototype).

    mesh    : its geometry, stage units (name, path and placement are each placement's)
    corners : (8, 3) float64 the corners of its box
    dropped : how many degenerate triangles it leaves out (each placement says so)
    """

    mesh: Mesh
    corners: np.ndarray
    dropped: int


def shared_surface(surface: PreparedSurface, triangle_material: np.ndarray, prototype: int) -> SharedSurface:
    """``surface`` as the prototype number `prototype`: its winding as authored, its
    degenerate triangles dropped (they stay degenerate under a similarity), unit normals."""
    layout = surface.layout(mirrored=False, drop_degenerate=True)
    if layout.kept is not None:
        triangle_material = triangle_material[layout.kept]
    points = np.asarray(surface.surface.points, np.float64)
    normal_values, normal_indices = None, layout.normal_indices
    if surface.normal_values is not None:
        normal_values, normal_indices = _world_normals(surface.normal_values, normal_indices, points, layout.triangles)
        normal_values = _read_only(normal_values)
    mesh = Mesh(name="", path="", points=_read_only(np.ascontiguousarray(points, dtype=FLOAT)),
                triangles=layout.triangles, normal_values=normal_values, normal_indices=normal_indices, uvs=layout.uvs,
                triangle_material=_read_only(np.ascontiguousarray(triangle_material, dtype=INDEX)),
                primvars=layout.primvars, prototype=prototype, world_from_points=np.eye(4))
    low, high = (points.min(axis=0), points.max(axis=0)) if len(points) else (np.zeros(3),) * 2
    corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])
    return SharedSurface(mesh, corners, int(np.count_nonzero(surface.degenerate)))


def place_instance(shared: SharedSurface, world_from_local: np.ndarray, meters_per_unit: float, name: str, path: str,
                   diagnostics: Diagnostics, instance: int = -1) -> Mesh | None:
    """One placement of `shared` as an instance: its geometry shared, ``world_from_points``
    the placement in metres. None (with the warning place_surface gives) when the placed
    surface lies beyond MAX_WORLD_COORDINATE or has no triangle.

    world_from_local : (4, 4) float64, column convention, stage units; is_instanceable
    """
    if not len(shared.mesh.triangles):
        return None
    placement = np.diag([meters_per_unit, meters_per_unit, meters_per_unit, 1.0]) @ world_from_local
    with np.errstate(over="ignore", invalid="ignore"):
        reach = float(np.abs(shared.corners @ placement[:3, :3].T + placement[:3, 3]).max())
    if not reach <= MAX_WORLD_COORDINATE:
        _note_out_of_reach(diagnostics, path)
        return None
    if shared.dropped:
        diagnostics.note("degenerate-triangles", "dropped {count} degenerate (zero-area) triangles on: {prims}", path,
                         shared.dropped)
    return dataclasses.replace(shared.mesh, name=name, path=path, instance=int(instance), world_from_points=placement)


def _world_normals(
    directions: np.ndarray, normal_indices: np.ndarray, points: np.ndarray, triangles: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(n', 3) float32 unit normals and their (t, 3) int32 corner indices, from the (n, 3)
    float64 world-space ``directions``; a corner whose direction has no length (or is NaN)
    takes its triangle's geometric normal, appended as a value of its own.

    points : (v, 3) float64 world; triangles : (t, 3) in the placement's winding
    """
    squares = directions * directions  # the sum np.linalg.norm forms, without its slow reduction
    lengths = np.sqrt(squares[:, 0] + squares[:, 1] + squares[:, 2])
    usable = lengths > 0.0
    unit = directions / np.where(usable, lengths, 1.0)[:, None]
    if not usable.all():
        unusable_corner = ~usable[normal_indices]
        fallen = np.flatnonzero(unusable_corner.any(axis=1))
        if len(fallen):
            geometric = _triangle_geometry(points, triangles[fallen])[0].T
            length = np.linalg.norm(geometric, axis=1)
            geometric /= np.where(length > 0.0, length, 1.0)[:, None]  # degenerate ones are gone
            normal_indices = np.array(normal_indices, dtype=INDEX)
            replacement = np.broadcast_to((len(unit) + np.arange(len(fallen)))[:, None], (len(fallen), 3))
            rows = normal_indices[fallen]
            normal_indices[fallen] = np.where(unusable_corner[fallen], replacement, rows)
            unit = np.concatenate([unit, geometric])
    return np.ascontiguousarray(unit, dtype=FLOAT), normal_indices


def _is_similarity(linear: np.ndarray, tolerance: float = _SIMILARITY_TOLERANCE) -> bool:
    """Whether the (3, 3) map is a rotation, a mirror or a uniform scale, or a product of them
    (AᵀA = s²·I to `tolerance`, relative)."""
    gram = linear.T @ linear
    scale = float(np.trace(gram)) / 3.0
    return scale > 0.0 and float(np.abs(gram - scale * np.eye(3)).max()) <= tolerance * scale


def _triangle_geometry(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((3, t) float64 area vectors e1 × e2 (length: twice the area), (t,) bool degenerate:
    |e1 × e2| <= _DEGENERATE_HEIGHT_RATIO × (longest edge)²), component by component."""
    components = np.ascontiguousarray(points.T, dtype=np.float64)  # (3, v)
    first, second, third = (np.take(components, triangles[:, corner], axis=1) for corner in range(3))
    edge_a, edge_b, edge_c = second - first, third - first, third - second
    cross = np.stack([
        edge_a[1] * edge_b[2] - edge_a[2] * edge_b[1],
        edge_a[2] * edge_b[0] - edge_a[0] * edge_b[2],
        edge_a[0] * edge_b[1] - edge_a[1] * edge_b[0],
    ])
    doubled_area = np.sqrt(cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2])
    longest = np.maximum(np.maximum(_squared_length(edge_a), _squared_length(edge_b)), _squared_length(edge_c))
    return cross, doubled_area <= _DEGENERATE_HEIGHT_RATIO * longest


def _squared_length(vectors: np.ndarray) -> np.ndarray:
    return vectors[0] * vectors[0] + vectors[1] * vectors[1] + vectors[2] * vectors[2]


def _select_corners(values: np.ndarray, rows: np.ndarray | None, mirrored: bool) -> np.ndarray:
    """(k, 3, w) float32 read-only: the triangles ``rows`` (None: all) of (t, 3, w) per-corner
    ``values``, corners 1 and 2 swapped when ``mirrored``.

    Values equal at a triangle's corners (stride 0 over the corners: uniform and constant
    primvars) come back as such a view again, built from the rows' one value each, or from
    the one value of them all (stride 0 over the triangles too), which np.take would write out
    at every corner; swapping equal corners changes nothing.
    """
    count = len(values) if rows is None else len(rows)
    width = values.shape[2]
    if values.strides[1] == 0:
        if values.strides[0] == 0 or len(values) == 0:
            value = np.asarray(values[:1, 0], dtype=FLOAT)  # (1, w) or (0, w)
            return np.broadcast_to(value[:, None, :], (count, 3, width))
        per_triangle = values[:, 0] if rows is None else np.take(values[:, 0], rows, axis=0)
        per_triangle = np.ascontiguousarray(per_triangle, dtype=FLOAT)
        return np.broadcast_to(per_triangle[:, None, :], (count, 3, width))
    if rows is None and not mirrored and values.dtype == FLOAT and not values.flags.writeable:
        return values  # the surface's own read-only array, shared as it is
    if rows is not None:
        values = np.take(values, rows, axis=0)
    if mirrored:
        values = values[:, _MIRRORED]
    return _read_only(np.array(values, dtype=FLOAT))  # a copy: the caller's array stays as it was


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def _index_by_point(
    corner_values: np.ndarray, triangles: np.ndarray, point_count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-corner values (t, 3, k) as (n, k) values and (t, 3) int64 indices into them.

    Value p < point_count belongs to point p (the value of one of its corners; unused points
    get any value); each corner whose value differs from its point's, bit for bit, gets a
    value of its own after them. Normals interpolated per vertex, and smooth limit normals,
    then cost one value per point.
    """
    width = corner_values.shape[2]
    flat = np.ascontiguousarray(corner_values, dtype=np.float64).reshape(-1, width)
    vertex = triangles.reshape(-1)
    owner = np.zeros(point_count, dtype=np.int64)
    owner[vertex] = np.arange(len(vertex))
    # (np.take: fancy indexing of rows is several times slower)
    point_values = np.take(flat, owner, axis=0) if len(flat) else np.zeros((point_count, width))
    bits, point_bits = flat.view(np.uint64), np.take(point_values.view(np.uint64), vertex, axis=0)
    differs = bits[:, 0] != point_bits[:, 0]  # column by column: .any(axis=1) is slow on short rows
    for column in range(1, width):
        differs |= bits[:, column] != point_bits[:, column]
    own = np.flatnonzero(differs)
    indices = vertex.copy()
    indices[own] = point_count + np.arange(len(own))
    return np.concatenate([point_values, np.take(flat, own, axis=0)]), indices.reshape(-1, 3)


def _area_weighted_vertex_normals(
    area_vectors: np.ndarray, triangles: np.ndarray, triangle_face: np.ndarray, point_count: int
) -> np.ndarray:
    """(v, 3) object-space vertex normals: the sum of the adjacent *faces'* area vectors.

    Summing per face, not per triangle, keeps the fan triangulation out of the result: in
    a fanned quad, vertices 0 and 2 touch both triangles but 1 and 3 only one. The
    (3, t) area vectors have length twice the triangle area, so a face's sum is its
    area-weighted normal; each face adds it once to each of its distinct vertices.
    """
    face_count = int(triangle_face.max(initial=-1)) + 1
    face_vectors = [np.bincount(triangle_face, weights=row, minlength=face_count) for row in area_vectors]
    distinct = _distinct_face_corners(triangles, triangle_face, point_count)
    vertices = triangles[distinct]
    corner_faces = np.broadcast_to(triangle_face[:, None], triangles.shape)[distinct]
    return np.stack(
        [np.bincount(vertices, weights=row[corner_faces], minlength=point_count) for row in face_vectors], axis=1
    )


def _distinct_face_corners(triangles: np.ndarray, triangle_face: np.ndarray, point_count: int) -> np.ndarray:
    """(t, 3) bool: True at the first corner, in triangle order, of each (face, vertex) pair.

    A face's triangles are consecutive (both triangulations make them so; otherwise every
    face goes through np.unique), so a corner needs comparing only with the earlier
    triangles of its own face, a few for all but very large faces.
    """
    count = len(triangles)
    first = np.ones((count, 3), dtype=bool)
    first[:, 1] = triangles[:, 1] != triangles[:, 0]
    first[:, 2] = (triangles[:, 2] != triangles[:, 0]) & (triangles[:, 2] != triangles[:, 1])
    if count == 0:
        return first
    if (np.diff(triangle_face) < 0).any():
        large = np.ones(count, dtype=bool)
    else:
        run_start = np.flatnonzero(np.r_[True, triangle_face[1:] != triangle_face[:-1]])
        run_length = np.diff(np.r_[run_start, count])
        rank = np.arange(count) - np.repeat(run_start, run_length)  # earlier triangles of the face
        large = np.repeat(run_length > _FACE_LOOKBACK + 1, run_length)
        for back in range(1, min(int(run_length.max()), _FACE_LOOKBACK + 1)):
            later = np.flatnonzero((rank >= back) & ~large)
            if not len(later):
                break
            earlier = triangles[later - back]
            for corner in range(3):
                vertex = triangles[later, corner]
                seen = (vertex == earlier[:, 0]) | (vertex == earlier[:, 1]) | (vertex == earlier[:, 2])
                first[later[seen], corner] = False
    if large.any():
        rows = np.flatnonzero(large)
        keys = (triangle_face[rows][:, None] * point_count + triangles[rows]).reshape(-1)
        _, first_index = np.unique(keys, return_index=True)
        mask = np.zeros(len(keys), dtype=bool)
        mask[first_index] = True
        first[rows] = mask.reshape(-1, 3)
    return first
