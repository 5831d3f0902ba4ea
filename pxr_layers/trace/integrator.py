"""Unidirectional path tracing as a schedule of wavefront stages (after pbrt-v4's wavefront).

One batch of paths (a contiguous range of path ids, path = pixel · spp + sample) moves
through the stages together, as structure-of-arrays queues compacted after each stage:

    camera rays → intersect → escaped (dome, distant cones) → emission (lights, emissive
    surfaces) → surface scatter: next-event estimation (light sample + shadow ray) and
    BSDF sampling → Russian roulette → next bounce

Emission found by BSDF sampling and by light sampling is combined with the power
heuristic, per lobe (see bsdf.py). ``max_depth`` counts scattering events: with
max_depth = 1 only direct lighting is computed. Straight pass-through at cut-out
surfaces (opacityThreshold) does not count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..paths import events
from ..paths.events import PathClassTrie
from ..scene import FLOAT
from . import bsdf, rng
from .bounce_norms import BounceNorms, lobe_reflectance
from .camera import PinholeCamera
from .embree import RayCaster
from .lights import LightSampler, orthonormal_basis
from .shading import MaterialTable, interpolate, surface_points
from .vectors import dot, max3
from .world import World

T_INFINITY = np.float32(1e30)
RANDOMS_PER_STEP = 8  # lobe, direction ×2, light pick, light position ×3, roulette
MAX_PASS_THROUGH = 16  # cut-out surfaces a path may cross on top of max_depth bounces


@dataclass(frozen=True)
class TraceSettings:
    """How to trace. spp: samples per pixel; seed and frame key every random number.

    norm_bounces : N, how many events after the camera keep their covariance norms C, T, R
                   (bounce_norms.py); 0 turns covariance off.
    record_paths : keep every contribution with its path class and norms (the path index).
    """

    spp: int = 16
    max_depth: int = 8
    seed: int = 0
    roulette_depth: int = 3  # Russian roulette from this many bounces on
    norm_bounces: int = 0
    record_paths: bool = False


@dataclass
class Contributions:
    """Every contribution of a batch, in the order the tracer made them.

    pixel  : (r,) int64; sample : (r,) int32; rgb : (r, 3) float32 (what the film adds)
    path_class : (r,) int64 index into ``sequences``
    norms  : (r, N, 3) float32 C, T, R of events 1..N after the camera (0 past the end)
    sequences : the batch's path classes, each its event ids after the camera (paths/events.py)
    """

    pixel: np.ndarray
    sample: np.ndarray
    rgb: np.ndarray
    path_class: np.ndarray
    norms: np.ndarray
    sequences: list[tuple[int, ...]]


@dataclass
class BatchResult:
    """Partial film for the contiguous pixel range [first_pixel, first_pixel + len(rgb)).

    rgb   : (k, 3) float64 sum of contributions (not yet divided by spp)
    alpha : (k,) float64 count of camera rays that hit geometry
    first_bounce_norms : (k, 3) float64 sums of the first bounce's C, T, R over the
            samples whose first event scatters, and first_bounce_count (k,) of them
            (None without covariance)
    records : every contribution (None unless settings.record_paths)
    rays  : rays cast (camera + bounce + shadow), for throughput figures
    """

    first_pixel: int
    rgb: np.ndarray
    alpha: np.ndarray
    first_bounce_norms: np.ndarray | None = None
    first_bounce_count: np.ndarray | None = None
    records: Contributions | None = None
    rays: int = 0


@dataclass
class _Paths:
    """The live paths of a batch, one lane each (structure of arrays).

    node : (n,) int64 path class so far (a PathClassTrie node; 0 = just the camera)
    row  : (n,) int64 the path's latest event in the batch's _EventNorms (−1: none yet)
    travelled : (n,) float32 metres from the camera (the ray cone's length)
    """

    pixel: np.ndarray
    sample: np.ndarray
    keys: np.ndarray
    depth: np.ndarray
    previous_pdf: np.ndarray
    previous_singular: np.ndarray
    throughput: np.ndarray
    node: np.ndarray
    row: np.ndarray
    travelled: np.ndarray

    def take(self, lanes: np.ndarray) -> _Paths:
        return _Paths(*(np.take(value, lanes, axis=-1) for value in vars(self).values()))


class _EventNorms:
    """C, T, R of every event of a batch's paths, as rows linked to the path's previous
    event: a path keeps one row number instead of N norms, and a record's N slots are
    gathered once, when the batch ends."""

    def __init__(self) -> None:
        self._parent: list[np.ndarray] = []
        self._norms: list[np.ndarray] = []
        self._rows = 0

    def append(self, parent: np.ndarray, curvature, texture, reflectance) -> np.ndarray:
        """New rows after `parent` (k,) rows; C, T, R (k,) or scalars. Returns their ids."""
        count = len(parent)
        norms = np.empty((count, 3), FLOAT)
        norms[:, 0], norms[:, 1], norms[:, 2] = curvature, texture, reflectance
        self._parent.append(parent)
        self._norms.append(norms)
        self._rows += count
        return np.arange(self._rows - count, self._rows)

    def first_events(self, rows: np.ndarray, slots: int) -> np.ndarray:
        """(r, slots, 3) norms of events 1..slots of the paths ending at `rows` (zeros past
        a path's last event)."""
        parent = np.concatenate(self._parent) if self._parent else np.zeros(0, np.int64)
        norms = np.concatenate(self._norms) if self._norms else np.zeros((0, 3), FLOAT)
        chain = [rows]  # chain[k] = the row k events before the last one (−1 past the first)
        while (chain[-1] >= 0).any():
            chain.append(np.where(chain[-1] >= 0, parent[np.maximum(chain[-1], 0)], -1))
        chain = np.stack(chain[:-1], axis=1) if len(chain) > 1 else np.full((len(rows), 0), -1)
        depth = (chain >= 0).sum(axis=1)
        out = np.zeros((len(rows), slots, 3), FLOAT)
        lanes = np.arange(len(rows))
        for slot in range(min(slots, chain.shape[1])):
            has = depth > slot
            out[has, slot] = norms[chain[lanes[has], depth[has] - 1 - slot]]
        return out


class _Film:
    """Collects contributions: always the pixel sums, the records when asked."""

    def __init__(self, first_pixel: int, pixel_count: int, record: bool):
        self.first_pixel = first_pixel
        self.rgb = np.zeros((3, pixel_count))
        self.record = record
        self.classes = PathClassTrie() if record else None
        self.event_norms = _EventNorms() if record else None
        self._records: list[tuple[np.ndarray, ...]] = []

    def add(self, paths: _Paths, lanes: np.ndarray, rgb: np.ndarray, event: np.ndarray | None = None,
            node: np.ndarray | None = None, row: np.ndarray | None = None) -> None:
        """Add rgb (3, len(lanes)) for `lanes` of `paths`. The path class is `node`, or the
        lanes' own node extended by `event` ids; its last norms row `row`, or the lanes'."""
        if not len(lanes):
            return
        where = paths.pixel[lanes] - self.first_pixel
        for channel in range(3):
            self.rgb[channel] += np.bincount(where, weights=rgb[channel], minlength=self.rgb.shape[1])
        if self.record:
            if node is None:
                node = self.classes.extend(paths.node[lanes], event)
            self._records.append((paths.pixel[lanes], paths.sample[lanes], rgb.T.astype(FLOAT), node,
                                  paths.row[lanes] if row is None else row))

    def records(self, slots: int) -> Contributions | None:
        if not self.record:
            return None
        if not self._records:
            return Contributions(np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3), FLOAT),
                                 np.zeros(0, np.int64), np.zeros((0, slots, 3), FLOAT), [])
        pixel, sample, rgb, node, row = (np.concatenate(column) for column in zip(*self._records))
        nodes, path_class = np.unique(node, return_inverse=True)
        norms = self.event_norms.first_events(row, slots)
        return Contributions(pixel, sample, rgb, path_class.reshape(-1), norms, self.classes.sequences(nodes))


@dataclass
class _Vertex:
    """The surface event being built at this step, for the live lanes.

    curvature, texture : (n,) float32 C and T (0 without covariance)
    """

    triangle: np.ndarray
    curvature: np.ndarray | float = 0.0
    texture: np.ndarray | float = 0.0


def power_heuristic(chosen: np.ndarray, other: np.ndarray) -> np.ndarray:
    """MIS weight of the strategy with density `chosen` against `other` (both (n,)).

    A delta strategy (infinite density) takes the whole weight.
    """
    a = np.minimum(chosen.astype(np.float64), 1e150) ** 2
    b = np.minimum(other.astype(np.float64), 1e150) ** 2
    return np.where(a + b > 0, a / np.maximum(a + b, 1e-300), 0.0).astype(FLOAT)


class Integrator:
    """Everything a batch needs, shared read-only between threads."""

    def __init__(self, world: World, materials: MaterialTable, lights: LightSampler, camera: PinholeCamera,
                 resolution: tuple[int, int], settings: TraceSettings, frame: float, caster: RayCaster,
                 vocabulary: events.EventVocabulary, triangle_subject: np.ndarray,
                 bounce_norms: BounceNorms | None = None):
        self.world = world
        self.materials = materials
        self.lights = lights
        self.camera = camera
        self.width, self.height = resolution
        self.settings = settings
        self.key = rng.frame_key(settings.seed, frame)
        self.caster = caster
        self.vocabulary = vocabulary  # names behind the event ids of recorded paths
        self.triangle_subject = triangle_subject  # (t,) the vocabulary's surface subject of each triangle
        self.bounce_norms = bounce_norms if settings.norm_bounces > 0 else None
        self.epsilon = np.float32(1e-5 * (world.radius + np.linalg.norm(world.center)) + 1e-7)
        self.has_infinite_lights = bool(lights.domes or any(not d.is_delta for d in lights.distant))
        emissive_material = np.concatenate([materials.emissive, [False]])
        self.triangle_emits = (world.triangle_light >= 0) | emissive_material[world.triangle_material]
        # ray cone of a camera ray: radians per pixel (the film window's width over its pixels)
        self.pixel_angle = np.float32(2 * camera.half_width / self.width)

    def trace(self, first_path: int, stop_path: int) -> BatchResult:
        """Trace paths [first_path, stop_path) to completion."""
        spp = self.settings.spp
        slots = self.settings.norm_bounces if self.bounce_norms else 0
        record = self.settings.record_paths
        path = np.arange(first_path, stop_path, dtype=np.int64)
        pixel = path // spp
        first_pixel = int(pixel[0])
        pixel_count = int(pixel[-1]) - first_pixel + 1
        keys = rng.path_keys(self.key, pixel, path % spp)
        jitter = rng.uniforms(keys, 0, 2)
        film_x = ((pixel % self.width) + jitter[0]) / self.width
        film_y = ((pixel // self.width) + jitter[1]) / self.height
        origins, directions = self.camera.rays(film_x, film_y)
        t_max = np.full(len(path), self.camera.t_max, FLOAT)

        n = len(path)
        paths = _Paths(
            pixel=pixel, sample=(path % spp).astype(np.int32), keys=keys, depth=np.zeros(n, np.int32),
            previous_pdf=np.zeros(n, FLOAT),
            previous_singular=np.ones(n, bool),  # the camera: what it sees directly is not MIS'd
            throughput=np.ones((3, n), FLOAT), node=np.zeros(n, np.int64), row=np.full(n, -1, np.int64),
            travelled=np.zeros(n, FLOAT),
        )
        film = _Film(first_pixel, pixel_count, record)
        alpha = np.zeros(pixel_count)
        first_bounce = np.zeros((3, pixel_count)) if slots else None
        first_bounce_count = np.zeros(pixel_count) if slots else None
        rays = 0

        for step in range(self.settings.max_depth + MAX_PASS_THROUGH + 1):
            if len(paths.pixel) == 0:
                break
            # -- intersect
            triangle, bary_u, bary_v, t_hit = self.caster.intersect(origins, directions, t_max)
            rays += len(paths.pixel)
            hit = triangle >= 0
            if step == 0:
                alpha += np.bincount(paths.pixel[hit] - first_pixel, minlength=pixel_count)

            # -- escaped rays see the dome and distant lights' cones
            if self.has_infinite_lights and not hit.all():
                missed = np.flatnonzero(~hit)
                for light, radiance, density in self.lights.escaped(directions[:, missed]):
                    weight = np.where(
                        paths.previous_singular[missed], 1.0, power_heuristic(paths.previous_pdf[missed], density)
                    )
                    film.add(paths, missed, paths.throughput[:, missed] * radiance * weight,
                             event=self._light_event(np.full(len(missed), light)) if record else None)

            if not hit.any():
                break  # every path escaped (always, in a world of sky alone: no triangle to index)

            # -- emission from lights and emissive surfaces hit by the ray
            emitting = np.flatnonzero(hit & np.take(self.triangle_emits, triangle))
            if len(emitting):
                tri = triangle[emitting]
                cos_emitter = -dot(np.take(self.world.geometric_normal, tri, axis=1), directions[:, emitting])
                st = interpolate(self.world.corner_uvs, tri, bary_u[emitting], bary_v[emitting])
                radiance = self.lights.emitted(tri, st, cos_emitter)
                density = self.lights.triangle_pdf(tri, t_hit[emitting], cos_emitter)
                weight = np.where(
                    paths.previous_singular[emitting], 1.0, power_heuristic(paths.previous_pdf[emitting], density)
                )
                film.add(paths, emitting, paths.throughput[:, emitting] * radiance * weight,
                         event=self._emitter_event(tri) if record else None)

            # Lights absorb what reaches them. Paths at max depth go on only through cut-outs.
            alive = hit.copy()
            alive[alive] &= np.take(self.world.triangle_light, triangle[alive]) < 0
            keep = np.flatnonzero(alive)
            if not len(keep):
                break
            paths, triangle = paths.take(keep), triangle[keep]
            directions = np.take(directions, keep, axis=1)
            if slots:
                paths.travelled = paths.travelled + t_hit[keep]
            points = surface_points(self.world, triangle, bary_u[keep], bary_v[keep])
            position, geometric_normal, shading_normal, st = (
                points.position, points.geometric_normal, points.shading_normal, points.st
            )
            wo = -directions
            cos_geometric = dot(geometric_normal, wo)
            inputs = self.materials.evaluate(np.take(self.world.triangle_material, triangle), st)

            # -- cut-out (opacityThreshold): pass straight through, not a bounce
            cut = (inputs.opacity_threshold > 0) & (inputs.opacity < inputs.opacity_threshold)
            scatters = ~cut & (paths.depth < self.settings.max_depth)
            facing = np.where(cos_geometric < 0, -geometric_normal, geometric_normal)
            offset = facing * self.epsilon

            # -- shading frame: normal on the viewer's side of the geometric normal
            shading_normal = np.where(dot(shading_normal, facing) < 0, -shading_normal, shading_normal)
            shading_normal = np.where(dot(shading_normal, wo) <= 1e-4, facing, shading_normal)
            frame = (*orthonormal_basis(shading_normal), shading_normal)

            wo_local = to_local(frame, wo)
            lobes = bsdf.prepare(inputs, wo_local[2], cos_geometric > 0)
            lobes.probability[:, ~scatters] = 0.0
            randoms = rng.uniforms(paths.keys, 2 + step * RANDOMS_PER_STEP, RANDOMS_PER_STEP)
            vertex = _Vertex(triangle)
            if slots and (record or step == 0):  # without records only the first bounce is kept
                footprint = paths.travelled * self.pixel_angle / np.maximum(np.abs(wo_local[2]), 0.05)
                vertex.curvature, vertex.texture = self.bounce_norms.curvature_and_texture(
                    triangle, st, frame[0], frame[1], footprint)

            # -- next-event estimation
            if self.lights.has_lights:
                rays += self._next_event(film, paths, vertex, position, offset, facing, wo_local, frame,
                                         lobes, randoms[3:7], scatters)

            # -- BSDF sampling
            sampled = bsdf.sample(lobes, wo_local, randoms[:3])
            new_direction = to_world(frame, sampled.direction)
            side = dot(new_direction, facing)
            consistent = np.where(sampled.transmit, side < 0, side > 0)
            scattered = sampled.valid & consistent & scatters
            if slots and step == 0:
                self._first_bounce(paths, vertex, scattered, sampled, lobes, first_bounce, first_bounce_count,
                                   first_pixel)
            if record:
                self._advance_history(film, paths, vertex, cut, scattered, sampled, lobes)
            paths.throughput = np.where(cut, paths.throughput, paths.throughput * sampled.weight)
            new_direction = np.where(cut, directions, new_direction)
            paths.previous_pdf = np.where(cut, paths.previous_pdf, sampled.pdf)
            paths.previous_singular = np.where(cut, paths.previous_singular, sampled.pdf == 0)
            paths.depth = paths.depth + (~cut)
            crossing = cut | sampled.transmit
            origins = position + np.where(crossing, -offset, offset)

            # -- Russian roulette
            survive = cut | scattered
            if step + 1 >= self.settings.roulette_depth:
                continue_probability = np.clip(max3(paths.throughput), 0.05, 1.0)
                lucky = randoms[7] < continue_probability
                survive &= lucky | cut
                paths.throughput = np.where(cut, paths.throughput, paths.throughput / continue_probability)
            survive &= max3(paths.throughput) > 0
            keep = np.flatnonzero(survive)
            paths = paths.take(keep)
            origins, directions = np.take(origins, keep, axis=1), np.take(new_direction, keep, axis=1)
            t_max = np.full(len(paths.pixel), T_INFINITY, FLOAT)

        first_bounce_norms = None if first_bounce is None else first_bounce.T
        return BatchResult(first_pixel, film.rgb.T, alpha, first_bounce_norms, first_bounce_count,
                           film.records(slots), rays)

    # -- path history: events, classes and per-event norms

    def _surface_event(self, triangle: np.ndarray, event_type, scatter, lobe) -> np.ndarray:
        return self.vocabulary.ids(event_type, scatter, lobe, np.take(self.triangle_subject, triangle))

    def _light_event(self, light: np.ndarray) -> np.ndarray:
        return self.vocabulary.ids(events.LIGHT, events.NO_SCATTER, events.NO_LOBE,
                                   self.vocabulary.light_subject(light))

    def _emitter_event(self, triangle: np.ndarray) -> np.ndarray:
        """L for a light's own geometry, O for an emissive surface."""
        light = np.take(self.world.triangle_light, triangle)
        surface = self._surface_event(triangle, events.OBJECT, events.NO_SCATTER, events.NO_LOBE)
        return np.where(light >= 0, self._light_event(np.maximum(light, 0)), surface)

    def _advance_history(self, film, paths, vertex, cut, scattered, sampled, lobes) -> None:
        """Append this vertex's event to every continuing path: its sampled lobe, or a
        straight pass (no operator, norms 0) for cut-outs."""
        lanes = np.flatnonzero(scattered | cut)
        passes = cut[lanes]
        lobe = np.where(passes, events.NO_LOBE, sampled.lobe[lanes])
        event_type = np.where(passes | sampled.transmit[lanes], events.TRANSMIT, events.REFLECT)
        scatter = np.where(passes, bsdf.SCATTER_STRAIGHT, sampled.scatter[lanes])
        event = self._surface_event(vertex.triangle[lanes], event_type, scatter, lobe)
        paths.node[lanes] = film.classes.extend(paths.node[lanes], event)
        if self.bounce_norms:
            reflectance = np.where(passes, 0.0, lobe_reflectance(lobes, np.minimum(lobe, bsdf.GLASS), lanes))
            paths.row[lanes] = film.event_norms.append(
                paths.row[lanes], np.where(passes, 0.0, vertex.curvature[lanes]),
                np.where(passes, 0.0, vertex.texture[lanes]), reflectance)

    def _first_bounce(self, paths, vertex, scattered, sampled, lobes, sums, counts, first_pixel) -> None:
        """Add the first event's C, T, R to the per-pixel sums (the debug pictures)."""
        lanes = np.flatnonzero(scattered)
        where = paths.pixel[lanes] - first_pixel
        reflectance = lobe_reflectance(lobes, sampled.lobe[lanes], lanes)
        for norm, values in enumerate((vertex.curvature[lanes], vertex.texture[lanes], reflectance)):
            sums[norm] += np.bincount(where, weights=values, minlength=len(counts))
        counts += np.bincount(where, minlength=len(counts))

    def _next_event(self, film, paths, vertex, position, offset, facing, wo_local, frame, lobes, u, allowed):
        """Sample one light per lane, add each non-singular lobe's MIS-weighted share."""
        sample = self.lights.sample(position, u)
        wi_local = to_local(frame, sample.direction)
        f, lobe_pdf = bsdf.evaluate(lobes, wo_local, wi_local)
        cos_incident = dot(sample.direction, facing)
        useful = allowed & (sample.pdf > 0) & (cos_incident > 0) & (max3(sample.radiance) > 0)
        useful &= f.max(axis=(0, 1)) > 0
        lanes = np.flatnonzero(useful)
        if not len(lanes):
            return 0
        distance = sample.distance[lanes]
        t_max = np.where(np.isfinite(distance), distance * (1 - 1e-4) - 2 * self.epsilon, T_INFINITY).astype(FLOAT)
        origins = np.take(position, lanes, axis=1) + np.take(offset, lanes, axis=1)
        blocked = self.caster.occluded(origins, np.take(sample.direction, lanes, axis=1), t_max)
        lanes = lanes[~blocked]
        if not len(lanes):
            return len(blocked)
        light_pdf = sample.pdf[lanes]
        delta = np.isinf(light_pdf)
        cos_shading = np.abs(wi_local[2, lanes])
        base = paths.throughput[:, lanes] * sample.radiance[:, lanes] * (cos_shading / np.where(delta, 1.0, light_pdf))
        light_events = self._sampled_light_event(sample, lanes) if film.record else None  # the same for every lobe
        for lobe in bsdf.GLOSSY_LOBES:
            lobe_f = f[lobe][:, lanes]
            active = max3(lobe_f) > 0
            if not active.any():
                continue
            weight = np.where(delta, 1.0, power_heuristic(light_pdf, lobe_pdf[lobe, lanes]))
            contribution = (base * lobe_f * weight)[:, active]
            contributing = lanes[active]
            node = row = None
            if film.record:
                scatter = bsdf.SCATTER_DIFFUSE if lobe == bsdf.DIFFUSE else bsdf.SCATTER_GLOSSY
                surface = self._surface_event(vertex.triangle[contributing], events.REFLECT, scatter, lobe)
                node = film.classes.extend(paths.node[contributing], surface)
                node = film.classes.extend(node, light_events[active])
                if self.bounce_norms:
                    row = film.event_norms.append(paths.row[contributing], vertex.curvature[contributing],
                                                  vertex.texture[contributing],
                                                  lobe_reflectance(lobes, lobe, contributing))
            film.add(paths, contributing, contribution, node=node, row=row)
        return len(blocked)

    def _sampled_light_event(self, sample, lanes: np.ndarray) -> np.ndarray:
        light = sample.light[lanes]
        emitter = self._emitter_event(np.maximum(sample.triangle[lanes], 0))
        return np.where(light >= 0, self._light_event(np.maximum(light, 0)), emitter)


def to_local(frame: tuple[np.ndarray, np.ndarray, np.ndarray], v: np.ndarray) -> np.ndarray:
    """World vectors (3, n) into the shading frames (tangent, bitangent, normal) (3, n) each."""
    tangent, bitangent, normal = frame
    return np.stack([dot(v, tangent), dot(v, bitangent), dot(v, normal)])


def to_world(frame: tuple[np.ndarray, np.ndarray, np.ndarray], v: np.ndarray) -> np.ndarray:
    """Local vectors (3, n) back to world space, float32."""
    tangent, bitangent, normal = frame
    return (tangent * v[0] + bitangent * v[1] + normal * v[2]).astype(FLOAT)
