"""Uniform refinement of polygon meshes to their subdivision surface, with OpenSubdiv's rules.

Pure numpy (no pxr): the stage reader hands it UsdGeom.Mesh arrays and gets back the refined
faces, limit points and limit normals. The semantics follow OpenSubdiv 3 (Sdc/Vtr/Far), which
is what UsdGeom.Mesh specifies:

* schemes ``catmullClark`` (any polygons; every face splits into quads), ``loop`` (triangles
  only; another mesh is refined with catmullClark and a warning says so) and ``bilinear``;
* ``interpolateBoundary`` ``none`` (faces at an unsharpened boundary vertex become holes),
  ``edgeOnly`` (boundary edges infinitely sharp), ``edgeAndCorner`` (and vertices of one face
  pinned; the USD default); non-manifold edges and vertices are infinitely sharp;
* semi-sharp creases and corners: sharpness decays by 1 per level (``uniform``) or by
  Chaikin's rule (``chaikin``: 3/4 of its own plus 1/4 of the average of the other semi-sharp
  edges at the vertex, then minus 1); values of ``SHARPNESS_INFINITE`` (10) or more never decay;
  fractional sharpness blends the sharp and smooth rules (OpenSubdiv's transition weights);
* ``holeIndices``: hole faces are refined (their neighbours keep their shape) but give no
  output faces;
* ``triangleSubdivisionRule = smooth``: OpenSubdiv's modified edge weights next to triangles;
* face-varying data (``st``): each channel is refined as a mesh of its own whose vertices are
  the distinct (vertex, value) pairs, so seams are boundaries of that mesh; the
  ``faceVaryingLinearInterpolation`` option (none, cornersOnly, cornersPlus1 - the default,
  cornersPlus2, boundaries, all) pins values as OpenSubdiv's FVarLevel does.

After the last level the vertices are pushed to the **limit surface** with the standard limit
stencils (smooth, crease/boundary and corner, with the last level's rules, as OpenSubdiv's
PrimvarRefiner::Limit), and the **normals are the limit normals**: the cross product of
OpenSubdiv's limit tangent stencils applied to the last level's points (smooth vertices: the
cosine/sine ring stencils; crease and boundary vertices: one normal per sector between sharp
edges, from the tangent along the crease and the cross tangent; corners of one face: their two
edges). These are exact for regular vertices, smooth extraordinary vertices and one-face
corners. At a crease or boundary vertex with 3 or more faces in a sector the standard rules have
no well-conditioned tangent plane (their subdominant eigenvalue exceeds the crease's 1/2) and
OpenSubdiv's cross tangent (Biermann et al.) is an approximation, a few degrees off the normal
of the limit faces beside it; the normal is still exactly perpendicular to the crease. Where no
stencil applies (corners spanning several faces, non-manifold fans) a corner gets the
area-weighted normal of the faces in its sector. The bilinear scheme has no limit step (its
refined points already lie on the bilinear patches) and gets those area-weighted normals.

Children are ordered so that callers can follow them: at each level a face's children are
consecutive, in the order of its corners (catmullClark/bilinear: the quad at each corner; loop:
the triangle at each corner, then the middle one), and corner 0 of a corner's child is the
child of that corner's vertex.

Everything is vectorised: edges of the authored mesh come from np.unique over sorted vertex
pairs, later levels are built structurally (each edge splits in two, each face adds one edge per
corner), and the rings around vertices are ranked by pointer jumping (O(log valence) passes).

**How many levels** (:class:`PixelFootprint`): each mesh is refined until its refined edges
(a cage edge halves per level) project to at most TARGET_EDGE_PIXELS on the image, at its
nearest distance from the camera; meshes out of view get at most OFF_VIEW_LEVEL; the reader
then lowers the highest levels first until the scene's refined triangles fit
request.MAX_SUBDIVISION_TRIANGLES (budgets.fit_subdivision_levels).

Why not Embree's own subdivision geometry (RTC_GEOMETRY_TYPE_SUBDIVISION)? It evaluates
Catmull-Clark patches on the fly with a tessellation rate per edge (so the level could follow
the footprint per edge, not per mesh, crack-free), and takes creases, corners, holes and
boundary modes (``RTC_SUBDIVISION_MODE_*``, close to OpenSubdiv's), with face-varying uvs
through its topology buffers. Against it, for now: only ``pxr_layers/trace/`` may call
Embree, and its core is to be rewritten on the Embree 4 API in a later issue, so the
geometry kind is that rewrite's choice; Embree has no loop or bilinear schemes, no
``triangleSubdivisionRule``, no Chaikin creases and no ``faceVaryingLinearInterpolation``
options but its own few; and the rest of the pipeline (GeomSubsets per triangle, primvars
per corner, limit normals, AOV ids) reads triangles. So this refiner stays, and hands the
tracer triangles.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from pxr_layers.request import MAX_SUBDIV_LEVEL
from pxr_layers.scene import Camera

logger = logging.getLogger(__name__)

INDEX = np.int64

# OpenSubdiv's Sdc::Crease::SHARPNESS_INFINITE: sharper values are clamped to it and never decay.
SHARPNESS_INFINITE = 10.0

SCHEMES = ("catmullClark", "loop", "bilinear")
BOUNDARY_INTERPOLATIONS = ("none", "edgeOnly", "edgeAndCorner")
FACE_VARYING_INTERPOLATIONS = (
    "none", "cornersOnly", "cornersPlus1", "cornersPlus2", "boundaries", "all",
)
TRIANGLE_SUBDIVISION_RULES = ("catmullClark", "smooth")
CREASE_METHODS = ("uniform", "chaikin")

# Vertex rules (OpenSubdiv's Crease::Rule; a dart, one sharp edge, uses the smooth rule).
_SMOOTH, _CREASE, _CORNER = 0, 1, 2

# OpenSubdiv's (and Hbr's) face weight next to a triangle for triangleSubdivisionRule = smooth.
_SMOOTH_TRIANGLE_EDGE_WEIGHT = 0.470


def _empty_indices() -> np.ndarray:
    return np.zeros(0, dtype=INDEX)


def _empty_sharpnesses() -> np.ndarray:
    return np.zeros(0, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class SubdivisionTags:
    """The UsdGeom.Mesh subdivision attributes (USD defaults), as plain arrays.

    crease_indices     : (n,) int vertex chains of all creases, one after the other
    crease_lengths     : (k,) int number of vertices of each crease
    crease_sharpnesses : (k,) float one per crease, or one per crease edge (sum(lengths - 1))
    corner_indices     : (m,) int vertices given a corner sharpness
    corner_sharpnesses : (m,) float
    hole_indices       : (h,) int authored faces that are holes
    """

    interpolate_boundary: str = "edgeAndCorner"
    face_varying_linear_interpolation: str = "cornersPlus1"
    triangle_subdivision_rule: str = "catmullClark"
    crease_method: str = "uniform"
    crease_indices: np.ndarray = field(default_factory=_empty_indices)
    crease_lengths: np.ndarray = field(default_factory=_empty_indices)
    crease_sharpnesses: np.ndarray = field(default_factory=_empty_sharpnesses)
    corner_indices: np.ndarray = field(default_factory=_empty_indices)
    corner_sharpnesses: np.ndarray = field(default_factory=_empty_sharpnesses)
    hole_indices: np.ndarray = field(default_factory=_empty_indices)


@dataclass(frozen=True, eq=False)
class FaceVaryingPrimvar:
    """A face-varying channel of the authored mesh.

    values  : (n, k) float64
    indices : (c,) int64 index into ``values`` per face corner (faceVertexIndices order); None
              means one value per corner, and corners at one vertex with equal values are
              joined (an unindexed primvar is then continuous where its values agree)
    """

    values: np.ndarray
    indices: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class RefinedMesh:
    """A mesh refined ``level`` times, hole faces left out.

    points               : (v, 3) float64 limit positions (refined positions with ``limit=False``
                           or the bilinear scheme), units of the input
    faces                : (f, k) int64 vertex indices, k = 4 (catmullClark, bilinear) or 3
                           (loop), in the winding of the authored faces
    face_origin          : (f,) int64 authored face each face comes from
    normal_values        : (n, 3) float64 unit normals (see the module docstring): one per
                           vertex where its corners share it, then one per other corner
    corner_normals       : (f, k) int64 index into normal_values per face corner
    vertex_data          : (v, m) float64 vertex primvars, refined and limited like the points
    varying_data         : (v, m) float64 varying primvars, refined linearly
    face_varying_values  : per face-varying channel, (n_i, m) float64 values
    face_varying_corners : per channel, (f, k) int64 index into its values per face corner
    scheme               : the scheme used (loop falls back to catmullClark on non-triangles)
    warnings             : problems met and how they were handled, one sentence each

    The per-corner arrays are indexed (a value per refined vertex, not per corner): a caller
    gathers them once, for its own corners.
    """

    points: np.ndarray
    faces: np.ndarray
    face_origin: np.ndarray
    normal_values: np.ndarray
    corner_normals: np.ndarray
    vertex_data: np.ndarray | None
    varying_data: np.ndarray | None
    face_varying_values: tuple[np.ndarray, ...]
    face_varying_corners: tuple[np.ndarray, ...]
    scheme: str
    warnings: tuple[str, ...]

    @property
    def normals(self) -> np.ndarray:
        """(f, k, 3) float64 unit normal per face corner."""
        return _rows(self.normal_values, self.corner_normals.reshape(-1)).reshape(*self.faces.shape, 3)

    @property
    def face_varying(self) -> tuple[np.ndarray, ...]:
        """One (f, k, m) float64 array per face-varying channel, per face corner."""
        return tuple(_rows(values, corners.reshape(-1)).reshape(*corners.shape, values.shape[1])
                     for values, corners in zip(self.face_varying_values, self.face_varying_corners))


def refine(
    points: np.ndarray,
    face_vertex_counts: np.ndarray,
    face_vertex_indices: np.ndarray,
    level: int,
    *,
    scheme: str = "catmullClark",
    tags: SubdivisionTags | None = None,
    vertex_data: np.ndarray | None = None,
    varying_data: np.ndarray | None = None,
    face_varying: Sequence[FaceVaryingPrimvar] = (),
    limit: bool = True,
) -> RefinedMesh:
    """Refine a polygon mesh ``level`` (>= 1) times and evaluate its limit surface.

    points              : (v, 3) float, any units
    face_vertex_counts  : (f,) int vertices per face; faces of fewer than 3 are left out
    face_vertex_indices : (sum(counts),) int
    vertex_data         : (v, m) float primvars interpolated like the points (vertex)
    varying_data        : (v, m) float primvars interpolated linearly (varying)
    limit               : False keeps the refined positions and area-weighted normals

    Raises ValueError on inconsistent input (the caller validates user data first).
    """
    tags = tags or SubdivisionTags()
    _check_token("scheme", scheme, SCHEMES)
    _check_token("interpolateBoundary", tags.interpolate_boundary, BOUNDARY_INTERPOLATIONS)
    _check_token(
        "faceVaryingLinearInterpolation",
        tags.face_varying_linear_interpolation,
        FACE_VARYING_INTERPOLATIONS,
    )
    _check_token(
        "triangleSubdivisionRule", tags.triangle_subdivision_rule, TRIANGLE_SUBDIVISION_RULES
    )
    _check_token("crease method", tags.crease_method, CREASE_METHODS)
    if int(level) != level or level < 1:
        raise ValueError(f"the subdivision level must be a positive integer, not {level!r}")
    points = np.asarray(points, dtype=np.float64)
    counts = np.asarray(face_vertex_counts, dtype=INDEX).reshape(-1)
    indices = np.asarray(face_vertex_indices, dtype=INDEX).reshape(-1)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (v, 3), not {points.shape}")
    if (counts < 0).any() or int(counts.sum()) != len(indices):
        raise ValueError("face_vertex_counts do not match face_vertex_indices")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(points)):
        raise ValueError("face_vertex_indices reach past the points")
    vertex_count = len(points)
    vertex_data = _optional_columns(vertex_data, vertex_count, "vertex_data")
    varying_data = _optional_columns(varying_data, vertex_count, "varying_data")
    warnings: list[str] = []

    kept_face, kept_corner = _kept_faces(counts, indices, warnings)
    kept_counts = counts[kept_face]
    if scheme == "loop" and (kept_counts != 3).any():
        warnings.append(
            "loop subdivision needs a triangle mesh; refined with catmullClark instead"
        )
        scheme = "catmullClark"

    base, fans = _base_level(
        kept_counts,
        indices[kept_corner],
        vertex_count,
        np.flatnonzero(kept_face).astype(INDEX),
        scheme,
        tags,
        warnings,
    )
    split = "triangles" if scheme == "loop" else "quads"
    rules = _Rules(scheme, split, tags.triangle_subdivision_rule == "smooth", tags.crease_method)
    linear_rules = _Rules("bilinear", split, False, tags.crease_method)

    channels = [_face_varying_level(base, primvar, kept_corner, tags) for primvar in face_varying]
    fvar_rules = linear_rules if tags.face_varying_linear_interpolation == "all" else rules

    data = points if vertex_data is None else np.hstack([points, vertex_data])
    current = base
    for _ in range(int(level)):
        child_sharpness = _child_edge_sharpness(current, tags.crease_method)
        data = _refine_vertex_data(current, data, rules, child_sharpness)
        if varying_data is not None:
            varying_data = _refine_vertex_data(current, varying_data, linear_rules, None)
        child = _child_level(current, split, child_sharpness)
        for index, (fvar_level, fvar_values) in enumerate(channels):
            fvar_child_sharpness = _child_edge_sharpness(fvar_level, tags.crease_method)
            channels[index] = (
                _child_level(fvar_level, split, fvar_child_sharpness, child.faces),
                _refine_vertex_data(fvar_level, fvar_values, fvar_rules, fvar_child_sharpness),
            )
        fans = _child_fans(current, fans, child) if split == "quads" else None
        current = child
    if fans is None:
        fans = _fans(current, current.edge_sharpness > 0.0)

    smooth_limit = limit and scheme != "bilinear"
    sums = _LimitSums.of(current, data, scheme, fans) if smooth_limit else None
    # Limit tangent masks, like limit position masks, weigh the last level's control points.
    normals = _corner_normals(current, fans, data[:, :3], scheme, sums)
    if smooth_limit:
        data = _limit_positions(current, data, scheme, sums.ring)
        del sums  # its tangents, 2 × (v, 3), served the normals only
        for index, (fvar_level, fvar_values) in enumerate(channels):
            if fvar_rules.scheme != "bilinear":
                fvar_ring = _LimitSums.of(fvar_level, fvar_values, scheme).ring
                channels[index] = (
                    fvar_level, _limit_positions(fvar_level, fvar_values, scheme, fvar_ring)
                )

    logger.debug(
        "refined %d faces to level %d with %s: %d faces", len(counts), level, scheme,
        current.face_count,
    )
    return _without_holes(
        current, data, vertex_data is not None, varying_data, normals, channels, scheme, warnings
    )


def _kept_faces(
    counts: np.ndarray, indices: np.ndarray, warnings: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """(f,) and (c,) masks of the faces (and their corners) that can be subdivided.

    Faces of fewer than 3 vertices, or repeating a vertex on an edge, are left out (OpenSubdiv
    rejects them); their neighbours then see a boundary.
    """
    _, corner_face, next_in_face, _ = _face_structure(counts)
    degenerate_face = np.zeros(len(counts), dtype=bool)
    degenerate_face[corner_face[indices == indices[next_in_face]]] = True
    kept_face = (counts >= 3) & ~degenerate_face
    repeating = int(((counts >= 3) & degenerate_face).sum())
    if repeating:
        # (faces of fewer than 3 vertices are the caller's to report: surfaces.read_mesh notes
        # them for every mesh, subdivided or not)
        warnings.append(
            f"{repeating} faces repeating a vertex on an edge were left out of the subdivision surface"
        )
    return kept_face, kept_face[corner_face]


def _without_holes(
    level: _Level,
    data: np.ndarray,
    has_vertex_data: bool,
    varying_data: np.ndarray | None,
    normals: tuple[np.ndarray, np.ndarray],
    channels: list[tuple[_Level, np.ndarray]],
    scheme: str,
    warnings: list[str],
) -> RefinedMesh:
    """The last level's faces that are not holes, and only the points they use.

    normals : ((n, 3) values, (c,) index per corner of ``level``), from _corner_normals
    """
    corners_per_face = 3 if scheme == "loop" else 4
    visible = ~level.face_hole
    holes = not visible.all()

    def shown(per_corner: np.ndarray) -> np.ndarray:
        """(f', k) the rows of the shown faces (without copying when nothing is hidden)."""
        per_face = per_corner.reshape(-1, corners_per_face)
        return per_face[visible] if holes else per_face

    faces = shown(level.corner_vertex)
    if holes:
        # Points only the hole faces used would be stray vertices for the renderer.
        used = np.zeros(level.vertex_count, dtype=bool)
        used[faces.reshape(-1)] = True
        faces = (np.cumsum(used) - 1)[faces]
        data = data[used]
        varying_data = None if varying_data is None else varying_data[used]
    normal_values, corner_normals = normals
    return RefinedMesh(
        points=np.ascontiguousarray(data[:, :3]),
        faces=faces,
        face_origin=level.face_origin[visible] if holes else level.face_origin,
        normal_values=normal_values,
        corner_normals=shown(corner_normals),
        vertex_data=np.ascontiguousarray(data[:, 3:]) if has_vertex_data else None,
        varying_data=varying_data,
        face_varying_values=tuple(values for _, values in channels),
        face_varying_corners=tuple(shown(fvar_level.corner_vertex) for fvar_level, _ in channels),
        scheme=scheme,
        warnings=tuple(warnings),
    )


def _check_token(name: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ValueError(f"{name} {value!r} is not one of {', '.join(allowed)}")


def _optional_columns(values, count: int, name: str) -> np.ndarray | None:
    if values is None:
        return None
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if values.ndim != 2 or len(values) != count:
        raise ValueError(f"{name} must be ({count}, m), not {values.shape}")
    return values


# --- mesh levels ------------------------------------------------------------------------------


class _Faces:
    """The faces of a level: their sizes, and each corner's face and neighbours in it.

    sizes       : (f,) corners per face
    offsets     : (f,) first corner of each face
    corner_face : (c,) the face of each corner
    corner_next : (c,) the next corner of the same face (corner_prev: the previous one)

    The authored level gives every array. A refined level (every face of ``uniform`` corners)
    makes its per-corner arrays on first use: the last level needs few of them, and a mesh's
    face-varying channels share its faces, so each level's are made once.
    """

    def __init__(self, sizes: np.ndarray, offsets: np.ndarray, corner_face: np.ndarray | None = None,
                 corner_next: np.ndarray | None = None, corner_prev: np.ndarray | None = None,
                 uniform: int = 0) -> None:
        self.sizes = sizes
        self.offsets = offsets
        self.uniform = uniform
        if corner_face is not None:  # instead of the cached properties below
            self.__dict__.update(corner_face=corner_face, corner_next=corner_next, corner_prev=corner_prev)

    @staticmethod
    def of_uniform(face_count: int, corners_per_face: int) -> _Faces:
        return _Faces(np.full(face_count, corners_per_face, dtype=INDEX),
                      np.arange(face_count, dtype=INDEX) * corners_per_face, uniform=corners_per_face)

    @functools.cached_property
    def corner_face(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.sizes), dtype=INDEX), self.uniform)

    @functools.cached_property
    def corner_next(self) -> np.ndarray:
        # +1, but from the last corner of a face back to its first
        following = np.arange(1, len(self.sizes) * self.uniform + 1, dtype=INDEX)
        following[self.uniform - 1::self.uniform] -= self.uniform
        return following

    @functools.cached_property
    def corner_prev(self) -> np.ndarray:
        preceding = np.arange(-1, len(self.sizes) * self.uniform - 1, dtype=INDEX)
        preceding[::self.uniform] += self.uniform
        return preceding


@dataclass(frozen=True, eq=False)
class _Level:
    """The topology and sharpness of one refinement level (of the mesh or of one fvar channel).

    Corners are face-vertices in face order; ``corner_edge[c]`` is the edge from corner c to the
    next corner of its face. Edge and vertex sharpness are OpenSubdiv's (0 smooth, 10 infinite).
    """

    vertex_count: int
    faces: _Faces
    corner_vertex: np.ndarray  # (c,)
    corner_edge: np.ndarray  # (c,)
    edge_vertices: np.ndarray  # (e, 2)
    edge_face_count: np.ndarray  # (e,)
    edge_sharpness: np.ndarray  # (e,) float64
    vertex_sharpness: np.ndarray  # (v,) float64
    face_hole: np.ndarray  # (f,) bool
    face_origin: np.ndarray  # (f,) authored face

    @property
    def face_sizes(self) -> np.ndarray:
        return self.faces.sizes

    @property
    def face_offsets(self) -> np.ndarray:
        return self.faces.offsets

    @property
    def corner_face(self) -> np.ndarray:
        return self.faces.corner_face

    @property
    def corner_next(self) -> np.ndarray:
        return self.faces.corner_next

    @property
    def corner_prev(self) -> np.ndarray:
        return self.faces.corner_prev

    @property
    def edge_count(self) -> int:
        return len(self.edge_vertices)

    @property
    def face_count(self) -> int:
        return len(self.face_sizes)

    def following_vertex(self, steps: int) -> np.ndarray:
        """(c,) the vertex ``steps`` corners further along each corner's face (1: the far end
        of its outgoing edge; 2 in a quad: the opposite corner's)."""
        size = self.faces.uniform
        if size:  # a rotation of each face's corners: no index arrays
            return np.roll(self.corner_vertex.reshape(-1, size), -steps, axis=1).reshape(-1)
        corners = self.corner_next
        for _ in range(steps - 1):
            corners = self.corner_next[corners]
        return self.corner_vertex[corners]


def _face_structure(counts: np.ndarray) -> tuple[np.ndarray, ...]:
    """(offsets, corner_face, corner_next, corner_prev) of faces with ``counts`` corners."""
    offsets = np.cumsum(counts) - counts
    corner_face = np.repeat(np.arange(len(counts), dtype=INDEX), counts)
    corners = np.arange(int(counts.sum()), dtype=INDEX)
    first = offsets[corner_face]
    last = first + counts[corner_face] - 1
    corner_next = np.where(corners == last, first, corners + 1)
    corner_prev = np.where(corners == first, last, corners - 1)
    return offsets.astype(INDEX), corner_face, corner_next, corner_prev


def _unique_edges(
    corner_vertex: np.ndarray, corner_next: np.ndarray, vertex_count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(edge keys, corner_edge, edge_vertices): edges as sorted vertex pairs (one int64 key)."""
    a = corner_vertex
    b = corner_vertex[corner_next]
    keys = np.minimum(a, b) * vertex_count + np.maximum(a, b)
    edge_keys, corner_edge = np.unique(keys, return_inverse=True)
    edge_vertices = np.stack(np.divmod(edge_keys, vertex_count), axis=1).astype(INDEX)
    return edge_keys, corner_edge.reshape(-1).astype(INDEX), edge_vertices


def _base_level(
    counts: np.ndarray,
    indices: np.ndarray,
    vertex_count: int,
    face_origin: np.ndarray,
    scheme: str,
    tags: SubdivisionTags,
    warnings: list[str],
) -> tuple[_Level, _Fans]:
    """Level 0 (with its fans) with OpenSubdiv's sharpening of creases, corners, boundaries
    and holes."""
    offsets, corner_face, corner_next, corner_prev = _face_structure(counts)
    edge_keys, corner_edge, edge_vertices = _unique_edges(indices, corner_next, vertex_count)
    edge_count = len(edge_keys)
    edge_face_count = np.bincount(corner_edge, minlength=edge_count).astype(INDEX)

    edge_sharpness = np.zeros(edge_count)
    crease_keys, crease_values = _crease_edges(tags, vertex_count, warnings)
    if len(crease_keys):
        found = np.minimum(np.searchsorted(edge_keys, crease_keys), max(edge_count - 1, 0))
        is_edge = edge_keys[found] == crease_keys if edge_count else np.zeros(len(found), bool)
        if not is_edge.all():
            warnings.append(
                f"{int((~is_edge).sum())} crease edges join vertices that share no edge and "
                "were ignored"
            )
        np.maximum.at(edge_sharpness, found[is_edge], crease_values[is_edge])

    vertex_sharpness = np.zeros(vertex_count)
    corner_indices = np.asarray(tags.corner_indices, dtype=INDEX).reshape(-1)
    corner_values = np.asarray(tags.corner_sharpnesses, dtype=np.float64).reshape(-1)
    if len(corner_indices) != len(corner_values):
        warnings.append(
            f"{len(corner_indices)} cornerIndices but {len(corner_values)} cornerSharpnesses: "
            "corners ignored"
        )
    elif len(corner_indices):
        valid = (corner_indices >= 0) & (corner_indices < vertex_count)
        if not valid.all():
            warnings.append(f"{int((~valid).sum())} cornerIndices out of range were ignored")
        np.maximum.at(
            vertex_sharpness,
            corner_indices[valid],
            np.clip(np.nan_to_num(corner_values[valid]), 0.0, SHARPNESS_INFINITE),
        )

    face_count = len(counts)
    face_hole = np.zeros(face_count, dtype=bool)
    holes = np.asarray(tags.hole_indices, dtype=INDEX).reshape(-1)
    # Hole indices name authored faces; faces left out (fewer than 3 vertices) are not here.
    authored_to_kept = np.full(int(face_origin.max(initial=-1)) + 1, -1, dtype=INDEX)
    authored_to_kept[face_origin] = np.arange(face_count, dtype=INDEX)
    holes = holes[(holes >= 0) & (holes < len(authored_to_kept))]
    holes = authored_to_kept[holes]
    face_hole[holes[holes >= 0]] = True

    boundary_edge = edge_face_count == 1
    if tags.interpolate_boundary == "none" and scheme != "bilinear":
        # OpenSubdiv: faces at a boundary vertex with a boundary edge not already infinitely
        # sharp are excluded (tagged as holes), before boundaries are sharpened.
        unsharpened = boundary_edge & (edge_sharpness < SHARPNESS_INFINITE)
        excluding_vertex = np.zeros(vertex_count, dtype=bool)
        excluding_vertex[edge_vertices[unsharpened].reshape(-1)] = True
        face_hole |= np.bincount(
            corner_face, weights=excluding_vertex[indices], minlength=face_count
        ) > 0
    edge_sharpness[edge_face_count != 2] = SHARPNESS_INFINITE  # boundaries and non-manifold

    level = _Level(
        vertex_count=vertex_count,
        faces=_Faces(counts.astype(INDEX), offsets, corner_face, corner_next, corner_prev,
                     uniform=int(counts[0]) if len(counts) and (counts == counts[0]).all() else 0),
        corner_vertex=indices.astype(INDEX),
        corner_edge=corner_edge,
        edge_vertices=edge_vertices,
        edge_face_count=edge_face_count,
        edge_sharpness=edge_sharpness,
        vertex_sharpness=vertex_sharpness,
        face_hole=face_hole,
        face_origin=face_origin,
    )
    vertex_faces = np.bincount(indices, minlength=vertex_count)
    vertex_edges = np.bincount(edge_vertices.reshape(-1), minlength=vertex_count)
    if tags.interpolate_boundary == "edgeAndCorner":
        vertex_sharpness[(vertex_faces == 1) & (vertex_edges == 2)] = SHARPNESS_INFINITE
    fans = _fans(level, edge_sharpness > 0.0)
    non_manifold = ~fans.manifold & (vertex_faces > 0)
    if non_manifold.any():
        warnings.append(
            f"{int(non_manifold.sum())} non-manifold (or inconsistently wound) vertices were "
            "made infinitely sharp"
        )
        vertex_sharpness[non_manifold] = SHARPNESS_INFINITE
    return level, fans


def _crease_edges(
    tags: SubdivisionTags, vertex_count: int, warnings: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """(edge keys, sharpness) of every authored crease edge (keys as in _unique_edges)."""
    crease_indices = np.asarray(tags.crease_indices, dtype=INDEX).reshape(-1)
    lengths = np.asarray(tags.crease_lengths, dtype=INDEX).reshape(-1)
    sharpnesses = np.asarray(tags.crease_sharpnesses, dtype=np.float64).reshape(-1)
    nothing = (np.zeros(0, dtype=INDEX), np.zeros(0))
    if not len(lengths) and not len(crease_indices):
        return nothing
    if (lengths < 0).any() or int(lengths.sum()) != len(crease_indices):
        warnings.append(
            f"creaseLengths sum to {int(lengths.sum())} but there are {len(crease_indices)} "
            "creaseIndices: creases ignored"
        )
        return nothing
    pairs_per_crease = np.maximum(lengths - 1, 0)
    if len(sharpnesses) == len(lengths):
        pair_sharpness = np.repeat(sharpnesses, pairs_per_crease)
    elif len(sharpnesses) == int(pairs_per_crease.sum()):
        pair_sharpness = sharpnesses
    else:
        warnings.append(
            f"{len(sharpnesses)} creaseSharpnesses for {len(lengths)} creases of "
            f"{int(pairs_per_crease.sum())} edges: creases ignored"
        )
        return nothing
    # The first vertex of each pair: every crease vertex but the last of its crease.
    offsets = np.cumsum(lengths) - lengths
    crease_of_pair = np.repeat(np.arange(len(lengths), dtype=INDEX), pairs_per_crease)
    first_pair = np.cumsum(pairs_per_crease) - pairs_per_crease
    start = offsets[crease_of_pair] + np.arange(len(crease_of_pair)) - first_pair[crease_of_pair]
    a = crease_indices[start]
    b = crease_indices[start + 1]
    valid = (a >= 0) & (b >= 0) & (a < vertex_count) & (b < vertex_count)
    if not valid.all():
        warnings.append(f"{int((~valid).sum())} crease edges out of range were ignored")
    a, b, pair_sharpness = a[valid], b[valid], pair_sharpness[valid]
    keys = np.minimum(a, b) * vertex_count + np.maximum(a, b)
    return keys, np.clip(np.nan_to_num(pair_sharpness), 0.0, SHARPNESS_INFINITE)


def _decrement(sharpness: np.ndarray) -> np.ndarray:
    """Uniform decay: one less per level, infinite stays infinite."""
    return np.where(
        sharpness >= SHARPNESS_INFINITE, SHARPNESS_INFINITE, np.maximum(sharpness - 1.0, 0.0)
    )


def _child_edge_sharpness(level: _Level, method: str) -> np.ndarray:
    """(e, 2) sharpness of the two children of each edge (at its first and second vertex)."""
    sharpness = level.edge_sharpness
    if method == "uniform":
        decayed = _decrement(sharpness)
        return np.stack([decayed, decayed], axis=1)
    # Chaikin (OpenSubdiv's Crease::SubdivideEdgeSharpnessAtVertex): 3/4 of its own sharpness
    # plus 1/4 of the average of the other semi-sharp edges at that vertex, then minus 1.
    semi = (sharpness > 0.0) & (sharpness < SHARPNESS_INFINITE)
    ends = level.edge_vertices
    semi_count = _bincount_ends(ends, semi, level.vertex_count)
    semi_sum = _bincount_ends(ends, sharpness * semi, level.vertex_count)
    children = np.empty((len(sharpness), 2))
    for end in (0, 1):
        vertex = ends[:, end]
        count = semi_count[vertex]
        others = (semi_sum[vertex] - sharpness) / np.maximum(count - 1, 1)
        blended = np.where(count > 1, 0.75 * sharpness + 0.25 * others, sharpness) - 1.0
        children[:, end] = np.where(
            sharpness >= SHARPNESS_INFINITE,
            SHARPNESS_INFINITE,
            np.where(sharpness <= 0.0, 0.0, np.maximum(blended, 0.0)),
        )
    return children


def _bincount_ends(ends: np.ndarray, weights: np.ndarray, size: int) -> np.ndarray:
    """(size,) sum of a per-edge weight over the edges at each vertex."""
    weights = np.asarray(weights, dtype=np.float64)
    return np.bincount(ends[:, 0], weights=weights, minlength=size) + np.bincount(
        ends[:, 1], weights=weights, minlength=size
    )


def _child_level(level: _Level, split: str, child_sharpness: np.ndarray, faces: _Faces | None = None) -> _Level:
    """The next level's topology, built structurally (no search for edges).

    Child vertices: the parent's vertices, then one per edge, then (quads) one per face.
    Child edges: the two halves of each parent edge (2e at its first vertex, 2e + 1 at its
    second), then one interior edge per parent corner.
    faces: the child faces when made already (those of the mesh's child level, which its
    face-varying channels share); None makes them.
    """
    vertex_count = level.vertex_count
    edge_count = level.edge_count
    corner_vertex = level.corner_vertex
    corner_edge = level.corner_edge
    corner_prev = level.corner_prev
    ends = level.edge_vertices
    corner_count = len(corner_vertex)
    corners = np.arange(corner_count, dtype=INDEX)
    incoming_edge = corner_edge[corner_prev]
    # The half of the outgoing (incoming) edge that touches the corner's vertex.
    half_out = 2 * corner_edge + (corner_vertex != ends[corner_edge, 0])
    half_in = 2 * incoming_edge + (corner_vertex != ends[incoming_edge, 0])
    edge_point = vertex_count + corner_edge  # child vertex on each corner's outgoing edge
    halves = np.empty((2 * edge_count, 2), dtype=INDEX)
    halves[:, 0] = ends.reshape(-1)
    halves[:, 1] = vertex_count + np.repeat(np.arange(edge_count, dtype=INDEX), 2)
    interior_edge = 2 * edge_count + corners

    if split == "quads":
        face_point = vertex_count + edge_count + level.corner_face
        child_vertices = np.stack(
            [corner_vertex, edge_point, face_point, vertex_count + incoming_edge], axis=1
        )
        child_edges = np.stack(
            [half_out, interior_edge, 2 * edge_count + corner_prev, half_in], axis=1
        )
        interior = np.stack([edge_point, face_point], axis=1)
        child_vertex_count = vertex_count + edge_count + level.face_count
        face_hole = level.face_hole[level.corner_face]
        face_origin = level.face_origin[level.corner_face]
        corners_per_face = 4
        new_vertices = edge_count + level.face_count
    else:
        face_count = level.face_count
        corner_triangles = np.stack([corner_vertex, edge_point, vertex_count + incoming_edge], 1)
        corner_triangle_edges = np.stack([half_out, interior_edge, half_in], axis=1)
        middle = edge_point.reshape(face_count, 1, 3)
        # Middle edge i joins the edge points of corners i and i + 1: corner i + 1's interior edge.
        middle_edges = np.roll(interior_edge.reshape(face_count, 3), -1, axis=1)[:, None, :]
        child_vertices = np.concatenate(
            [corner_triangles.reshape(face_count, 3, 3), middle], axis=1
        ).reshape(-1, 3)
        child_edges = np.concatenate(
            [corner_triangle_edges.reshape(face_count, 3, 3), middle_edges], axis=1
        ).reshape(-1, 3)
        interior = np.stack([edge_point, vertex_count + incoming_edge], axis=1)
        child_vertex_count = vertex_count + edge_count
        face_hole = np.repeat(level.face_hole, 4)
        face_origin = np.repeat(level.face_origin, 4)
        corners_per_face = 3
        new_vertices = edge_count

    return _Level(
        vertex_count=child_vertex_count,
        faces=faces if faces is not None else _Faces.of_uniform(len(face_hole), corners_per_face),
        corner_vertex=child_vertices.reshape(-1),
        corner_edge=child_edges.reshape(-1),
        edge_vertices=np.concatenate([halves, interior]),
        edge_face_count=np.concatenate(
            [np.repeat(level.edge_face_count, 2), np.full(corner_count, 2, dtype=INDEX)]
        ),
        edge_sharpness=np.concatenate([child_sharpness.reshape(-1), np.zeros(corner_count)]),
        vertex_sharpness=np.concatenate(
            [_decrement(level.vertex_sharpness), np.zeros(new_vertices)]
        ),
        face_hole=face_hole,
        face_origin=face_origin,
    )


# --- refinement of data -----------------------------------------------------------------------


@dataclass(frozen=True)
class _Rules:
    scheme: str  # catmullClark, loop or bilinear (linear rules, no creasing)
    split: str  # quads (a face point per face) or triangles (loop's topology)
    smooth_triangles: bool
    crease_method: str


def _rows(array: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``array[index]`` along the first axis: np.take, several times faster than fancy
    indexing on the rows of a 2-D array."""
    return np.take(array, index, axis=0)


def _scatter(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size, m) sums of the rows of ``values`` (n, m) grouped by ``index`` (n,)."""
    out = np.empty((size, values.shape[1]))
    for column in range(values.shape[1]):
        out[:, column] = np.bincount(index, weights=values[:, column], minlength=size)
    return out


def _face_points(level: _Level, data: np.ndarray) -> np.ndarray:
    """(f, m) the average of each face's vertices."""
    corner_values = _rows(data, level.corner_vertex)
    if level.face_count and (level.face_sizes == level.face_sizes[0]).all():
        size = int(level.face_sizes[0])
        return corner_values.reshape(-1, size, data.shape[1]).mean(axis=1)
    sums = np.add.reduceat(corner_values, level.face_offsets, axis=0)
    return sums / level.face_sizes[:, None]


def _vertex_rules(vertex_sharpness: np.ndarray, sharp_edge_count: np.ndarray) -> np.ndarray:
    """OpenSubdiv's DetermineVertexVertexRule: sharp vertex or > 2 sharp edges: corner."""
    return np.where(
        (vertex_sharpness > 0.0) | (sharp_edge_count > 2),
        _CORNER,
        np.where(sharp_edge_count == 2, _CREASE, _SMOOTH),
    )


def _crease_neighbour_sum(
    ends: np.ndarray, data: np.ndarray, sharp_at_first: np.ndarray, sharp_at_second: np.ndarray,
    size: int,
) -> np.ndarray:
    """(size, m) sum, per vertex, of the far ends of its sharp edges."""
    total = np.zeros((size, data.shape[1]))
    first = np.flatnonzero(sharp_at_first)
    second = np.flatnonzero(sharp_at_second)
    if len(first):
        total += _scatter(ends[first, 0], _rows(data, ends[first, 1]), size)
    if len(second):
        total += _scatter(ends[second, 1], _rows(data, ends[second, 0]), size)
    return total


def _refine_vertex_data(
    level: _Level, data: np.ndarray, rules: _Rules, child_sharpness: np.ndarray | None
) -> np.ndarray:
    """(child vertex count, m) data of the next level (vertex points, edge points, face points)."""
    ends = level.edge_vertices
    first, second = ends[:, 0], ends[:, 1]
    end_sums = _rows(data, first) + _rows(data, second)
    midpoints = 0.5 * end_sums
    if rules.scheme == "bilinear":
        parts = [data, midpoints]
        if rules.split == "quads":
            parts.append(_face_points(level, data))
        return np.concatenate(parts)

    vertex_count = level.vertex_count
    edge_count = level.edge_count
    corner_vertex = level.corner_vertex
    corner_edge = level.corner_edge
    sharpness = level.edge_sharpness
    face_counts = np.bincount(corner_vertex, minlength=vertex_count)
    valence = np.maximum(face_counts, 1)[:, None].astype(np.float64)
    # Around a smooth (interior, manifold) vertex the far ends of its corners' outgoing edges
    # are all its neighbours, each once; other vertices do not use this sum.
    ring_vertex = level.following_vertex(1)

    # Edge points: the smooth mask, the crease midpoint, or a blend while sharpness < 1.
    if rules.scheme == "catmullClark":
        face_points = _face_points(level, data)
        face_sum = _scatter(corner_edge, _rows(face_points, level.corner_face), edge_count)
        face_weight = np.full(edge_count, 0.25)
        if rules.smooth_triangles and (level.face_sizes == 3).any():
            triangles = np.bincount(
                corner_edge,
                weights=(level.face_sizes[level.corner_face] == 3).astype(np.float64),
                minlength=edge_count,
            )
            face_weight = 0.5 * (
                _SMOOTH_TRIANGLE_EDGE_WEIGHT * triangles + 0.25 * (2.0 - triangles)
            )
        vertex_weight = 0.5 * (1.0 - 2.0 * face_weight)
        smooth_edges = (
            vertex_weight[:, None] * end_sums
            + face_weight[:, None] * face_sum
        )
    else:  # loop: 3/8 of the edge's ends, 1/8 of the two opposite vertices
        opposite = _rows(data, corner_vertex[level.corner_prev])
        smooth_edges = 0.375 * end_sums + 0.125 * _scatter(
            corner_edge, opposite, edge_count
        )
    child_is_crease = (sharpness >= 1.0) | (
        (child_sharpness[:, 0] > 0.0) & (child_sharpness[:, 1] > 0.0)
    )
    crease_weight = np.where(sharpness <= 0.0, 0.0, np.where(child_is_crease, 1.0, sharpness))
    edge_points = smooth_edges + crease_weight[:, None] * (midpoints - smooth_edges)

    # Vertex points: the rule of the parent, blended towards the child's while sharpness decays.
    if rules.scheme == "catmullClark":
        ring_sum = _scatter(
            corner_vertex,
            _rows(data, ring_vertex) + _rows(face_points, level.corner_face),
            vertex_count,
        )
        smooth_vertices = ((valence - 2.0) * data + ring_sum / valence) / valence
    else:
        edge_weight, self_weight = _loop_vertex_weights(face_counts)
        neighbour_sum = _scatter(corner_vertex, _rows(data, ring_vertex), vertex_count)
        smooth_vertices = self_weight[:, None] * data + edge_weight[:, None] * neighbour_sum
    vertex_points = _blend_vertex_rules(level, data, smooth_vertices, child_sharpness, rules)

    parts = [vertex_points, edge_points]
    if rules.scheme == "catmullClark":
        parts.append(face_points)
    return np.concatenate(parts)


def _loop_vertex_weights(valence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edge weight, self weight) of Loop's smooth vertex mask (Loop's original beta)."""
    n = np.maximum(valence, 1).astype(np.float64)
    beta = 0.375 + 0.25 * np.cos(2.0 * np.pi / n)
    edge_weight = np.where(valence == 6, 0.0625, (0.625 - beta * beta) / n)
    return edge_weight, 1.0 - edge_weight * n


def _blend_vertex_rules(
    level: _Level,
    data: np.ndarray,
    smooth_vertices: np.ndarray,
    child_sharpness: np.ndarray,
    rules: _Rules,
) -> np.ndarray:
    """OpenSubdiv's ComputeVertexVertexMask: parent rule, child rule, fractional blend."""
    ends = level.edge_vertices
    size = level.vertex_count
    sharpness = level.edge_sharpness
    vertex_sharpness = level.vertex_sharpness
    sharp = sharpness > 0.0
    if not sharp.any() and not (vertex_sharpness > 0.0).any():
        return smooth_vertices
    child_sharp = child_sharpness > 0.0
    child_vertex_sharpness = _decrement(vertex_sharpness)
    parent_rule = _vertex_rules(vertex_sharpness, _bincount_ends(ends, sharp, size))
    child_sharp_count = np.bincount(
        ends[:, 0], weights=child_sharp[:, 0], minlength=size
    ) + np.bincount(ends[:, 1], weights=child_sharp[:, 1], minlength=size)
    child_rule = _vertex_rules(child_vertex_sharpness, child_sharp_count)

    def apply(rule: np.ndarray, at_first: np.ndarray, at_second: np.ndarray) -> np.ndarray:
        crease = 0.75 * data + 0.125 * _crease_neighbour_sum(ends, data, at_first, at_second, size)
        return np.where(
            (rule == _SMOOTH)[:, None],
            smooth_vertices,
            np.where((rule == _CREASE)[:, None], crease, data),
        )

    parent_points = apply(parent_rule, sharp, sharp)
    blend = (parent_rule != child_rule) & (parent_rule != _SMOOTH)
    if not blend.any():
        return parent_points
    child_points = apply(child_rule, child_sharp[:, 0], child_sharp[:, 1])
    # Transition weight: the average sharpness of what goes from sharp to smooth here.
    if rules.crease_method == "uniform":
        transition = sharp & (sharpness <= 1.0)
        transition = np.stack([transition, transition], axis=1)
    else:
        transition = sharp[:, None] & ~child_sharp
    vertex_transition = (vertex_sharpness > 0.0) & (child_vertex_sharpness <= 0.0)
    count = (
        np.bincount(ends[:, 0], weights=transition[:, 0], minlength=size)
        + np.bincount(ends[:, 1], weights=transition[:, 1], minlength=size)
        + vertex_transition
    )
    total = (
        np.bincount(ends[:, 0], weights=sharpness * transition[:, 0], minlength=size)
        + np.bincount(ends[:, 1], weights=sharpness * transition[:, 1], minlength=size)
        + vertex_sharpness * vertex_transition
    )
    parent_weight = np.clip(total / np.maximum(count, 1.0), 0.0, 1.0)[:, None]
    blended = parent_weight * parent_points + (1.0 - parent_weight) * child_points
    return np.where(blend[:, None], blended, parent_points)


# --- limit surface ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _LimitSums:
    """What the limit stencils sum over each vertex's corners. They weigh, per corner, e_j the
    data at the far end of its outgoing edge and (catmullClark) d_j the data at its quad's
    opposite corner: gathered one column of the data at a time, used by both sums, and let go
    (gathered whole, (m, c) twice, they were a refine's largest arrays: fresh memory, slow to
    touch).

    ring     : (v, m) catmullClark: the sum of 4 e_j + d_j; loop: of e_j (_limit_positions)
    tangents : the (v, 3) sums of OpenSubdiv's two limit tangent masks over the first 3
               columns (the points; _tangent_weights), valid at smooth interior vertices;
               None when not asked for
    """

    ring: np.ndarray
    tangents: tuple[np.ndarray, np.ndarray] | None

    @staticmethod
    def of(level: _Level, data: np.ndarray, scheme: str, fans: _Fans | None = None) -> _LimitSums:
        """The sums of the limit stencils of ``data`` on ``level``, with the tangents given its ``fans``."""
        corner_vertex = level.corner_vertex
        size = level.vertex_count
        edge_end = level.following_vertex(1)
        opposite = level.following_vertex(2) if scheme == "catmullClark" else None
        weights = None if fans is None else _tangent_weights(level, fans, scheme)
        ring = np.empty((size, data.shape[1]))
        tangents = None if weights is None else (np.empty((size, 3)), np.empty((size, 3)))
        for column, values in enumerate(np.ascontiguousarray(data.T)):
            edge = np.take(values, edge_end)
            diagonal = None if opposite is None else np.take(values, opposite)
            ring[:, column] = np.bincount(
                corner_vertex, weights=edge if diagonal is None else 4.0 * edge + diagonal, minlength=size
            )
            if tangents is None or column >= 3:
                continue
            for tangent, (edge_weight, diagonal_weight) in zip(tangents, weights):
                terms = edge_weight * edge
                if diagonal_weight is not None:
                    terms += diagonal_weight * diagonal
                tangent[:, column] = np.bincount(corner_vertex, weights=terms, minlength=size)
        return _LimitSums(ring, tangents)


def _limit_positions(level: _Level, data: np.ndarray, scheme: str, ring_sum: np.ndarray) -> np.ndarray:
    """(v, m) data pushed to the limit surface (OpenSubdiv's limit position masks); ``ring_sum``
    is _LimitSums.ring of ``data``."""
    ends = level.edge_vertices
    size = level.vertex_count
    corner_vertex = level.corner_vertex
    sharp = level.edge_sharpness > 0.0
    rule = _vertex_rules(level.vertex_sharpness, _bincount_ends(ends, sharp, size))
    face_counts = np.bincount(corner_vertex, minlength=size)
    n = np.maximum(face_counts, 1).astype(np.float64)
    # As in _refine_vertex_data: a smooth vertex's neighbours are its corners' next vertices.
    if scheme == "catmullClark":
        # Regular: (1/36) [1 4 1; 4 16 4; 1 4 1]; valence n: 1/(n(n+5)) per diagonal vertex.
        diagonal_weight = 1.0 / (n * (n + 5.0))
        self_weight = 1.0 - 5.0 * n * diagonal_weight
        smooth = self_weight[:, None] * data + diagonal_weight[:, None] * ring_sum
        smooth = np.where((face_counts == 2)[:, None], data, smooth)  # OpenSubdiv: a corner
    else:
        # Loop's beta is positive for every valence, so the division is safe.
        loop_edge_weight, _ = _loop_vertex_weights(face_counts)
        edge_weight = 1.0 / (n + 3.0 / (8.0 * loop_edge_weight))
        smooth = (1.0 - n * edge_weight)[:, None] * data + edge_weight[:, None] * ring_sum
    crease = (4.0 * data + _crease_neighbour_sum(ends, data, sharp, sharp, size)) / 6.0
    return np.where(
        (rule == _SMOOTH)[:, None], smooth, np.where((rule == _CREASE)[:, None], crease, data)
    )


@dataclass(frozen=True, eq=False)
class _Fans:
    """The corners around each vertex, in counter-clockwise order (seen from the front).

    position : (c,) rank of the corner around its vertex from the fan's first corner
    twin     : (c,) the corner of the neighbouring face across the corner's outgoing edge
               (wound the other way), -1 on a boundary or a non-manifold edge
    manifold : (v,) the corners form one fan of consistently wound faces
    closed   : (v,) that fan is a closed ring (an interior vertex)

    Counter-clockwise, the corner after c is twin[prev(c)] (across c's incoming edge), and
    the one before c is next(twin[c]) (across its outgoing edge).
    """

    position: np.ndarray
    twin: np.ndarray
    manifold: np.ndarray
    closed: np.ndarray

    def successor(self, level: _Level, corners: np.ndarray) -> np.ndarray:
        """(n,) the next corner around the vertex of each of ``corners``, -1 after the last."""
        following = self.twin[level.corner_prev[corners]]
        after = self.position[np.maximum(following, 0)]
        return np.where((following >= 0) & (after != 0), following, -1)

    def predecessor(self, level: _Level, corners: np.ndarray) -> np.ndarray:
        """(n,) the previous corner around the vertex of each of ``corners``, -1 at the first."""
        across = self.twin[corners]
        before = level.corner_next[np.maximum(across, 0)]
        return np.where((across >= 0) & (self.position[corners] != 0), before, -1)


def _fans(level: _Level, sharp_edge: np.ndarray) -> _Fans:
    """Rank corners around their vertices by pointer jumping (no loop per vertex).

    A closed ring is cut after a sharp edge when it has one, so that its sectors (runs of
    faces between sharp edges, see _sectors) are contiguous. The reference for _child_fans,
    and what the authored mesh and loop levels use.
    """
    corner_vertex = level.corner_vertex
    corner_edge = level.corner_edge
    size = level.vertex_count
    corner_count = len(corner_vertex)
    corners = np.arange(corner_count, dtype=INDEX)
    # The other corner of each corner's edge, if the edge has two faces wound against each other.
    lowest = np.full(level.edge_count, corner_count, dtype=INDEX)
    highest = np.full(level.edge_count, -1, dtype=INDEX)
    np.minimum.at(lowest, corner_edge, corners)
    np.maximum.at(highest, corner_edge, corners)
    low, high = lowest[corner_edge], highest[corner_edge]
    twin = np.where(low == corners, high, low)
    twin_ok = level.edge_face_count[corner_edge] == 2
    twin_ok &= corner_vertex[twin] == corner_vertex[level.corner_next]
    twin[~twin_ok] = -1
    # Counter-clockwise around the vertex: across the corner's incoming edge.
    rotate = twin[level.corner_prev]
    head = np.ones(corner_count, dtype=bool)  # nothing rotates into it
    head[rotate[rotate >= 0]] = False
    closed = np.bincount(corner_vertex, weights=head, minlength=size) == 0
    score = corners + corner_count * (~sharp_edge[corner_edge])
    best = np.full(size, 2 * corner_count, dtype=INDEX)
    np.minimum.at(best, corner_vertex, score)
    head[best[closed & (best < 2 * corner_count)] % corner_count] = True
    successor = rotate.copy()
    linked = np.flatnonzero(rotate >= 0)
    successor[linked[head[rotate[linked]]]] = -1
    linked = np.flatnonzero(successor >= 0)
    predecessor = np.full(corner_count, -1, dtype=INDEX)
    predecessor[successor[linked]] = linked

    # Wyllie's list ranking: each pass doubles how far back every pointer reaches.
    position = (predecessor >= 0).astype(INDEX)
    pointer = predecessor.copy()
    live = np.flatnonzero(pointer >= 0)
    for _ in range(corner_count.bit_length() + 1):
        if not len(live):
            break
        reach = pointer[live]
        position[live] += position[reach]
        pointer[live] = pointer[reach]
        live = live[pointer[live] >= 0]
    unreached = np.zeros(size, dtype=bool)  # a second ring at one vertex never ends
    unreached[corner_vertex[live]] = True
    heads_per_vertex = np.bincount(corner_vertex, weights=head, minlength=size)
    face_counts = np.bincount(corner_vertex, minlength=size)
    edge_counts = np.bincount(level.edge_vertices.reshape(-1), minlength=size)
    manifold = (
        (heads_per_vertex == 1) & ~unreached & (edge_counts == face_counts + ~closed)
    )
    return _Fans(position, twin, manifold, closed)


def _child_fans(parent: _Level, fans: _Fans, child: _Level) -> _Fans:
    """The fans of a quad split's child level, from its parent's fans without searching.

    Child corner 4c + k lies in the child quad of parent corner c: k = 0 at its vertex point,
    1 at the point of its outgoing edge, 2 at its face point, 3 at the point of its incoming
    edge. Counter-clockwise around an edge point come 4 next(o) + 3, 4 o + 1, 4 next(t) + 3,
    4 t + 1 (o the edge's lower corner, t its twin); around a face point the face's corners in
    order; around a vertex point the parent vertex's corners in order.
    """
    corners = np.arange(len(parent.corner_vertex), dtype=INDEX)
    following, preceding = parent.corner_next, parent.corner_prev
    twin = fans.twin
    has_twin = twin >= 0
    incoming_twin = twin[preceding]
    child_twin = np.stack(
        [
            np.where(has_twin, 4 * following[np.maximum(twin, 0)] + 3, -1),
            4 * following + 2,
            4 * preceding + 1,
            np.where(incoming_twin >= 0, 4 * incoming_twin, -1),
        ],
        axis=1,
    ).reshape(-1)
    owner = ~has_twin | (corners < twin)  # one corner per edge ranks its edge point's fan
    position = np.stack(
        [
            fans.position,
            np.where(owner, 1, 3),
            corners - parent.face_offsets[parent.corner_face],
            np.where(owner[preceding], 0, 2),
        ],
        axis=1,
    ).reshape(-1)
    edge_closed = np.zeros(parent.edge_count, dtype=bool)
    edge_closed[parent.corner_edge[has_twin]] = True
    all_faces = np.ones(parent.face_count, dtype=bool)
    closed = np.concatenate([fans.closed, edge_closed, all_faces])
    manifold = np.concatenate(
        [fans.manifold, edge_closed | (parent.edge_face_count == 1), all_faces]
    )
    # A closed ring with sharp edges must start after one (see _fans); decayed sharpness can
    # leave an inherited start smooth. Only halves of parent edges (k = 0, 3) can be sharp.
    halves = np.concatenate([4 * corners, 4 * corners + 3])
    sharp_out = halves[child.edge_sharpness[child.corner_edge[halves]] > 0.0]
    sharp_out = sharp_out[closed[child.corner_vertex[sharp_out]]]
    if len(sharp_out):
        unset = np.iinfo(INDEX).max
        first_sharp = np.full(child.vertex_count, unset, dtype=INDEX)
        np.minimum.at(first_sharp, child.corner_vertex[sharp_out], position[sharp_out])
        shift = np.where(first_sharp == unset, 0, first_sharp)
        if (shift > 0).any():
            moved = np.flatnonzero((shift > 0)[child.corner_vertex])
            vertex = child.corner_vertex[moved]
            valence = np.bincount(vertex, minlength=child.vertex_count)[vertex]
            position[moved] = (position[moved] - shift[vertex]) % valence
    return _Fans(position, child_twin, manifold, closed)


def _sectors(
    level: _Level, fans: _Fans, sharp_edge: np.ndarray, corners: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(first, last): the first and last corner of the sector of each of ``corners``.

    ``corners`` holds whole vertices; a sector starts at a fan's first corner or at a corner
    whose outgoing edge (the edge crossed to reach it) is sharp.
    """
    count = len(level.corner_vertex)
    preceding = fans.predecessor(level, corners)
    start = (preceding < 0) | sharp_edge[level.corner_edge[corners]]
    is_start = np.zeros(count, dtype=bool)
    is_start[corners[start]] = True
    # Pointer jumping back to the sector's first corner (a start points at itself).
    jump = np.zeros(count, dtype=INDEX)
    jump[corners] = np.where(start, corners, preceding)
    pending = corners[~start]
    for _ in range(count.bit_length() + 1):
        if not len(pending):
            break
        jump[pending] = jump[jump[pending]]
        pending = pending[~is_start[jump[pending]]]
    first = jump[corners]
    following = fans.successor(level, corners)
    is_last = (following < 0) | is_start[np.maximum(following, 0)]
    last_of = np.zeros(count, dtype=INDEX)
    last_of[first[is_last]] = corners[is_last]
    return first, last_of[first]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (n, 3) arrays (np.cross is several times slower on big arrays)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _corner_normals(
    level: _Level, fans: _Fans, points: np.ndarray, scheme: str, sums: _LimitSums | None
) -> tuple[np.ndarray, np.ndarray]:
    """The unit normal of each corner of the final level, as ((n, 3) values, (c,) index into
    them per corner): limit normals given the ``sums`` of the limit stencils (with tangents),
    area-weighted normals without them (no limit step).

    With sums, corners of smooth interior vertices get the limit normal of their vertex
    (value v for vertex v); the others (boundaries, creases, corners, non-manifold fans: few)
    are handled per sector by _sector_normals, a value each after the vertices'. Without it
    every corner gets its sector's area-weighted normal.
    """
    corner_vertex = level.corner_vertex
    size = level.vertex_count
    sharp_edge = level.edge_sharpness > 0.0
    sharp_edge_count = _bincount_ends(level.edge_vertices, sharp_edge, size)
    rule = _vertex_rules(level.vertex_sharpness, sharp_edge_count)
    face_counts = np.bincount(corner_vertex, minlength=size)
    limit = sums is not None
    if limit:
        whole_vertex = fans.manifold & fans.closed & (rule == _SMOOTH) & (face_counts >= 3)
        vertex_normals = _cross(*sums.tangents)  # tan1 x tan2
    else:
        # One sector (no sharp edge): the area-weighted normal of all the vertex's faces.
        whole_vertex = fans.manifold & fans.closed & (sharp_edge_count == 0)
        face_areas = _corner_face_areas(level, points, level.face_offsets)
        vertex_normals = _scatter(corner_vertex, _rows(face_areas, level.corner_face), size)
    values = [_unit_rows(vertex_normals)]
    index = corner_vertex.copy()
    others = np.flatnonzero(~whole_vertex[corner_vertex])
    if len(others):
        values.append(_unit_rows(_sector_normals(level, points, fans, scheme, rule, others, limit)))
        index[others] = size + np.arange(len(others))
    values = np.concatenate(values) if len(values) > 1 else values[0]
    bad = np.flatnonzero(~np.isfinite(values[:, 0])[index])
    if len(bad):
        # A fan whose normal vanishes (degenerate geometry) takes its face's direction, and a
        # face of no area any unit vector: a renderer needs finite normals.
        replacements = _unit_rows(_corner_face_areas(level, points, bad))
        replacements[~np.isfinite(replacements[:, 0])] = (0.0, 0.0, 1.0)
        index[bad] = len(values) + np.arange(len(bad))
        values = np.concatenate([values, replacements])
    return values, index


def _unit_rows(vectors: np.ndarray) -> np.ndarray:
    """(n, 3) rows scaled to unit length; rows of zero length become NaN (for the caller)."""
    length = np.sqrt(np.einsum("ij,ij->i", vectors, vectors))
    with np.errstate(divide="ignore", invalid="ignore"):
        return vectors / np.where(length > 1e-300, length, np.nan)[:, None]


def _corner_face_areas(level: _Level, points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n, 3) area-weighted normal of the face of each of ``corners`` (exact for tri and quad)."""
    size = int(level.face_sizes[0]) if level.face_count else 3
    first = level.face_offsets[level.corner_face[corners]]
    face = _rows(points, level.corner_vertex[first[:, None] + np.arange(size)])  # (n, size, 3)
    if size == 3:
        return 0.5 * _cross(face[:, 1] - face[:, 0], face[:, 2] - face[:, 0])
    return 0.5 * _cross(face[:, 2] - face[:, 0], face[:, 3] - face[:, 1])


def _tangent_weights(level: _Level, fans: _Fans, scheme: str) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Per corner, the weights of its e_j and (catmullClark) d_j in OpenSubdiv's two limit
    tangent masks of its vertex, j its rank counter-clockwise around the vertex: [(edge,
    diagonal) of tan1, of tan2], (c,) each (diagonal None for loop). They depend only on
    (valence, j): they are gathered from a table. Valid at smooth interior vertices.
    """
    corner_vertex = level.corner_vertex
    # Valences below 3 are never smooth here; clamping keeps their (unused) weights finite.
    valence = np.maximum(np.bincount(corner_vertex, minlength=level.vertex_count), 3)
    corner_valence = valence[corner_vertex]
    tables, row_start = _tangent_weight_tables(valence, scheme)
    entry = row_start[corner_valence] + np.minimum(fans.position, corner_valence - 1)
    return [(edge_table[entry], None if diagonal_table is None else diagonal_table[entry])
            for edge_table, diagonal_table in tables]


def _tangent_weight_tables(valence: np.ndarray, scheme: str):
    """([(edge, diagonal) weights of tan1, of tan2], row_start) for the valences present.

    The weights of rank j around a vertex of valence n are at row_start[n] + j. catmullClark
    (OpenSubdiv's Catmark masks): 4 cos(j theta) on e_j and (cos(j theta) + cos((j+1) theta)) /
    (4 lambda - 1) on d_j, lambda the subdominant eigenvalue; tan2 the same with sines. loop:
    cos(j theta) and sin(j theta) on e_j.
    """
    present = np.flatnonzero(np.bincount(valence))  # (np.unique would import numpy.ma: 12 ms)
    row_start = np.zeros(int(present.max(initial=0)) + 1, dtype=INDEX)
    row_start[present] = np.cumsum(present) - present
    n = np.repeat(present, present).astype(np.float64)
    rank = np.arange(len(n)) - np.repeat(np.cumsum(present) - present, present)
    theta = 2.0 * np.pi / n
    angle = rank * theta
    if scheme != "catmullClark":
        return [(np.cos(angle), None), (np.sin(angle), None)], row_start
    cos_theta = np.cos(theta)
    subdominant = 5.0 / 16.0 + (
        cos_theta + np.cos(0.5 * theta) * np.sqrt(2.0 * (9.0 + cos_theta))
    ) / 16.0
    face_scale = 1.0 / (4.0 * subdominant - 1.0)
    tables = [
        (4.0 * wave(angle), face_scale * (wave(angle) + wave(angle + theta)))
        for wave in (np.cos, np.sin)
    ]
    return tables, row_start


def _sector_normals(
    level: _Level,
    points: np.ndarray,
    fans: _Fans,
    scheme: str,
    rule: np.ndarray,
    corners: np.ndarray,
    limit: bool,
) -> np.ndarray:
    """(n, 3) normals of ``corners`` (sorted, whole vertices), one per sector of their vertex.

    With ``limit``: at crease vertices tan1 runs along the crease (leading minus trailing edge)
    and tan2 is OpenSubdiv's cross tangent over the sector (Biermann et al. for catmullClark,
    Loop's for loop); a corner vertex's one-face sector uses its two edges. Everything else -
    corner sectors of several faces, non-manifold fans, or no ``limit`` - gets the
    area-weighted normal of the sector's faces (of the whole vertex when non-manifold).
    """
    corner_vertex = level.corner_vertex[corners]
    first, last = _sectors(level, fans, level.edge_sharpness > 0.0, corners)
    sector = np.searchsorted(corners, first)  # the sector's first corner, local index
    count = len(corners)
    areas = _corner_face_areas(level, points, corners)
    manifold = fans.manifold[corner_vertex]
    normals = _scatter(sector, areas, count)[sector]
    if not manifold.all():
        vertices, local_vertex = np.unique(corner_vertex, return_inverse=True)
        local_vertex = local_vertex.reshape(-1)
        whole = _scatter(local_vertex, areas, len(vertices))[local_vertex]
        normals = np.where(manifold[:, None], normals, whole)
    if not limit:
        return normals

    sector_size = np.bincount(sector, minlength=count)
    k = sector_size[sector].astype(np.float64)  # faces in the corner's sector
    i = (fans.position[corners] - fans.position[corners[sector]]).astype(np.float64)
    vertex = _rows(points, corner_vertex)
    ring = _rows(points, level.corner_vertex[level.corner_next[corners]])
    leading = ring  # at a sector's first corner, its outgoing edge leads the sector
    trailing = _rows(points, level.corner_vertex[level.corner_prev[last]])
    theta = np.pi / k
    if scheme == "catmullClark":
        diagonal = _rows(points, level.corner_vertex[level.corner_next[level.corner_next[corners]]])
        terms = (4.0 * np.sin(i * theta))[:, None] * ring + (
            np.sin(i * theta) + np.sin((i + 1.0) * theta)
        )[:, None] * diagonal
    else:
        general = (2.0 - 2.0 * np.cos(theta)) * np.sin(i * theta)
        weight = np.where(k == 2, i == 1, np.where(k == 3, i >= 1, general))
        terms = weight[:, None] * ring
    sums = _scatter(sector, terms, count)
    cos_t, sin_t = np.cos(theta), np.sin(theta)  # per corner; used at sector starts
    both_ends = leading + trailing
    if scheme == "catmullClark":
        # Biermann's cross tangent (k >= 2 faces; OpenSubdiv's common denominator dropped).
        r = (cos_t + 1.0) / np.where(k >= 2, sin_t, 1.0)
        cross_tangent = (
            (4.0 * r * (cos_t - 1.0))[:, None] * vertex
            - (r * (1.0 + 2.0 * cos_t))[:, None] * both_ends
            + sums
        )
    else:
        cross_tangent = np.where(
            (k == 2)[:, None],
            sums - vertex,
            np.where(
                (k == 3)[:, None],
                sums - vertex - 0.5 * both_ends,
                sums - sin_t[:, None] * both_ends,
            ),
        )
    cross_tangent = np.where((k == 1)[:, None], both_ends - 2.0 * vertex, cross_tangent)
    at_crease = rule[corner_vertex] == _CREASE
    limit_normals = np.where(
        at_crease[:, None],
        _cross(leading - trailing, cross_tangent),
        _cross(leading - vertex, trailing - vertex),
    )
    defined = manifold & (at_crease | (k == 1)) & (rule[corner_vertex] != _SMOOTH)
    use = defined[sector] & manifold
    return np.where(use[:, None], _rows(limit_normals, sector), normals)


# --- face-varying channels --------------------------------------------------------------------


def _corner_classes(corner_vertex: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(class of each corner, first corner of each class): corners at the same vertex with
    equal ``keys`` rows (c, k) are one class. Classes are numbered in sorted order."""
    order = np.lexsort((*keys.T[::-1], corner_vertex))
    sorted_vertex = corner_vertex[order]
    differs = np.ones(len(order), dtype=bool)
    differs[1:] = sorted_vertex[1:] != sorted_vertex[:-1]
    for column in keys.T:  # (column by column: .any(axis=1) is slow on short rows)
        sorted_column = column[order]
        differs[1:] |= sorted_column[1:] != sorted_column[:-1]
    starts = np.flatnonzero(differs)
    corner_class = np.empty(len(order), dtype=INDEX)
    corner_class[order] = np.cumsum(differs) - 1
    return corner_class, order[starts]


def _face_varying_level(
    base: _Level, primvar: FaceVaryingPrimvar, kept_corner: np.ndarray, tags: SubdivisionTags
) -> tuple[_Level, np.ndarray]:
    """(level, values): a channel as a mesh whose vertices are its (vertex, value) pairs.

    Seams are boundaries of that mesh (infinitely sharp); interior edges and vertices inherit
    the mesh's sharpness; values are pinned as OpenSubdiv's FVarLevel does for the
    faceVaryingLinearInterpolation option.
    """
    values = np.asarray(primvar.values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if primvar.indices is None:
        if len(values) != len(kept_corner):
            raise ValueError(f"{len(values)} face-varying values for {len(kept_corner)} corners")
        corner_values = values[kept_corner]  # (a mask)
        fvar_vertex, first_corner = _corner_classes(base.corner_vertex, corner_values)
    else:
        indices = np.asarray(primvar.indices, dtype=INDEX).reshape(-1)
        if len(indices) != len(kept_corner) or (
            len(indices) and (indices.min() < 0 or indices.max() >= len(values))
        ):
            raise ValueError("face-varying indices do not match the corners and values")
        corner_values = _rows(values, indices[kept_corner])
        fvar_vertex, first_corner = _corner_classes(
            base.corner_vertex, indices[kept_corner][:, None]
        )
    vertex_of_value = base.corner_vertex[first_corner]
    value_count = len(first_corner)
    _, corner_edge, edge_vertices = _unique_edges(fvar_vertex, base.corner_next, value_count)
    edge_count = len(edge_vertices)
    edge_face_count = np.bincount(corner_edge, minlength=edge_count).astype(INDEX)
    edge_sharpness = np.zeros(edge_count)
    np.maximum.at(edge_sharpness, corner_edge, base.edge_sharpness[base.corner_edge])
    fvar_boundary = edge_face_count != 2
    edge_sharpness[fvar_boundary] = SHARPNESS_INFINITE
    vertex_sharpness = base.vertex_sharpness[vertex_of_value].copy()

    option = tags.face_varying_linear_interpolation
    linear_boundaries = option in ("boundaries", "all")
    dependent = option in ("cornersPlus1", "cornersPlus2")
    corners_are_sharp = option != "none"
    sharpen_darts = option == "cornersPlus2" or linear_boundaries
    vertex_count = base.vertex_count

    span = np.bincount(fvar_vertex, minlength=value_count)  # faces around each value
    value_boundary_ends = _bincount_ends(edge_vertices, fvar_boundary, value_count)
    mesh_boundary_ends = _bincount_ends(
        base.edge_vertices, base.edge_face_count != 2, vertex_count
    )
    siblings = np.bincount(vertex_of_value, minlength=vertex_count)
    seam_ends = np.bincount(vertex_of_value, weights=value_boundary_ends, minlength=vertex_count)
    on_mesh_boundary = mesh_boundary_ends > 0
    mismatch = (seam_ends > mesh_boundary_ends) | (siblings > 1)
    mismatch |= linear_boundaries & on_mesh_boundary
    all_sharp = mismatch & (
        linear_boundaries
        | (base.vertex_sharpness >= SHARPNESS_INFINITE)
        | (dependent & (siblings > 2))
        | (sharpen_darts & (siblings == 1) & ~on_mesh_boundary)
    )
    if dependent:
        two = mismatch & (siblings == 2)
        interior_infinite = (~fvar_boundary) & (edge_sharpness >= SHARPNESS_INFINITE)
        creased_span = _bincount_ends(edge_vertices, interior_infinite, value_count) > 0
        all_sharp |= two & (
            np.bincount(vertex_of_value, weights=creased_span, minlength=vertex_count) > 0
        )
        if option == "cornersPlus2":
            # A value spanning one face makes the other value a concave corner: pin both.
            all_sharp |= two & (
                np.bincount(vertex_of_value, weights=span == 1, minlength=vertex_count) > 0
            )
    pinned = all_sharp[vertex_of_value] | ((span == 1) & corners_are_sharp)
    vertex_sharpness[pinned] = SHARPNESS_INFINITE

    level = _Level(
        vertex_count=value_count,
        faces=base.faces,
        corner_vertex=fvar_vertex,
        corner_edge=corner_edge,
        edge_vertices=edge_vertices,
        edge_face_count=edge_face_count,
        edge_sharpness=edge_sharpness,
        vertex_sharpness=vertex_sharpness,
        face_hole=base.face_hole,
        face_origin=base.face_origin,
    )
    return level, _rows(corner_values, first_corner)


# --- how many levels: refinement from the projected size --------------------------------------

TARGET_EDGE_PIXELS = 4.0
"""The longest a refined edge may project to, in pixels. A straight segment of s pixels across
a limit surface curving with radius R pixels misses it by about s²/8R: with s = 4 that is at
most a quarter of a pixel wherever the surface curves over 8 pixels or more (a cage edge
spans a few R), and the kink between segments (s/R radians) is then at most half a radian
only on features a few pixels wide. The shading normals are the limit normals, so only
silhouettes and shadow terminators show the facets; 4 px keeps both smooth at the render's
resolution. Each halving of it would cost 4 times the triangles. Measured on a Catmull-Clark
unit cube whose cage edge spans 22 px: level 3 (its choice) misses the limit surface by 0.1 px
at most, level 2 by 0.35 px, level 1 by 1.2 px (tests/test_adaptive_subdivision.py)."""

OFF_VIEW_LEVEL = 2
"""The most levels a mesh out of view (behind the camera, or outside the cone that holds the
image) gets: it is only seen in reflections and shadows, where a Catmull-Clark shape within a
few percent of its cage edge (level 2: a cube's silhouette within 2%) is what a shadow's edge
shows. A mesh whose cage is already finer than TARGET_EDGE_PIXELS at its distance gets 0,
as it would in view."""

CAGE_EDGE_PERCENTILE = 90.0
"""Which cage edge stands for the mesh: a high percentile of its edge lengths, so that the
long edges that make a silhouette polygonal decide, but not the few slivers of a dense mesh."""


@dataclass(frozen=True, eq=False)
class PixelFootprint:
    """What the camera sees of the world: where it is and how large a pixel is there.

    eye            : (3,) float64, the camera's position, metres
    forward        : (3,) float64, unit view direction
    pixel_size     : the world size of a pixel's smaller side at a distance of 1 (metres per
                     metre of distance)
    view_tangent   : tangent of the half-angle of a cone around ``forward`` that holds the
                     whole image (its corners, aperture offsets included)
    near           : metres; nearer distances count as this (the near clipping distance)
    """

    eye: np.ndarray
    forward: np.ndarray
    pixel_size: float
    view_tangent: float
    near: float

    @classmethod
    def of_camera(cls, camera: Camera, resolution: tuple[int, int], pixel_aspect_ratio: float) -> PixelFootprint:
        """The footprint of ``camera`` rendering ``resolution`` (width, height) pixels, each
        ``pixel_aspect_ratio`` times as wide as tall. UsdRender's conform policy keeps one
        aperture and fits the other to the image (or keeps both and stretches the pixels):
        the pixel is taken from whichever aperture gives the smaller one and the view cone
        from whichever gives the wider view, so that neither is underestimated whatever the
        policy. An orthographic camera (not rendered yet) is read as the pinhole of its
        apertures."""
        width, height = resolution
        if not pixel_aspect_ratio > 0.0:  # the tracer refuses such a spec: any level will do
            pixel_aspect_ratio = 1.0
        focal = camera.focal_length
        h_aperture, v_aperture = camera.horizontal_aperture, camera.vertical_aperture
        pixel_width = min(h_aperture / width, v_aperture * pixel_aspect_ratio / height) / focal
        aspect = width * pixel_aspect_ratio / height
        half_width = (max(h_aperture, v_aperture * aspect) / 2 + abs(camera.horizontal_aperture_offset)) / focal
        half_height = (max(v_aperture, h_aperture / aspect) / 2 + abs(camera.vertical_aperture_offset)) / focal
        matrix = np.asarray(camera.world_from_camera, np.float64)
        forward = -matrix[:3, 2]
        return cls(eye=matrix[:3, 3].copy(), forward=forward / np.linalg.norm(forward),
                   pixel_size=pixel_width * min(1.0, 1.0 / pixel_aspect_ratio),
                   view_tangent=math.hypot(half_width, half_height), near=float(camera.clipping[0]))

    def level(self, world_from_object: np.ndarray, edge_length: float, lower: np.ndarray, upper: np.ndarray) -> int:
        """The fewest levels (at most MAX_SUBDIV_LEVEL) that bring a cage edge of
        ``edge_length`` to TARGET_EDGE_PIXELS at the nearest distance of the mesh's bounds
        from the eye; at most OFF_VIEW_LEVEL when the bounds are out of view.

        world_from_object : (4, 4) float64, column convention, object units → metres
        edge_length       : the cage edge that stands for the mesh (cage_edge_length), object units
        lower, upper      : (3,) the cage's object-space bounds

        The edge is scaled by the transform's largest singular value: exact for a uniform
        scale, the longest an edge can become under a non-uniform one.
        """
        linear = world_from_object[:3, :3]
        corners = np.array(list(itertools.product(*zip(lower, upper))), np.float64)  # (8, 3)
        world = corners @ linear.T + world_from_object[:3, 3]
        world_lower, world_upper = world.min(axis=0), world.max(axis=0)
        nearest = np.clip(self.eye, world_lower, world_upper)
        distance = max(float(np.linalg.norm(nearest - self.eye)), self.near)
        pixels = edge_length * float(np.linalg.norm(linear, 2)) / (distance * self.pixel_size)
        level = _halvings(pixels / TARGET_EDGE_PIXELS)
        return level if self.sees(world_lower, world_upper) else min(level, OFF_VIEW_LEVEL)

    def sees(self, lower: np.ndarray, upper: np.ndarray) -> bool:
        """Whether the world box ``lower``..``upper`` (metres) may be in view: False when its
        bounding sphere is behind the eye or outside the view cone (conservative: a box
        beside the image's corner may count as seen)."""
        centre, radius = (lower + upper) / 2, float(np.linalg.norm(upper - lower)) / 2
        offset = centre - self.eye
        along = float(offset @ self.forward)
        if along < -radius:
            return False
        across = float(np.linalg.norm(offset - along * self.forward))
        cosine = 1.0 / math.sqrt(1.0 + self.view_tangent ** 2)
        # Distance from the centre to the cone's side (an underestimate behind the apex).
        return across * cosine - along * self.view_tangent * cosine <= radius


def _halvings(ratio: float) -> int:
    """The fewest halvings (0 to MAX_SUBDIV_LEVEL) that bring ``ratio`` to 1 or below; 0 for
    NaN (a degenerate mesh or footprint)."""
    if not ratio > 1.0:
        return 0
    if ratio >= 2.0 ** MAX_SUBDIV_LEVEL:
        return MAX_SUBDIV_LEVEL
    return math.ceil(math.log2(ratio))


def cage_edge_length(points: np.ndarray, face_vertex_counts: np.ndarray, face_vertex_indices: np.ndarray) -> float:
    """The CAGE_EDGE_PERCENTILE of the lengths of the faces' edges (shared edges counted once
    per face), in the points' units; 0 for a mesh without faces.

    points : (v, 3) float64; face_vertex_counts : (f,) int; face_vertex_indices : (sum(counts),) int
    """
    counts = np.asarray(face_vertex_counts, INDEX)
    if not len(face_vertex_indices):
        return 0.0
    starts = np.cumsum(counts) - counts
    following = np.arange(len(face_vertex_indices), dtype=INDEX) + 1
    faces = counts > 0
    following[(starts + counts - 1)[faces]] = starts[faces]  # the last corner closes its face
    edges = points[face_vertex_indices[following]] - points[face_vertex_indices]
    return float(np.percentile(np.linalg.norm(edges, axis=1), CAGE_EDGE_PERCENTILE))


def refined_triangle_count(face_vertex_counts: np.ndarray, level: int, scheme: str) -> int:
    """How many triangles :func:`refine` at ``level`` (0: the cage, fan-triangulated) gives,
    split as the reader splits them: a refined quad in two, a loop triangle as it is. Hole
    faces are counted (an upper bound).

    face_vertex_counts : (f,) int; faces of fewer than 3 vertices make none
    """
    counts = np.asarray(face_vertex_counts, INDEX)
    counts = counts[counts >= 3]
    if level == 0:
        return int((counts - 2).sum())
    if scheme == "loop" and (counts == 3).all():
        return len(counts) * 4 ** level
    # The first level turns an n-gon into n quads, each later level a quad into 4.
    return 2 * int(counts.sum()) * 4 ** (level - 1)
