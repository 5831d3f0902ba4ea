"""Light sampling for next-event estimation, and light pdfs for multiple importance sampling.

Three kinds of emitters:

* emitting triangles: the tessellated area lights (one-sided, or outward for spheres and
  cylinders) and triangles of emissive materials (two-sided); sampled by area × luminance.
* distant lights: a delta direction (angle = 0) or a cone of directions, uniformly.
* dome lights: a lat-long map sampled from a piecewise-constant distribution over it,
  weighted by luminance × sin θ.

One light per shading point is picked from a discrete distribution over "sources"
(all emitting triangles count as one source) in proportion to an estimate of their power.
Vectors and colours are component-major (3, n) arrays (see vectors.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import FLOAT, SceneData
from .shading import MaterialTable, interpolate
from .textures import sample_bilinear
from .vectors import dot, length, luminance, transform_rows
from .world import World

DOME_GRID = (64, 128)  # (rows, columns) of the dome's sampling distribution at most


@dataclass
class LightSample:
    """n light samples toward points.

    direction : (3, n) unit, from the shading point toward the light
    distance  : (n,) metres to the sampled point (inf for distant and dome)
    radiance  : (3, n) arriving radiance (irradiance for a delta distant light)
    pdf       : (n,) solid-angle density including the light selection (inf = delta)
    light     : (n,) int32 index into SceneData.lights, -1 for an emissive surface
    triangle  : (n,) int32 sampled emitting triangle, -1 for distant and dome
    """

    direction: np.ndarray
    distance: np.ndarray
    radiance: np.ndarray
    pdf: np.ndarray
    light: np.ndarray
    triangle: np.ndarray


def _cumulative(weights: np.ndarray) -> np.ndarray:
    cdf = np.cumsum(weights, dtype=np.float64)
    return cdf / cdf[-1]


def _pick(cdf: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.minimum(np.searchsorted(cdf, u, side="right"), len(cdf) - 1)


class DomeDistribution:
    """Piecewise-constant sampling of a lat-long dome (OpenEXR orientation, +Y up).

    Pixel column x has longitude π − 2π(x + ½)/w; row y latitude π/2 − π(y + ½)/h;
    direction (cos lat · sin lon, sin lat, cos lat · cos lon) in the dome's frame.
    """

    def __init__(self, light_index: int, radiance: np.ndarray, pixels: np.ndarray | None, light_from_world: np.ndarray):
        self.light_index = light_index
        self.radiance = np.asarray(radiance, FLOAT)
        self.pixels = pixels
        self.light_from_world = light_from_world.astype(FLOAT)  # (3, 3) rotation
        rows, cols = DOME_GRID
        if pixels is None:
            lum = np.ones((rows, cols))
        else:
            rows, cols = min(rows, pixels.shape[0]), min(cols, pixels.shape[1])
            lum = _block_mean(luminance(np.moveaxis(pixels[..., :3], -1, 0).astype(np.float64)), rows, cols)
        theta = (np.arange(rows) + 0.5) / rows * np.pi
        weights = np.maximum(lum, 0) * np.sin(theta)[:, None]
        weights += weights.mean() * 1e-3 + 1e-12  # every direction keeps a nonzero density
        self.shape = (rows, cols)
        self.cell_probability = weights / weights.sum()
        self.row_cdf = _cumulative(self.cell_probability.sum(axis=1))
        self.column_cdf = np.cumsum(self.cell_probability, axis=1)
        self.column_cdf /= self.column_cdf[:, -1:]
        mean_texel = 1.0 if pixels is None else float(luminance(np.moveaxis(pixels[..., :3], -1, 0)).mean())
        self.mean_luminance = float(luminance(self.radiance)) * mean_texel

    def radiance_toward(self, direction_world: np.ndarray) -> np.ndarray:
        """Radiance (3, n) arriving from world directions (3, n)."""
        if self.pixels is None:
            return np.repeat(self.radiance[:, None], direction_world.shape[1], axis=1)
        st = self._st(transform_rows(self.light_from_world, direction_world))
        texels = sample_bilinear(self.pixels, st, "repeat", "clamp")
        return texels[:3] * self.radiance[:, None]

    @staticmethod
    def _st(local: np.ndarray) -> np.ndarray:
        """Lat-long st (2, n) of dome-frame directions (3, n)."""
        latitude = np.arcsin(np.clip(local[1], -1, 1))
        longitude = np.arctan2(local[0], local[2])
        s = (np.pi - longitude) / (2 * np.pi)
        t = (latitude + np.pi / 2) / np.pi  # st's t runs bottom to top
        return np.stack([s, t]).astype(FLOAT)

    def pdf(self, direction_world: np.ndarray) -> np.ndarray:
        """Solid-angle density (n,) of sampling world directions (3, n)."""
        local = transform_rows(self.light_from_world, direction_world)
        st = self._st(local)
        rows, cols = self.shape
        column = np.clip((st[0] * cols).astype(np.int64), 0, cols - 1)
        row = np.clip(((1 - st[1]) * rows).astype(np.int64), 0, rows - 1)
        sin_theta = np.sqrt(np.maximum(1 - local[1] ** 2, 1e-12))
        return (self.cell_probability[row, column] * rows * cols / (2 * np.pi**2 * sin_theta)).astype(FLOAT)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions (3, n) world and their densities (n,), from u (2, n)."""
        rows, cols = self.shape
        row = _pick(self.row_cdf, u[0])
        column = np.minimum((u[1][:, None] >= self.column_cdf[row]).sum(axis=1), cols - 1)
        # Reuse the fractional position inside the chosen cell for a continuous direction.
        row_low = np.where(row > 0, self.row_cdf[np.maximum(row - 1, 0)], 0.0)
        row_fraction = (u[0] - row_low) / np.maximum(self.row_cdf[row] - row_low, 1e-12)
        column_low = np.where(column > 0, self.column_cdf[row, np.maximum(column - 1, 0)], 0.0)
        column_fraction = (u[1] - column_low) / np.maximum(self.column_cdf[row, column] - column_low, 1e-12)
        v = (row + np.clip(row_fraction, 0, 1)) / rows
        s = (column + np.clip(column_fraction, 0, 1)) / cols
        latitude = np.pi / 2 - np.pi * v
        longitude = np.pi - 2 * np.pi * s
        local = np.stack(
            [np.cos(latitude) * np.sin(longitude), np.sin(latitude), np.cos(latitude) * np.cos(longitude)]
        ).astype(FLOAT)
        world = transform_rows(self.light_from_world.T, local)  # inverse rotation = transpose
        return world, self.pdf(world)


def _block_mean(image: np.ndarray, rows: int, cols: int) -> np.ndarray:
    h, w = image.shape
    row_edges = np.linspace(0, h, rows + 1).astype(int)
    col_edges = np.linspace(0, w, cols + 1).astype(int)
    summed = np.add.reduceat(np.add.reduceat(image, row_edges[:-1], axis=0), col_edges[:-1], axis=1)
    counts = np.diff(row_edges)[:, None] * np.diff(col_edges)[None, :]
    return summed / counts


@dataclass
class DistantLight:
    light_index: int
    direction: np.ndarray  # (3,) unit, toward the light
    radiance: np.ndarray  # (3,)
    cos_max: float  # cosine of the cone's half angle; 1 for a delta light

    @property
    def is_delta(self) -> bool:
        return self.cos_max >= 1.0

    @property
    def solid_angle(self) -> float:
        return 2 * np.pi * (1 - self.cos_max)

    @property
    def irradiance(self) -> np.ndarray:
        """Irradiance on a surface facing the light (3,)."""
        if self.is_delta:
            return self.radiance
        return self.radiance * np.pi * (1 - self.cos_max**2)


class LightSampler:
    """Picks and samples lights; knows every light's density for MIS."""

    def __init__(self, scene: SceneData, world: World, materials: MaterialTable):
        self.world = world
        self.materials = materials
        emissive_material = np.concatenate([materials.emissive, [False]])  # index -1 → False
        surface_emitter = (world.triangle_light < 0) & emissive_material[world.triangle_material]
        light_emitter = world.triangle_light >= 0
        self.emitter_triangles = np.flatnonzero(surface_emitter | light_emitter).astype(np.int32)
        self.light_radiance = np.array([light.radiance for light in scene.lights], FLOAT).reshape(-1, 3).T.copy()

        sources: list[tuple[str, object, float]] = []
        scene_area = np.pi * world.radius**2
        if len(self.emitter_triangles):
            tri = self.emitter_triangles
            radiance = self._triangle_radiance_estimate(tri)
            sides = np.where(world.triangle_light[tri] < 0, 2.0, 1.0)
            power = world.area[tri] * luminance(radiance) * np.pi * sides
            keep = power > 0
            self.emitter_triangles = tri[keep]
            power = power[keep]
            if len(power):
                self.triangle_cdf = _cumulative(power)
                self.triangle_probability = np.zeros(world.triangle_count, FLOAT)
                self.triangle_probability[self.emitter_triangles] = power / power.sum()
                sources.append(("area", None, float(power.sum())))
        self.distant: list[DistantLight] = []
        self.domes: list[DomeDistribution] = []
        for index, light in enumerate(scene.lights):
            rotation = np.asarray(light.world_from_light, np.float64)[:3, :3]
            if light.kind == "distant":
                toward = rotation @ np.array([0.0, 0.0, 1.0])
                half_angle = np.radians(np.clip(light.angle, 0.0, 360.0) / 2)
                distant = DistantLight(index, (toward / np.linalg.norm(toward)).astype(FLOAT),
                                       np.asarray(light.radiance, FLOAT), float(np.cos(half_angle)))
                self.distant.append(distant)
                sources.append(("distant", distant, float(luminance(distant.irradiance)) * scene_area))
            elif light.kind == "dome":
                orthonormal = rotation / np.linalg.norm(rotation, axis=0, keepdims=True)
                pixels = None if light.texture is None else scene.textures[light.texture].pixels
                dome = DomeDistribution(index, light.radiance, pixels, orthonormal.T)
                self.domes.append(dome)
                sources.append(("dome", dome, dome.mean_luminance * np.pi * scene_area))
        self.sources = [source for source in sources if source[2] > 0]
        power = np.array([source[2] for source in self.sources] or [1.0])
        self.source_cdf = _cumulative(power)
        self.source_probability = power / power.sum()
        self._area_probability = 0.0
        self._probability_of: dict[int, float] = {}
        for (kind, obj, _), probability in zip(self.sources, self.source_probability):
            if kind == "area":
                self._area_probability = float(probability)
            else:
                self._probability_of[id(obj)] = float(probability)

    @property
    def has_lights(self) -> bool:
        return bool(self.sources)

    def _triangle_radiance_estimate(self, triangles: np.ndarray) -> np.ndarray:
        """Radiance (3, t) of emitting triangles at their centroids (for power estimates)."""
        third = np.full(len(triangles), 1 / 3, FLOAT)
        st = interpolate(self.world.corner_uvs, triangles, third, third)
        return self.emitted(triangles, st, np.ones(len(triangles), FLOAT))

    def emitted(self, triangle: np.ndarray, st: np.ndarray, cos_toward_viewer: np.ndarray) -> np.ndarray:
        """Radiance (3, n) leaving emitting triangles (n,) toward a viewer.

        st                : (2, n) texture coordinates on the triangles
        cos_toward_viewer : (n,) cosine between the triangle's geometric normal and the
                            direction to the viewer; light shapes emit on their front only.
        """
        light = np.take(self.world.triangle_light, triangle)
        is_light = light >= 0
        radiance = np.zeros((3, len(triangle)), FLOAT)
        lights = np.flatnonzero(is_light)
        if len(lights):
            front = cos_toward_viewer[lights] > 0
            radiance[:, lights] = np.take(self.light_radiance, light[lights], axis=1) * front
        surface = np.flatnonzero(~is_light)
        if len(surface):
            material = np.take(self.world.triangle_material, triangle[surface])
            radiance[:, surface] = self.materials.emission(material, st[:, surface])
        return radiance

    def triangle_pdf(self, triangle: np.ndarray, distance: np.ndarray, cos_light: np.ndarray) -> np.ndarray:
        """Solid-angle density (n,) with which next-event estimation picks a point seen at
        `distance` (n,) on `triangle` (n,) under |cos_light| (n,)."""
        if self._area_probability == 0:
            return np.zeros(len(triangle), FLOAT)
        area_density = self._area_probability * np.take(self.triangle_probability, triangle) / np.take(
            self.world.area, triangle
        )
        return (area_density * distance**2 / np.maximum(np.abs(cos_light), 1e-8)).astype(FLOAT)

    def source_probability_of(self, source: object) -> float:
        return self._probability_of.get(id(source), 0.0)

    def sample(self, points: np.ndarray, u: np.ndarray) -> LightSample:
        """One light sample per point. points (3, n) metres, u (4, n) uniforms."""
        n = points.shape[1]
        direction = np.zeros((3, n), FLOAT)
        direction[2] = 1
        distance = np.full(n, np.inf, FLOAT)
        radiance = np.zeros((3, n), FLOAT)
        pdf = np.zeros(n, FLOAT)
        light = np.full(n, -1, np.int32)
        triangle = np.full(n, -1, np.int32)
        if not self.sources:
            return LightSample(direction, distance, radiance, pdf, light, triangle)
        source = _pick(self.source_cdf, u[0])
        for source_index, (kind, obj, _) in enumerate(self.sources):
            lanes = np.flatnonzero(source == source_index)
            if not len(lanes):
                continue
            probability = self.source_probability[source_index]
            if kind == "area":
                self._sample_triangles(points, u, lanes, direction, distance, radiance, pdf, light, triangle)
            elif kind == "distant":
                distant: DistantLight = obj  # type: ignore[assignment]
                light[lanes] = distant.light_index
                if distant.is_delta:
                    direction[:, lanes] = distant.direction[:, None]
                    pdf[lanes] = np.inf
                    radiance[:, lanes] = (distant.radiance / probability)[:, None]
                else:
                    direction[:, lanes] = _sample_cone(distant.direction, distant.cos_max, u[1, lanes], u[2, lanes])
                    pdf[lanes] = probability / distant.solid_angle
                    radiance[:, lanes] = distant.radiance[:, None]
            else:
                dome: DomeDistribution = obj  # type: ignore[assignment]
                light[lanes] = dome.light_index
                sampled, density = dome.sample(u[1:3, lanes])
                direction[:, lanes] = sampled
                radiance[:, lanes] = dome.radiance_toward(sampled)
                pdf[lanes] = probability * density
        return LightSample(direction, distance, radiance, pdf, light, triangle)

    def _sample_triangles(self, points, u, lanes, direction, distance, radiance, pdf, light, triangle):
        chosen = np.take(self.emitter_triangles, _pick(self.triangle_cdf, u[3, lanes]))
        # A uniform point on the triangle.
        root = np.sqrt(u[1, lanes])
        bu = (u[2, lanes] * root).astype(FLOAT)
        bv = (1.0 - root).astype(FLOAT)
        position = interpolate(self.world.corner_positions, chosen, bu, bv)
        offset = position - points[:, lanes]
        distance_to = length(offset)
        to_light = offset / np.maximum(distance_to, 1e-12)
        normal = np.take(self.world.geometric_normal, chosen, axis=1)
        cos_light = -dot(normal, to_light)
        st = interpolate(self.world.corner_uvs, chosen, bu, bv)
        direction[:, lanes] = to_light
        distance[lanes] = distance_to
        radiance[:, lanes] = self.emitted(chosen, st, cos_light)
        pdf[lanes] = self.triangle_pdf(chosen, distance_to, cos_light)
        light[lanes] = np.take(self.world.triangle_light, chosen)
        triangle[lanes] = chosen

    def escaped(self, directions: np.ndarray):
        """Each infinite light seen along escaping directions (3, n).

        Yields (light index, radiance (3, n), density (n,) of NEE picking that direction).
        """
        for dome in self.domes:
            probability = self.source_probability_of(dome)
            yield dome.light_index, dome.radiance_toward(directions), probability * dome.pdf(directions)
        for distant in self.distant:
            if distant.is_delta:
                continue
            inside = dot(directions, distant.direction[:, None]) >= distant.cos_max
            radiance = np.where(inside, distant.radiance[:, None], 0.0).astype(FLOAT)
            density = np.where(inside, self.source_probability_of(distant) / distant.solid_angle, 0.0)
            yield distant.light_index, radiance, density.astype(FLOAT)


def _sample_cone(axis: np.ndarray, cos_max: float, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Uniform directions (3, n) within the cone around the unit axis (3,)."""
    cos_theta = 1.0 - u1 * (1.0 - cos_max)
    sin_theta = np.sqrt(np.maximum(1.0 - cos_theta**2, 0.0))
    phi = 2 * np.pi * u2
    tangent, bitangent = orthonormal_basis(axis[:, None].astype(FLOAT))
    return (tangent * (sin_theta * np.cos(phi)) + bitangent * (sin_theta * np.sin(phi))
            + axis[:, None] * cos_theta).astype(FLOAT)


def orthonormal_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent and bitangent (3, n) completing unit normals (3, n) (Duff et al. 2017)."""
    x, y, z = normal
    sign = np.where(z >= 0, 1.0, -1.0).astype(FLOAT)
    a = -1.0 / (sign + z)
    b = x * y * a
    tangent = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x])
    bitangent = np.stack([b, sign + y * y * a, -y])
    return tangent.astype(FLOAT), bitangent.astype(FLOAT)
