"""Principal curvatures per triangle, from the change of the shading normal across it.

Over a triangle the shading normal is interpolated linearly, so its derivative along the
surface is one constant 2×2 shape operator S: for each edge e (tangent components) the
normals at its ends differ by Δn = S·e (Rusinkiewicz 2004, "Estimating curvatures and
their derivatives on triangle meshes", per-face step). Three edges give six equations for
the three unknowns of the symmetric S, solved in the least-squares sense.

Consequences the covariance queries rely on:

* flat-shaded or planar geometry (equal corner normals) has curvature exactly 0;
* tessellated analytic gprims carry analytic normals, so a sphere of radius r gives
  k1 = k2 = 1/r to float precision whatever the tessellation;
* meshes with authored or computed smooth normals get the curvature those normals imply.

Sign: k > 0 where the surface bends away from its normal (convex: a sphere with outward
normals), k < 0 where it bends toward it. Units: 1/m (world space is in metres).

The normal equations of every triangle have the same shape, so they are solved in closed
form (:func:`_solve_normal_equations`) rather than by a batched LU, over chunks of triangles
small enough that their float64 temporaries stay in cache and are reused by the allocator
(fresh pages for millions of triangles cost more in the kernel than the arithmetic).
:func:`reference_triangle_curvatures` keeps the direct solve as the reference.
"""

from __future__ import annotations

import numpy as np

from ..scene import FLOAT

CHUNK_TRIANGLES = 1 << 14  # float64 temporaries of 128 kB-1.2 MB per chunk

# The three edges of a triangle, (start corner, end corner).
_EDGES = ((0, 1), (1, 2), (2, 0))


def triangle_curvatures(
    corner_positions: np.ndarray, corner_normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal curvatures of every triangle.

    corner_positions, corner_normals : (3 corners, 3, t) float32 (World layout), metres
    Returns k1 (t,), k2 (t,) float32 in 1/m with k1 ≥ k2, and the unit direction of k1
    (3, t) float32 in world space.
    """
    count = corner_positions.shape[2]
    k1, k2 = np.empty(count, FLOAT), np.empty(count, FLOAT)
    direction = np.empty((3, count), FLOAT)
    for start in range(0, count, CHUNK_TRIANGLES):
        rows = slice(start, min(start + CHUNK_TRIANGLES, count))
        k1[rows], k2[rows], direction[:, rows] = _chunk_curvatures(
            corner_positions[:, :, rows], corner_normals[:, :, rows]
        )
    return k1, k2, direction


def _chunk_curvatures(
    corner_positions: np.ndarray, corner_normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """triangle_curvatures of (3, 3, n) corners, in float64: (k1, k2, direction) float64."""
    p = corner_positions.astype(np.float64)
    n = corner_normals.astype(np.float64)
    axis_u, axis_v = _tangent_axes(p)

    # Normal equations of  [eu ev 0; 0 eu ev] · (a, b, c) = (Δn·u, Δn·v)  over the 3 edges:
    # M = [[A, B, 0], [B, A + C, B], [0, B, C]] with A = Σeu², B = Σeu·ev, C = Σev², and the
    # right side (Σeu·du, Σ(ev·du + eu·dv), Σev·dv).
    sum_uu = sum_uv = sum_vv = right_a = right_b = right_c = 0.0
    for start, end in _EDGES:
        edge = p[end] - p[start]
        change = n[end] - n[start]
        eu, ev = _dot(edge, axis_u), _dot(edge, axis_v)
        du, dv = _dot(change, axis_u), _dot(change, axis_v)
        sum_uu = sum_uu + eu * eu
        sum_uv = sum_uv + eu * ev
        sum_vv = sum_vv + ev * ev
        right_a = right_a + eu * du
        right_b = right_b + ev * du + eu * dv
        right_c = right_c + ev * dv
    a, b, c = _solve_normal_equations(sum_uu, sum_uv, sum_vv, right_a, right_b, right_c)

    mean = (a + c) / 2
    spread = np.sqrt(((a - c) / 2) ** 2 + b**2)
    angle = 0.5 * np.arctan2(2 * b, a - c)  # direction of k1 in (axis_u, axis_v)
    direction = axis_u * np.cos(angle) + axis_v * np.sin(angle)
    return mean + spread, mean - spread, direction


def _tangent_axes(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, n) float64 unit axis_u along edge 0→1 and axis_v = normal × axis_u, of the
    (3 corners, 3, n) float64 corners (zero vectors on degenerate triangles)."""
    edge_01 = p[1] - p[0]
    normal = _cross(edge_01, p[2] - p[0])
    normal /= np.maximum(np.sqrt(_dot(normal, normal)), 1e-300)
    axis_u = edge_01 / np.maximum(np.sqrt(_dot(edge_01, edge_01)), 1e-300)
    return axis_u, _cross(normal, axis_u)


def _solve_normal_equations(
    sum_uu: np.ndarray,
    sum_uv: np.ndarray,
    sum_vv: np.ndarray,
    right_a: np.ndarray,
    right_b: np.ndarray,
    right_c: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, c) solving M·x = right for M = [[A, B, 0], [B, A + C, B], [0, B, C]] by its
    adjugate: det M = (A + C)(AC − B²). A system as singular as a degenerate triangle's
    (|det M| <= 1e-30 · max|M|³, max|M| = A + C) gets x = 0."""
    A, B, C = sum_uu, sum_uv, sum_vv
    trace = A + C
    determinant = trace * (A * C - B * B)
    regular = np.abs(determinant) > 1e-30 * np.maximum(trace, 1e-300) ** 3
    inverse = np.where(regular, 1.0 / np.where(regular, determinant, 1.0), 0.0)
    bb = B * B
    a = ((trace * C - bb) * right_a - B * C * right_b + bb * right_c) * inverse
    b = (-B * C * right_a + A * C * right_b - A * B * right_c) * inverse
    c = (bb * right_a - A * B * right_b + (A * trace - bb) * right_c) * inverse
    return a, b, c


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Component-wise dot product of (3, n) arrays: (n,)."""
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


def _cross(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Cross product of (3, n) arrays (np.cross on axis 0 transposes them first)."""
    return np.stack([x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]])


def reference_triangle_curvatures(
    corner_positions: np.ndarray, corner_normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """triangle_curvatures by building each 3×3 normal matrix and np.linalg.solve: slow, the
    reference for the closed form."""
    p = corner_positions.astype(np.float64)
    n = corner_normals.astype(np.float64)
    axis_u, axis_v = _tangent_axes(p)
    normal_matrix = np.zeros((p.shape[2], 3, 3))
    right_side = np.zeros((p.shape[2], 3))
    for start, end in _EDGES:
        edge = p[end] - p[start]
        change = n[end] - n[start]
        eu, ev = _dot(edge, axis_u), _dot(edge, axis_v)
        du, dv = _dot(change, axis_u), _dot(change, axis_v)
        rows = (np.stack([eu, ev, np.zeros_like(eu)], axis=1), np.stack([np.zeros_like(eu), eu, ev], axis=1))
        for row, target in zip(rows, (du, dv)):
            normal_matrix += row[:, :, None] * row[:, None, :]
            right_side += row * target[:, None]
    regular = np.abs(np.linalg.det(normal_matrix)) > 1e-30 * np.maximum(np.abs(normal_matrix).max(axis=(1, 2)), 1e-300) ** 3
    solution = np.zeros((p.shape[2], 3))
    if regular.any():
        solution[regular] = np.linalg.solve(normal_matrix[regular], right_side[regular][:, :, None])[:, :, 0]
    a, b, c = solution.T
    mean = (a + c) / 2
    spread = np.sqrt(((a - c) / 2) ** 2 + b**2)
    angle = 0.5 * np.arctan2(2 * b, a - c)
    direction = axis_u * np.cos(angle) + axis_v * np.sin(angle)
    return (mean + spread).astype(FLOAT), (mean - spread).astype(FLOAT), direction.astype(FLOAT)
