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

from dataclasses import dataclass, field

import numpy as np

from ..scene import FLOAT
from . import bsdf, rng
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
    """How to trace. spp: samples per pixel; seed and frame key every random number."""

    spp: int = 16
    max_depth: int = 8
    seed: int = 0
    roulette_depth: int = 3  # Russian roulette from this many bounces on


@dataclass
class BatchResult:
    """Partial film for the contiguous pixel range [first_pixel, first_pixel + len(rgb)).

    rgb   : (k, 3) float64 sum of contributions (not yet divided by spp)
    alpha : (k,) float64 count of camera rays that hit geometry
    rays  : rays cast (camera + bounce + shadow), for throughput figures
    """

    first_pixel: int
    rgb: np.ndarray
    alpha: np.ndarray
    rays: int = 0


@dataclass
class _Contributions:
    pixels: list[np.ndarray] = field(default_factory=list)
    rgb: list[np.ndarray] = field(default_factory=list)

    def add(self, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """pixel (n,) int64, rgb (3, n) float32."""
        if len(pixel):
            self.pixels.append(pixel)
            self.rgb.append(rgb)


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
                 resolution: tuple[int, int], settings: TraceSettings, frame: float, caster: RayCaster):
        self.world = world
        self.materials = materials
        self.lights = lights
        self.camera = camera
        self.width, self.height = resolution
        self.settings = settings
        self.key = rng.frame_key(settings.seed, frame)
        self.caster = caster
        self.epsilon = np.float32(1e-5 * (world.radius + np.linalg.norm(world.center)) + 1e-7)
        self.has_infinite_lights = bool(lights.domes or any(not d.is_delta for d in lights.distant))
        emissive_material = np.concatenate([materials.emissive, [False]])
        self.triangle_emits = (world.triangle_light >= 0) | emissive_material[world.triangle_material]

    def trace(self, first_path: int, stop_path: int) -> BatchResult:
        """Trace paths [first_path, stop_path) to completion."""
        spp = self.settings.spp
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
        throughput = np.ones((3, n), FLOAT)
        previous_pdf = np.zeros(n, FLOAT)
        previous_singular = np.ones(n, bool)  # the camera: what it sees directly is not MIS'd
        depth = np.zeros(n, np.int32)
        out = _Contributions()
        alpha = np.zeros(pixel_count)
        rays = 0

        for step in range(self.settings.max_depth + MAX_PASS_THROUGH + 1):
            if len(pixel) == 0:
                break
            # -- intersect
            triangle, bary_u, bary_v, t_hit = self.caster.intersect(origins, directions, t_max)
            rays += len(pixel)
            hit = triangle >= 0
            if step == 0:
                alpha += np.bincount(pixel[hit] - first_pixel, minlength=pixel_count)

            # -- escaped rays see the dome and distant lights' cones
            if self.has_infinite_lights and not hit.all():
                missed = np.flatnonzero(~hit)
                for _, radiance, density in self.lights.escaped(directions[:, missed]):
                    weight = np.where(
                        previous_singular[missed], 1.0, power_heuristic(previous_pdf[missed], density)
                    )
                    out.add(pixel[missed], throughput[:, missed] * radiance * weight)

            # -- emission from lights and emissive surfaces hit by the ray
            emitting = np.flatnonzero(hit & np.take(self.triangle_emits, triangle))
            if len(emitting):
                tri = triangle[emitting]
                cos_emitter = -dot(np.take(self.world.geometric_normal, tri, axis=1), directions[:, emitting])
                st = interpolate(self.world.corner_uvs, tri, bary_u[emitting], bary_v[emitting])
                radiance = self.lights.emitted(tri, st, cos_emitter)
                density = self.lights.triangle_pdf(tri, t_hit[emitting], cos_emitter)
                weight = np.where(
                    previous_singular[emitting], 1.0, power_heuristic(previous_pdf[emitting], density)
                )
                out.add(pixel[emitting], throughput[:, emitting] * radiance * weight)

            # Lights absorb what reaches them. Paths at max depth go on only through cut-outs.
            alive = hit.copy()
            alive[alive] &= np.take(self.world.triangle_light, triangle[alive]) < 0
            keep = np.flatnonzero(alive)
            if not len(keep):
                break
            pixel, keys, depth, triangle = pixel[keep], keys[keep], depth[keep], triangle[keep]
            previous_pdf, previous_singular = previous_pdf[keep], previous_singular[keep]
            throughput, directions = np.take(throughput, keep, axis=1), np.take(directions, keep, axis=1)
            points = surface_points(self.world, triangle, bary_u[keep], bary_v[keep])
            position, geometric_normal, shading_normal, st = (
                points.position, points.geometric_normal, points.shading_normal, points.st
            )
            wo = -directions
            cos_geometric = dot(geometric_normal, wo)
            inputs = self.materials.evaluate(np.take(self.world.triangle_material, triangle), st)

            # -- cut-out (opacityThreshold): pass straight through, not a bounce
            cut = (inputs.opacity_threshold > 0) & (inputs.opacity < inputs.opacity_threshold)
            scatters = ~cut & (depth < self.settings.max_depth)
            facing = np.where(cos_geometric < 0, -geometric_normal, geometric_normal)
            offset = facing * self.epsilon

            # -- shading frame: normal on the viewer's side of the geometric normal
            shading_normal = np.where(dot(shading_normal, facing) < 0, -shading_normal, shading_normal)
            shading_normal = np.where(dot(shading_normal, wo) <= 1e-4, facing, shading_normal)
            frame = (*orthonormal_basis(shading_normal), shading_normal)

            wo_local = to_local(frame, wo)
            lobes = bsdf.prepare(inputs, wo_local[2], cos_geometric > 0)
            lobes.probability[:, ~scatters] = 0.0
            randoms = rng.uniforms(keys, 2 + step * RANDOMS_PER_STEP, RANDOMS_PER_STEP)

            # -- next-event estimation
            if self.lights.has_lights:
                rays += self._next_event(out, pixel, throughput, position, offset, facing, wo_local, frame,
                                         lobes, randoms[3:7], scatters)

            # -- BSDF sampling
            sampled = bsdf.sample(lobes, wo_local, randoms[:3])
            new_direction = to_world(frame, sampled.direction)
            side = dot(new_direction, facing)
            consistent = np.where(sampled.transmit, side < 0, side > 0)
            scattered = sampled.valid & consistent & scatters
            throughput = np.where(cut, throughput, throughput * sampled.weight)
            new_direction = np.where(cut, directions, new_direction)
            previous_pdf = np.where(cut, previous_pdf, sampled.pdf)
            previous_singular = np.where(cut, previous_singular, sampled.pdf == 0)
            depth = depth + (~cut)
            crossing = cut | sampled.transmit
            origins = position + np.where(crossing, -offset, offset)

            # -- Russian roulette
            survive = cut | scattered
            if step + 1 >= self.settings.roulette_depth:
                continue_probability = np.clip(max3(throughput), 0.05, 1.0)
                lucky = randoms[7] < continue_probability
                survive &= lucky | cut
                throughput = np.where(cut, throughput, throughput / continue_probability)
            survive &= max3(throughput) > 0
            keep = np.flatnonzero(survive)
            pixel, keys, depth = pixel[keep], keys[keep], depth[keep]
            previous_pdf, previous_singular = previous_pdf[keep], previous_singular[keep]
            throughput, origins, directions = (np.take(a, keep, axis=1) for a in (throughput, origins, new_direction))
            t_max = np.full(len(pixel), T_INFINITY, FLOAT)

        rgb = np.zeros((pixel_count, 3))
        if out.pixels:
            where = np.concatenate(out.pixels) - first_pixel
            values = np.concatenate(out.rgb, axis=1).astype(np.float64)
            for channel in range(3):
                rgb[:, channel] = np.bincount(where, weights=values[channel], minlength=pixel_count)
        return BatchResult(first_pixel, rgb, alpha, rays)

    def _next_event(self, out, pixel, throughput, position, offset, facing, wo_local, frame, lobes, u, allowed):
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
        base = throughput[:, lanes] * sample.radiance[:, lanes] * (cos_shading / np.where(delta, 1.0, light_pdf))
        for lobe in bsdf.GLOSSY_LOBES:
            lobe_f = f[lobe][:, lanes]
            active = max3(lobe_f) > 0
            if not active.any():
                continue
            weight = np.where(delta, 1.0, power_heuristic(light_pdf, lobe_pdf[lobe, lanes]))
            contribution = base * lobe_f * weight
            out.add(pixel[lanes[active]], contribution[:, active])
        return len(blocked)


def to_local(frame: tuple[np.ndarray, np.ndarray, np.ndarray], v: np.ndarray) -> np.ndarray:
    """World vectors (3, n) into the shading frames (tangent, bitangent, normal) (3, n) each."""
    tangent, bitangent, normal = frame
    return np.stack([dot(v, tangent), dot(v, bitangent), dot(v, normal)])


def to_world(frame: tuple[np.ndarray, np.ndarray, np.ndarray], v: np.ndarray) -> np.ndarray:
    """Local vectors (3, n) back to world space, float32."""
    tangent, bitangent, normal = frame
    return (tangent * v[0] + bitangent * v[1] + normal * v[2]).astype(FLOAT)
