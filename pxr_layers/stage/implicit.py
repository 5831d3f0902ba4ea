"""Tessellate UsdGeom's implicit gprims (Sphere, Cube, Cylinder, Cone, Capsule, Plane).

Round shapes are surfaces of revolution about the local Z axis, built from a profile of
rings and then rotated onto the authored ``axis``. Normals are analytic (unit, outward)
and uvs run u = angle / 2π around the axis and v = 0 → 1 along each profile strip (sphere:
south pole → north pole). Every strip gets its own vertices, so caps have flat normals and
do not share the side's smooth ones.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom

from pxr_layers.errors import StageError

from . import values
from .surfaces import LocalSurface

# Segments around the axis: at 64 the polygon's sagitta is 0.12 % of the radius, invisible
# in a silhouette at any reasonable screen size.
AROUND_SEGMENTS = 64
# Rings from pole to pole of a sphere (a capsule's hemispheres get half each).
SPHERE_RINGS = 32

# Cyclic permutations of (x, y, z) are rotations (determinant +1), so they move the
# canonical Z axis onto X or Y without mirroring the triangles' winding.
_AXIS_FROM_Z = {
    "Z": np.eye(3),
    "X": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
    "Y": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
}

# The attributes each implicit gprim is built from (sizes in stage units). The schemas are
# disjoint (Cylinder_1 is not a Cylinder), so a prim matches exactly one row.
_SIZE_ATTRIBUTES = {
    UsdGeom.Sphere: ("radius",),
    UsdGeom.Cube: ("size",),
    UsdGeom.Cylinder: ("radius", "height"),
    UsdGeom.Cylinder_1: ("radiusBottom", "radiusTop", "height"),
    UsdGeom.Cone: ("radius", "height"),
    UsdGeom.Capsule: ("radius", "height"),
    UsdGeom.Capsule_1: ("radiusBottom", "radiusTop", "height"),
    UsdGeom.Plane: ("width", "length"),
}
IMPLICIT_TYPES = tuple(_SIZE_ATTRIBUTES)


@dataclass(frozen=True)
class _Ring:
    """One circle of a profile: radius and height on the axis, the outward normal's radial and
    axial components, and the v texture coordinate."""

    radius: float
    height: float
    normal_radial: float
    normal_axial: float
    v: float


def is_implicit(prim: Usd.Prim) -> bool:
    return any(prim.IsA(schema) for schema in IMPLICIT_TYPES)


def _dimensions(prim: Usd.Prim, time: Usd.TimeCode, file: str | None = None) -> dict[str, float | None]:
    """The sizes an implicit gprim is built from (``_SIZE_ATTRIBUTES``), in stage units;
    None where the attribute has no value (a blocked opinion). StageError naming the
    attribute for a value that is not a number (values.real)."""
    schema = next((schema for schema in _SIZE_ATTRIBUTES if prim.IsA(schema)), None)
    if schema is None:
        raise ValueError(f"not an implicit gprim: {prim.GetPath()}")
    return {name: values.real(prim.GetAttribute(name), time, file) for name in _SIZE_ATTRIBUTES[schema]}


def unusable_dimension(prim: Usd.Prim, time: Usd.TimeCode, file: str | None = None) -> str | None:
    """Why an implicit gprim of valid sizes has no surface (e.g. "radius is 0"), or None
    when it has one.

    Raises StageError naming the file, prim and attribute for a size no shape can have:
    negative, NaN, infinite, or not a number. A size of 0 (or none: a blocked opinion) is a
    shape that is not there, not a mistake: it is how an animation grows a shape from
    nothing or collapses it away, and the right image of it is no surface, so the caller
    skips the prim (walk.py, with a warning, as it may still surprise).
    """
    found = _why_unusable(prim, _dimensions(prim, time, file))
    if found is None:
        return None
    reason, invalid = found
    if invalid:
        raise StageError(f"{reason}: a size must be a finite number, not negative",
                         file=file, prim=str(prim.GetPath()))
    return reason


def _why_unusable(prim: Usd.Prim, dimensions: dict[str, float | None]) -> tuple[str, bool] | None:
    """(Why the sizes make no surface, whether that is because one is invalid: negative or
    not finite), or None when they make one.

    Every size must be finite and positive, except that a capsule's ``height`` may be 0
    (its hemispheres then make a sphere) and one of the two radii of a tapered shape may be
    0 (a cone, or a capsule ending in a point), but not both."""
    is_capsule = prim.IsA(UsdGeom.Capsule) or prim.IsA(UsdGeom.Capsule_1)
    for name, value in dimensions.items():
        if value is None:
            return f"{name} has no value", False
        if not math.isfinite(value) or value < 0.0:
            return f"{name} is {value:g}", True
        may_be_zero = (name == "height" and is_capsule) or name in ("radiusBottom", "radiusTop")
        if value == 0.0 and not may_be_zero:
            return f"{name} is 0", False
    if dimensions.get("radiusBottom") == 0.0 and dimensions.get("radiusTop") == 0.0:
        return "radiusBottom and radiusTop are 0", False
    return None


def tessellate(prim: Usd.Prim, time: Usd.TimeCode) -> LocalSurface:
    """Triangulate an implicit gprim in its object space (stage units).

    Callers check the prim with :func:`unusable_dimension` first (walk.py does: an error for
    invalid sizes, the prim skipped with a warning for sizes of 0); sizes that cannot make a
    surface raise ValueError here rather than give NaN points or collapsed triangles.
    """
    size = _dimensions(prim, time)
    found = _why_unusable(prim, size)
    if found is not None:
        raise ValueError(f"{prim.GetPath()}: {found[0]}")
    axis = str(prim.GetAttribute(UsdGeom.Tokens.axis).Get(time))
    if prim.IsA(UsdGeom.Cube):
        return _cube(size["size"])
    if prim.IsA(UsdGeom.Plane):
        return _plane(size["width"], size["length"], axis)
    if prim.IsA(UsdGeom.Sphere):
        return _revolve([_sphere_cap(size["radius"], 0.0, -1.0, 1.0, SPHERE_RINGS)], "Z")
    bottom = size.get("radiusBottom", size.get("radius"))
    top = 0.0 if prim.IsA(UsdGeom.Cone) else size.get("radiusTop", size.get("radius"))
    if prim.IsA(UsdGeom.Capsule) or prim.IsA(UsdGeom.Capsule_1):
        return _revolve(_capsule(bottom, top, size["height"]), axis)
    return _revolve(_frustum(bottom, top, size["height"]), axis)


def _sphere_cap(
    radius: float, center: float, start: float, end: float, rings: int
) -> list[_Ring]:
    """Rings of a sphere between latitudes asin(start) and asin(end) (sines in [-1, 1])."""
    latitudes = np.linspace(math.asin(start), math.asin(end), rings + 1)
    profile = []
    for index, latitude in enumerate(latitudes):
        cos_lat, sin_lat = math.cos(latitude), math.sin(latitude)
        # Exact zeros at the poles keep the fan triangles there from becoming slivers.
        if abs(cos_lat) < 1e-12:
            cos_lat = 0.0
        profile.append(
            _Ring(radius * cos_lat, center + radius * sin_lat, cos_lat, sin_lat, index / rings)
        )
    return profile


def _frustum(bottom_radius: float, top_radius: float, height: float) -> list[list[_Ring]]:
    """Bottom cap, side and top cap of a (possibly pointed) cylinder centred on the origin."""
    low, high = -height / 2.0, height / 2.0
    # The side's outward normal is perpendicular to its slope (Δradius, Δheight).
    slope_length = math.hypot(top_radius - bottom_radius, height) or 1.0
    normal_radial = height / slope_length
    normal_axial = (bottom_radius - top_radius) / slope_length
    strips = [
        [_Ring(bottom_radius, low, normal_radial, normal_axial, 0.0),
         _Ring(top_radius, high, normal_radial, normal_axial, 1.0)],
    ]
    if bottom_radius > 0.0:
        strips.append([_Ring(0.0, low, 0.0, -1.0, 0.0), _Ring(bottom_radius, low, 0.0, -1.0, 1.0)])
    if top_radius > 0.0:
        strips.append([_Ring(top_radius, high, 0.0, 1.0, 0.0), _Ring(0.0, high, 0.0, 1.0, 1.0)])
    return strips


def _capsule(bottom_radius: float, top_radius: float, height: float) -> list[list[_Ring]]:
    """Hemispheres on both ends of a ``height``-long cylinder (caps excluded from height)."""
    half_rings = SPHERE_RINGS // 2
    low, high = -height / 2.0, height / 2.0
    bottom = _sphere_cap(bottom_radius, low, -1.0, 0.0, half_rings)
    top = _sphere_cap(top_radius, high, 0.0, 1.0, half_rings)
    if bottom_radius == top_radius:
        # Equal radii meet with the same normal: one smooth strip (no seam in the shading),
        # with v re-spread by arc length over the whole strip.
        rings = bottom + top
        steps = [math.hypot(b.radius - a.radius, b.height - a.height)
                 for a, b in itertools.pairwise(rings)]
        arc = np.concatenate([[0.0], np.cumsum(steps)]) / (sum(steps) or 1.0)
        return [[_Ring(r.radius, r.height, r.normal_radial, r.normal_axial, float(v))
                 for r, v in zip(rings, arc)]]
    return [bottom, _frustum(bottom_radius, top_radius, height)[0], top]


def _revolve(strips: list[list[_Ring]], axis: str) -> LocalSurface:
    points, normals, uvs, triangles = [], [], [], []
    vertex_count = 0
    angles = np.linspace(0.0, 2.0 * math.pi, AROUND_SEGMENTS + 1)
    cos_a, sin_a = np.cos(angles), np.sin(angles)
    cos_a[-1], sin_a[-1] = 1.0, 0.0  # the seam column closes exactly on the first one
    columns = AROUND_SEGMENTS + 1
    for strip in strips:
        for ring in strip:
            points.append(np.stack([ring.radius * cos_a, ring.radius * sin_a,
                                    np.full(columns, ring.height)], axis=1))
            normals.append(np.stack([ring.normal_radial * cos_a, ring.normal_radial * sin_a,
                                     np.full(columns, ring.normal_axial)], axis=1))
            uvs.append(np.stack([angles / (2.0 * math.pi), np.full(columns, ring.v)], axis=1))
        for ring_index in range(len(strip) - 1):
            below = vertex_count + ring_index * columns + np.arange(AROUND_SEGMENTS)
            above = below + columns
            # Quad (below j, below j+1, above j+1, above j) is counter-clockwise seen from
            # outside; a ring of radius 0 collapses one of its two triangles, which is skipped.
            if strip[ring_index].radius > 0.0:
                triangles.append(np.stack([below, below + 1, above + 1], axis=1))
            if strip[ring_index + 1].radius > 0.0:
                triangles.append(np.stack([below, above + 1, above], axis=1))
        vertex_count += len(strip) * columns
    rotation = _AXIS_FROM_Z.get(axis, np.eye(3))
    all_points = np.concatenate(points) @ rotation.T
    all_normals = np.concatenate(normals) @ rotation.T
    return _surface(all_points, np.concatenate(triangles), all_normals, np.concatenate(uvs))


def _cube(size: float) -> LocalSurface:
    """An axis-aligned cube of edge ``size``: 6 flat quads, uvs 0 → 1 on every face."""
    half = size / 2.0
    corner_uvs = np.array([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)])
    points, normals, uvs, triangles = [], [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            # u ⊥ normal and v = normal × u give u × v = normal, so the quad below is
            # counter-clockwise seen from outside.
            u_dir = np.roll(np.array([0.0, 1.0, 0.0]), axis) * sign
            v_dir = np.cross(normal, u_dir)
            base = len(points) * 4
            points.append(normal * half + np.outer(corner_uvs[:, 0] - 0.5, u_dir) * size
                          + np.outer(corner_uvs[:, 1] - 0.5, v_dir) * size)
            normals.append(np.tile(normal, (4, 1)))
            uvs.append(corner_uvs)
            triangles += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return _surface(np.concatenate(points), np.asarray(triangles), np.concatenate(normals),
                    np.concatenate(uvs))


def _plane(width: float, length: float, axis: str) -> LocalSurface:
    """A width × length rectangle facing +axis (UsdGeomPlane's width/length axis table)."""
    index = {"X": 0, "Y": 1, "Z": 2}.get(axis, 2)
    width_axis, length_axis = {0: (2, 1), 1: (0, 2), 2: (0, 1)}[index]
    normal = np.zeros(3)
    normal[index] = 1.0
    points = []
    uvs = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    for u, v in uvs:
        point = np.zeros(3)
        point[width_axis] = (u - 0.5) * width
        point[length_axis] = (v - 0.5) * length
        points.append(point)
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    # Axis X and Y tables give a clockwise quad seen from +axis: reverse it to face +axis.
    edge_normal = np.cross(points[1] - points[0], points[3] - points[0])
    if np.dot(edge_normal, normal) < 0.0:
        triangles = triangles[:, [0, 2, 1]]
    return _surface(np.asarray(points), triangles, np.tile(normal, (4, 1)), np.asarray(uvs))


def _surface(
    points: np.ndarray,
    triangles: np.ndarray,
    vertex_normals: np.ndarray,
    vertex_uvs: np.ndarray,
) -> LocalSurface:
    triangles = np.asarray(triangles, dtype=np.int64)
    return LocalSurface(
        points=np.asarray(points, dtype=np.float64),
        triangles=triangles,
        normals=np.asarray(vertex_normals, dtype=np.float64)[triangles],
        smooth=False,
        uvs=np.asarray(vertex_uvs, dtype=np.float64)[triangles],
        triangle_face=np.zeros(len(triangles), dtype=np.int64),
        face_count=1,
    )
