"""Triangulate UsdGeom.Mesh prims into object-space surfaces.

Polygonal meshes (``subdivisionScheme = none``) are fan-triangulated. Subdivision meshes are
refined to the level the reader chose for them with :mod:`.subdivision` (OpenSubdiv's rules,
limit points and limit normals) and their quads split in two; as the UsdGeom schema says,
their authored normals are then ignored (with a warning: meshes exported with normals often
leave ``subdivisionScheme`` at its catmullClark default by mistake). :func:`read_cage` reads
what choosing that level takes (see subdivision.PixelFootprint and reader.py).

Besides the uv primvar, :func:`read_mesh` reads the primvars materials' primvar readers name
(any interpolation, 1–4 components) per triangle corner; constant ones (inherited from
ancestors too) cost no per-corner memory: :func:`constant_primvar` explains.

The result, :class:`LocalSurface`, is still in the gprim's own space and stage units; it is
computed once per distinct surface (a prototype, or prims that read the same opinions: see
:func:`mesh_opinions`) and placed in the world (possibly many times) by :mod:`.placement`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np
from pxr import Usd, UsdGeom

from pxr_layers.errors import StageError
from pxr_layers.request import MAX_SUBDIV_LEVEL

from . import subdivision
from .budgets import SceneBudget
from .diagnostics import Diagnostics
from .values import integer_array, real_array, usd_type_name


@dataclass(frozen=True)
class LocalSurface:
    """A gprim triangulated in its object space (stage units).

    points        : (v, 3) float64, object space
    triangles     : (t, 3) int64 indices into points, counter-clockwise seen from the front
                    (``orientation = leftHanded`` already flipped)
    normals       : (t, 3, 3) float64 object-space shading normal per corner (not
                    necessarily unit length; the limit normals of a refined subdivision
                    surface), or None
    smooth        : when ``normals`` is None, True asks placement for area-weighted vertex
                    normals (a subdivision mesh read at level 0 looks smooth in any
                    renderer); False means flat shading
    uvs           : (t, 3, 2) float64 st per corner, or None
    triangle_face : (t,) int64 index of the authored face each triangle comes from
                    (GeomSubsets select faces), also for refined subdivision surfaces
    face_count    : number of authored faces
    primvars      : name (without ``primvars:``) → (t, 3, w) float32 values per corner,
                    w = 1–4 components, of the primvars asked for that the gprim has
                    (or inherits: constant ones); read-only. Constant primvars are
                    ``np.broadcast_to`` views of one value (strides 0, 0, 4), uniform ones
                    views of one row per triangle (stride 0 over the corners): see
                    :func:`constant_primvar`
    """

    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    smooth: bool
    uvs: np.ndarray | None
    triangle_face: np.ndarray
    face_count: int
    primvars: Mapping[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class SubdivisionCage:
    """What choosing a subdivision mesh's level takes (:func:`read_cage`), object space.

    edge_length  : the cage edge that stands for the mesh (subdivision.cage_edge_length),
                   stage units; None when not measured (the level is not chosen by size)
    lower, upper : (3,) float64 bounds of its points, stage units
    triangles    : triangles it makes at each level 0 .. MAX_SUBDIV_LEVEL
    """

    edge_length: float | None
    lower: np.ndarray
    upper: np.ndarray
    triangles: tuple[int, ...]


def read_cage(prim: Usd.Prim, time: Usd.TimeCode, file: str, *, measure_edges: bool = True) -> SubdivisionCage | None:
    """The cage of a UsdGeom.Mesh that subdivides (``subdivisionScheme`` other than none,
    catmullClark when unauthored); None for one that does not, has no faces, or has
    non-finite points (read_mesh notes those). Raises StageError as read_mesh does for the
    same attributes (types, topology, a mesh past the triangle budget on its own).
    measure_edges False leaves edge_length None: it takes a percentile over every edge, and
    only a level chosen by size on the image needs it."""
    arrays = _cage_arrays(prim, time, file)
    if arrays is None:
        return None
    scheme, points, counts, indices = arrays
    return SubdivisionCage(
        edge_length=subdivision.cage_edge_length(points, counts, indices) if measure_edges else None,
        lower=points.min(axis=0),
        upper=points.max(axis=0),
        triangles=tuple(subdivision.refined_triangle_count(counts, level, scheme)
                        for level in range(MAX_SUBDIV_LEVEL + 1)),
    )


def refined_control_points(prim: Usd.Prim, time: Usd.TimeCode, file: str, level: int) -> np.ndarray | None:
    """(v, 3) float64 control points, object space, of a subdividing mesh refined ``level``
    times without taking them to the limit: a subdivision surface lies inside the hull of
    every level's control points, so they bound it, closer at each level. None as read_cage;
    raises StageError as read_cage does, and ValueError where the refiner does."""
    arrays = _cage_arrays(prim, time, file)
    if arrays is None:
        return None
    scheme, points, counts, indices = arrays
    tags = subdivision_tags(UsdGeom.Mesh(prim), time, Diagnostics(), file, str(prim.GetPath()))
    return subdivision.refine(points, counts, indices, level, scheme=scheme, tags=tags, limit=False).points


def _cage_arrays(prim: Usd.Prim, time: Usd.TimeCode, file: str
                 ) -> tuple[str, np.ndarray, np.ndarray, np.ndarray] | None:
    """(scheme, points, face counts, face indices) of a mesh that subdivides, checked as
    read_mesh checks them; None for one that does not, has no faces or non-finite points."""
    mesh = UsdGeom.Mesh(prim)
    scheme = mesh.GetSubdivisionSchemeAttr().Get(time)
    if scheme == UsdGeom.Tokens.none:
        return None
    path = str(prim.GetPath())
    counts = integer_array(mesh.GetFaceVertexCountsAttr(), time, file)
    _check_budget(counts, SceneBudget(), file, path)
    indices = integer_array(mesh.GetFaceVertexIndicesAttr(), time, file)
    points = _mesh_points(mesh, time, None, file, path)
    _check_topology(points, counts, indices, file, path)
    if not len(indices) or not np.isfinite(points).all():
        return None
    return str(scheme), points, counts, indices


# Every attribute read_mesh reads (their metadata too: interpolation, elementSize), but the
# uv primvar and the material primvars and their indices, whose names mesh_opinions is given.
_SURFACE_ATTRIBUTES = (
    "points", "faceVertexCounts", "faceVertexIndices", "holeIndices", "orientation",
    "subdivisionScheme", "normals", "primvars:normals", "primvars:normals:indices",
    "interpolateBoundary", "faceVaryingLinearInterpolation", "triangleSubdivisionRule",
    "creaseIndices", "creaseLengths", "creaseSharpnesses", "cornerIndices", "cornerSharpnesses",
)


def mesh_opinions(
    prim: Usd.Prim, time: Usd.TimeCode, uv_primvar: str, primvars: tuple[str, ...] = ()
) -> tuple | None:
    """Where the values read_mesh reads come from: for each attribute, the (layer, spec path)
    of every opinion on it. Two meshes with equal keys read the same surface (prims that
    reference one asset, as the OpenChessSet's Black and White pieces do). None when a value
    might vary in time: the same specs then give different values under different layer
    offsets.

    primvars : the material primvars read_mesh is asked for; a constant one inherited from an
               ancestor counts with the ancestor's opinions (the same asset under two
               differently coloured parents does not share a surface)
    """
    attributes = [prim.GetAttribute(name) for name in (
        *_SURFACE_ATTRIBUTES, f"primvars:{uv_primvar}", f"primvars:{uv_primvar}:indices"
    )]
    for name in primvars:
        primvar = find_primvar(prim, name)
        attributes += [primvar.GetAttr(), primvar.GetIndicesAttr()] if primvar else [None, None]
    return _opinions(attributes, time)


def geometry_opinions(prim: Usd.Prim, time: Usd.TimeCode) -> tuple | None:
    """:func:`mesh_opinions` of the attributes that make the shape alone (no uv, no material
    primvars): meshes with equal keys have one cage, and share one subdivision level."""
    return _opinions([prim.GetAttribute(name) for name in _SURFACE_ATTRIBUTES], time)


def _opinions(attributes: list[Usd.Attribute | None], time: Usd.TimeCode) -> tuple | None:
    """For each attribute, the (layer, spec path) of every opinion on it (() for a missing
    one); None when a value might vary in time."""
    key = []
    for attribute in attributes:
        if not attribute:
            key.append(())
            continue
        if attribute.ValueMightBeTimeVarying():
            return None
        stack = attribute.GetPropertyStack(time)
        key.append(tuple((spec.layer.identifier, spec.path) for spec in stack))
    return tuple(key)


def find_primvar(prim: Usd.Prim, name: str) -> UsdGeom.Primvar | None:
    """The primvar ``name`` (without ``primvars:``) that applies to ``prim``: its own when it
    has a value, else a constant one of its nearest ancestor that has one (constant primvars
    inherit down namespace); None when neither."""
    primvar = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)
    return primvar if primvar and primvar.HasAuthoredValue() else None


def read_mesh(
    prim: Usd.Prim,
    time: Usd.TimeCode,
    uv_primvar: str,
    diagnostics: Diagnostics,
    file: str,
    *,
    subdiv_level: int,
    points: np.ndarray | None = None,
    primvars: tuple[str, ...] = (),
    budget: SceneBudget | None = None,
) -> LocalSurface | None:
    """Triangulate a UsdGeom.Mesh with its normals, the ``uv_primvar`` primvar and the
    ``primvars`` its materials read.

    subdiv_level : refinement level of a subdivision mesh (the reader's choice: see
                   reader.py); 0 (or ``subdivisionScheme = none``) fan-triangulates the
                   control mesh, shaded smooth if it is a subdivision mesh without authored
                   normals (at level 0 authored normals are kept, as Storm keeps them on an
                   unrefined mesh; refined, they are ignored with a warning)
    points       : (v, 3) object-space points (stage units) replacing the authored ones,
                   e.g. skinned (the authored normals, of the rest pose, are then replaced by
                   smooth normals of these points); None reads ``points`` at ``time``
    primvars     : names (without ``primvars:``) of primvars to read into
                   LocalSurface.primvars, of any interpolation, indexed or not, found with
                   inheritance (find_primvar); missing ones are left out, ones of another type
                   than 1–4 numbers or with too few values are left out with a note
    budget       : the read's budgets (budgets.py), for the triangles already in the scene;
                   None: this mesh alone

    Faces listed in ``holeIndices`` produce no triangles, nor do faces of fewer than 3
    vertices (noted, naming the first; Hydra leaves them out too).

    Raises StageError naming the attribute for points, faceVertexCounts, faceVertexIndices
    or holeIndices of another type than the schema's (values.py) and for inconsistent
    topology (a negative count, counts that do not add up to the indices, an index past the
    points), and for a mesh whose faces alone would take the scene past its triangle budget
    (budgets.MAX_SCENE_TRIANGLES: checked on faceVertexCounts, before the indices and the
    points are read). A mesh with NaN or infinite points (a simulation that blew up, a broken
    deformer) is computed data gone bad, not a mistake in the topology: it is skipped with a
    note naming it and how many points, and None returned, as the walk skips a prim with a
    non-finite transform.
    """
    mesh = UsdGeom.Mesh(prim)
    path = str(prim.GetPath())
    points_override = points
    counts = integer_array(mesh.GetFaceVertexCountsAttr(), time, file)
    _check_budget(counts, budget or SceneBudget(), file, path)
    indices = integer_array(mesh.GetFaceVertexIndicesAttr(), time, file)
    points = _mesh_points(mesh, time, points, file, path)
    _check_topology(points, counts, indices, file, path)
    non_finite = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
    if non_finite:
        diagnostics.note(
            "non-finite-points",
            "meshes with NaN or infinite points skipped: {prims}",
            f"{path} ({non_finite} of {len(points)} points{' as posed' if points_override is not None else ''})",
        )
        return None
    _note_short_faces(counts, diagnostics, path)

    scheme = mesh.GetSubdivisionSchemeAttr().Get(time)
    if scheme != UsdGeom.Tokens.none and subdiv_level > 0:
        # UsdGeom: normals are ignored on subdivision surfaces (a wrong type is still reported).
        if _authored_normals(mesh, time, diagnostics, path) is not None:
            diagnostics.note(
                "subdivision-normals",
                "authored normals are ignored on meshes that subdivide (the limit surface's normals "
                "shade them; subdivisionScheme is catmullClark unless authored): author "
                'subdivisionScheme = "none" on a polygon mesh to keep its normals: {prims}',
                path,
            )
        return _subdivision_surface(
            mesh, time, uv_primvar, primvars, diagnostics, file, path, points, counts, indices, scheme,
            subdiv_level,
        )

    face_count = len(counts)
    triangles_per_face = np.maximum(counts - 2, 0)
    holes = integer_array(mesh.GetHoleIndicesAttr(), time, file)
    holes = holes[(holes >= 0) & (holes < face_count)]
    triangles_per_face[holes] = 0

    # Fan triangulation in corner (face-vertex) indices: face f with corners o..o+n-1 gives
    # (o, o+k, o+k+1) for k = 1..n-2. Corner indices address faceVarying data directly.
    face_offsets = np.cumsum(counts) - counts
    triangle_face = np.repeat(np.arange(face_count, dtype=np.int64), triangles_per_face)
    first_triangle = np.cumsum(triangles_per_face) - triangles_per_face
    fan_step = np.arange(len(triangle_face), dtype=np.int64) - first_triangle[triangle_face] + 1
    base = face_offsets[triangle_face]
    corners = np.stack([base, base + fan_step, base + fan_step + 1], axis=1)
    if mesh.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded:
        # Reversing the corner order makes the left-hand-rule front face counter-clockwise.
        corners = corners[:, [0, 2, 1]]
    triangles = indices[corners]

    topology = _Topology(
        corners=corners,
        triangles=triangles,
        triangle_face=triangle_face,
        point_count=len(points),
        face_count=face_count,
        corner_count=len(indices),
    )
    normals = _read_normals(mesh, time, topology, diagnostics, path)
    posed = points_override is not None
    if posed:
        # Authored normals belong to the rest pose: the posed (skinned) surface is shaded by
        # smooth normals of its own points instead.
        normals = None
    smooth = normals is None and (posed or scheme != UsdGeom.Tokens.none)
    uvs = None
    primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar(uv_primvar)
    if primvar and primvar.HasAuthoredValue():
        uvs = _per_corner(primvar, time, 2, topology, diagnostics, path)
    return LocalSurface(
        points=points,
        triangles=triangles,
        normals=normals,
        smooth=smooth,
        uvs=uvs,
        triangle_face=triangle_face,
        face_count=face_count,
        primvars=_polygon_primvars(prim, time, primvars, topology, diagnostics, path),
    )


def _mesh_points(
    mesh: UsdGeom.Mesh, time: Usd.TimeCode, points: np.ndarray | None, file: str, path: str
) -> np.ndarray:
    """(v, 3) float64 object-space points: the given ones, else the authored ``points``."""
    if points is None:
        return real_array(mesh.GetPointsAttr(), time, 3, file, "point3f[]")
    given = np.asarray(points, dtype=np.float64)
    if given.ndim != 2 or given.shape[1] != 3:
        raise StageError(
            f"the points given for this mesh have shape {given.shape}, not (n, 3)",
            file=file,
            prim=path,
        )
    return given


def _check_budget(counts: np.ndarray, budget: SceneBudget, file: str, path: str) -> None:
    """StageError when the faces ``counts`` declares, as faces or fan-triangulated, would take
    the scene past its triangle budget (refinement adds triangles within the scene's
    subdivision budget: budgets.fit_subdivision_levels)."""
    budget.check_triangles(len(counts), f"faceVertexCounts declares {len(counts):,} faces", file=file, prim=path)
    triangles = int(np.maximum(counts - 2, 0).sum())
    budget.check_triangles(triangles, f"its {len(counts):,} faces make {triangles:,} triangles", file=file,
                           prim=path)


def _check_topology(
    points: np.ndarray, counts: np.ndarray, indices: np.ndarray, file: str, path: str
) -> None:
    """Raise StageError naming the first bad value of counts or indices."""
    negative = np.flatnonzero(counts < 0)
    if len(negative):
        first = int(negative[0])
        raise StageError(
            f"faceVertexCounts[{first}] is {int(counts[first])}: a face cannot have a "
            "negative number of vertices",
            file=file,
            prim=path,
        )
    if int(counts.sum()) != len(indices):
        raise StageError(
            f"faceVertexCounts sum to {int(counts.sum())} but there are {len(indices)} "
            "faceVertexIndices",
            file=file,
            prim=path,
        )
    outside = np.flatnonzero((indices < 0) | (indices >= len(points)))
    if len(outside):
        first = int(outside[0])
        raise StageError(
            f"faceVertexIndices[{first}] is {int(indices[first])} but there are "
            f"{len(points)} points",
            file=file,
            prim=path,
        )


def _note_short_faces(counts: np.ndarray, diagnostics: Diagnostics, path: str) -> None:
    """Note faces of 0, 1 or 2 vertices (they make no triangle, and are left out), naming the
    first one's index and count."""
    short = np.flatnonzero(counts < 3)
    if len(short):
        first = int(short[0])
        diagnostics.note(
            "short-faces",
            "faces of fewer than 3 vertices left out (they have no surface): {prims}",
            f"{path} ({len(short)} faces, the first faceVertexCounts[{first}] = {int(counts[first])})",
        )


def _vector_array(value, width: int) -> np.ndarray | None:
    """(n, width) float64 if ``value`` is an array of ``width``-vectors of reals, else None.

    A scalar, one vector, or a flat array (int[], double[]) is not reshaped into vectors: its
    numbers would be read as nonsense.
    """
    array = np.asarray(value)
    if array.ndim != 2 or array.shape[1] != width or array.dtype.kind != "f":
        return None
    return array.astype(np.float64)


def _expected_count(
    interpolation: str, point_count: int, face_count: int, corner_count: int
) -> int | None:
    """How many values a primvar of ``interpolation`` needs (None: unknown interpolation)."""
    return {
        UsdGeom.Tokens.constant: 1,
        UsdGeom.Tokens.uniform: face_count,
        UsdGeom.Tokens.vertex: point_count,
        UsdGeom.Tokens.varying: point_count,
        UsdGeom.Tokens.faceVarying: corner_count,
    }.get(interpolation)


def _note_too_few(
    diagnostics: Diagnostics, path: str, name: str, count: int, interpolation: str
) -> None:
    diagnostics.note(
        "primvar-size",
        "primvars with too few values for their interpolation were ignored on: {prims}",
        f"{path} ({name}: {count} values, {interpolation})",
    )


def _note_bad_type(diagnostics: Diagnostics, path: str, name: str, value) -> None:
    diagnostics.note(
        "primvar-type",
        "primvars of an unexpected type were ignored on: {prims}",
        f"{path}.{name} ({usd_type_name(value)})",
    )


@dataclass(frozen=True)
class _Topology:
    corners: np.ndarray  # (t, 3) indices into faceVertexIndices
    triangles: np.ndarray  # (t, 3) indices into points
    triangle_face: np.ndarray  # (t,)
    point_count: int
    face_count: int
    corner_count: int


def _authored_normals(
    mesh: UsdGeom.Mesh, time: Usd.TimeCode, diagnostics: Diagnostics, path: str
) -> tuple[np.ndarray, str] | None:
    """((n, 3) values, interpolation) of the authored normals, or None.

    ``primvars:normals`` wins over the ``normals`` attribute. Normals of another type than an
    array of 3-vectors (int, int[], double[] are seen in the wild) are ignored with a warning,
    and the caller computes normals instead.
    """
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    if primvar and primvar.HasAuthoredValue():
        values, interpolation = primvar.ComputeFlattened(time), primvar.GetInterpolation()
        name = primvar.GetName()
    else:
        attribute = mesh.GetNormalsAttr()
        if not attribute.HasAuthoredValue():
            return None
        values, interpolation = attribute.Get(time), mesh.GetNormalsInterpolation()
        name = "normals"
    if values is None:
        return None
    array = _vector_array(values, 3)
    if array is None:
        diagnostics.note(
            "normals-type",
            "normals that are not an array of 3-vectors were ignored (normals computed "
            "instead) on: {prims}",
            f"{path}.{name} ({usd_type_name(values)})",
        )
        return None
    return array, interpolation


def _read_normals(
    mesh: UsdGeom.Mesh,
    time: Usd.TimeCode,
    topology: _Topology,
    diagnostics: Diagnostics,
    path: str,
) -> np.ndarray | None:
    """Per-corner authored normals (see _authored_normals), or None.

    Authored normals are not negated for ``leftHanded`` meshes: they state the front side
    explicitly, and the triangle corners were reordered so the winding agrees with them.
    """
    authored = _authored_normals(mesh, time, diagnostics, path)
    if authored is None:
        return None
    values, interpolation = authored
    return _expand(values, interpolation, topology, diagnostics, path, "normals")


def _per_corner(
    primvar: UsdGeom.Primvar,
    time: Usd.TimeCode,
    width: int,
    topology: _Topology,
    diagnostics: Diagnostics,
    path: str,
) -> np.ndarray | None:
    values = primvar.ComputeFlattened(time)
    if values is None:
        return None
    array = _vector_array(values, width)
    if array is None:
        _note_bad_type(diagnostics, path, primvar.GetName(), values)
        return None
    return _expand(
        array, primvar.GetInterpolation(), topology, diagnostics, path, primvar.GetPrimvarName()
    )


def _expand(
    values: np.ndarray,
    interpolation: str,
    topology: _Topology,
    diagnostics: Diagnostics,
    path: str,
    name: str,
) -> np.ndarray | None:
    """Any primvar interpolation → (t, 3, k) writable values per triangle corner (None, noted,
    with too few values)."""
    if not _has_enough(values, interpolation, topology, diagnostics, path, name):
        return None
    corners = _corner_values(values, interpolation, topology.triangle_face, topology.corners, topology.triangles,
                             dtype=values.dtype)
    return corners if corners.flags.writeable else corners.copy()  # constant and uniform come as views


def _has_enough(values: np.ndarray, interpolation: str, topology: _Topology, diagnostics: Diagnostics, path: str,
                name: str) -> bool:
    """Whether a primvar has the values its interpolation needs on this mesh (noted if not)."""
    expected = _expected_count(
        interpolation, topology.point_count, topology.face_count, topology.corner_count
    )
    if expected is None or len(values) < expected:
        _note_too_few(diagnostics, path, name, len(values), interpolation)
        return False
    return True


# --- material primvars ------------------------------------------------------------------------

# Components of a material primvar by the scalar type of its value: bool and integer values
# are read as floats, quaternions, matrices, strings and the like are not read.
_PRIMVAR_WIDTHS = {
    **dict.fromkeys(("bool", "uchar", "int", "uint", "int64", "uint64", "half", "float", "double"), 1),
    **dict.fromkeys(("int2", "half2", "float2", "double2", "texCoord2h", "texCoord2f", "texCoord2d"), 2),
    **dict.fromkeys(
        ("int3", "half3", "float3", "double3")
        + tuple(f"{role}3{precision}" for role in ("color", "normal", "point", "vector", "texCoord")
                for precision in "hfd"),
        3,
    ),
    **dict.fromkeys(("int4", "half4", "float4", "double4", "color4h", "color4f", "color4d"), 4),
}
_MAX_PRIMVAR_WIDTH = 4


def constant_primvar(value, triangle_count: int, dtype=np.float32) -> np.ndarray:
    """(t, 3, w) float32 (or ``dtype``) read-only view of one w-component value at every corner.

    It costs w floats, not 3·t·w: ``np.broadcast_to`` gives strides (0, 0, 4). Slices stay
    such views; np.take and fancy indexing would write every corner out, which is why
    placement selects the rows of stride-0 arrays through their one row or value.
    """
    value = np.ascontiguousarray(value, dtype=dtype).reshape(-1)
    return np.broadcast_to(value, (triangle_count, 3, len(value)))


def _uniform_primvar(per_triangle: np.ndarray, dtype=np.float32) -> np.ndarray:
    """(t, 3, w) read-only view of (t, w) values, one per triangle (corner stride 0)."""
    per_triangle = np.ascontiguousarray(per_triangle, dtype=dtype)
    return np.broadcast_to(per_triangle[:, None, :], (len(per_triangle), 3, per_triangle.shape[1]))


def _primvar_array(
    value, primvar: UsdGeom.Primvar, diagnostics: Diagnostics, path: str
) -> np.ndarray | None:
    """(n, w) float64 elements of a material primvar's ``value`` (an array, or one element
    for a non-array primvar), w = 1–4 from its type and elementSize; None, noted, for
    other types."""
    type_name = primvar.GetTypeName()
    width = _PRIMVAR_WIDTHS.get(str(type_name.scalarType))
    element_size = primvar.GetElementSize()
    if width is not None and element_size > 1:
        # elementSize groups that many values per element: only scalars make vectors of it.
        width = width * element_size if width == 1 else None
    array = np.asarray(value)
    if (
        width is None
        or width > _MAX_PRIMVAR_WIDTH
        or array.dtype.kind not in "biuf"
        or array.size % width
        or (not type_name.isArray and array.size != width)
    ):
        _note_bad_type(diagnostics, path, primvar.GetName(), value)
        return None
    return array.astype(np.float64).reshape(-1, width)


def _corner_values(
    values: np.ndarray,
    interpolation: str,
    triangle_face: np.ndarray,
    corners: np.ndarray,
    triangles: np.ndarray,
    dtype=np.float32,
) -> np.ndarray:
    """(t, 3, w) float32 (or ``dtype``) values per triangle corner of a primvar with enough
    ``values``.

    values        : (n, w): one (constant), per face (uniform), per ``triangles`` index
                    (vertex, varying) or per ``corners`` index (faceVarying)
    triangle_face : (t,) face of each triangle, indexing uniform values
    corners       : (t, 3) indices of faceVarying values
    triangles     : (t, 3) indices of vertex and varying values
    Constant and uniform primvars come back as read-only views (constant_primvar).
    """
    if interpolation == UsdGeom.Tokens.constant:
        return constant_primvar(values[0], len(triangles), dtype)
    if interpolation == UsdGeom.Tokens.uniform:
        return _uniform_primvar(np.take(values, triangle_face, axis=0), dtype)
    index = corners if interpolation == UsdGeom.Tokens.faceVarying else triangles
    return np.take(values.astype(dtype, copy=False), index, axis=0)


def _read_only(primvars: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``primvars`` with every array made read-only (the views already are)."""
    for values in primvars.values():
        values.flags.writeable = False
    return primvars


def _polygon_primvars(
    prim: Usd.Prim,
    time: Usd.TimeCode,
    names: tuple[str, ...],
    topology: _Topology,
    diagnostics: Diagnostics,
    path: str,
) -> dict[str, np.ndarray]:
    """name → (t, 3, w) float32 per corner of a polygon mesh, for those of ``names`` it has
    (see read_mesh)."""
    result = {}
    for name in names:
        primvar = find_primvar(prim, name)
        if primvar is None:
            continue
        raw = primvar.ComputeFlattened(time)
        values = None if raw is None else _primvar_array(raw, primvar, diagnostics, path)
        if values is None:
            continue
        interpolation = primvar.GetInterpolation()
        if not _has_enough(values, interpolation, topology, diagnostics, path, name):
            continue
        result[name] = _corner_values(
            values, interpolation, topology.triangle_face, topology.corners, topology.triangles
        )
    return _read_only(result)


def with_constant_primvars(
    surface: LocalSurface,
    prim: Usd.Prim,
    time: Usd.TimeCode,
    names: tuple[str, ...],
    diagnostics: Diagnostics,
) -> LocalSurface:
    """``surface`` (an implicit gprim's tessellation) with those of the primvars ``names``
    that are constant on ``prim`` or inherited from its ancestors; other interpolations mean
    nothing on a shape with no authored faces or points, and are left out with a note."""
    path = str(prim.GetPath())
    primvars = {}
    for name in names:
        primvar = find_primvar(prim, name)
        if primvar is None:
            continue
        interpolation = primvar.GetInterpolation()
        if interpolation != UsdGeom.Tokens.constant:
            diagnostics.note(
                "implicit-primvar",
                "primvars that are not constant were ignored on implicit shapes (a cube, a "
                "sphere, ... has no authored faces or points to vary over): {prims}",
                f"{path} ({name}: {interpolation})",
            )
            continue
        raw = primvar.ComputeFlattened(time)
        values = None if raw is None else _primvar_array(raw, primvar, diagnostics, path)
        if values is None:
            continue
        if len(values) < 1:
            _note_too_few(diagnostics, path, name, 0, interpolation)
            continue
        primvars[name] = constant_primvar(values[0], len(surface.triangles))
    return replace(surface, primvars=primvars)


# --- subdivision surfaces ---------------------------------------------------------------------

# The two triangles of a refined quad, in its corners: the winding of the quad.
_QUAD_TRIANGLES = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
_TRIANGLE = np.array([[0, 1, 2]], dtype=np.int64)


@dataclass(frozen=True)
class _SubdivisionPrimvar:
    """A primvar of a subdivision mesh, ready for subdivision.refine."""

    interpolation: str
    values: np.ndarray  # (n, w) float64: per point, per face, per corner (or indexed), or one
    indices: np.ndarray | None  # (c,) faceVarying indices in refinement corner order


def _subdivision_surface(
    mesh: UsdGeom.Mesh,
    time: Usd.TimeCode,
    uv_primvar: str,
    primvar_names: tuple[str, ...],
    diagnostics: Diagnostics,
    file: str,
    path: str,
    points: np.ndarray,
    counts: np.ndarray,
    indices: np.ndarray,
    scheme: str,
    level: int,
) -> LocalSurface:
    """Refine a subdivision mesh ``level`` times to its limit surface and triangulate it.

    The uv primvar and the material primvars ``primvar_names`` go through the refinement
    together: vertex ones limited like the points, varying ones linearly, faceVarying ones
    as channels of their own (seams where their indices differ); uniform ones follow each
    refined triangle's authored face, constant ones are broadcast.
    """
    if scheme not in subdivision.SCHEMES:
        diagnostics.note(
            "subdivision-scheme",
            "unknown subdivisionScheme values were read as catmullClark on: {prims}",
            f"{path} ({scheme})",
        )
        scheme = "catmullClark"
    corner_order = None
    if mesh.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded:
        # Reversed faces are right-handed: the refinement and its normals see the front.
        corner_order = _reversed_face_corners(counts)
        indices = indices[corner_order]

    def prepared(primvar: UsdGeom.Primvar | None, width: int | None) -> _SubdivisionPrimvar | None:
        if primvar is None:
            return None
        return _subdivision_primvar(primvar, time, width, counts, corner_order, len(points),
                                    diagnostics, path)

    # The uv primvar under the key None, then the material primvars by name.
    uv = UsdGeom.PrimvarsAPI(mesh).GetPrimvar(uv_primvar)
    channels: dict[str | None, _SubdivisionPrimvar] = {}
    for key, primvar, width in [
        (None, uv if uv and uv.HasAuthoredValue() else None, 2),
        *((name, find_primvar(mesh.GetPrim(), name), None) for name in primvar_names),
    ]:
        channel = prepared(primvar, width)
        if channel is not None:
            channels[key] = channel

    # Vertex and varying channels side by side as columns; each faceVarying one on its own.
    column_start: dict[str | None, int] = {}
    vertex_columns: list[np.ndarray] = []
    varying_columns: list[np.ndarray] = []
    face_varying: list[subdivision.FaceVaryingPrimvar] = []
    for key, channel in channels.items():
        if channel.interpolation == UsdGeom.Tokens.faceVarying:
            column_start[key] = len(face_varying)
            face_varying.append(subdivision.FaceVaryingPrimvar(channel.values, channel.indices))
        elif channel.interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            columns = vertex_columns if channel.interpolation == UsdGeom.Tokens.vertex else varying_columns
            column_start[key] = sum(block.shape[1] for block in columns)
            columns.append(channel.values)
    refined = subdivision.refine(
        points,
        counts,
        indices,
        level,
        scheme=scheme,
        tags=subdivision_tags(mesh, time, diagnostics, file, path),
        vertex_data=np.hstack(vertex_columns) if vertex_columns else None,
        varying_data=np.hstack(varying_columns) if varying_columns else None,
        face_varying=face_varying,
    )
    for warning in refined.warnings:
        diagnostics.note(
            "subdivision",
            "subdivision meshes read with adjustments: {prims}",
            f"{path} ({warning})",
        )

    corners_per_face = refined.faces.shape[1]
    split = _QUAD_TRIANGLES if corners_per_face == 4 else _TRIANGLE
    face_corner = np.arange(len(refined.faces), dtype=np.int64) * corners_per_face
    triangle_corners = (face_corner[:, None, None] + split[None]).reshape(-1, 3)
    triangles = refined.faces.reshape(-1)[triangle_corners]
    triangle_face = np.repeat(refined.face_origin, len(split))

    per_corner: dict[str | None, np.ndarray] = {}  # float32, but the uvs' float64
    for key, channel in channels.items():
        interpolation, values = channel.interpolation, channel.values
        width = values.shape[1]
        value_corners = triangle_corners
        if interpolation == UsdGeom.Tokens.faceVarying:
            values = refined.face_varying_values[column_start[key]]
            value_corners = refined.face_varying_corners[column_start[key]].reshape(-1)[triangle_corners]
        elif interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            data = refined.vertex_data if interpolation == UsdGeom.Tokens.vertex else refined.varying_data
            start = column_start[key]
            values = data[:, start:start + width]
        per_corner[key] = _corner_values(values, interpolation, triangle_face, value_corners,
                                         triangles, np.float32 if key is not None else np.float64)
    uvs = per_corner.pop(None, None)
    return LocalSurface(
        points=refined.points,
        triangles=triangles,
        normals=np.take(refined.normal_values, refined.corner_normals.reshape(-1)[triangle_corners], axis=0),
        smooth=True,
        # (t, 3, 2) of its own, as ever: constant and uniform uvs written out
        uvs=uvs if uvs is None or uvs.flags.writeable else np.array(uvs),
        triangle_face=triangle_face,
        face_count=len(counts),
        primvars=_read_only(per_corner),
    )


def _reversed_face_corners(counts: np.ndarray) -> np.ndarray:
    """(c,) corner order that reverses each face's winding, keeping its first corner."""
    offsets = np.cumsum(counts) - counts
    corner_face = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    local = np.arange(int(counts.sum()), dtype=np.int64) - offsets[corner_face]
    size = counts[corner_face]
    return offsets[corner_face] + (size - local) % size


def subdivision_tags(
    mesh: UsdGeom.Mesh, time: Usd.TimeCode, diagnostics: Diagnostics, file: str, path: str
) -> subdivision.SubdivisionTags:
    """The mesh's subdivision attributes; unknown tokens fall back to the schema's default;
    StageError for arrays of another type than the schema's."""
    defaults = subdivision.SubdivisionTags()

    def token(attribute: Usd.Attribute, allowed: tuple[str, ...], fallback: str) -> str:
        value = attribute.Get(time)
        if value is None:
            return fallback
        if value not in allowed:
            diagnostics.note(
                "subdivision-token",
                "unknown subdivision tokens were replaced by the default on: {prims}",
                f"{path}.{attribute.GetName()} ({value})",
            )
            return fallback
        return str(value)

    def array(attribute: Usd.Attribute, dtype) -> np.ndarray:
        if dtype == np.int64:
            return integer_array(attribute, time, file)
        return real_array(attribute, time, 1, file, "float[]").reshape(-1)

    return subdivision.SubdivisionTags(
        interpolate_boundary=token(
            mesh.GetInterpolateBoundaryAttr(),
            subdivision.BOUNDARY_INTERPOLATIONS,
            defaults.interpolate_boundary,
        ),
        face_varying_linear_interpolation=token(
            mesh.GetFaceVaryingLinearInterpolationAttr(),
            subdivision.FACE_VARYING_INTERPOLATIONS,
            defaults.face_varying_linear_interpolation,
        ),
        triangle_subdivision_rule=token(
            mesh.GetTriangleSubdivisionRuleAttr(),
            subdivision.TRIANGLE_SUBDIVISION_RULES,
            defaults.triangle_subdivision_rule,
        ),
        crease_indices=array(mesh.GetCreaseIndicesAttr(), np.int64),
        crease_lengths=array(mesh.GetCreaseLengthsAttr(), np.int64),
        crease_sharpnesses=array(mesh.GetCreaseSharpnessesAttr(), np.float64),
        corner_indices=array(mesh.GetCornerIndicesAttr(), np.int64),
        corner_sharpnesses=array(mesh.GetCornerSharpnessesAttr(), np.float64),
        hole_indices=array(mesh.GetHoleIndicesAttr(), np.int64),
    )


def _subdivision_primvar(
    primvar: UsdGeom.Primvar,
    time: Usd.TimeCode,
    width: int | None,
    counts: np.ndarray,
    corner_order: np.ndarray | None,
    point_count: int,
    diagnostics: Diagnostics,
    path: str,
) -> _SubdivisionPrimvar | None:
    """A primvar for refinement: faceVarying keeps its indices (seams are where they differ),
    per corner values follow ``corner_order`` (left-handed faces reversed). None, noted, when
    its values do not fit.

    width : 2 for the uv primvar (an array of 2-vectors of reals, nothing else); None for a
            material primvar, whose type gives its 1–4 components
    """
    interpolation = primvar.GetInterpolation()
    corner_count = int(counts.sum())
    indexed = interpolation == UsdGeom.Tokens.faceVarying and primvar.IsIndexed()
    raw = primvar.Get(time) if indexed else primvar.ComputeFlattened(time)
    if raw is None:
        return None
    if width is None:
        values = _primvar_array(raw, primvar, diagnostics, path)
    else:
        values = _vector_array(raw, width)
        if values is None:
            _note_bad_type(diagnostics, path, primvar.GetName(), raw)
    if values is None:
        return None
    name = primvar.GetPrimvarName()
    if indexed:
        indices = np.asarray(primvar.GetIndices(time), dtype=np.int64)
        if len(indices) < corner_count or (
            corner_count and (indices[:corner_count].min() < 0
                              or indices[:corner_count].max() >= len(values))
        ):
            _note_too_few(diagnostics, path, name, len(indices), interpolation)
            return None
        indices = indices[:corner_count]
        if corner_order is not None:
            indices = indices[corner_order]
        return _SubdivisionPrimvar(interpolation, values, indices)
    expected = _expected_count(interpolation, point_count, len(counts), corner_count)
    if expected is None or len(values) < expected:
        _note_too_few(diagnostics, path, name, len(values), interpolation)
        return None
    values = values[:expected]
    if interpolation == UsdGeom.Tokens.faceVarying and corner_order is not None:
        values = values[corner_order]
    return _SubdivisionPrimvar(interpolation, values, None)
