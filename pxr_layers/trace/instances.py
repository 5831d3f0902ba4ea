"""Hits through Embree instances and hits on moving rows, placed in scratch rows that every
stage reads as it reads a flat row.

A ray that hits a surface through an instance reports the prototype's row, in the
prototype's own space, and the instance (embree.RayCaster.intersect). The stages read a
hit through per-row tables: the World's, its GeometryArrays, and the tables built from them
(the event subjects, the light link groups, the curvature norms). So such a hit is
*placed*: its prototype row is written into a scratch row, transformed by the instance's
placement s·R + t (positions by it, normals and directions by R, areas ×s², curvatures and
texture gradients ÷s; the subject and link group are the instance's own), and the hit names
that row from then on. A hit on a moving row (World.moving_first on; instance
embree.MOVING) is placed alike from the row's tables at the two time steps around the
ray's time, interpolated as Embree interpolates its vertices (linearly: positions, hence
the geometric normal and area, exactly; shading normals, curvatures and texture gradients
interpolated and renormalised). A hit on a strand (a curve's tube or a point's sphere;
instance embree.STRAND − segment) is placed as a small triangle in the tangent plane at the
hit point, which is its centroid (the hit's barycentrics become 1/3, 1/3), facing Embree's
normal there, its first corner along the curve's tangent (surface.fibre_direction reads
it): its shading normal that normal, its curvatures a tube's (1/r around, 0 along the
curve, r the curve's radius at the hit), a sphere's (1/r both ways) or a flat ribbon's (0),
its texture coordinates the hit's (u, v), its thickness (GeometryArrays) the diameter.
Downstream, nothing tells it from a flat row, and a scene without instances, motion or
strands pays nothing.

The scratch rows are per tracing thread and per use: a :class:`Slot` (one per thread at a
time, :meth:`InstanceRows.slot`) holds REGIONS regions of ``lanes`` rows, and lane j of a
query writes row ``region start + j``. A path's hits alternate between two regions with the
bounce, because the row of a path's previous vertex is read again at the next bounce
(emission's MIS density, light linking); shadow rays crossing surfaces write the third.
"""

from __future__ import annotations

import math
import queue
from contextlib import contextmanager
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from ..compiled import inline, kernel, scratch
from .embree import MOVING, STRAND
from .world import BEZIER, BSPLINE, LINEAR, GeometryArrays, MovingSteps, StrandTables, World

PATH_EVEN, PATH_ODD, SHADOW = range(3)
REGIONS = 3
MAX_SLOTS = 16
"""Slots of scratch rows at most: threads beyond that many wait for one (the rows cost about
REGIONS × lanes × 0.4 kB a slot)."""


class RowTables(NamedTuple):
    """Every per-row table a stage reads at a hit (what a placed row must hold): the
    GeometryArrays (triangle-major), the World's component-major tables (the fields named
    as the World's attributes, :meth:`of`), and the frame's tables built from them. subject:
    (rows,) int64 the event subject (render.prepare); curvature: (rows,) float32 C, or (0,)
    without covariance; link_group: (rows,) int32, or (0,) without light linking."""

    geometry: GeometryArrays
    geometric_normal: np.ndarray
    corner_positions: np.ndarray
    corner_normals: np.ndarray
    corner_uvs: np.ndarray
    corner_primvars: np.ndarray
    curvature_k1: np.ndarray
    curvature_k2: np.ndarray
    principal_direction: np.ndarray
    gradient_s: np.ndarray
    gradient_t: np.ndarray
    triangle_object: np.ndarray
    subject: np.ndarray
    curvature: np.ndarray
    link_group: np.ndarray

    @classmethod
    def of(cls, world: World, geometry: GeometryArrays, subject: np.ndarray, curvature: np.ndarray,
           link_group: np.ndarray) -> RowTables:
        """The tables of `world` (each field that is not an argument here is the World's
        attribute of its name)."""
        frame = {"geometry": geometry, "subject": subject, "curvature": curvature, "link_group": link_group}
        return cls(**frame, **{name: getattr(world, name) for name in cls._fields if name not in frame})


class InstanceTables(NamedTuple):
    """Per instance (i,): transform (i, 3, 4) float32, rotation (i, 3, 3) float32, scale (i,)
    float32 (World.instance_*), object (i,) int32, subject_first (i,) int64 its first event
    subject, link_group (i,) int32 ((0,) without light linking); per row, subject_rank (rows,)
    int64: a prototype row's material among its prototype's distinct materials (the
    instance's subjects are subject_first + rank); motion_index (i,) int32 and motion (m, k,
    3, 4) float32: the moving instances' placements at each time step (World.instance_motion*);
    moving: the World's moving rows at each time step, moving_first their first row;
    strands: the World's StrandTables, strand_first the first strand row."""

    transform: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray
    object: np.ndarray
    subject_first: np.ndarray
    link_group: np.ndarray
    subject_rank: np.ndarray
    motion_index: np.ndarray
    motion: np.ndarray
    moving: MovingSteps
    moving_first: int
    strands: StrandTables
    strand_first: int

    @classmethod
    def of(cls, world: World, subject_first: np.ndarray, subject_rank: np.ndarray,
           object_link_group: np.ndarray) -> InstanceTables:
        """The instances of `world`; object_link_group (objects,) int32, (0,) without linking."""
        link_group = object_link_group[world.instance_object] if len(object_link_group) else object_link_group
        return cls(world.instance_transform, world.instance_rotation, world.instance_scale, world.instance_object,
                   subject_first, link_group.astype(np.int32), subject_rank, world.instance_motion_index,
                   world.instance_motion, world.moving_steps or MovingSteps.empty(), world.moving_first,
                   world.strands or StrandTables.of(()), world.strand_first)


class InstanceRows:
    """The scratch rows of a World with instances, and who may write which.

    world    : built with ``scratch_rows = rows_needed(lanes, slots)`` scratch rows
    lanes    : the most lanes one query places (a batch's paths)
    """

    def __init__(self, world: World, rows: RowTables, instances: InstanceTables, lanes: int, slots: int):
        if len(world.area) - world.scratch_first < rows_needed(lanes, slots):
            raise ValueError(f"the world has {len(world.area) - world.scratch_first} scratch rows, "
                             f"{rows_needed(lanes, slots)} needed")
        self.rows, self.instances, self.lanes = rows, instances, lanes
        self._free: queue.SimpleQueue[int] = queue.SimpleQueue()
        for slot in range(slots):
            self._free.put(world.scratch_first + slot * REGIONS * lanes)

    @contextmanager
    def slot(self) -> Iterator[Slot]:
        """A slot of scratch rows for this thread's queries, until the block ends (waits for
        one when every slot is taken)."""
        first = self._free.get()
        try:
            yield Slot(self, first)
        finally:
            self._free.put(first)


def rows_needed(lanes: int, slots: int) -> int:
    return slots * REGIONS * lanes


class Slot:
    """One thread's scratch rows: :meth:`region` names where a query's hits go."""

    def __init__(self, owner: InstanceRows, first: int):
        self._owner, self._first = owner, first

    def region(self, use: int) -> Region:
        """PATH_EVEN / PATH_ODD (a path's hits at even / odd steps) or SHADOW."""
        return Region(self._owner, self._first + use * self._owner.lanes)

    def path_region(self, step: int) -> Region:
        return self.region(PATH_ODD if step % 2 else PATH_EVEN)


class Region:
    """``lanes`` consecutive scratch rows: lane j of a query placed here writes row first + j."""

    def __init__(self, owner: InstanceRows, first: int):
        self._owner, self.first = owner, first

    def place(self, triangle: np.ndarray, instance: np.ndarray, time: np.ndarray,
              lanes: np.ndarray | None = None, strand_hits: StrandHits | None = None) -> None:
        """Place the instanced, moving and strand hits among `triangle` (n,) int32 (World
        rows, changed in place to their scratch rows) with `instance` (n,) int32 (−1: none of
        them; embree.MOVING: a moving row; embree.STRAND − k: a strand) at `time` (n,) float32
        (shutter fractions, the rays'); entry j is lane ``lanes[j]`` (int64; None: lane j).
        strand_hits: the rays and hits, which strand hits are placed from (their u, v are
        set to the placed triangle's); None in a world without strands."""
        owner = self._owner
        if lanes is None:
            lanes = np.arange(len(triangle), dtype=np.int64)
        if len(lanes) and int(lanes.max()) >= owner.lanes:
            raise ValueError(f"a query of lane {int(lanes.max())} places hits in regions of {owner.lanes} rows")
        hits = strand_hits or StrandHits.none()
        _place_kernel(owner.rows, owner.instances, triangle, instance, np.ascontiguousarray(time, np.float32), lanes,
                      self.first, scratch(3, 4), scratch(3, 3), scratch(4, 4), hits)


class StrandHits(NamedTuple):
    """What a strand hit is placed from, per entry (n,): origin, direction (n, 3) float32 its
    ray, t (n,) float32 the hit's distance, normal (n, 3) float32 Embree's normal there
    (RayCaster.intersect), u, v (n,) float32 its parameters (written: 1/3 on strand hits)."""

    origin: np.ndarray
    direction: np.ndarray
    t: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @classmethod
    def none(cls) -> StrandHits:
        vectors, scalars = np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        return cls(vectors, vectors, scalars, vectors, scalars, scalars)


@kernel
def _place_kernel(rows, instances, triangle, instance, time, lanes, first, transform, rotation, control, hits):
    """transform (3, 4), rotation (3, 3): float64 scratch, the instance's placement at the
    ray's time (its own when it stands still); control (4, 4) float64 scratch, a moving
    strand segment's control points at the ray's time."""
    geometry = rows.geometry
    has_curvature, has_links = len(rows.curvature) > 0, len(rows.link_group) > 0
    for entry in range(len(triangle)):
        k = instance[entry]
        source = triangle[entry]
        if source < 0 or (k < 0 and k != MOVING and k > STRAND):
            continue
        row = first + lanes[entry]
        if k <= STRAND:
            _place_strand(rows, instances, source, STRAND - k, row, hits, entry, time[entry], control)
            triangle[entry] = row
            continue
        if k == MOVING:
            _place_moving(rows, instances, source, row, time[entry])
            triangle[entry] = row
            continue
        if instances.motion_index[k] >= 0:
            scale = _placement_at(instances.motion[instances.motion_index[k]], time[entry], transform, rotation)
        else:
            scale = instances.scale[k]
            for axis in range(3):
                for column in range(3):
                    transform[axis, column] = instances.transform[k, axis, column]
                    rotation[axis, column] = instances.rotation[k, axis, column]
                transform[axis, 3] = instances.transform[k, axis, 3]
        for corner in range(3):
            for axis in range(3):
                position = transform[axis, 3]
                normal = 0.0
                for column in range(3):
                    position += transform[axis, column] * geometry.corner_positions[source, corner, column]
                    normal += rotation[axis, column] * geometry.corner_normals[source, corner, column]
                geometry.corner_positions[row, corner, axis] = position
                geometry.corner_normals[row, corner, axis] = normal
                rows.corner_positions[corner, axis, row] = position
                rows.corner_normals[corner, axis, row] = normal
            _copy_corner_values(rows, source, row, corner)
        for axis in range(3):
            normal = principal = along_s = along_t = 0.0
            for column in range(3):
                normal += rotation[axis, column] * geometry.geometric_normal[source, column]
                principal += rotation[axis, column] * rows.principal_direction[column, source]
                along_s += rotation[axis, column] * rows.gradient_s[column, source]
                along_t += rotation[axis, column] * rows.gradient_t[column, source]
            geometry.geometric_normal[row, axis] = normal
            rows.geometric_normal[axis, row] = normal
            rows.principal_direction[axis, row] = principal
            rows.gradient_s[axis, row] = along_s / scale
            rows.gradient_t[axis, row] = along_t / scale
        geometry.area[row] = geometry.area[source] * scale * scale
        geometry.thickness[row] = geometry.thickness[source] * scale
        geometry.triangle_material[row] = geometry.triangle_material[source]
        geometry.triangle_light[row] = -1
        rows.curvature_k1[row] = rows.curvature_k1[source] / scale
        rows.curvature_k2[row] = rows.curvature_k2[source] / scale
        rows.triangle_object[row] = instances.object[k]
        rows.subject[row] = instances.subject_first[k] + instances.subject_rank[source]
        if has_curvature:
            rows.curvature[row] = rows.curvature[source] / scale
        if has_links:
            rows.link_group[row] = instances.link_group[k]
        triangle[entry] = row


@inline
def _copy_corner_values(rows, source, row, corner):
    """Copy corner `corner`'s texture coordinates and primvars from row `source` to row `row`."""
    geometry = rows.geometry
    for axis in range(2):
        geometry.corner_uvs[row, corner, axis] = geometry.corner_uvs[source, corner, axis]
        rows.corner_uvs[corner, axis, row] = geometry.corner_uvs[source, corner, axis]
    for column in range(geometry.corner_primvars.shape[2]):
        geometry.corner_primvars[row, corner, column] = geometry.corner_primvars[source, corner, column]
        rows.corner_primvars[corner, column, row] = geometry.corner_primvars[source, corner, column]


@inline
def _time_step(count, time):
    """(step, b): of `count` ≥ 2 evenly spaced time steps over the shutter, the one at or
    before `time` (a shutter fraction, clamped to [0, 1]) and the weight of the next one, as
    Embree interpolates between them."""
    last = count - 1
    position = min(max(time, 0.0), 1.0) * last
    step = min(int(position), last - 1)
    return step, position - step


@inline
def _curve_at(vertices, first, basis, u):
    """(radius, ∂P/∂u x, y, z) of the segment whose control points start at vertices[first]
    (x, y, z, radius rows) at parameter u ∈ [0, 1], in its basis (world.STRAND_SHAPES codes),
    as Embree evaluates the curve."""
    if basis == LINEAR:
        return (vertices[first, 3] + u * (vertices[first + 1, 3] - vertices[first, 3]),
                vertices[first + 1, 0] - vertices[first, 0], vertices[first + 1, 1] - vertices[first, 1],
                vertices[first + 1, 2] - vertices[first, 2])
    v, uu = 1.0 - u, u * u
    if basis == BEZIER:
        w0, w1, w2, w3 = v * v * v, 3.0 * u * v * v, 3.0 * uu * v, uu * u
        d0, d1, d2, d3 = -3.0 * v * v, 3.0 * v * v - 6.0 * u * v, 6.0 * u * v - 3.0 * uu, 3.0 * uu
    elif basis == BSPLINE:
        w0, w1 = v * v * v / 6.0, (3.0 * uu * u - 6.0 * uu + 4.0) / 6.0
        w2, w3 = (-3.0 * uu * u + 3.0 * uu + 3.0 * u + 1.0) / 6.0, uu * u / 6.0
        d0, d1, d2, d3 = -0.5 * v * v, 1.5 * uu - 2.0 * u, -1.5 * uu + u + 0.5, 0.5 * uu
    else:  # catmullRom
        w0, w1 = 0.5 * (-uu * u + 2.0 * uu - u), 0.5 * (3.0 * uu * u - 5.0 * uu + 2.0)
        w2, w3 = 0.5 * (-3.0 * uu * u + 4.0 * uu + u), 0.5 * (uu * u - uu)
        d0, d1 = 0.5 * (-3.0 * uu + 4.0 * u - 1.0), 0.5 * (9.0 * uu - 10.0 * u)
        d2, d3 = 0.5 * (-9.0 * uu + 8.0 * u + 1.0), 0.5 * (3.0 * uu - 2.0 * u)
    radius = x = y = z = 0.0
    for k in range(4):
        weight, slope = (w0, w1, w2, w3)[k], (d0, d1, d2, d3)[k]
        radius += weight * vertices[first + k, 3]
        x += slope * vertices[first + k, 0]
        y += slope * vertices[first + k, 1]
        z += slope * vertices[first + k, 2]
    return radius, x, y, z


@inline
def _place_strand(rows, instances, source, segment, row, hits, entry, time, control):
    """Write the hit `entry` of `hits` on segment `segment` of strand row `source` into
    scratch row `row` (the module docstring); a moving strand as it is at `time` (a shutter
    fraction), its segment's control points interpolated into `control` (4, 4) as Embree
    interpolates them."""
    geometry, strands = rows.geometry, instances.strands
    local = source - instances.strand_first
    span = strands.span[local]
    first = strands.segments[strands.segment_first[local] + segment]
    t = hits.t[entry]
    nx, ny, nz = hits.normal[entry, 0], hits.normal[entry, 1], hits.normal[entry, 2]
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx / length, ny / length, nz / length
    moving, step, b = strands.motion, 0, 0.0
    start = strands.motion_first[local]
    if start >= 0:
        step, b = _time_step(moving.shape[0], time)
        start += first - strands.vertex_first[local]
    for k in range(span + 1):
        for column in range(4):
            if start >= 0:
                control[k, column] = (1.0 - b) * moving[step, start + k, column] + b * moving[step + 1, start + k, column]
            else:
                control[k, column] = strands.vertices[first + k, column]
    radius = control[0, 3]
    if span > 0:  # a tube: the curve's radius and tangent at the hit's parameter
        radius, ax, ay, az = _curve_at(control, 0, strands.basis[local], hits.u[entry])
    else:
        ax, ay, az = (1.0, 0.0, 0.0) if abs(nx) < 0.9 else (0.0, 1.0, 0.0)
    along = ax * nx + ay * ny + az * nz  # the tangent without its normal part
    ax, ay, az = ax - along * nx, ay - along * ny, az - along * nz
    length = math.sqrt(ax * ax + ay * ay + az * az)
    if length == 0.0:
        ax, ay, az = (1.0, 0.0, 0.0) if abs(nx) < 0.9 else (0.0, 1.0, 0.0)
        along = ax * nx + ay * ny + az * nz
        ax, ay, az = ax - along * nx, ay - along * ny, az - along * nz
        length = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / length, ay / length, az / length
    bx, by, bz = ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax  # around the tube: n × a
    size = 0.01 * radius if radius > 0 else 1e-6
    for corner in range(3):
        angle = 2.0 * math.pi * corner / 3.0  # counter-clockwise about n: a, then b (b = n × a)
        ca, cb = size * math.cos(angle), size * math.sin(angle)
        for axis in range(3):
            value = (hits.origin[entry, axis] + t * hits.direction[entry, axis]
                     + ca * (ax, ay, az)[axis] + cb * (bx, by, bz)[axis])
            geometry.corner_positions[row, corner, axis] = value
            rows.corner_positions[corner, axis, row] = value
            normal = (nx, ny, nz)[axis]
            geometry.corner_normals[row, corner, axis] = normal
            rows.corner_normals[corner, axis, row] = normal
        for axis in range(2):
            value = (hits.u[entry], hits.v[entry])[axis]
            geometry.corner_uvs[row, corner, axis] = value
            rows.corner_uvs[corner, axis, row] = value
        for column in range(geometry.corner_primvars.shape[2]):
            geometry.corner_primvars[row, corner, column] = 0.0
            rows.corner_primvars[corner, column, row] = 0.0
    for axis in range(3):
        normal = (nx, ny, nz)[axis]
        geometry.geometric_normal[row, axis] = normal
        rows.geometric_normal[axis, row] = normal
        rows.principal_direction[axis, row] = (bx, by, bz)[axis]
        rows.gradient_s[axis, row] = 0.0
        rows.gradient_t[axis, row] = 0.0
    geometry.area[row] = 0.75 * math.sqrt(3.0) * size * size
    geometry.triangle_material[row] = geometry.triangle_material[source]
    geometry.triangle_light[row] = -1
    curvature = 1.0 / radius if radius > 0 else 0.0
    geometry.thickness[row] = 2.0 * radius
    if strands.ribbon[local]:
        curvature = 0.0  # a flat ribbon
        geometry.thickness[row] = 0.0
    rows.curvature_k1[row] = curvature
    rows.curvature_k2[row] = curvature if span == 0 else 0.0
    rows.triangle_object[row] = rows.triangle_object[source]
    rows.subject[row] = rows.subject[source]
    if len(rows.curvature) > 0:
        rows.curvature[row] = curvature  # C = max(|k1|, |k2|) (bounce_norms.py)
    if len(rows.link_group) > 0:
        rows.link_group[row] = rows.link_group[source]
    hits.u[entry] = hits.v[entry] = 1.0 / 3.0


@inline
def _placement_at(steps, time, transform, rotation):
    """Write into transform (3, 4) the placement at `time` (a shutter fraction) between the
    (k, 3, 4) `steps` around it, linearly as Embree interpolates them, and into rotation
    (3, 3) its linear part over its scale s = |det|^(1/3), which it returns."""
    step, b = _time_step(steps.shape[0], time)
    for axis in range(3):
        for column in range(4):
            transform[axis, column] = (1.0 - b) * steps[step, axis, column] + b * steps[step + 1, axis, column]
    determinant = (transform[0, 0] * (transform[1, 1] * transform[2, 2] - transform[1, 2] * transform[2, 1])
                   - transform[0, 1] * (transform[1, 0] * transform[2, 2] - transform[1, 2] * transform[2, 0])
                   + transform[0, 2] * (transform[1, 0] * transform[2, 1] - transform[1, 1] * transform[2, 0]))
    scale = abs(determinant) ** (1.0 / 3.0)
    inverse = 1.0 / scale if scale > 0 else 0.0
    for axis in range(3):
        for column in range(3):
            rotation[axis, column] = transform[axis, column] * inverse
    return scale


@inline
def _place_moving(rows, instances, source, row, time):
    """Write moving row `source` at `time` (a shutter fraction) into scratch row `row`."""
    geometry, steps = rows.geometry, instances.moving
    local = source - instances.moving_first
    step, b = _time_step(steps.area.shape[0], time)
    a = 1.0 - b
    for corner in range(3):
        length = 0.0
        for axis in range(3):
            value = a * steps.corner_positions[step, local, corner, axis] + b * steps.corner_positions[step + 1, local, corner, axis]
            geometry.corner_positions[row, corner, axis] = value
            rows.corner_positions[corner, axis, row] = value
            normal = a * steps.corner_normals[step, local, corner, axis] + b * steps.corner_normals[step + 1, local, corner, axis]
            geometry.corner_normals[row, corner, axis] = normal
            length += normal * normal
        scale = 1.0 / math.sqrt(length) if length > 0 else 0.0
        for axis in range(3):
            geometry.corner_normals[row, corner, axis] *= scale
            rows.corner_normals[corner, axis, row] = geometry.corner_normals[row, corner, axis]
        _copy_corner_values(rows, source, row, corner)
    # The geometric normal and area of the interpolated corners: the triangle Embree hit.
    p = geometry.corner_positions[row]
    ex, ey, ez = p[1, 0] - p[0, 0], p[1, 1] - p[0, 1], p[1, 2] - p[0, 2]
    fx, fy, fz = p[2, 0] - p[0, 0], p[2, 1] - p[0, 1], p[2, 2] - p[0, 2]
    nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
    double_area = math.sqrt(nx * nx + ny * ny + nz * nz)
    inverse = 1.0 / double_area if double_area > 0 else 0.0
    geometry.area[row] = 0.5 * double_area
    geometry.thickness[row] = 0.0
    for axis, value in ((0, nx), (1, ny), (2, nz)):
        geometry.geometric_normal[row, axis] = value * inverse
        rows.geometric_normal[axis, row] = value * inverse
    length = 0.0
    for axis in range(3):
        principal = a * steps.principal_direction[step, local, axis] + b * steps.principal_direction[step + 1, local, axis]
        rows.principal_direction[axis, row] = principal
        length += principal * principal
        rows.gradient_s[axis, row] = a * steps.gradient_s[step, local, axis] + b * steps.gradient_s[step + 1, local, axis]
        rows.gradient_t[axis, row] = a * steps.gradient_t[step, local, axis] + b * steps.gradient_t[step + 1, local, axis]
    scale = 1.0 / math.sqrt(length) if length > 0 else 0.0
    for axis in range(3):
        rows.principal_direction[axis, row] *= scale
    geometry.triangle_material[row] = geometry.triangle_material[source]
    geometry.triangle_light[row] = -1
    rows.curvature_k1[row] = a * steps.curvature_k1[step, local] + b * steps.curvature_k1[step + 1, local]
    rows.curvature_k2[row] = a * steps.curvature_k2[step, local] + b * steps.curvature_k2[step + 1, local]
    rows.triangle_object[row] = rows.triangle_object[source]
    rows.subject[row] = rows.subject[source]
    if len(rows.curvature) > 0:
        rows.curvature[row] = rows.curvature[source]
    if len(rows.link_group) > 0:
        rows.link_group[row] = rows.link_group[source]
