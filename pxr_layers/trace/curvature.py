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
"""

from __future__ import annotations

import numpy as np

from ..scene import FLOAT


def triangle_curvatures(
    corner_positions: np.ndarray, corner_normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal curvatures of every triangle.

    corner_positions, corner_normals : (3 corners, 3, t) float32 (World layout), metres
    Returns k1 (t,), k2 (t,) float32 in 1/m with k1 ≥ k2, and the unit direction of k1
    (3, t) float32 in world space.
    """
    p = corner_positions.astype(np.float64)
    n = corner_normals.astype(np.float64)
    edge_01 = p[1] - p[0]
    normal = np.cross(edge_01, p[2] - p[0], axis=0)
    normal /= np.maximum(np.linalg.norm(normal, axis=0), 1e-300)
    axis_u = edge_01 / np.maximum(np.linalg.norm(edge_01, axis=0), 1e-300)
    axis_v = np.cross(normal, axis_u, axis=0)

    # Normal equations of  [eu ev 0; 0 eu ev] · (a, b, c) = (Δn·u, Δn·v)  over the 3 edges.
    normal_matrix = np.zeros((p.shape[2], 3, 3))
    right_side = np.zeros((p.shape[2], 3))
    for start, end in ((0, 1), (1, 2), (2, 0)):
        edge = p[end] - p[start]
        change = n[end] - n[start]
        eu, ev = np.sum(edge * axis_u, axis=0), np.sum(edge * axis_v, axis=0)
        du, dv = np.sum(change * axis_u, axis=0), np.sum(change * axis_v, axis=0)
        rows = (np.stack([eu, ev, np.zeros_like(eu)], axis=1), np.stack([np.zeros_like(eu), eu, ev], axis=1))
        for row, target in zip(rows, (du, dv)):
            normal_matrix += row[:, :, None] * row[:, None, :]
            right_side += row * target[:, None]
    # Degenerate triangles (no area) would make the system singular: they get zero curvature.
    regular = np.abs(np.linalg.det(normal_matrix)) > 1e-30 * np.maximum(np.abs(normal_matrix).max(axis=(1, 2)), 1e-300) ** 3
    a = np.zeros(p.shape[2])
    b = np.zeros(p.shape[2])
    c = np.zeros(p.shape[2])
    if regular.any():
        solution = np.linalg.solve(normal_matrix[regular], right_side[regular][:, :, None])[:, :, 0]
        a[regular], b[regular], c[regular] = solution.T

    mean = (a + c) / 2
    spread = np.sqrt(((a - c) / 2) ** 2 + b**2)
    angle = 0.5 * np.arctan2(2 * b, a - c)  # direction of k1 in (axis_u, axis_v)
    direction = axis_u * np.cos(angle) + axis_v * np.sin(angle)
    return (mean + spread).astype(FLOAT), (mean - spread).astype(FLOAT), direction.astype(FLOAT)
