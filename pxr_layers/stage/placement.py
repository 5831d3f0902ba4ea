"""Place an object-space LocalSurface in the world: scene.Mesh in metres.

Handles what depends on the transform: the stage-units → metres scale, mirroring
transforms (a negative determinant reverses the winding, UsdGeom_WindingOrder), normals
through the inverse transpose, smooth normals measured in world space, and degenerate
triangles (zero area once placed).
"""

from __future__ import annotations

import logging

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


def place_surface(
    surface: LocalSurface,
    world_from_local: np.ndarray,
    meters_per_unit: float,
    triangle_material: np.ndarray,
    name: str,
    path: str,
    diagnostics: Diagnostics,
    instance: int = -1,
) -> Mesh | None:
    """Transform ``surface`` to world metres; None when no triangle survives.

    world_from_local  : (4, 4) float64, column convention, stage units
    triangle_material : (t,) integer material index per triangle of ``surface``
    instance          : Mesh.instance (GprimPlacement.instance), -1 if not point-instanced
    """
    linear = world_from_local[:3, :3]
    points = (surface.points @ linear.T + world_from_local[:3, 3]) * meters_per_unit
    triangles = surface.triangles
    normals = surface.normals
    uvs = surface.uvs
    if np.linalg.det(linear) < 0.0:
        # A mirror turns counter-clockwise into clockwise: swap two corners back.
        order = [0, 2, 1]
        triangles = triangles[:, order]
        normals = None if normals is None else normals[:, order]
        uvs = None if uvs is None else uvs[:, order]

    corners = points[triangles]  # (t, 3, 3)
    edge_a = corners[:, 1] - corners[:, 0]
    edge_b = corners[:, 2] - corners[:, 0]
    geometric = np.cross(edge_a, edge_b)  # length = twice the area
    doubled_area = np.linalg.norm(geometric, axis=1)
    edge_c = corners[:, 2] - corners[:, 1]
    squared_lengths = [np.einsum("ij,ij->i", edge, edge) for edge in (edge_a, edge_b, edge_c)]
    longest_squared = np.max(squared_lengths, axis=0)
    degenerate = doubled_area <= _DEGENERATE_HEIGHT_RATIO * longest_squared
    unit_geometric = geometric / np.where(degenerate, 1.0, doubled_area)[:, None]

    if normals is not None:
        normals = normals @ normal_matrix(linear).T
    elif surface.smooth:
        vertex_normals = _area_weighted_vertex_normals(
            len(points), triangles, surface.triangle_face, geometric
        )
        normals = vertex_normals[triangles]
    if normals is not None:
        normals = _normalise_or(normals, unit_geometric)

    if degenerate.any():
        diagnostics.note(
            "degenerate-triangles",
            "dropped {count} degenerate (zero-area) triangles on: {prims}",
            path,
            int(degenerate.sum()),
        )
        keep = ~degenerate
        triangles, triangle_material = triangles[keep], triangle_material[keep]
        normals = None if normals is None else normals[keep]
        uvs = None if uvs is None else uvs[keep]
    if len(triangles) == 0:
        logger.debug("%s has no triangles; skipped", path)
        return None
    return Mesh(
        name=name,
        path=path,
        points=np.ascontiguousarray(points, dtype=FLOAT),
        triangles=np.ascontiguousarray(triangles, dtype=INDEX),
        normals=None if normals is None else np.ascontiguousarray(normals, dtype=FLOAT),
        uvs=None if uvs is None else np.ascontiguousarray(uvs, dtype=FLOAT),
        triangle_material=np.ascontiguousarray(triangle_material, dtype=INDEX),
        instance=int(instance),
    )


def _area_weighted_vertex_normals(
    point_count: int, triangles: np.ndarray, triangle_face: np.ndarray, geometric: np.ndarray
) -> np.ndarray:
    """(v, 3) vertex normals: the sum of the adjacent *faces'* area vectors.

    Summing per face, not per triangle, keeps the fan triangulation out of the result: in
    a fanned quad, vertices 0 and 2 touch both triangles but 1 and 3 only one. The
    cross products in ``geometric`` have length twice the triangle area, so a face's sum is
    its area-weighted normal.
    """
    face_vectors = np.zeros((int(triangle_face.max(initial=-1)) + 1, 3))
    np.add.at(face_vectors, triangle_face, geometric)
    # Each (face, vertex) pair once, however many of the face's triangles share the vertex;
    # one int64 key per pair keeps np.unique one-dimensional (fast on large meshes).
    keys = np.unique(np.repeat(triangle_face, 3) * point_count + triangles.ravel())
    faces, vertices = np.divmod(keys, point_count)
    vertex_normals = np.zeros((point_count, 3))
    np.add.at(vertex_normals, vertices, face_vectors[faces])
    return vertex_normals


def _normalise_or(vectors: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Normalise (t, 3, 3) corner vectors; zero-length ones take the triangle's (t, 3) fallback."""
    lengths = np.linalg.norm(vectors, axis=2, keepdims=True)
    usable = lengths > 0.0
    unit = vectors / np.where(usable, lengths, 1.0)
    return np.where(usable, unit, fallback[:, None, :])
