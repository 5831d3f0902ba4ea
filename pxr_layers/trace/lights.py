"""Light sampling for next-event estimation, and light pdfs for multiple importance sampling.

Three kinds of emitters:

* emitting triangles: the tessellated area lights (one-sided, or outward for spheres and
  cylinders) and triangles of emissive materials (two-sided); sampled by area × luminance.
* distant lights: a delta direction (angle = 0) or a cone of directions, uniformly.
* dome lights: a lat-long map sampled from a piecewise-constant distribution over it,
  weighted by luminance × sin θ.

One light per shading point is picked from a discrete distribution over "sources"
(all emitting triangles count as one source) in proportion to an estimate of their power.
``LightSampler`` builds the tables (``LightArrays``) once per frame; kernels call
:func:`sample`, :func:`emitted`, :func:`triangle_pdf` and the dome functions lane by lane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..scene import FLOAT, SceneData
from . import shading, textures
from ..compiled import inline, kernel, scratch
from .shading import MaterialArrays, MaterialTable
from .vectors import basis, luminance, normalized
from .world import GeometryArrays, World

DOME_GRID = (64, 128)  # (rows, columns) of the dome's sampling distribution at most


def _cumulative(weights: np.ndarray) -> np.ndarray:
    cdf = np.cumsum(weights, dtype=np.float64)
    return cdf / cdf[-1]


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
            lum = _block_mean(luminance(np.moveaxis(textures.rgb_view(pixels), -1, 0).astype(np.float64)), rows, cols)
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
    def irradiance(self) -> np.ndarray:
        """Irradiance on a surface facing the light (3,)."""
        if self.is_delta:
            return self.radiance
        return self.radiance * np.pi * (1 - self.cos_max**2)



AREA, DISTANT, DOME = range(3)  # source kinds


class LightArrays(NamedTuple):
    """What kernels read of the lights of a frame.

    light_radiance   : (lights, 3) radiance of each light (its shape's, for area lights)
    emitter_triangles: (e,) int32 triangles NEE samples, triangle_cdf (e,) float64 over them
    triangle_probability : (t,) float32 probability of each triangle among the emitters
    area_probability : (1,) float64 probability of the area source
    distant_*        : per distant light (d,): direction (d, 3) unit toward it, radiance
                       (d, 3), cos_max (cosine of the cone's half angle, 1 = delta), light
                       index, source probability
    dome_*           : per dome (D,): radiance (D, 3), light_from_world (D, 3, 3), texture
                       (index into texture_info, −1 = none), rows, columns, offset into the
                       flat cell tables, offset into dome_row_cdf, light index, probability
    dome_cell_probability, dome_column_cdf : flat float64 (Σ rows·columns); dome_row_cdf
                       flat float64 (Σ rows)
    source_kind (s,) int64 AREA / DISTANT / DOME, source_item (s,) index among its kind,
    source_cdf (s,) float64
    texels, texture_info : the domes' textures (textures.py atlas)
    """

    light_radiance: np.ndarray
    emitter_triangles: np.ndarray
    triangle_cdf: np.ndarray
    triangle_probability: np.ndarray
    area_probability: np.ndarray
    distant_direction: np.ndarray
    distant_radiance: np.ndarray
    distant_cos_max: np.ndarray
    distant_light: np.ndarray
    distant_probability: np.ndarray
    dome_radiance: np.ndarray
    dome_rotation: np.ndarray
    dome_texture: np.ndarray
    dome_rows: np.ndarray
    dome_columns: np.ndarray
    dome_cell_offset: np.ndarray
    dome_row_offset: np.ndarray
    dome_light: np.ndarray
    dome_probability: np.ndarray
    dome_cell_probability: np.ndarray
    dome_column_cdf: np.ndarray
    dome_row_cdf: np.ndarray
    source_kind: np.ndarray
    source_item: np.ndarray
    source_cdf: np.ndarray
    texels: np.ndarray
    texture_info: np.ndarray


class LightSampler:
    """Picks lights in proportion to an estimate of their power; builds ``arrays``."""

    def __init__(self, scene: SceneData, world: World, materials: MaterialTable, geometry: GeometryArrays):
        emissive_material = np.concatenate([materials.emissive, [False]])  # index -1 → False
        surface_emitter = (world.triangle_light < 0) & emissive_material[world.triangle_material]
        light_emitter = world.triangle_light >= 0
        self.triangle_emits = surface_emitter | light_emitter  # (t,) bool
        emitter_triangles = np.flatnonzero(self.triangle_emits).astype(np.int32)
        light_radiance = np.array([light.radiance for light in scene.lights], FLOAT).reshape(-1, 3)

        sources: list[tuple[int, int, float]] = []  # (kind, index among its kind, power)
        scene_area = np.pi * world.radius**2
        triangle_cdf = np.ones(1)
        triangle_probability = np.zeros(world.triangle_count, FLOAT)
        if len(emitter_triangles):
            radiance = _centroid_emission(emitter_triangles, geometry, materials.arrays, light_radiance)
            sides = np.where(world.triangle_light[emitter_triangles] < 0, 2.0, 1.0)
            power = world.area[emitter_triangles] * luminance(radiance.T) * np.pi * sides
            keep = power > 0
            emitter_triangles, power = emitter_triangles[keep], power[keep]
            if len(power):
                triangle_cdf = _cumulative(power)
                triangle_probability[emitter_triangles] = power / power.sum()
                sources.append((AREA, 0, float(power.sum())))
        self.distant: list[DistantLight] = []
        self.domes: list[DomeDistribution] = []
        for index, light in enumerate(scene.lights):
            rotation = np.asarray(light.world_from_light, np.float64)[:3, :3]
            if light.kind == "distant":
                toward = rotation @ np.array([0.0, 0.0, 1.0])
                half_angle = np.radians(np.clip(light.angle, 0.0, 360.0) / 2)
                distant = DistantLight(index, (toward / np.linalg.norm(toward)).astype(FLOAT),
                                       np.asarray(light.radiance, FLOAT), float(np.cos(half_angle)))
                sources.append((DISTANT, len(self.distant), float(luminance(distant.irradiance)) * scene_area))
                self.distant.append(distant)
            elif light.kind == "dome":
                orthonormal = rotation / np.linalg.norm(rotation, axis=0, keepdims=True)
                pixels = None if light.texture is None else scene.textures[light.texture].pixels
                dome = DomeDistribution(index, light.radiance, pixels, orthonormal.T)
                sources.append((DOME, len(self.domes), dome.mean_luminance * np.pi * scene_area))
                self.domes.append(dome)
        sources = [source for source in sources if source[2] > 0]
        self.has_lights = bool(sources)
        self.has_infinite_lights = bool(self.domes or any(not d.is_delta for d in self.distant))
        power = np.array([source[2] for source in sources] or [1.0])
        probability = power / power.sum()
        probability_of = {(kind, item): p for (kind, item, _), p in zip(sources, probability)}
        dome_textures: list[np.ndarray] = []
        texture_of = []  # each dome's texture in the atlas, −1: none
        for dome in self.domes:
            texture_of.append(-1 if dome.pixels is None else len(dome_textures))
            if dome.pixels is not None:
                dome_textures.append(dome.pixels)
        texels, texture_info = textures.pack(dome_textures)
        rows = np.array([dome.shape[0] for dome in self.domes], np.int64)
        cols = np.array([dome.shape[1] for dome in self.domes], np.int64)

        def flat(values: list[np.ndarray]) -> np.ndarray:
            return np.concatenate([np.ravel(v) for v in values]) if values else np.zeros(0)

        self.arrays = LightArrays(
            light_radiance=light_radiance,
            emitter_triangles=emitter_triangles,
            triangle_cdf=triangle_cdf,
            triangle_probability=triangle_probability,
            area_probability=np.array([probability_of.get((AREA, 0), 0.0)], np.float64),
            distant_direction=np.array([d.direction for d in self.distant], np.float64).reshape(-1, 3),
            distant_radiance=np.array([d.radiance for d in self.distant], np.float64).reshape(-1, 3),
            distant_cos_max=np.array([d.cos_max for d in self.distant], np.float64),
            distant_light=np.array([d.light_index for d in self.distant], np.int64),
            distant_probability=np.array([probability_of.get((DISTANT, item), 0.0) for item in range(len(self.distant))],
                                         np.float64),
            dome_radiance=np.array([d.radiance for d in self.domes], np.float64).reshape(-1, 3),
            dome_rotation=np.array([d.light_from_world for d in self.domes], np.float64).reshape(-1, 3, 3),
            dome_texture=np.array(texture_of, np.int64),
            dome_rows=rows, dome_columns=cols,
            dome_cell_offset=np.cumsum(rows * cols) - rows * cols,  # where each dome's cells start
            dome_row_offset=np.cumsum(rows) - rows,
            dome_light=np.array([d.light_index for d in self.domes], np.int64),
            dome_probability=np.array([probability_of.get((DOME, item), 0.0) for item in range(len(self.domes))],
                                      np.float64),
            dome_cell_probability=flat([d.cell_probability for d in self.domes]),
            dome_column_cdf=flat([d.column_cdf for d in self.domes]),
            dome_row_cdf=flat([d.row_cdf for d in self.domes]),
            source_kind=np.array([kind for kind, _, _ in sources] or [AREA], np.int64),
            source_item=np.array([item for _, item, _ in sources] or [0], np.int64),
            source_cdf=_cumulative(power),
            texels=texels, texture_info=texture_info,
        )


def _centroid_emission(triangles: np.ndarray, geometry: GeometryArrays, materials: MaterialArrays,
                       light_radiance: np.ndarray) -> np.ndarray:
    """Radiance (e, 3) leaving emitting triangles at their centroids, toward their front."""
    out = np.zeros((len(triangles), 3), np.float64)
    _centroid_emission_kernel(triangles, geometry, materials, light_radiance, scratch(shading.REGISTERS, 4),
                              scratch(shading.MATERIAL_FIELDS), scratch(3), out)
    return out


@kernel
def _centroid_emission_kernel(triangles, geometry, materials, light_radiance, registers, inputs, radiance, out):
    third = 1.0 / 3.0
    for lane in range(len(triangles)):
        emitted(triangles[lane], third, third, 1.0, geometry, light_radiance, materials, registers, inputs, radiance)
        out[lane, 0], out[lane, 1], out[lane, 2] = radiance[0], radiance[1], radiance[2]


# -- per-lane functions of kernels

@inline
def pick(cdf, start, count, u):
    """The first index i in [0, count) with cdf[start + i] > u (the last if none)."""
    low, high = 0, count - 1
    while low < high:
        middle = (low + high) // 2
        if cdf[start + middle] > u:
            high = middle
        else:
            low = middle + 1
    return low


@inline
def emitted(triangle, u, v, cos_toward_viewer, geometry, light_radiance, materials, registers, inputs, out):
    """Radiance leaving an emitting `triangle` at barycentrics (u, v) toward a viewer under
    cos_toward_viewer (from its geometric normal) into out (3,): light shapes emit on their
    front only, emissive surfaces on both sides, in proportion to their presence (the
    fraction of paths that do not pass through them). registers, inputs: scratch of
    shading.material_inputs."""
    light = geometry.triangle_light[triangle]
    if light >= 0:
        front = 1.0 if cos_toward_viewer > 0 else 0.0
        out[0], out[1], out[2] = (light_radiance[light, 0] * front, light_radiance[light, 1] * front,
                                  light_radiance[light, 2] * front)
    else:
        shading.shade_point(materials, geometry, triangle, u, v, registers, inputs)
        present = 1.0 - shading.pass_fraction(inputs)  # what passes through does not emit
        out[0], out[1], out[2] = (inputs[shading.EMISSIVE] * present, inputs[shading.EMISSIVE + 1] * present,
                                  inputs[shading.EMISSIVE + 2] * present)


@inline
def cone_pdf(probability, cos_max):
    """Solid-angle density of a distant light's cone (sampled uniformly), with its source
    probability."""
    return probability / (2 * math.pi * (1 - cos_max))


@inline
def triangle_pdf(triangle, distance, cos_light, area_probability, triangle_probability, area):
    """Solid-angle density with which NEE picks a point seen at `distance` on `triangle`
    under |cos_light|."""
    if area_probability[0] == 0:
        return 0.0
    area_density = area_probability[0] * triangle_probability[triangle] / area[triangle]
    return area_density * distance * distance / max(abs(cos_light), 1e-8)


@inline
def dome_local(rotation, dome, x, y, z):
    return (rotation[dome, 0, 0] * x + rotation[dome, 0, 1] * y + rotation[dome, 0, 2] * z,
            rotation[dome, 1, 0] * x + rotation[dome, 1, 1] * y + rotation[dome, 1, 2] * z,
            rotation[dome, 2, 0] * x + rotation[dome, 2, 1] * y + rotation[dome, 2, 2] * z)


@inline
def _lat_long(lx, ly, lz):
    """Lat-long st of a dome-frame direction (st's t runs bottom to top)."""
    latitude = math.asin(min(max(ly, -1.0), 1.0))
    longitude = math.atan2(lx, lz)
    return (math.pi - longitude) / (2 * math.pi), (latitude + math.pi / 2) / math.pi


@inline
def dome_radiance(lights, dome, x, y, z):
    """Radiance (r, g, b) dome `dome` sends from world direction (x, y, z)."""
    r, g, b = lights.dome_radiance[dome, 0], lights.dome_radiance[dome, 1], lights.dome_radiance[dome, 2]
    texture = lights.dome_texture[dome]
    if texture < 0:
        return r, g, b
    lx, ly, lz = dome_local(lights.dome_rotation, dome, x, y, z)
    s, t = _lat_long(lx, ly, lz)
    i00, i10, i01, i11, fx, fy = textures.footprint(lights.texture_info, texture, s, t, 0, 2)
    texels, channels = lights.texels, lights.texture_info[texture, textures.CHANNELS]
    return (r * textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 0)),
            g * textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 1)),
            b * textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 2)))


@inline
def dome_pdf(lights, dome, x, y, z):
    """Solid-angle density of dome `dome`'s own sampling of world direction (x, y, z)
    (without the source's probability)."""
    lx, ly, lz = dome_local(lights.dome_rotation, dome, x, y, z)
    s, t = _lat_long(lx, ly, lz)
    rows, cols = lights.dome_rows[dome], lights.dome_columns[dome]
    column = min(max(np.int64(s * cols), 0), cols - 1)
    row = min(max(np.int64((1 - t) * rows), 0), rows - 1)
    sin_theta = math.sqrt(max(1 - ly * ly, 1e-12))
    cell = lights.dome_cell_probability[lights.dome_cell_offset[dome] + row * cols + column]
    return cell * rows * cols / (2 * math.pi * math.pi * sin_theta)


@inline
def dome_sample(lights, dome, u1, u2):
    """A world direction (x, y, z) from dome `dome`'s distribution."""
    rows, cols = lights.dome_rows[dome], lights.dome_columns[dome]
    row_cdf, column_cdf = lights.dome_row_cdf, lights.dome_column_cdf
    row_start, cell_start = lights.dome_row_offset[dome], lights.dome_cell_offset[dome]
    row = pick(row_cdf, row_start, rows, u1)
    row_low = row_cdf[row_start + row - 1] if row > 0 else 0.0
    row_fraction = (u1 - row_low) / max(row_cdf[row_start + row] - row_low, 1e-12)
    start = cell_start + row * cols
    column = pick(column_cdf, start, cols, u2)
    column_low = column_cdf[start + column - 1] if column > 0 else 0.0
    column_fraction = (u2 - column_low) / max(column_cdf[start + column] - column_low, 1e-12)
    v = (row + min(max(row_fraction, 0.0), 1.0)) / rows
    s = (column + min(max(column_fraction, 0.0), 1.0)) / cols
    latitude = math.pi / 2 - math.pi * v
    longitude = math.pi - 2 * math.pi * s
    lx, ly, lz = math.cos(latitude) * math.sin(longitude), math.sin(latitude), math.cos(latitude) * math.cos(longitude)
    rotation = lights.dome_rotation  # world = rotationᵀ · local (a rotation's inverse)
    return (rotation[dome, 0, 0] * lx + rotation[dome, 1, 0] * ly + rotation[dome, 2, 0] * lz,
            rotation[dome, 0, 1] * lx + rotation[dome, 1, 1] * ly + rotation[dome, 2, 1] * lz,
            rotation[dome, 0, 2] * lx + rotation[dome, 1, 2] * ly + rotation[dome, 2, 2] * lz)


@inline
def sample(lights, geometry, materials, px, py, pz, u0, u1, u2, u3, registers, inputs, scratch):
    """One light sample toward point (px, py, pz) from uniforms u0 (source), u1, u2
    (position), u3 (triangle). Returns (direction x, y, z unit toward the light; distance,
    metres, inf for distant and dome; radiance r, g, b arriving (irradiance for a delta
    distant light, already divided by its probability); pdf, solid angle, with the
    light's selection, inf for a delta; light index, −1 for an emissive surface; triangle
    sampled, −1 for distant and dome). pdf 0: no sample."""
    source = pick(lights.source_cdf, 0, len(lights.source_cdf), u0)
    kind, item = lights.source_kind[source], lights.source_item[source]
    if kind == AREA:
        chosen = lights.emitter_triangles[pick(lights.triangle_cdf, 0, len(lights.triangle_cdf), u3)]
        root = math.sqrt(u1)
        bu, bv = u2 * root, 1.0 - root
        corners = geometry.corner_positions
        w = 1.0 - bu - bv
        qx = w * corners[chosen, 0, 0] + bu * corners[chosen, 1, 0] + bv * corners[chosen, 2, 0]
        qy = w * corners[chosen, 0, 1] + bu * corners[chosen, 1, 1] + bv * corners[chosen, 2, 1]
        qz = w * corners[chosen, 0, 2] + bu * corners[chosen, 1, 2] + bv * corners[chosen, 2, 2]
        ox, oy, oz = qx - px, qy - py, qz - pz
        distance = math.sqrt(ox * ox + oy * oy + oz * oz)
        dx, dy, dz = normalized(ox, oy, oz, 1e-12)
        normal = geometry.geometric_normal
        cos_light = -(normal[chosen, 0] * dx + normal[chosen, 1] * dy + normal[chosen, 2] * dz)
        emitted(chosen, bu, bv, cos_light, geometry, lights.light_radiance, materials, registers, inputs, scratch)
        pdf = triangle_pdf(chosen, distance, cos_light, lights.area_probability, lights.triangle_probability,
                           geometry.area)
        return (dx, dy, dz, distance, scratch[0], scratch[1], scratch[2], pdf, geometry.triangle_light[chosen],
                chosen)
    if kind == DISTANT:
        light = lights.distant_light[item]
        ax, ay, az = lights.distant_direction[item, 0], lights.distant_direction[item, 1], lights.distant_direction[item, 2]
        r, g, b = lights.distant_radiance[item, 0], lights.distant_radiance[item, 1], lights.distant_radiance[item, 2]
        probability = lights.distant_probability[item]
        cos_max = lights.distant_cos_max[item]
        if cos_max >= 1.0:
            return ax, ay, az, math.inf, r / probability, g / probability, b / probability, math.inf, light, -1
        cos_theta = 1.0 - u1 * (1.0 - cos_max)
        sin_theta = math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))
        phi = 2 * math.pi * u2
        tx, ty, tz, bx, by, bz = basis(ax, ay, az)
        cx, sx = sin_theta * math.cos(phi), sin_theta * math.sin(phi)
        dx, dy, dz = (tx * cx + bx * sx + ax * cos_theta, ty * cx + by * sx + ay * cos_theta,
                      tz * cx + bz * sx + az * cos_theta)
        pdf = cone_pdf(probability, cos_max)
        return dx, dy, dz, math.inf, r, g, b, pdf, light, -1
    dx, dy, dz = dome_sample(lights, item, u1, u2)
    r, g, b = dome_radiance(lights, item, dx, dy, dz)
    pdf = lights.dome_probability[item] * dome_pdf(lights, item, dx, dy, dz)
    return dx, dy, dz, math.inf, r, g, b, pdf, lights.dome_light[item], -1
