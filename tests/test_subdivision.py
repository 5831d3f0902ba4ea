"""stage/subdivision.py and subdivision meshes through read_mesh.

The expected values are analytic (closed-form limit stencils worked by hand, the uniform
bicubic B-spline, linear precision, OpenSubdiv's documented rules), not earlier output.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

from pxr_layers.errors import StageError
from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.subdivision import FaceVaryingPrimvar, SubdivisionTags, refine
from pxr_layers.stage.surfaces import read_mesh

NORMALS_TYPES = "usd-wg/test_assets/schemaTests/usdGeom/meshes/normals_types/normalsTypes.usda"  # in ../shared/scenes

# The cube [-1/2, 1/2]^3, faces wound counter-clockwise seen from outside.
CUBE_POINTS = np.array(
    [(-0.5, -0.5, 0.5), (0.5, -0.5, 0.5), (-0.5, 0.5, 0.5), (0.5, 0.5, 0.5),
     (-0.5, 0.5, -0.5), (0.5, 0.5, -0.5), (-0.5, -0.5, -0.5), (0.5, -0.5, -0.5)]
)
CUBE_INDICES = np.array(
    [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]
)
CUBE_COUNTS = np.full(6, 4)


def grid(columns: int, rows: int, heights=None):
    """A grid of quads with vertex (i, j) at x = i, y = j: (points, counts, indices).

    Vertex (i, j) is index i * (rows + 1) + j; face (i, j) (i-major) is wound
    counter-clockwise seen from +z.
    """
    i, j = np.meshgrid(np.arange(columns + 1.0), np.arange(rows + 1.0), indexing="ij")
    z = np.zeros(i.size) if heights is None else np.asarray(heights, dtype=float).ravel()
    points = np.stack([i.ravel(), j.ravel(), z], axis=1)
    fi, fj = (a.ravel() for a in np.meshgrid(np.arange(columns), np.arange(rows), indexing="ij"))

    def vertex(a, b):
        return a * (rows + 1) + b

    faces = np.stack(
        [vertex(fi, fj), vertex(fi + 1, fj), vertex(fi + 1, fj + 1), vertex(fi, fj + 1)], axis=1
    )
    return points, np.full(len(faces), 4), faces.ravel()


def triangle_grid(columns: int, rows: int):
    """The grid's quads split along one diagonal: a regular (valence 6) triangle mesh."""
    points, _, quads = grid(columns, rows)
    quads = quads.reshape(-1, 4)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return points, np.full(len(triangles), 3), triangles.ravel()


def bspline_basis(t: np.ndarray, derivative: bool = False) -> np.ndarray:
    """(n, 4) uniform cubic B-spline basis (or its derivative) on one span, t in [0, 1]."""
    t = np.asarray(t, dtype=float)[:, None]
    if derivative:
        return np.hstack([-(1 - t) ** 2 / 2, (3 * t**2 - 4 * t) / 2,
                          (-3 * t**2 + 2 * t + 1) / 2, t**2 / 2])
    return np.hstack([(1 - t) ** 3 / 6, (3 * t**3 - 6 * t**2 + 4) / 6,
                      (-3 * t**3 + 3 * t**2 + 3 * t + 1) / 6, t**3 / 6])


def bspline_surface(control: np.ndarray, u: np.ndarray, v: np.ndarray, du=False, dv=False):
    """(n, k) tensor-product uniform bicubic B-spline with control[i, j] at knot (i, j)."""
    span_u = np.minimum(np.floor(u).astype(int), control.shape[0] - 3)
    span_v = np.minimum(np.floor(v).astype(int), control.shape[1] - 3)
    basis_u = bspline_basis(u - span_u, du)
    basis_v = bspline_basis(v - span_v, dv)
    result = np.zeros((len(u), control.shape[2]))
    for a in range(4):
        for b in range(4):
            weight = (basis_u[:, a] * basis_v[:, b])[:, None]
            result += weight * control[span_u - 1 + a, span_v - 1 + b]
    return result


def unit(vectors):
    vectors = np.asarray(vectors, dtype=float)
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


# --- Catmull-Clark limit ----------------------------------------------------------------------


def test_cube_corner_limit_is_the_closed_form_stencil_value_and_refinement_converges_to_it():
    # Limit stencil at a valence-3 vertex of a quad mesh: (n^2 V + 4 sum(e) + sum(d)) / (n(n+5)).
    # Corner (1/2, 1/2, 1/2): sum(e) = (1/2, 1/2, 1/2), sum(d) = -(1/2, 1/2, 1/2), so
    # (9 + 4 - 1) / 24 * (1/2, 1/2, 1/2) = (1/4, 1/4, 1/4).
    expected = np.array([0.25, 0.25, 0.25])
    distances = []
    for level in (1, 2, 3, 4, 5):
        limit = refine(CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES, level)
        # The child of an authored vertex keeps its index; its limit point never moves.
        np.testing.assert_allclose(limit.points[3], expected, atol=1e-12)
        refined = refine(CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES, level, limit=False)
        distances.append(np.linalg.norm(refined.points[3] - expected))
    # The refined corner converges to the limit: about 1/6 of the distance per level.
    ratios = np.array(distances[1:]) / np.array(distances[:-1])
    assert (ratios < 0.2).all() and distances[-1] < 5e-5, distances


def test_cube_face_centre_limit_is_34_81():
    # By hand: level-1 face point (0, 0, 1/2), edge points (3/8, 0, 3/8), corner vertex points
    # 5/18 (1, 1, 1); regular limit (16 V + 4 sum(e) + sum(d)) / 36 gives z = 34/81.
    limit = refine(CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES, 2)
    top = np.argmax(limit.points[:, 2])
    np.testing.assert_allclose(limit.points[top], [0.0, 0.0, 34.0 / 81.0], atol=1e-12)
    # The limit surface is smooth and convex: every unit normal points away from the centre.
    assert np.allclose(np.linalg.norm(limit.normals, axis=-1), 1.0)
    outward = np.einsum("fkc,fkc->fk", limit.normals, limit.points[limit.faces])
    assert (outward > 0).all()
    np.testing.assert_allclose(limit.normals[limit.faces == top], [[0, 0, 1]] * 4, atol=1e-12)


def test_regular_grid_is_the_uniform_bicubic_b_spline_up_to_its_boundary_and_corners(rng):
    heights = rng.uniform(-1.0, 1.0, (9, 9))
    points, counts, indices = grid(8, 8, heights)
    limit = refine(points, counts, indices, 2)
    # Boundary edges are creases and edgeAndCorner pins the corners: the limit is the B-spline
    # of the control grid extended by phantom points P[-1] = 2 P[0] - P[1] in u, then in v.
    control = points.reshape(9, 9, 3)
    control = np.concatenate([2 * control[:1] - control[1:2], control,
                              2 * control[-1:] - control[-2:-1]], axis=0)
    control = np.concatenate([2 * control[:, :1] - control[:, 1:2], control,
                              2 * control[:, -1:] - control[:, -2:-1]], axis=1)
    # Linear precision: x and y of the limit are the B-spline parameters (shifted by the phantoms).
    u, v = limit.points[:, 0] + 1.0, limit.points[:, 1] + 1.0
    assert len(limit.points) == 33 * 33
    np.testing.assert_allclose(limit.points, bspline_surface(control, u, v), atol=1e-12)
    # Limit normals: the cross product of the B-spline's partial derivatives.
    expected_normals = unit(np.cross(bspline_surface(control, u, v, du=True),
                                     bspline_surface(control, u, v, dv=True)))
    vertex_normals = np.zeros_like(limit.points)
    vertex_normals[limit.faces.ravel()] = limit.normals.reshape(-1, 3)
    np.testing.assert_allclose(vertex_normals, expected_normals, atol=1e-9)
    for corner in range(4):  # every corner of a vertex's faces has the vertex's normal
        np.testing.assert_allclose(
            limit.normals[:, corner], vertex_normals[limit.faces[:, corner]], atol=1e-12
        )


def half_fan(faces: int, seed: int, bump: float):
    """A boundary vertex (index 0) with ``faces`` quads spread over a half disc, bumpy."""
    rng = np.random.default_rng(seed)
    angles = np.linspace(0.0, np.pi, faces + 1)
    middle = 0.5 * (angles[:-1] + angles[1:])
    ring = np.stack([np.cos(angles), np.sin(angles), rng.uniform(-bump, bump, faces + 1)], 1)
    far = np.stack(
        [1.4 * np.cos(middle), 1.4 * np.sin(middle), rng.uniform(-bump, bump, faces)], axis=1
    )
    points = np.vstack([[0.0, 0.0, 0.0], ring, far])
    quads = [[0, 1 + m, 2 + faces + m, 2 + m] for m in range(faces)]
    return points, np.full(faces, 4), np.array(quads).ravel()


def limit_face_normal(points, counts, indices, level=7):
    """The area-weighted normal of the limit surface's faces at vertex 0 at a deep level."""
    deep = refine(points, counts, indices, level)
    face = deep.points[deep.faces[(deep.faces == 0).any(axis=1)]]
    return unit(np.cross(face[:, 2] - face[:, 0], face[:, 3] - face[:, 1]).sum(axis=0))


def test_irregular_boundary_normals_are_perpendicular_to_the_boundary_curve():
    # With 3 or more faces at a boundary vertex the standard rules' subdominant eigenvalue
    # exceeds the crease's 1/2, so no stencil gives the limit surface's normal exactly;
    # OpenSubdiv's cross tangent (Biermann et al.) approximates it. What is exact: the normal
    # is perpendicular to the boundary curve's tangent, the difference of the control points
    # next to the vertex along the boundary (the uniform B-spline's derivative).
    for faces in (3, 4, 5, 7):
        for seed in range(3):
            points, counts, indices = half_fan(faces, seed, 0.3)
            refined = refine(points, counts, indices, 2)
            control = refine(points, counts, indices, 2, limit=False).points
            at_vertex = refined.normals[refined.faces == 0]  # one sector: one normal
            normal = at_vertex[0]
            np.testing.assert_allclose(at_vertex, np.broadcast_to(normal, at_vertex.shape),
                                       atol=1e-12)
            boundary = [c for c in np.unique(refined.faces[(refined.faces == 0).any(axis=1)])
                        if abs(control[c, 1]) < 1e-9 and c != 0]  # the boundary lies on y = 0
            assert len(boundary) == 2
            tangent = unit(control[boundary[0]] - control[boundary[1]])
            assert abs(normal @ tangent) < 1e-12
            assert normal @ limit_face_normal(points, counts, indices, 6) > np.cos(np.radians(15))
    quad = np.array([(0.0, 0.0, 0.0), (1.0, 0.0, 0.3), (1.2, 1.1, -0.2), (0.0, 1.0, 0.4)])
    corner = refine(quad, [4], [0, 1, 2, 3], 2).normals[0, 0]  # a one-face corner is exact
    np.testing.assert_allclose(corner, limit_face_normal(quad, [4], [0, 1, 2, 3], 9), atol=0.005)


def test_catmull_clark_refines_any_polygon_into_quads_that_remember_their_face():
    points = np.array([(0, 0, 0), (1, 0, 0), (1.5, 1, 0), (0.5, 1.6, 0), (-0.5, 1, 0), (2, 0, 0)])
    counts = [5, 3]
    indices = [0, 1, 2, 3, 4, 1, 5, 2]
    refined = refine(points, counts, indices, 2)
    assert refined.faces.shape == ((5 + 3) * 4, 4)
    np.testing.assert_array_equal(np.bincount(refined.face_origin), [5 * 4, 3 * 4])
    # A planar mesh stays planar, with the plane's normal everywhere (boundaries included).
    np.testing.assert_allclose(refined.points[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(refined.normals.reshape(-1, 3), [[0, 0, 1]] * (8 * 4 * 4),
                               atol=1e-9)


# --- creases, corners, boundaries, holes -------------------------------------------------------


def crease_grid(rng, sharpness):
    """A bumpy 6 x 6 grid with a crease along y = 3 (one sharpness, or one per edge)."""
    heights = rng.uniform(-1.0, 1.0, (7, 7))
    heights[:, 3] = 0.0  # the crease line y = 3 is straight: x from 0 to 6 at z = 0
    points, counts, indices = grid(6, 6, heights)
    crease = [i * 7 + 3 for i in range(7)]
    tags = SubdivisionTags(
        crease_indices=np.array(crease), crease_lengths=np.array([7]),
        crease_sharpnesses=np.atleast_1d(np.asarray(sharpness, dtype=float)),
    )
    return points, counts, indices, tags


def test_infinitely_sharp_crease_stays_on_its_edge_polyline(rng):
    points, counts, indices, tags = crease_grid(rng, 10.0)
    for limit in (True, False):
        refined = refine(points, counts, indices, 3, tags=tags, limit=limit)
        on_crease = np.abs(refined.points[:, 1] - 3.0) < 1e-9
        assert on_crease.sum() == 6 * 8 + 1
        np.testing.assert_allclose(refined.points[on_crease, 2], 0.0, atol=1e-12)
    smooth = refine(points, counts, indices, 3)
    assert np.abs(smooth.points[np.abs(smooth.points[:, 1] - 3.0) < 1e-9, 2]).max() > 1e-2


def test_semi_sharp_crease_blends_the_sharp_and_smooth_rules_by_its_sharpness():
    levels = {}
    for sharpness in (0.0, 0.5, 1.0):
        points, counts, indices, tags = crease_grid(np.random.default_rng(7), sharpness)
        levels[sharpness] = refine(points, counts, indices, 1, tags=tags, limit=False).points
    # OpenSubdiv: an edge of sharpness s < 1 is s * crease + (1 - s) * smooth, and so is a
    # vertex whose sharp edges decay to smooth (weight: their average sharpness).
    np.testing.assert_allclose(levels[0.5], 0.5 * (levels[0.0] + levels[1.0]), atol=1e-12)


def test_sharpness_decays_by_one_per_level(rng):
    points, counts, indices, sharp = crease_grid(rng, 10.0)
    two = SubdivisionTags(crease_indices=sharp.crease_indices, crease_lengths=sharp.crease_lengths,
                          crease_sharpnesses=np.array([2.0]))
    # Sharpness 2 is sharp for two levels, then smooth.
    np.testing.assert_allclose(
        refine(points, counts, indices, 2, tags=two, limit=False).points,
        refine(points, counts, indices, 2, tags=sharp, limit=False).points, atol=1e-12,
    )
    third = refine(points, counts, indices, 3, tags=two, limit=False).points
    sharp_third = refine(points, counts, indices, 3, tags=sharp, limit=False).points
    assert np.abs(third - sharp_third).max() > 1e-3


def test_chaikin_matches_uniform_on_an_even_crease_and_differs_on_an_uneven_one(rng):
    points, counts, indices, tags = crease_grid(rng, 2.0)
    chaikin = SubdivisionTags(
        crease_indices=tags.crease_indices, crease_lengths=tags.crease_lengths,
        crease_sharpnesses=tags.crease_sharpnesses, crease_method="chaikin",
    )
    np.testing.assert_allclose(
        refine(points, counts, indices, 3, tags=chaikin).points,
        refine(points, counts, indices, 3, tags=tags).points, atol=1e-12,
    )
    per_edge = np.array([1.0, 3.0, 1.0, 3.0, 1.0, 3.0])  # one sharpness per crease edge
    uneven = {method: SubdivisionTags(
        crease_indices=tags.crease_indices, crease_lengths=tags.crease_lengths,
        crease_sharpnesses=per_edge, crease_method=method) for method in ("uniform", "chaikin")}
    difference = (refine(points, counts, indices, 3, tags=uneven["chaikin"]).points
                  - refine(points, counts, indices, 3, tags=uneven["uniform"]).points)
    assert np.abs(difference).max() > 1e-4


def test_infinitely_sharp_corner_stays_put(rng):
    heights = rng.uniform(-1.0, 1.0, (7, 7))
    points, counts, indices = grid(6, 6, heights)
    corner = 3 * 7 + 3
    tags = SubdivisionTags(corner_indices=np.array([corner]), corner_sharpnesses=np.array([10.0]))
    for level in (1, 3):
        refined = refine(points, counts, indices, level, tags=tags)
        np.testing.assert_allclose(refined.points[corner], points[corner], atol=1e-12)
    assert np.abs(refine(points, counts, indices, 2).points[corner] - points[corner]).max() > 1e-3


def test_interpolate_boundary_none_drops_the_faces_at_the_boundary():
    points, counts, indices = grid(4, 4)
    refined = refine(points, counts, indices, 1, tags=SubdivisionTags(interpolate_boundary="none"))
    inner = {f for f in range(16) if 0 < f // 4 < 3 and 0 < f % 4 < 3}
    assert set(refined.face_origin.tolist()) == inner
    assert len(refined.faces) == len(inner) * 4
    # Unused boundary points are dropped too: faces index the points that remain.
    assert refined.faces.max() == len(refined.points) - 1


def test_edge_and_corner_pins_corners_and_edge_only_rounds_them(rng):
    heights = rng.uniform(-1.0, 1.0, (5, 5))
    points, counts, indices = grid(4, 4, heights)
    pinned = refine(points, counts, indices, 2,
                    tags=SubdivisionTags(interpolate_boundary="edgeAndCorner"))
    np.testing.assert_allclose(pinned.points[0], points[0], atol=1e-12)
    rounded = refine(points, counts, indices, 2,
                     tags=SubdivisionTags(interpolate_boundary="edgeOnly"))
    # edgeOnly: the corner lies on the boundary's uniform cubic B-spline, whose value at a knot
    # is (P_a + 4 V + P_b) / 6; the corner's boundary neighbours are vertices 1 and 5.
    np.testing.assert_allclose(rounded.points[0], (points[1] + 4 * points[0] + points[5]) / 6,
                               atol=1e-12)


def test_holes_are_refined_but_give_no_faces(rng):
    heights = rng.uniform(-1.0, 1.0, (5, 5))
    points, counts, indices = grid(4, 4, heights)
    holed = refine(points, counts, indices, 2, tags=SubdivisionTags(hole_indices=np.array([5])))
    whole = refine(points, counts, indices, 2)
    assert 5 not in holed.face_origin and len(holed.faces) == 15 * 16
    # The hole's neighbours keep the shape they had: hole faces still take part in the rules.
    keep = whole.face_origin != 5
    np.testing.assert_allclose(holed.points[holed.faces], whole.points[whole.faces[keep]],
                               atol=1e-12)


def test_triangle_subdivision_rule_smooth_uses_opensubdiv_weights_next_to_triangles():
    # Two triangles sharing the edge 0-2: its edge point is 0.03 (v0 + v2) + 0.47 (F0 + F1).
    points = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 1.0)])
    counts, indices = [3, 3], [0, 1, 2, 0, 2, 3]
    face_points = [points[[0, 1, 2]].mean(axis=0), points[[0, 2, 3]].mean(axis=0)]
    expected = 0.03 * (points[0] + points[2]) + 0.47 * (face_points[0] + face_points[1])
    smooth = refine(points, counts, indices, 1, limit=False,
                    tags=SubdivisionTags(triangle_subdivision_rule="smooth"))
    standard = refine(points, counts, indices, 1, limit=False)
    # The child quad of corner 0 is (v0, edge 0-1, face 0, edge 2-0): corner 3 is edge 0-2.
    np.testing.assert_allclose(smooth.points[smooth.faces[0, 3]], expected, atol=1e-12)
    np.testing.assert_allclose(
        standard.points[standard.faces[0, 3]],
        0.25 * (points[0] + points[2] + face_points[0] + face_points[1]), atol=1e-12,
    )


# --- loop and bilinear ---------------------------------------------------------------------------


def test_loop_keeps_a_planar_mesh_on_its_plane_and_linear_uvs_linear(rng):
    points, counts, indices = triangle_grid(6, 5)
    points[:, :2] += rng.uniform(-0.2, 0.2, (len(points), 2))  # irregular shapes, same plane
    points[:, 2] = 0.7 - 0.3 * points[:, 0] + 0.2 * points[:, 1]  # 0.3 x - 0.2 y + z = 0.7
    plane_normal = unit([0.3, -0.2, 1.0])
    st_of = np.array([[0.5, -0.25], [0.125, 0.75]])

    def st(xy):
        return xy @ st_of.T + [0.1, 0.2]

    per_corner = st(points[indices, :2])
    refined = refine(points, counts, indices, 3, scheme="loop",
                     face_varying=[FaceVaryingPrimvar(per_corner)],
                     vertex_data=st(points[:, :2]))
    assert refined.scheme == "loop" and refined.faces.shape == (len(counts) * 64, 3)
    np.testing.assert_allclose(refined.points @ plane_normal, 0.7 * plane_normal[2], atol=1e-12)
    np.testing.assert_allclose(np.abs(refined.normals.reshape(-1, 3) @ plane_normal), 1.0,
                               atol=1e-9)
    np.testing.assert_allclose(refined.vertex_data, st(refined.points[:, :2]), atol=1e-12)
    np.testing.assert_allclose(refined.face_varying[0],
                               st(refined.points[refined.faces][..., :2]), atol=1e-12)


def test_loop_regular_vertex_limit_is_the_quartic_box_spline_value(rng):
    points, counts, indices = triangle_grid(6, 6)
    points[:, 2] = rng.uniform(-1.0, 1.0, len(points))
    centre = 3 * 7 + 3  # (3, 3); the quads were split along (i, j)-(i + 1, j + 1)
    neighbours = [centre - 1, centre + 1, centre - 7, centre + 7, centre - 8, centre + 8]
    # The three-direction quartic box spline at a lattice point: 1/2 there, 1/12 per neighbour.
    expected = 0.5 * points[centre] + sum(points[n] for n in neighbours) / 12.0
    limit = refine(points, counts, indices, 1, scheme="loop")
    np.testing.assert_allclose(limit.points[centre], expected, atol=1e-12)
    deep = refine(points, counts, indices, 5, scheme="loop", limit=False)
    assert np.linalg.norm(deep.points[centre] - expected) < 1e-3


def test_loop_on_quads_falls_back_to_catmull_clark_and_says_so():
    refined = refine(CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES, 1, scheme="loop")
    assert refined.scheme == "catmullClark" and refined.faces.shape[1] == 4
    assert any("loop" in warning and "catmullClark" in warning for warning in refined.warnings)


def test_bilinear_points_lie_on_the_authored_bilinear_patch(rng):
    corners = rng.uniform(-1.0, 1.0, (4, 3))  # a non-planar quad
    refined = refine(corners, [4], [0, 1, 2, 3], 2, scheme="bilinear")
    s, t = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5), indexing="ij")
    s, t = s.ravel()[:, None], t.ravel()[:, None]
    patch = ((1 - s) * (1 - t) * corners[0] + s * (1 - t) * corners[1]
             + s * t * corners[2] + (1 - s) * t * corners[3])
    distance = np.linalg.norm(refined.points[:, None, :] - patch[None], axis=2)
    assert len(refined.points) == 25 and distance.min(axis=1).max() < 1e-12


# --- face-varying ------------------------------------------------------------------------------


def seamed_grid(rng, islands):
    """A 4 x 4 grid whose faces belong to uv islands; random uvs per (island, vertex)."""
    points, counts, indices = grid(4, 4)
    faces = indices.reshape(-1, 4)
    island_of_face = np.array([islands(f // 4, f % 4) for f in range(16)])
    table = rng.uniform(0.0, 1.0, (3, len(points), 2))
    values = table.reshape(-1, 2)
    fvar_indices = (island_of_face[:, None] * len(points) + faces).ravel()
    return points, counts, indices, FaceVaryingPrimvar(values, fvar_indices), table, island_of_face


def level_one_value(refined, corner: int):
    """The level-1 value of a corner's vertex: corner 0 of the child face of that corner."""
    return refined.face_varying[0][corner, 0]


def corner_of(indices, island_of_face, vertex, island):
    faces = np.flatnonzero(island_of_face == island)
    corners = [4 * f + k for f in faces for k in range(4) if indices[4 * f + k] == vertex]
    return corners[0]


def test_face_varying_all_is_linear_and_boundaries_pins_seams(rng):
    points, counts, indices, st, table, island = seamed_grid(rng, lambda i, j: int(i >= 2))
    linear = refine(points, counts, indices, 1, limit=False, face_varying=[st],
                    tags=SubdivisionTags(face_varying_linear_interpolation="all"))
    corners = st.values[st.indices].reshape(-1, 4, 2)
    # Level 1 of linear data: vertices stay, edge points are midpoints, face points averages.
    np.testing.assert_allclose(linear.face_varying[0][:, 0], st.values[st.indices], atol=1e-12)
    np.testing.assert_allclose(
        linear.face_varying[0][:, 2], np.repeat(corners.mean(axis=1), 4, axis=0), atol=1e-12
    )
    np.testing.assert_allclose(
        linear.face_varying[0][:, 1],
        0.5 * (corners + np.roll(corners, -1, axis=1)).reshape(-1, 2), atol=1e-12,
    )
    boundaries = refine(points, counts, indices, 1, limit=False, face_varying=[st],
                        tags=SubdivisionTags(face_varying_linear_interpolation="boundaries"))
    seam_vertex = 2 * 5 + 2  # (2, 2): on the seam x = 2, inside the mesh
    for side in (0, 1):
        c = corner_of(indices, island, seam_vertex, side)
        np.testing.assert_allclose(level_one_value(boundaries, c), table[side, seam_vertex],
                                   atol=1e-12)
    # The interior of an island stays smooth: the Catmull-Clark vertex rule on its values.
    inner = 1 * 5 + 2  # (1, 2)
    c = corner_of(indices, island, inner, 0)
    assert np.abs(level_one_value(boundaries, c) - table[0, inner]).max() > 1e-3


def test_face_varying_none_makes_seams_smooth_boundary_curves(rng):
    points, counts, indices, st, table, island = seamed_grid(rng, lambda i, j: int(i >= 2))
    smooth = refine(points, counts, indices, 1, limit=False, face_varying=[st],
                    tags=SubdivisionTags(face_varying_linear_interpolation="none"))
    seam_vertex = 2 * 5 + 2
    above, below = 2 * 5 + 3, 2 * 5 + 1
    for side in (0, 1):
        # The seam is a crease of each island: (a + 6 V + b) / 8 along it.
        expected = (table[side, above] + 6 * table[side, seam_vertex] + table[side, below]) / 8
        c = corner_of(indices, island, seam_vertex, side)
        np.testing.assert_allclose(level_one_value(smooth, c), expected, atol=1e-12)


def test_face_varying_corners_only_pins_one_face_corners_and_plus1_junctions(rng):
    # Three islands meeting at (2, 2): left, right-bottom, right-top.
    points, counts, indices, st, table, island = seamed_grid(
        rng, lambda i, j: 0 if i < 2 else (1 if j < 2 else 2)
    )
    junction = 2 * 5 + 2
    seam_end = 2 * 5 + 0  # (2, 0): one face on each side of the seam at the mesh boundary

    def value(option, vertex, side):
        refined = refine(points, counts, indices, 1, limit=False, face_varying=[st],
                         tags=SubdivisionTags(face_varying_linear_interpolation=option))
        return level_one_value(refined, corner_of(indices, island, vertex, side))

    # cornersOnly: a value spanning one face is pinned; "none" leaves it on its boundary curve.
    np.testing.assert_allclose(value("cornersOnly", seam_end, 0), table[0, seam_end], atol=1e-12)
    expected = (table[0, 1 * 5 + 0] + 6 * table[0, seam_end] + table[0, 2 * 5 + 1]) / 8
    np.testing.assert_allclose(value("none", seam_end, 0), expected, atol=1e-12)
    # The left value at the junction spans two faces: a crease for cornersOnly, pinned by
    # cornersPlus1 because three values meet there.
    assert np.abs(value("cornersOnly", junction, 0) - table[0, junction]).max() > 1e-3
    np.testing.assert_allclose(value("cornersPlus1", junction, 0), table[0, junction], atol=1e-12)


def test_unindexed_face_varying_values_join_where_they_agree(rng):
    heights = rng.uniform(-1.0, 1.0, (5, 5))
    points, counts, indices = grid(4, 4, heights)
    st = points[indices, :2] * 0.25  # continuous, authored per corner
    refined = refine(points, counts, indices, 2, face_varying=[FaceVaryingPrimvar(st)])
    # Joined corners make one smooth channel: linear in the limit (x, y) like the points.
    np.testing.assert_allclose(refined.face_varying[0],
                               refined.points[refined.faces][..., :2] * 0.25, atol=1e-12)


# --- the fast path against its reference ---------------------------------------------------------


def fan_test_meshes(rng):
    """Meshes with boundaries, creases of decaying and Chaikin sharpness, a corner, a hole,
    polygons, a non-manifold vertex and an inconsistently wound face."""
    bumpy, counts, indices = grid(5, 4, rng.uniform(-1.0, 1.0, 30))
    creased = SubdivisionTags(
        crease_indices=np.array([1, 6, 11, 16, 21, 26, 2, 7]),
        crease_lengths=np.array([6, 2]),
        crease_sharpnesses=np.array([1.0, 3.0, 10.0, 0.5, 2.0, 1.5]),
        corner_indices=np.array([13]), corner_sharpnesses=np.array([2.0]),
        hole_indices=np.array([7]), crease_method="chaikin",
    )
    yield bumpy, counts, indices, creased
    yield bumpy, counts, indices, SubdivisionTags(
        crease_indices=creased.crease_indices, crease_lengths=creased.crease_lengths,
        crease_sharpnesses=creased.crease_sharpnesses,
    )
    yield CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES, SubdivisionTags()
    polygons = np.array([(0, 0, 0), (1, 0, 0), (1.5, 1, 0.3), (0.5, 1.6, 0), (-0.5, 1, 0.2),
                         (2, 0, 0.1), (-1, -1, 0), (0, -1, 0.4)])
    # A pentagon, a triangle, and a quad touching the pentagon at vertex 0 only (a bowtie),
    # then a triangle wound against the pentagon.
    yield polygons, [5, 3, 3, 3], [0, 1, 2, 3, 4, 1, 5, 2, 0, 6, 7, 3, 2, 4], SubdivisionTags()


def test_fans_propagated_through_levels_match_the_pointer_jumping_reference(rng):
    from pxr_layers.stage import subdivision as sd

    for points, counts, indices, tags in fan_test_meshes(rng):
        counts, indices = np.asarray(counts), np.asarray(indices)
        level, fans = sd._base_level(counts, indices, len(points), np.arange(len(counts)),
                                     "catmullClark", tags, [])
        data = np.asarray(points, dtype=float)
        for _ in range(3):
            child_sharpness = sd._child_edge_sharpness(level, tags.crease_method)
            rules = sd._Rules("catmullClark", "quads", False, tags.crease_method)
            data = sd._refine_vertex_data(level, data, rules, child_sharpness)
            child = sd._child_level(level, "quads", child_sharpness)
            fast = sd._child_fans(level, fans, child)
            sharp = child.edge_sharpness > 0.0
            reference = sd._fans(child, sharp)
            np.testing.assert_array_equal(fast.twin, reference.twin)
            np.testing.assert_array_equal(fast.manifold, reference.manifold)
            np.testing.assert_array_equal(fast.closed, reference.closed)
            good = np.flatnonzero(reference.manifold[child.corner_vertex])
            # The same ring: rank differences agree up to a rotation of each ring...
            valence = np.bincount(child.corner_vertex)[child.corner_vertex[good]]
            offset = (fast.position[good] - reference.position[good]) % valence
            per_vertex = np.full(child.vertex_count, -1)
            per_vertex[child.corner_vertex[good]] = offset
            np.testing.assert_array_equal(offset, per_vertex[child.corner_vertex[good]])
            # ... and the same sectors (labelled by their first corner, which may differ where
            # a smooth ring starts elsewhere), so the same normals.
            fast_first, _ = sd._sectors(child, fast, sharp, good)
            reference_first, _ = sd._sectors(child, reference, sharp, good)
            pairs = np.unique(np.stack([fast_first, reference_first]), axis=1).shape[1]
            assert pairs == len(np.unique(fast_first)) == len(np.unique(reference_first))
            # (the tangent masks weigh each corner by its rank in its fan: sums per fans)
            normals = [values[index] for values, index in (
                sd._corner_normals(child, fans_, data, "catmullClark",
                                   sd._LimitSums.of(child, data, "catmullClark", fans_))
                for fans_ in (fast, reference))]
            np.testing.assert_allclose(normals[0], normals[1], atol=1e-12)
            level, fans = child, fast


# --- performance -----------------------------------------------------------------------------


def test_fifty_thousand_quads_refine_to_level_two_quickly(rng):
    points, counts, indices = grid(250, 200, rng.uniform(0.0, 0.3, 251 * 201))
    start = time.perf_counter()
    refined = refine(points, counts, indices, 2)
    elapsed = time.perf_counter() - start
    assert len(refined.faces) == 50_000 * 16
    logging.getLogger(__name__).info("50k quads to level 2, limit and normals: %.2f s", elapsed)
    assert elapsed < 10.0  # about 1.5 s on a shared 2-core machine; a regression guard only


# --- read_mesh through USD -----------------------------------------------------------------------


def mesh_prim(stage, path, points, counts, indices, scheme="catmullClark"):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([tuple(map(float, p)) for p in points])
    mesh.CreateFaceVertexCountsAttr([int(c) for c in counts])
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in indices])
    mesh.CreateSubdivisionSchemeAttr(scheme)
    return mesh


def read(prim, level=2, **kwargs):
    diagnostics = Diagnostics()
    surface = read_mesh(prim, Usd.TimeCode.Default(), "st", diagnostics, "test.usda",
                        subdiv_level=level, **kwargs)
    return surface, diagnostics


def test_catmull_clark_cube_comes_back_smooth_refined_with_unit_corner_normals():
    stage = Usd.Stage.CreateInMemory()
    mesh = mesh_prim(stage, "/cube", CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES)
    surface, _ = read(mesh.GetPrim(), level=2)
    assert len(surface.triangles) == 6 * 16 * 2 and surface.face_count == 6
    assert surface.normals.shape == (len(surface.triangles), 3, 3)
    np.testing.assert_allclose(np.linalg.norm(surface.normals, axis=2), 1.0, atol=1e-12)
    assert set(surface.triangle_face.tolist()) == set(range(6))
    corners = surface.points[surface.triangles]
    geometric = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert (np.einsum("tc,tkc->tk", geometric, surface.normals) > 0).all()  # winding = front
    assert np.abs(surface.points).max() < 0.5  # the limit surface shrinks inside the cage
    control, _ = read(mesh.GetPrim(), level=0)
    assert len(control.triangles) == 12 and control.smooth and control.normals is None


def test_left_handed_subdivision_mesh_still_faces_outward():
    stage = Usd.Stage.CreateInMemory()
    reversed_indices = CUBE_INDICES.reshape(-1, 4)[:, ::-1].ravel()
    mesh = mesh_prim(stage, "/cube", CUBE_POINTS, CUBE_COUNTS, reversed_indices)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    surface, _ = read(mesh.GetPrim())
    corners = surface.points[surface.triangles]
    geometric = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert (np.einsum("tc,tc->t", geometric, corners.mean(axis=1)) > 0).all()
    assert (np.einsum("tkc,tkc->tk", surface.normals, corners) > 0).all()


def test_uvs_are_refined_per_corner_and_authored_normals_ignored():
    stage = Usd.Stage.CreateInMemory()
    points, counts, indices = grid(3, 3)
    mesh = mesh_prim(stage, "/grid", points, counts, indices)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray([tuple(p[:2] / 3.0) for p in points[indices]]))
    mesh.CreateNormalsAttr([(1.0, 0.0, 0.0)] * len(points))  # wrong on purpose: ignored
    surface, _ = read(mesh.GetPrim(), level=2)
    assert surface.uvs.shape == (len(surface.triangles), 3, 2)
    np.testing.assert_allclose(surface.uvs, surface.points[surface.triangles][..., :2] / 3.0,
                               atol=1e-6)
    up = np.broadcast_to([0.0, 0.0, 1.0], (surface.normals.size // 3, 3))
    np.testing.assert_allclose(surface.normals.reshape(-1, 3), up, atol=1e-9)


def test_indexed_uvs_with_a_seam_keep_each_side_of_the_seam():
    stage = Usd.Stage.CreateInMemory()
    points, counts, indices = grid(2, 1)
    mesh = mesh_prim(stage, "/strip", points, counts, indices)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    # Face 0 maps to the left of the texture, face 1 to the right half shifted by 0.5.
    st.Set(Vt.Vec2fArray(
        [(0, 0), (0.25, 0), (0.25, 1), (0, 1), (0.75, 0), (1, 0), (1, 1), (0.75, 1)]
    ))
    st.SetIndices(Vt.IntArray([0, 1, 2, 3, 4, 5, 6, 7]))
    surface, _ = read(mesh.GetPrim(), level=2)
    for face, (low, high) in enumerate([(0.0, 0.25), (0.75, 1.0)]):
        u = surface.uvs[surface.triangle_face == face][..., 0]
        assert u.min() >= low - 1e-6 and u.max() <= high + 1e-6


def test_given_points_replace_the_authored_ones():
    stage = Usd.Stage.CreateInMemory()
    mesh = mesh_prim(stage, "/cube", CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES)
    surface, _ = read(mesh.GetPrim(), level=1)
    moved, _ = read(mesh.GetPrim(), level=1, points=CUBE_POINTS * 2.0 + [1.0, 0.0, 0.0])
    np.testing.assert_allclose(moved.points, surface.points * 2.0 + [1.0, 0.0, 0.0], atol=1e-12)
    with pytest.raises(StageError, match="shape"):
        read(mesh.GetPrim(), level=1, points=np.zeros((8, 2)))


def test_loop_mesh_of_quads_warns_and_is_refined_with_catmull_clark():
    stage = Usd.Stage.CreateInMemory()
    mesh = mesh_prim(stage, "/cube", CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES, scheme="loop")
    surface, diagnostics = read(mesh.GetPrim(), level=1)
    assert len(surface.triangles) == 6 * 4 * 2
    assert any("/cube" in w and "catmullClark" in w for w in diagnostics.finish())


def test_negative_face_vertex_count_names_the_entry():
    stage = Usd.Stage.CreateInMemory()
    mesh = mesh_prim(stage, "/bad", CUBE_POINTS, [4, 4, 4, -1, 5, 4], CUBE_INDICES[:20])
    with pytest.raises(StageError, match=r"faceVertexCounts\[3\] is -1"):
        read(mesh.GetPrim())


def test_negative_face_vertex_index_names_the_entry():
    stage = Usd.Stage.CreateInMemory()
    mesh = mesh_prim(stage, "/bad", CUBE_POINTS, [4], [0, 1, -2, 3], scheme="none")
    with pytest.raises(StageError, match=r"faceVertexIndices\[2\] is -2"):
        read(mesh.GetPrim())


@pytest.fixture
def normals_types_stage(shared_scenes):
    return Usd.Stage.Open(str(shared_scenes / NORMALS_TYPES))


@pytest.mark.parametrize("level", [0, 2])
def test_normals_of_the_wrong_type_warn_and_are_computed_instead(normals_types_stage, level):
    diagnostics = Diagnostics()
    surfaces = {}
    for prim in normals_types_stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            surfaces[prim.GetName()] = read_mesh(
                prim, Usd.TimeCode.Default(), "st", diagnostics, NORMALS_TYPES,
                subdiv_level=level,
            )
    warnings = diagnostics.finish()
    typed = [w for w in warnings if "normals that are not an array of 3-vectors" in w]
    assert len(typed) == 1  # one grouped warning
    for name in ("int", "intArray", "doubleArray", "double", "point3f"):
        assert f"/World/{name}.normals (" in typed[0], (name, typed[0])
    assert "(int[])" in typed[0] and "(double[])" in typed[0]
    for name in ("intArray", "doubleArray", "int"):
        surface = surfaces[name]
        if level == 0:
            assert surface.normals is None and surface.smooth  # computed by placement
        else:
            np.testing.assert_allclose(np.linalg.norm(surface.normals, axis=2), 1.0, atol=1e-12)
    if level == 0:  # well-typed normals (float and double precision) are used
        assert surfaces["normal3fArray"].normals is not None
        assert surfaces["double3Array"].normals is not None


def test_posed_points_replace_the_rest_pose_normals_by_smooth_ones():
    stage = Usd.Stage.CreateInMemory()
    mesh = mesh_prim(stage, "/cube", CUBE_POINTS, CUBE_COUNTS, CUBE_INDICES)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateNormalsAttr([(0.0, 0.0, 1.0)] * len(CUBE_POINTS))  # of the rest pose
    rest, _ = read(mesh.GetPrim(), level=0)
    assert rest.normals is not None and not rest.smooth
    posed, _ = read(mesh.GetPrim(), level=0, points=CUBE_POINTS * [1.0, 2.0, 1.0])
    assert posed.normals is None and posed.smooth
