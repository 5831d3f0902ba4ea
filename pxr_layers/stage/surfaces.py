"""Triangulate UsdGeom.Mesh prims into object-space surfaces.

The result, :class:`LocalSurface`, is still in the gprim's own space and stage units; it is
computed once per prototype and placed in the world (possibly many times, for instances)
by :mod:`.placement`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom

from pxr_layers.errors import StageError

from .diagnostics import Diagnostics


@dataclass(frozen=True)
class LocalSurface:
    """A gprim triangulated in its object space (stage units).

    points        : (v, 3) float64, object space
    triangles     : (t, 3) int64 indices into points, counter-clockwise seen from the front
                    (``orientation = leftHanded`` already flipped)
    normals       : (t, 3, 3) float64 object-space shading normal per corner (not
                    necessarily unit length), or None
    smooth        : when ``normals`` is None, True asks for area-weighted vertex normals
                    computed in world space (a subdivision surface looks smooth in any
                    renderer); False means flat shading
    uvs           : (t, 3, 2) float64 st per corner, or None
    triangle_face : (t,) int64 index of the authored face each triangle comes from
                    (GeomSubsets select faces)
    face_count    : number of authored faces
    """

    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    smooth: bool
    uvs: np.ndarray | None
    triangle_face: np.ndarray
    face_count: int


def _as_array(value, width: int, dtype=np.float64) -> np.ndarray:
    if value is None:
        return np.zeros((0, width), dtype=dtype)
    return np.asarray(value, dtype=dtype).reshape(-1, width)


def read_mesh(
    prim: Usd.Prim,
    time: Usd.TimeCode,
    uv_primvar: str,
    diagnostics: Diagnostics,
    file: str,
) -> LocalSurface:
    """Fan-triangulate a UsdGeom.Mesh with its normals and the ``uv_primvar`` primvar.

    Faces with fewer than 3 vertices and faces listed in ``holeIndices`` produce no
    triangles. Raises StageError on NaN/infinite points or inconsistent topology.
    """
    mesh = UsdGeom.Mesh(prim)
    path = str(prim.GetPath())
    points = _as_array(mesh.GetPointsAttr().Get(time), 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int64)

    if not np.isfinite(points).all():
        bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
        raise StageError(f"{bad} points are NaN or infinite", file=file, prim=path)
    if (counts < 0).any() or int(counts.sum()) != len(indices):
        raise StageError(
            f"faceVertexCounts sum to {int(counts.sum())} but there are {len(indices)} "
            "faceVertexIndices",
            file=file,
            prim=path,
        )
    if len(indices) and (indices.min() < 0 or indices.max() >= len(points)):
        raise StageError(
            f"faceVertexIndices reach point {int(indices.max())} but there are "
            f"{len(points)} points",
            file=file,
            prim=path,
        )

    face_count = len(counts)
    triangles_per_face = np.maximum(counts - 2, 0)
    holes = np.asarray(mesh.GetHoleIndicesAttr().Get(time) or [], dtype=np.int64)
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
    smooth = normals is None and mesh.GetSubdivisionSchemeAttr().Get(time) != UsdGeom.Tokens.none
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
    )


@dataclass(frozen=True)
class _Topology:
    corners: np.ndarray  # (t, 3) indices into faceVertexIndices
    triangles: np.ndarray  # (t, 3) indices into points
    triangle_face: np.ndarray  # (t,)
    point_count: int
    face_count: int
    corner_count: int


def _read_normals(
    mesh: UsdGeom.Mesh,
    time: Usd.TimeCode,
    topology: _Topology,
    diagnostics: Diagnostics,
    path: str,
) -> np.ndarray | None:
    """Per-corner authored normals: ``primvars:normals`` wins over the ``normals`` attribute.

    Authored normals are not negated for ``leftHanded`` meshes: they state the front side
    explicitly, and the triangle corners were reordered so the winding agrees with them.
    """
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    if primvar and primvar.HasAuthoredValue():
        return _per_corner(primvar, time, 3, topology, diagnostics, path)
    attribute = mesh.GetNormalsAttr()
    if attribute.HasAuthoredValue():
        values = attribute.Get(time)
        if values is None:
            return None
        interpolation = mesh.GetNormalsInterpolation()
        return _expand(_as_array(values, 3), interpolation, topology, diagnostics, path, "normals")
    return None


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
    try:
        array = _as_array(values, width)
    except (ValueError, TypeError):
        diagnostics.note(
            "primvar-type",
            "primvars of an unexpected type were ignored on: {prims}",
            f"{path}.{primvar.GetName()}",
        )
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
    """Any primvar interpolation → (t, 3, k) values per triangle corner."""
    expected = {
        UsdGeom.Tokens.constant: 1,
        UsdGeom.Tokens.uniform: topology.face_count,
        UsdGeom.Tokens.vertex: topology.point_count,
        UsdGeom.Tokens.varying: topology.point_count,
        UsdGeom.Tokens.faceVarying: topology.corner_count,
    }.get(interpolation)
    if expected is None or len(values) < expected:
        diagnostics.note(
            "primvar-size",
            "primvars with too few values for their interpolation were ignored on: {prims}",
            f"{path} ({name}: {len(values)} values, {interpolation})",
        )
        return None
    triangle_count = len(topology.triangles)
    if interpolation == UsdGeom.Tokens.constant:
        return np.broadcast_to(values[0], (triangle_count, 3, values.shape[1])).copy()
    if interpolation == UsdGeom.Tokens.uniform:
        per_face = values[topology.triangle_face]
        return np.repeat(per_face[:, None, :], 3, axis=1)
    if interpolation == UsdGeom.Tokens.faceVarying:
        return values[topology.corners]
    return values[topology.triangles]
