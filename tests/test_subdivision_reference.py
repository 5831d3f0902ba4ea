"""subdivision.refine against its own output before the refiner was made faster (issue 38).

test_subdivision.py checks the refiner against analytic values; this checks that a faster
refiner still computes what the checked one did, on meshes that reach every rule: creases of
uniform and Chaikin decay, corners, holes, polygons, a non-manifold vertex, an inconsistently
wound face, triangles (loop), bilinear, face-varying channels of every
faceVaryingLinearInterpolation option, vertex and varying data, with and without the limit.
The reference (subdivision_reference.npz beside this file) was written by ``python
tests/test_subdivision_reference.py`` at commit ecd1143, before the change.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from pxr_layers.stage.subdivision import FaceVaryingPrimvar, SubdivisionTags, refine

REFERENCE = Path(__file__).with_name("subdivision_reference.npz")


def cases():
    """(name, refine's arguments) of each reference case."""
    rng = np.random.default_rng(38)
    columns, rows = 5, 4
    i, j = np.meshgrid(np.arange(columns + 1.0), np.arange(rows + 1.0), indexing="ij")
    points = np.stack([i.ravel(), j.ravel(), rng.uniform(-1.0, 1.0, i.size)], axis=1)
    fi, fj = (a.ravel() for a in np.meshgrid(np.arange(columns), np.arange(rows), indexing="ij"))
    quads = np.stack([fi * (rows + 1) + fj, (fi + 1) * (rows + 1) + fj, (fi + 1) * (rows + 1) + fj + 1,
                      fi * (rows + 1) + fj + 1], axis=1)
    counts, indices = np.full(len(quads), 4), quads.ravel()
    creases = dict(crease_indices=np.array([1, 6, 11, 16, 21, 26, 2, 7]), crease_lengths=np.array([6, 2]),
                   crease_sharpnesses=np.array([1.0, 3.0, 10.0, 0.5, 2.0, 1.5]),
                   corner_indices=np.array([13]), corner_sharpnesses=np.array([2.0]), hole_indices=np.array([7]))
    # st with a seam down the middle column (indexed), and per-corner values (unindexed)
    st_values = np.concatenate([points[:, :2] / 5.0, points[:, :2] / 5.0 + 0.5])
    st_indices = indices + len(points) * (np.repeat(fi, 4) >= 3)
    per_corner = rng.uniform(0.0, 1.0, (len(indices), 3))
    vertex_data = rng.uniform(-1.0, 1.0, (len(points), 2))
    common = dict(vertex_data=vertex_data, varying_data=vertex_data[:, :1],
                  face_varying=[FaceVaryingPrimvar(st_values, st_indices), FaceVaryingPrimvar(per_corner)])
    for option in ("none", "cornersOnly", "cornersPlus1", "cornersPlus2", "boundaries", "all"):
        tags = SubdivisionTags(face_varying_linear_interpolation=option, **creases)
        yield f"grid-fvar-{option}", (points, counts, indices, 2), dict(tags=tags, **common)
    yield "grid-chaikin", (points, counts, indices, 2), dict(
        tags=SubdivisionTags(crease_method="chaikin", **creases), **common)
    for boundary in ("none", "edgeOnly"):
        yield f"grid-boundary-{boundary}", (points, counts, indices, 2), dict(
            tags=SubdivisionTags(interpolate_boundary=boundary), **common)
    yield "grid-unlimited", (points, counts, indices, 2), dict(limit=False, **common)
    yield "grid-bilinear", (points, counts, indices, 2), dict(scheme="bilinear", **common)
    polygons = np.array([(0, 0, 0), (1, 0, 0), (1.5, 1, 0.3), (0.5, 1.6, 0), (-0.5, 1, 0.2),
                         (2, 0, 0.1), (-1, -1, 0), (0, -1, 0.4)], dtype=float)
    # a pentagon, a triangle, a quad touching the pentagon at one vertex, a triangle wound against it
    polygon_counts = np.array([5, 3, 3, 3])
    polygon_indices = np.array([0, 1, 2, 3, 4, 1, 5, 2, 0, 6, 7, 3, 2, 4])
    for rule in ("catmullClark", "smooth"):
        yield f"polygons-{rule}", (polygons, polygon_counts, polygon_indices, 2), dict(
            tags=SubdivisionTags(triangle_subdivision_rule=rule),
            face_varying=[FaceVaryingPrimvar(rng.uniform(0.0, 1.0, (len(polygon_indices), 2)))])
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    yield "loop", (points, np.full(len(triangles), 3), triangles.ravel(), 2), dict(
        scheme="loop", tags=SubdivisionTags(**creases), vertex_data=vertex_data,
        face_varying=[FaceVaryingPrimvar(rng.uniform(0.0, 1.0, (triangles.size, 2)))])


def arrays(refined) -> dict[str, np.ndarray]:
    found = {"points": refined.points, "faces": refined.faces, "face_origin": refined.face_origin,
             "normals": refined.normals}
    if refined.vertex_data is not None:
        found["vertex_data"] = refined.vertex_data
    if refined.varying_data is not None:
        found["varying_data"] = refined.varying_data
    found.update({f"face_varying{index}": values for index, values in enumerate(refined.face_varying)})
    return found


def test_refine_computes_what_it_did_before_it_was_made_faster():
    reference = np.load(REFERENCE)
    checked = 0
    for name, args, kwargs in cases():
        for key, values in arrays(refine(*args, **kwargs)).items():
            expected = reference[f"{name}/{key}"]
            assert values.shape == expected.shape, (name, key)
            if values.dtype.kind == "f":
                np.testing.assert_allclose(values, expected, rtol=1e-12, atol=1e-12, err_msg=f"{name}/{key}")
            else:
                np.testing.assert_array_equal(values, expected, err_msg=f"{name}/{key}")
            checked += 1
    assert checked == len(reference.files)


if __name__ == "__main__":
    np.savez_compressed(REFERENCE, **{f"{name}/{key}": values for name, args, kwargs in cases()
                                      for key, values in arrays(refine(*args, **kwargs)).items()})
    print(f"wrote {REFERENCE}", file=sys.stderr)
