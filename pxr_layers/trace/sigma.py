"""The whole 4×4 covariance Σ of every recorded contribution's first N events.

With ``TraceSettings.record_sigma`` the path recorder (recorder.py) keeps, beside each
event's norms row, the world-space data of that vertex (``SigmaVertices``) and, per record,
its light end (``SigmaLightEnds``). When the batch ends, :func:`record_sigma` runs the
world-space covariance chain of ``covariance/path.py`` for every record: each record is its
own chain from its light end (an emitter hit after vertex k, or a next-event connection at
vertex k) through vertex k, k−1, ..., 1, vectorised over all records of the same depth.

What a record gets (``Contributions.sigma``)
--------------------------------------------
(r, N, 10) float32: for events 1..N after the camera (camera-first, the slots of
``Contributions.norms``), the upper triangle of Σ LEAVING the event's vertex toward the eye
(after the inverse projection, before the travel: ``PathCovariance.leaving``), row-major
xx xy xu xv yy yu yv uu uv vv (``covariance.PACKED_ENTRY_NAMES``). Amplitude convention of
the ``pxr_layers.covariance`` docstring: cycles²/m² (spatial), cycles²/rad² (angular),
cycles²/(m·rad) mixed. Zeros past the path's last event and for pass-through (cut-out) and
light events, which apply no operator.

The frame (ẑ, x̂, ŷ) of each Σ is right-handed, ŷ = ẑ × x̂:

* ẑ = ω_o, the direction from the vertex toward the eye (the previous vertex or the camera);
* x̂ ⟂ the plane of ω_o and the shading normal n at the vertex, i.e. along ±(n × ω_o): a
  tangent direction of the surface, the axis across which the view is NOT foreshortened;
* ŷ = ω_o × x̂ lies in the plane of (ω_o, n), the axis the inverse projection stretches by
  1/|cos θo| (so a texture seen obliquely has its ŷ frequencies raised by 1/cos θo).

The sign of x̂ depends on the path's history (path.py carries it), but flipping x̂ in a
right-handed frame flips ŷ too, and Σ is unchanged by (x, y, u, v) → −(x, y, u, v): every
entry is well defined. When ω_o is along n (a vertex seen exactly head-on) the plane is
undefined and x̂ is the arriving frame's x̂ turned into the tangent plane (path.py step 5).

Vertices, lobes and emitters
----------------------------
* Each scattering vertex is a ``path.SurfaceVertex``: ω_o, the shading normal (turned
  toward ω_o, as the tracer shades), the triangle's principal curvatures and direction
  (``World``), the texture block of the albedo texture in its own uv with the world
  gradients of that uv (``BounceNorms.uv_texture``, looked up with the ray-cone footprint
  that T used), the distance to the eye-side vertex along the path (through any cut-outs),
  and transmit for refracted events.
* The lobe's bandwidth is b = R² (R the event's stored reflectance norm, ``bounce_norms``):
  0 for diffuse, 1/(4π²α²) for GGX lobes; singular lobes (R = SINGULAR_REFLECTANCE: perfect
  mirrors, smooth glass) get b = inf, a perfect mirror for the chain.
* Emitters (``EmitterTable``): rect lights and emissive mesh triangles are square area
  lights (``area_light_covariance``, "square") of the whole light's (or the emitting
  object's) world area, foreshortened by the geometric normal of the triangle reached;
  disk lights are disks; sphere and cylinder lights are replaced by the disk of their mean
  silhouette, area/4 (Cauchy's formula: exact for a sphere, the average over directions
  for a cylinder), facing the ray. Point (``treatAsPoint``) and line (``treatAsLine``)
  lights are point emitters of extent ``POINT_LIGHT_EXTENT`` (a line's length is ignored).
  Distant lights fill their cone (``distant_light_covariance``, half-angle acos(cos_max));
  delta ones get ``DIRECTIONAL_LIGHT_EXTENT``. Domes are uniform (Σ = 0): a dome texture's
  spectrum is not included. Light shaping (spot cones, focus, IES profiles) and rect light
  textures change the emitted radiance with direction or position but their spectra are
  not included either: the emitter's Σ is that of the unshaped shape.
* The distance of a next-event connection is its shadow ray's span (between the ray's
  ends, each lifted off its surface by the tracer's epsilon); an emitter hit's is measured
  along the path to the emitting triangle's plane.

Memory: 11 float32 and one int32 per event row and 6 per record (when on); nothing when off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..covariance import pack_upper
from ..covariance.path import (
    SurfaceVertex,
    area_light_covariance,
    distant_light_covariance,
    dome_covariance,
    path_covariance,
)
from ..lpe.conditions import SIGMA_ENTRY_COUNT
from ..scene import FLOAT
from .bounce_norms import SINGULAR_REFLECTANCE, BounceNorms
from .lights import LightSampler
from .stages.next_event import SHADOW_SPAN
from .stages.queues import T_INFINITY
from .world import World


# Columns of SigmaVertices.values.
TRAVELLED = 0  # metres from the camera along the path to the vertex
FOOTPRINT = 1  # metres: the ray cone's width the texture was looked up with
TOWARD_EYE = 2  # 3 columns: unit ω_o, world space
NORMAL = 5  # 3 columns: the shading normal, toward ω_o
ST = 8  # 2 columns: the mesh's st at the hit
KIND = 10  # PASS, REFLECT or TRANSMIT
VERTEX_FIELDS = 11
PASS, REFLECT, TRANSMIT = 0.0, 1.0, 2.0

# Emitter kinds (EmitterTable.kind).
SQUARE, DISK, SILHOUETTE, POINT, DISTANT, DOME = range(6)
# A light's triangles whose normals agree to this make a planar light (rect, disk).
_PLANAR_TOLERANCE = 1e-4


@dataclass(frozen=True)
class SigmaInputs:
    """What the recorder needs of the frame to compute Σ (shared read-only by threads).

    ray_cone : the camera's ray cone (Integrator.ray_cone)."""

    world: World
    lights: LightSampler
    bounce_norms: BounceNorms
    ray_cone: RayCone


@dataclass(frozen=True)
class RayCone:
    """How wide a camera sample's ray bundle is at a distance t travelled along its path: a
    pixel's angle times t, plus a lens's defocus, the width 2·lens_radius·|1 − t/focus| of
    the cone of rays through the lens that converge on the plane in focus (0 for a pinhole).

    pixel_angle : radians per pixel (the film window's width over its pixels)
    lens_radius, focus_distance : metres (ThinLensCamera's)
    """

    pixel_angle: float
    lens_radius: float = 0.0
    focus_distance: float = 0.0

    def footprint(self, travelled: np.ndarray, cos_out: np.ndarray) -> np.ndarray:
        """The footprint (n,) float32 metres the texture is looked up with, for T
        (Integrator.trace) and for Σ's texture block alike: the bundle's width at
        `travelled` (n,) over max(|cos θo|, 0.05)."""
        width = travelled * np.float32(self.pixel_angle)
        if self.lens_radius > 0:
            width = width + np.float32(2 * self.lens_radius) * np.abs(1 - travelled / np.float32(self.focus_distance))
        return width / np.maximum(np.abs(cos_out), 0.05)


class SigmaVertices:
    """Per event row (parallel to ``EventNorms`` rows): values (rows, VERTEX_FIELDS) float32
    (columns above) and triangle (rows,) int32."""

    def __init__(self, capacity: int) -> None:
        self.values = np.zeros((capacity, VERTEX_FIELDS), FLOAT)
        self.triangle = np.zeros(capacity, np.int32)

    def _room(self, size: int) -> None:
        if size > len(self.triangle):
            capacity = max(size, 2 * len(self.triangle))
            self.values = _grown(self.values, capacity)
            self.triangle = _grown(self.triangle, capacity)

    def add(self, first_row: int, lanes: np.ndarray, travelled: np.ndarray, surfaces, kind: np.ndarray,
            ray_cone: RayCone) -> None:
        """Rows first_row, first_row + 1, ... for the SurfaceQueue lanes `lanes` (k,), in order;
        travelled (n,) the PathQueue's; kind (k,) PASS / REFLECT / TRANSMIT."""
        stop = first_row + len(lanes)
        self._room(stop)
        rows = self.values[first_row:stop]
        frame = surfaces.frame[lanes]  # (k, 3, 3) rows tangent, bitangent, normal
        wo = surfaces.wo[lanes]
        rows[:, TRAVELLED] = travelled[lanes]
        rows[:, FOOTPRINT] = ray_cone.footprint(travelled[lanes], wo[:, 2])
        rows[:, TOWARD_EYE:TOWARD_EYE + 3] = np.einsum("ki,kij->kj", wo, frame)
        rows[:, NORMAL:NORMAL + 3] = frame[:, 2]
        rows[:, ST:ST + 2] = surfaces.st[lanes]
        rows[:, KIND] = kind
        self.triangle[first_row:stop] = surfaces.triangle[lanes]


class SigmaLightEnds:
    """Per record (parallel to ``RecordBuffer``): light (r,) int32 (−1: an emissive surface),
    triangle (r,) int32 (−1: distant, dome, point), direction (r, 3) float32 unit, the
    propagation direction from the light toward the vertex it reaches, distance (r,)
    float32 metres (inf for distant lights and domes)."""

    def __init__(self, capacity: int) -> None:
        self.light = np.zeros(capacity, np.int32)
        self.triangle = np.zeros(capacity, np.int32)
        self.direction = np.zeros((capacity, 3), FLOAT)
        self.distance = np.zeros(capacity, FLOAT)

    def add(self, first: int, light: np.ndarray, triangle: np.ndarray, direction: np.ndarray,
            distance: np.ndarray) -> None:
        stop = first + len(light)
        if stop > len(self.light):
            capacity = max(stop, 2 * len(self.light))
            for name in ("light", "triangle", "direction", "distance"):
                setattr(self, name, _grown(getattr(self, name), capacity))
        self.light[first:stop], self.triangle[first:stop] = light, triangle
        self.direction[first:stop], self.distance[first:stop] = direction, distance

    def first(self, count: int) -> SigmaLightEnds:
        """The ends of the first `count` records (views)."""
        ends = SigmaLightEnds(0)
        ends.light, ends.triangle = self.light[:count], self.triangle[:count]
        ends.direction, ends.distance = self.direction[:count], self.distance[:count]
        return ends


def shadow_distance(t_max: np.ndarray) -> np.ndarray:
    """Distance of next-event connections from their shadow rays' t_max (the span between
    the ray's offset ends): inf for rays that go on forever (distant lights, domes)."""
    return np.where(t_max >= T_INFINITY, np.float32(np.inf), t_max / np.float32(SHADOW_SPAN))


def emitter_hit_distance(world: World, triangle: np.ndarray, origin: np.ndarray, direction: np.ndarray,
                         since_vertex: np.ndarray) -> np.ndarray:
    """Metres from the last scattering vertex to emitting triangles a path's rays hit:
    `since_vertex` (k,) travelled since that vertex (through cut-outs) plus the ray's
    distance from `origin` (k, 3) along `direction` (k, 3) to the triangle's plane; inf
    where triangle < 0 (an escaped ray)."""
    hit = triangle >= 0
    tri = np.where(hit, triangle, 0)
    normal = world.geometric_normal[:, tri].T.astype(np.float64)
    corner = world.corner_positions[0][:, tri].T.astype(np.float64)
    along = np.einsum("ki,ki->k", direction.astype(np.float64), normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ki,ki->k", corner - origin, normal) / along
    t = np.where(np.isfinite(t), np.abs(t), 0.0)
    return np.where(hit, since_vertex + t, np.inf).astype(FLOAT)


class EmitterTable:
    """How each light (and emissive object) is seen as an emitter (module docstring).

    kind (lights,) int64 SQUARE / DISK / SILHOUETTE / POINT / DISTANT / DOME; area (lights,)
    m² (world area of a light's shape; SILHOUETTE: its mean silhouette); angular_radius
    (lights,) radians (DISTANT); object_area (objects,) m² the emitting area of each object
    (emissive meshes)."""

    def __init__(self, world: World, lights: LightSampler) -> None:
        arrays = lights.arrays
        count = len(arrays.emission.radiance)
        self.kind = np.full(count, POINT, np.int64)
        self.area = np.zeros(count)
        self.angular_radius = np.zeros(count)
        shape = world.triangle_light >= 0
        owner = world.triangle_light[shape]
        area = world.area[shape].astype(np.float64)
        self.area = np.bincount(owner, weights=area, minlength=count)[:count]
        triangles = np.bincount(owner, minlength=count)[:count]
        normals = world.geometric_normal[:, shape].astype(np.float64)
        first = np.full(count, -1, np.int64)
        first[owner[::-1]] = np.arange(len(owner))[::-1]  # each light's first shape triangle
        for light in np.flatnonzero(triangles):
            mine = owner == light
            planar = np.all(np.einsum("in,i->n", normals[:, mine], normals[:, first[light]]) > 1 - _PLANAR_TOLERANCE)
            if planar:
                self.kind[light] = SQUARE if triangles[light] == 2 else DISK  # world.light_shape: a rect is 2
            else:
                self.kind[light] = SILHOUETTE
                self.area[light] /= 4.0
        self.kind[arrays.distant_light] = DISTANT
        self.angular_radius[arrays.distant_light] = np.arccos(np.clip(arrays.distant_cos_max, -1.0, 1.0))
        self.kind[arrays.dome_light] = DOME
        surface = lights.triangle_emits & ~shape
        self.object_area = np.bincount(world.triangle_object[surface], weights=world.area[surface],
                                       minlength=len(world.object_names))

    def covariance(self, world: World, light: np.ndarray, triangle: np.ndarray, direction: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Σ (n, 4, 4) leaving the emitters of n records and its frame's x̂ (3, n); light,
        triangle (n,) as SigmaLightEnds, direction (3, n) propagation from the light."""
        n = len(light)
        sigma, x_axis = np.zeros((n, 4, 4)), np.zeros((3, n))
        surface = light < 0
        # an emissive surface's record is a square of its object's area (a stage may have no light)
        kind = np.full(n, SQUARE, self.kind.dtype)
        area = self.object_area[world.triangle_object[np.maximum(triangle, 0)]]
        kind[~surface], area[~surface] = self.kind[light[~surface]], self.area[light[~surface]]
        for code in np.unique(kind):
            lanes = np.flatnonzero(kind == code)
            toward = direction[:, lanes]
            if code in (SQUARE, DISK):
                normal = world.geometric_normal[:, np.maximum(triangle[lanes], 0)]
                part = area_light_covariance(area[lanes], toward, normal, "square" if code == SQUARE else "disk")
            elif code == SILHOUETTE:
                part = area_light_covariance(area[lanes], toward, None, "disk")
            elif code == POINT:
                part = area_light_covariance(0.0, toward)
            elif code == DISTANT:
                part = distant_light_covariance(self.angular_radius[light[lanes]], toward)
            else:
                part = dome_covariance(toward)
            sigma[lanes], x_axis[:, lanes] = part
        return sigma, x_axis


def record_sigma(inputs: SigmaInputs, emitters: EmitterTable, rows: np.ndarray, parent: np.ndarray,
                 reflectance: np.ndarray, vertices: SigmaVertices, ends: SigmaLightEnds, slots: int) -> np.ndarray:
    """Σ of events 1..slots of every record: (r, slots, 10) float32 (module docstring).

    rows (r,) each record's last event row (−1: none); parent (rows,) the norms rows'
    links; reflectance (rows,) float32 each row's R; vertices and ends as recorded."""
    count = len(rows)
    out = np.zeros((count, slots, SIGMA_ENTRY_COUNT), FLOAT)
    if not count or not slots:
        return out
    # Each record's rows from its light end to the camera: chain[:, 0] is its last event.
    links = [rows]
    while (links[-1] >= 0).any():
        current = links[-1]
        links.append(np.where(current >= 0, parent[np.maximum(current, 0)], -1))
    chain = np.stack(links[:-1], axis=1) if len(links) > 1 else np.full((count, 0), -1)
    events = (chain >= 0).sum(axis=1)
    slot = events[:, None] - 1 - np.arange(chain.shape[1])[None, :]  # each link's event slot
    scattering = (chain >= 0) & (vertices.values[np.maximum(chain, 0), KIND] != PASS)
    depth = scattering.sum(axis=1)
    # the scattering links first, light end first (a stable sort keeps their order)
    order = np.argsort(~scattering, axis=1, kind="stable")
    chain, slot = np.take_along_axis(chain, order, 1), np.take_along_axis(slot, order, 1)

    has_vertex = depth > 0
    direction = ends.direction[has_vertex].T.astype(np.float64)
    emitted = np.zeros((count, 4, 4))
    emitted_x = np.zeros((3, count))
    emitted[has_vertex], emitted_x[:, has_vertex] = emitters.covariance(
        inputs.world, ends.light[has_vertex], ends.triangle[has_vertex], direction)
    for length in np.unique(depth[has_vertex]):
        records = np.flatnonzero(depth == length)
        group = chain[records, :length]  # (k, length) light end first
        path = path_covariance(emitted[records], emitted_x[:, records], ends.direction[records].T.astype(np.float64),
                               ends.distance[records].astype(np.float64),
                               _surface_vertices(inputs, vertices, reflectance, group, ends.direction[records]))
        for position in range(length):
            where = slot[records, position]
            keep = where < slots
            out[records[keep], where[keep]] = pack_upper(path.leaving[position][keep])
    return out


def _surface_vertices(inputs: SigmaInputs, vertices: SigmaVertices, reflectance: np.ndarray, group: np.ndarray,
                      light_direction: np.ndarray) -> list[SurfaceVertex]:
    """The SurfaceVertex of each position of `group` (k, length) rows, light end first."""
    world = inputs.world
    values = vertices.values[group].astype(np.float64)  # (k, length, fields)
    triangle = vertices.triangle[group]
    length = group.shape[1]
    out = []
    for position in range(length):
        own = values[:, position]
        tri = triangle[:, position]
        toward_eye = own[:, TOWARD_EYE:TOWARD_EYE + 3].T
        if position == 0:
            toward_light = -light_direction.T.astype(np.float64)
        else:
            toward_light = -values[:, position - 1, TOWARD_EYE:TOWARD_EYE + 3].T
        eye_side = values[:, position + 1, TRAVELLED] if position + 1 < length else 0.0
        block_uv, grad_u, grad_v = inputs.bounce_norms.uv_texture(tri, own[:, ST:ST + 2], own[:, FOOTPRINT])
        r = reflectance[group[:, position]].astype(np.float64)
        bandwidth = np.where(r >= np.float32(SINGULAR_REFLECTANCE), np.inf, r * r)
        out.append(SurfaceVertex(
            toward_light=toward_light, toward_eye=toward_eye, distance_to_eye=own[:, TRAVELLED] - eye_side,
            normal=own[:, NORMAL:NORMAL + 3].T, k1=world.curvature_k1[tri].astype(np.float64),
            k2=world.curvature_k2[tri].astype(np.float64),
            principal_direction=world.principal_direction[:, tri].astype(np.float64), texture_uv=block_uv,
            gradient_s=grad_u, gradient_t=grad_v, bandwidth=bandwidth, transmit=own[:, KIND] == TRANSMIT))
    return out


def _grown(array: np.ndarray, capacity: int) -> np.ndarray:
    grown = np.zeros((capacity,) + array.shape[1:], array.dtype)
    grown[:len(array)] = array
    return grown
