"""Light sampling for next-event estimation, and light pdfs for multiple importance sampling.

Four kinds of emitters:

* emitting triangles: the tessellated area lights (one-sided, or outward for spheres and
  cylinders) and triangles of emissive materials (two-sided); sampled by area × an estimate
  of their power (the emission averaged over points and cosine-weighted directions, so a
  narrow cone or an IES profile is sampled in proportion to what it sends).
* positional delta lights: spheres with ``treatAsPoint`` (a point) and cylinders with
  ``treatAsLine`` (a segment, sampled uniformly along it), with the power of the shape they
  stand for.
* distant lights: a delta direction (angle = 0) or a cone of directions, uniformly.
* dome lights: a lat-long map sampled from a piecewise-constant distribution over it,
  weighted by luminance × sin θ.

One light per shading point is picked from a discrete distribution over "sources"
(all emitting triangles count as one source) in proportion to an estimate of their power.
``LightSampler`` builds the tables (``LightArrays``) once per frame; kernels call
:func:`sample`, :func:`emitted`, :func:`triangle_pdf` and the dome functions lane by lane.

What a light sends toward a direction (:func:`emitted`, :func:`shaping_factor`) follows the
UsdLux documentation (as hdEmbree, its reference implementation, evaluates it): θ is the
angle between the light's −Z axis and the emission direction; focus multiplies by
lerp(|cos θ|^focus, focusTint, 1), the cone by 1 − smoothstep(θ; cone·(1 − softness), cone)
(a hard cut at the cone without softness), an IES profile by its candela at (θ scaled by
angleScale, φ), φ the azimuth about the light's Z of the direction toward the light, as
hdEmbree takes it, divided by the profile's power under ``normalize``. A RectLight's colour
map multiplies its emission at each point (top-left corner of the image at local (+X, +Y)).

Light linking (``collection:lightLink``) and shadow linking (``collection:shadowLink``) are
per-triangle link groups (:func:`lit`, :func:`blocks`). A light whose shadows only some
geometry casts is found by light sampling alone (weight 1, no MIS), because a BSDF ray
toward it stops at geometry its shadow rays pass through; only singular (mirror, glass)
paths, which light sampling cannot take, receive it by hitting it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..scene import FLOAT, IesProfile, Light, SceneData
from . import bsdf, shading, textures
from ..compiled import inline, kernel, scratch
from .shading import MaterialArrays, MaterialTable
from .vectors import basis, luminance, luminance_of, normalized
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



AREA, DISTANT, DOME, POINT = range(4)  # source kinds

# Columns of LightArrays.light_shaping, one row per light.
SHAPED = 0  # 1: the light has a LightShaping (0: every factor is 1)
AXIS = 1  # 3 columns: the light's −Z axis in world space, unit
CONE_START, CONE_END = 4, 5  # radians: the smoothstep's ramp, cone·(1 − softness) .. cone
FOCUS = 6
TINT = 7  # 3 columns: focusTint
IES_PROFILE = 10  # row of ies_info, −1: none
IES_ANGLE_SCALE = 11
IES_FACTOR = 12  # 1 / the profile's power under ies:normalize, else 1
SHAPING_FIELDS = 13

POWER_SAMPLES = 128  # (point, direction) pairs averaged to estimate a shaped or textured emitter's power
SHAPE_WIDTH, SHAPE_HEIGHT = 0, 1  # columns of LightArrays.light_size


class LightArrays(NamedTuple):
    """What kernels read of the lights of a frame.

    light_radiance   : (lights, 3) radiance of each light (its shape's, for area lights)
    light_shaping    : (lights, SHAPING_FIELDS) float64 ShapingAPI rows (columns above)
    light_from_world : (lights, 3, 4) float64 affine map from world metres to the light's
                       local frame (its linear part also takes IES directions there)
    light_size       : (lights, 2) float64 rect width and height in local units
    light_texture    : (lights,) int64 a rect's colour map in the atlas (texture_info), −1 none
    light_response   : (lights, 2) float64 the diffuse and specular multipliers
    camera_visible   : (lights,) bool camera rays see the light
    sampled_only     : (lights,) bool found by light sampling alone (restricted shadow links)
    ies_info         : (p, 5) int64 per IES profile: offset and count of its vertical angles
                       in ies_angles, offset and count of its horizontal angles, offset of
                       its (H, V) candela table in ies_candela
    ies_angles, ies_candela : flat float64 tables (radians, candela)
    link_group       : (t,) int32 each triangle's link group, or (0,) when no light is linked
                       (group_of: every triangle and the camera then in group 0)
    link_lit, link_blocks : (groups, lights) bool: the group's geometry is lit by / blocks
                       the light

    Light selection is per link group G (one group without linking): a shading point picks
    only among the lights that light it, so linking costs no noise. Every `*_probability`
    and cdf below has the groups on its first axis.

    group_has_lights : (G,) bool some light lights the group
    emitter_triangles: (e,) int32 triangles NEE samples, triangle_cdf (G, e) float64 over them
    triangle_probability : (G, t) float32 probability of each triangle among the emitters
    area_probability : (G,) float64 probability of the area source
    point_*          : per positional delta light (q,): light index, centre (q, 3) metres,
                       segment (q, 3) (a line's full length along its axis, zeros for a
                       point), intensity scale (the emitting area it stands for, seen
                       broadside: π r² for a point, 2 r ℓ for a line, m²), probability (G, q)
    distant_*        : per distant light (d,): direction (d, 3) unit toward it, radiance
                       (d, 3), cos_max (cosine of the cone's half angle, 1 = delta), light
                       index, source probability (G, d)
    dome_*           : per dome (D,): radiance (D, 3), light_from_world (D, 3, 3), texture
                       (index into texture_info, −1 = none), rows, columns, offset into the
                       flat cell tables, offset into dome_row_cdf, light index, probability (G, D)
    dome_cell_probability, dome_column_cdf : flat float64 (Σ rows·columns); dome_row_cdf
                       flat float64 (Σ rows)
    source_kind (s,) int64 AREA / DISTANT / DOME / POINT, source_item (s,) index among its
    kind, source_cdf (G, s) float64
    texels, texture_info : the domes' and rects' textures (textures.py atlas)
    """

    light_radiance: np.ndarray
    light_shaping: np.ndarray
    light_from_world: np.ndarray
    light_size: np.ndarray
    light_texture: np.ndarray
    light_response: np.ndarray
    camera_visible: np.ndarray
    sampled_only: np.ndarray
    ies_info: np.ndarray
    ies_angles: np.ndarray
    ies_candela: np.ndarray
    link_group: np.ndarray
    link_lit: np.ndarray
    link_blocks: np.ndarray
    group_has_lights: np.ndarray
    emitter_triangles: np.ndarray
    triangle_cdf: np.ndarray
    triangle_probability: np.ndarray
    area_probability: np.ndarray
    point_light: np.ndarray
    point_center: np.ndarray
    point_segment: np.ndarray
    point_scale: np.ndarray
    point_probability: np.ndarray
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


def _shaping_row(light: Light, ies_row: int) -> np.ndarray:
    """light_shaping row of `light` (see the column constants)."""
    row = np.zeros(SHAPING_FIELDS)
    row[IES_PROFILE] = -1
    linear = np.asarray(light.world_from_light, np.float64)[:3, :3]
    axis = linear @ np.array([0.0, 0.0, -1.0])
    row[AXIS:AXIS + 3] = axis / max(np.linalg.norm(axis), 1e-30)
    shaping = light.shaping
    if shaping is None or light.kind in ("distant", "dome"):
        return row
    cone = np.radians(shaping.cone_angle)
    row[SHAPED] = 1
    row[CONE_START], row[CONE_END] = cone * (1 - shaping.cone_softness), cone
    row[FOCUS] = shaping.focus
    row[TINT:TINT + 3] = shaping.focus_tint
    if shaping.ies is not None:
        row[IES_PROFILE] = ies_row
        row[IES_ANGLE_SCALE] = shaping.ies_angle_scale
        row[IES_FACTOR] = 1 / shaping.ies.power if shaping.ies_normalize and shaping.ies.power > 0 else 1.0
    return row


class LightSampler:
    """Picks lights in proportion to an estimate of their power; builds ``arrays``."""

    def __init__(self, scene: SceneData, world: World, materials: MaterialTable, geometry: GeometryArrays):
        lights = scene.lights
        emissive_material = np.concatenate([materials.emissive, [False]])  # index -1 → False
        surface_emitter = (world.triangle_light < 0) & emissive_material[world.triangle_material]
        light_emitter = world.triangle_light >= 0
        self.triangle_emits = surface_emitter | light_emitter  # (t,) bool
        emitter_triangles = np.flatnonzero(self.triangle_emits).astype(np.int32)

        profiles = [light.shaping.ies for light in lights if light.shaping and light.shaping.ies is not None]
        ies_rows = {id(profile): row for row, profile in enumerate(profiles)}
        ies_info, ies_angles, ies_candela = _ies_tables(profiles)
        textured = [light.kind in ("rect", "dome") and light.texture is not None for light in lights]
        texels, texture_info = textures.pack([scene.textures[light.texture].pixels
                                              for light, has in zip(lights, textured) if has])
        atlas_index = np.where(textured, np.cumsum(textured) - 1, -1).astype(np.int64)  # each light's image
        inverse = [np.linalg.inv(np.asarray(light.world_from_light, np.float64))[:3] for light in lights]
        group, lit_table, blocks_table = _link_groups(scene, world)
        point_lights, centers, segments, scales = _positional(lights)
        self.arrays = LightArrays(
            light_radiance=np.array([light.radiance for light in lights], FLOAT).reshape(-1, 3),
            light_shaping=np.array([_shaping_row(light, ies_rows.get(id(light.shaping.ies), -1) if light.shaping
                                                 else -1) for light in lights], np.float64).reshape(-1, SHAPING_FIELDS),
            light_from_world=np.array(inverse, np.float64).reshape(-1, 3, 4),
            light_size=np.array([(light.width, light.height) for light in lights], np.float64).reshape(-1, 2),
            light_texture=np.where([light.kind == "rect" for light in lights], atlas_index, -1).astype(np.int64),
            light_response=np.array([(light.diffuse, light.specular) for light in lights], np.float64).reshape(-1, 2),
            camera_visible=np.array([light.camera_visible for light in lights], bool),
            sampled_only=np.array([light.shadow_link is not None for light in lights], bool),
            ies_info=ies_info, ies_angles=ies_angles, ies_candela=ies_candela,
            link_group=group, link_lit=lit_table, link_blocks=blocks_table, group_has_lights=np.zeros(1, bool),
            emitter_triangles=emitter_triangles, triangle_cdf=np.ones((1, 1)),
            triangle_probability=np.zeros((1, 0), FLOAT), area_probability=np.zeros(1),
            point_light=np.array(point_lights, np.int64),
            point_center=centers, point_segment=segments, point_scale=scales,
            point_probability=np.zeros((1, len(point_lights))),
            distant_direction=np.zeros((0, 3)), distant_radiance=np.zeros((0, 3)), distant_cos_max=np.zeros(0),
            distant_light=np.zeros(0, np.int64), distant_probability=np.zeros((1, 0)),
            dome_radiance=np.zeros((0, 3)), dome_rotation=np.zeros((0, 3, 3)), dome_texture=np.zeros(0, np.int64),
            dome_rows=np.zeros(0, np.int64), dome_columns=np.zeros(0, np.int64),
            dome_cell_offset=np.zeros(0, np.int64), dome_row_offset=np.zeros(0, np.int64),
            dome_light=np.zeros(0, np.int64), dome_probability=np.zeros((1, 0)), dome_cell_probability=np.zeros(0),
            dome_column_cdf=np.zeros(0), dome_row_cdf=np.zeros(0), source_kind=np.zeros(1, np.int64),
            source_item=np.zeros(1, np.int64), source_cdf=np.ones((1, 1)), texels=texels, texture_info=texture_info,
        )

        lit_table = self.arrays.link_lit  # (G, lights)
        groups = len(lit_table)
        # (kind, index among its kind, light or −1 for all emitting triangles, power)
        sources: list[tuple[int, int, int, float]] = []
        scene_area = np.pi * world.radius**2
        triangle_cdf = np.ones((groups, 1))
        triangle_probability = np.zeros((groups, world.triangle_count), FLOAT)
        area_power = np.zeros(groups)
        if len(emitter_triangles):
            radiance = _mean_emission(emitter_triangles, geometry, materials.arrays, self.arrays)
            emitter_light = world.triangle_light[emitter_triangles]
            sides = np.where(emitter_light < 0, 2.0, 1.0)
            power = world.area[emitter_triangles] * radiance * np.pi * sides
            keep = power > 0
            emitter_triangles, power, emitter_light = emitter_triangles[keep], power[keep], emitter_light[keep]
            if len(power):
                # per group, the triangles of the lights that light it; emissive surfaces (light −1,
                # the appended column) light every group
                allowed = np.concatenate([lit_table, np.ones((groups, 1), bool)], axis=1)[:, emitter_light]
                group_power = np.where(allowed, power, 0.0)
                area_power = group_power.sum(axis=1)
                triangle_cdf = np.array([_cumulative(row) if row.sum() > 0 else np.ones(len(row))
                                         for row in group_power])
                triangle_probability[:, emitter_triangles] = group_power / np.maximum(area_power, 1e-300)[:, None]
                sources.append((AREA, 0, -1, 1.0))
        if point_lights:
            point_power = _point_power(self.arrays)
            sources.extend((POINT, item, point_lights[item], float(power)) for item, power in enumerate(point_power))
        self.distant: list[DistantLight] = []
        self.domes: list[DomeDistribution] = []
        for index, light in enumerate(lights):
            rotation = np.asarray(light.world_from_light, np.float64)[:3, :3]
            if light.kind == "distant":
                toward = rotation @ np.array([0.0, 0.0, 1.0])
                half_angle = np.radians(np.clip(light.angle, 0.0, 360.0) / 2)
                distant = DistantLight(index, (toward / np.linalg.norm(toward)).astype(FLOAT),
                                       np.asarray(light.radiance, FLOAT), float(np.cos(half_angle)))
                sources.append((DISTANT, len(self.distant), index, float(luminance(distant.irradiance)) * scene_area))
                self.distant.append(distant)
            elif light.kind == "dome":
                orthonormal = rotation / np.linalg.norm(rotation, axis=0, keepdims=True)
                pixels = None if light.texture is None else scene.textures[light.texture].pixels
                dome = DomeDistribution(index, light.radiance, pixels, orthonormal.T)
                sources.append((DOME, len(self.domes), index, dome.mean_luminance * np.pi * scene_area))
                self.domes.append(dome)
        # (G, s): each source's power for each link group (the area source's is the group's own)
        power = np.array([[area_power[group] if kind == AREA else source_power * (lit_table[group, light])
                           for kind, _, light, source_power in sources] for group in range(groups)]).reshape(groups, -1)
        useful = power.sum(axis=0) > 0
        sources = [source for source, keep in zip(sources, useful) if keep]
        power = power[:, useful]
        total = power.sum(axis=1)
        self.has_lights = bool(sources)
        self.has_infinite_lights = bool(self.domes or any(not d.is_delta for d in self.distant))
        probability = power / np.maximum(total, 1e-300)[:, None]
        column = {(kind, item): at for at, (kind, item, _, _) in enumerate(sources)}

        def of(kind: int, count: int) -> np.ndarray:
            """(G, count) probability of each source of `kind` (0 for those left out)."""
            out = np.zeros((groups, count))
            for item in range(count):
                if (kind, item) in column:
                    out[:, item] = probability[:, column[kind, item]]
            return out

        rows = np.array([dome.shape[0] for dome in self.domes], np.int64)
        cols = np.array([dome.shape[1] for dome in self.domes], np.int64)
        self.arrays = self.arrays._replace(
            group_has_lights=total > 0,
            triangle_cdf=triangle_cdf,
            triangle_probability=triangle_probability,
            emitter_triangles=emitter_triangles,
            area_probability=np.ascontiguousarray(of(AREA, 1)[:, 0]),
            point_probability=of(POINT, len(point_lights)),
            distant_direction=np.array([d.direction for d in self.distant], np.float64).reshape(-1, 3),
            distant_radiance=np.array([d.radiance for d in self.distant], np.float64).reshape(-1, 3),
            distant_cos_max=np.array([d.cos_max for d in self.distant], np.float64),
            distant_light=np.array([d.light_index for d in self.distant], np.int64),
            distant_probability=of(DISTANT, len(self.distant)),
            dome_radiance=np.array([d.radiance for d in self.domes], np.float64).reshape(-1, 3),
            dome_rotation=np.array([d.light_from_world for d in self.domes], np.float64).reshape(-1, 3, 3),
            dome_texture=np.array([atlas_index[d.light_index] for d in self.domes], np.int64),
            dome_rows=rows, dome_columns=cols,
            dome_cell_offset=np.cumsum(rows * cols) - rows * cols,  # where each dome's cells start
            dome_row_offset=np.cumsum(rows) - rows,
            dome_light=np.array([d.light_index for d in self.domes], np.int64),
            dome_probability=of(DOME, len(self.domes)),
            dome_cell_probability=_flat([d.cell_probability for d in self.domes]),
            dome_column_cdf=_flat([d.column_cdf for d in self.domes]),
            dome_row_cdf=_flat([d.row_cdf for d in self.domes]),
            source_kind=np.array([kind for kind, _, _, _ in sources] or [AREA], np.int64),
            source_item=np.array([item for _, item, _, _ in sources] or [0], np.int64),
            source_cdf=np.array([_cumulative(row) if row.sum() > 0 else np.ones(len(row))
                                 for row in (power if sources else np.ones((groups, 1)))]),
        )


def _flat(values: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([np.ravel(v) for v in values]).astype(np.float64) if values else np.zeros(0)


def _ies_tables(profiles: list[IesProfile]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ies_info (p, 5) int64, ies_angles, ies_candela) of `profiles` (see LightArrays)."""
    info, angles, candela = [], [], []
    angle_offset = candela_offset = 0
    for profile in profiles:
        vertical, horizontal = len(profile.vertical), len(profile.horizontal)
        info.append((angle_offset, vertical, angle_offset + vertical, horizontal, candela_offset))
        angles += [profile.vertical, profile.horizontal]
        candela.append(profile.candela)
        angle_offset += vertical + horizontal
        candela_offset += profile.candela.size
    return np.array(info, np.int64).reshape(-1, 5), _flat(angles), _flat(candela)


def _positional(lights: tuple[Light, ...]) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray]:
    """The point and line lights: (their light indices, centres (q, 3) metres, segments
    (q, 3), intensity scales (q,) m²: see LightArrays.point_*)."""
    indices, centers, segments, scales = [], [], [], []
    for index, light in enumerate(lights):
        if light.kind not in ("point", "line"):
            continue
        world_from_light = np.asarray(light.world_from_light, np.float64)
        indices.append(index)
        centers.append(world_from_light[:3, 3])
        if light.kind == "point":
            segments.append(np.zeros(3))
            # the silhouette of the sphere it stands for: π r², and π (abc)^(2/3) for an ellipsoid on average
            scale = np.linalg.svd(world_from_light[:3, :3], compute_uv=False)
            scales.append(np.pi * light.radius**2 * float(np.prod(scale)) ** (2 / 3))
        else:  # a cylinder along local X: its silhouette broadside is 2 r ℓ
            segment = world_from_light[:3, 0] * light.length
            segments.append(segment)
            across = float(np.sqrt(np.prod(np.linalg.svd(world_from_light[:3, 1:3], compute_uv=False))))
            scales.append(2 * light.radius * across * float(np.linalg.norm(segment)))
    return (indices, np.array(centers, np.float64).reshape(-1, 3), np.array(segments, np.float64).reshape(-1, 3),
            np.array(scales, np.float64))


def _link_groups(scene: SceneData, world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(link_group (t,) int32, lit (groups, lights) bool, blocks (groups, lights) bool) of
    the lights' light and shadow links; ((0,), (1, lights) True, same) when no light is
    linked. Light shapes light nothing and block every light whose shadows are not linked."""
    lights = scene.lights
    if all(light.light_link is None and light.shadow_link is None for light in lights):
        return np.zeros(0, np.int32), np.ones((1, len(lights)), bool), np.ones((1, len(lights)), bool)
    mesh_of_object = world.object_mesh
    rows = np.ones((len(mesh_of_object), 2, len(lights)), bool)
    for column, light in enumerate(lights):
        for side, members in enumerate((light.light_link, light.shadow_link)):
            if members is None:
                continue
            member = np.zeros(len(scene.meshes) + 1, bool)  # the extra last entry: light shapes (−1)
            member[list(members)] = True
            rows[:, side, column] = member[mesh_of_object]
    unique, object_group = np.unique(rows.reshape(len(rows), -1), axis=0, return_inverse=True)
    unique = unique.reshape(-1, 2, len(lights))
    group = object_group.reshape(-1).astype(np.int32)[world.triangle_object]
    return group, np.ascontiguousarray(unique[:, 0]), np.ascontiguousarray(unique[:, 1])


def _mean_emission(triangles: np.ndarray, geometry: GeometryArrays, materials: MaterialArrays,
                   lights: LightArrays) -> np.ndarray:
    """Luminance (e,) of the radiance emitting triangles send, averaged over their area and
    cosine-weighted directions of their front ((1/π) ∫ L cos dω, from POWER_SAMPLES points
    and directions uniform over the light's cone where it is shaped or textured, from the
    centroid elsewhere)."""
    out = np.zeros(len(triangles), np.float64)
    _mean_emission_kernel(triangles, geometry, materials, lights, POWER_SAMPLES, scratch(shading.REGISTERS, 4),
                          scratch(shading.MATERIAL_FIELDS), scratch(3), out)
    return out


@inline
def _hammersley(k, count):
    """Point k of a `count`-point Hammersley set in [0, 1)²."""
    bits, inverse, place = k, 0.0, 0.5
    while bits > 0:
        if bits & 1:
            inverse += place
        bits >>= 1
        place *= 0.5
    return (k + 0.5) / count, inverse


@inline
def _spread_direction(lights, light, a, b):
    """A direction (ex, ey, ez) from (a, b) ∈ [0, 1)², uniform over the directions a shaped
    light can emit into (its cone about its axis, the whole sphere for an unshaped light or
    a cone of 180°), and that set's solid angle: a narrow spotlight's power is then
    estimated from directions inside its cone, not from the few that fall there by chance."""
    cos_max = math.cos(lights.light_shaping[light, CONE_END]) if lights.light_shaping[light, SHAPED] > 0 else -1.0
    cos_theta = 1.0 - a * (1.0 - cos_max)
    sin_theta = math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))
    ax, ay, az = lights.light_shaping[light, AXIS], lights.light_shaping[light, AXIS + 1], lights.light_shaping[light, AXIS + 2]
    tx, ty, tz, bx, by, bz = basis(ax, ay, az)
    cx, sx = sin_theta * math.cos(2 * math.pi * b), sin_theta * math.sin(2 * math.pi * b)
    return (tx * cx + bx * sx + ax * cos_theta, ty * cx + by * sx + ay * cos_theta, tz * cx + bz * sx + az * cos_theta,
            2 * math.pi * (1.0 - cos_max))


# a light triangle or point whose estimate falls below this fraction of its unshaped power
# keeps that much: every part of a light stays reachable by light sampling
POWER_FLOOR = 1e-4


@kernel
def _mean_emission_kernel(triangles, geometry, materials, lights, samples, registers, inputs, radiance, out):
    normal = geometry.geometric_normal
    third = 1.0 / 3.0
    for lane in range(len(triangles)):
        triangle = triangles[lane]
        light = geometry.triangle_light[triangle]
        nx, ny, nz = normal[triangle, 0], normal[triangle, 1], normal[triangle, 2]
        if not (light >= 0 and (lights.light_shaping[light, SHAPED] > 0 or lights.light_texture[light] >= 0)):
            emitted(triangle, third, third, nx, ny, nz, 1.0, geometry, lights, materials, registers, inputs, radiance)
            out[lane] = luminance_of(radiance[0], radiance[1], radiance[2])
            continue
        total = 0.0
        for k in range(samples):
            a, b = _hammersley(k, samples)
            ex, ey, ez, solid_angle = _spread_direction(lights, light, a, b)
            cos_out = ex * nx + ey * ny + ez * nz
            if cos_out <= 0:
                continue
            other = math.sqrt(b)  # a point uniform over the triangle
            emitted(triangle, a * other, 1.0 - other, ex, ey, ez, cos_out, geometry, lights, materials, registers,
                    inputs, radiance)
            # the mean over cosine-weighted directions, (1/π) ∫ L cos dω, from uniform ones
            total += luminance_of(radiance[0], radiance[1], radiance[2]) * cos_out * solid_angle / math.pi
        base = lights.light_radiance[light]
        out[lane] = max(total / samples, POWER_FLOOR * luminance_of(base[0], base[1], base[2]))


def _point_power(lights: LightArrays) -> np.ndarray:
    """Power estimate (q,) of each positional delta light: its luminance times the shaping
    factor integrated over the directions it can emit into (POWER_SAMPLES² of them)."""
    out = np.zeros(len(lights.point_light), np.float64)
    _point_power_kernel(lights, POWER_SAMPLES * POWER_SAMPLES, out)
    return out


@kernel
def _point_power_kernel(lights, samples, out):
    for item in range(len(lights.point_light)):
        light = lights.point_light[item]
        sx, sy, sz = lights.point_segment[item, 0], lights.point_segment[item, 1], lights.point_segment[item, 2]
        length = math.sqrt(sx * sx + sy * sy + sz * sz)
        radiance = lights.light_radiance[light]
        total = solid_angle = 0.0
        for k in range(samples):
            a, b = _hammersley(k, samples)
            ex, ey, ez, solid_angle = _spread_direction(lights, light, a, b)
            fr, fg, fb = shaping_factor(lights, light, ex, ey, ez)
            broadside = 1.0
            if length > 0:  # a segment's silhouette shrinks as |sin| of the angle to its axis
                along = (ex * sx + ey * sy + ez * sz) / length
                broadside = math.sqrt(max(1.0 - along * along, 0.0))
            total += luminance_of(radiance[0] * fr, radiance[1] * fg, radiance[2] * fb) * broadside
        unshaped = luminance_of(radiance[0], radiance[1], radiance[2]) * 4 * math.pi
        out[item] = max(total / samples * solid_angle, POWER_FLOOR * unshaped) * lights.point_scale[item]


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
def emitted(triangle, u, v, ex, ey, ez, cos_toward_viewer, geometry, lights, materials, registers, inputs, out):
    """Radiance leaving an emitting `triangle` at barycentrics (u, v) in unit world direction
    (ex, ey, ez), under cos_toward_viewer from its geometric normal, into out (3,): light
    shapes emit on their front only, shaped (shaping_factor) and textured; emissive surfaces
    on both sides, in proportion to their presence (the fraction of paths that do not pass
    through them). registers, inputs: scratch of shading.material_inputs."""
    light = geometry.triangle_light[triangle]
    if light < 0:
        shading.shade_point(materials, geometry, triangle, u, v, registers, inputs)
        present = 1.0 - shading.pass_fraction(inputs)  # what passes through does not emit
        out[0], out[1], out[2] = (inputs[shading.EMISSIVE] * present, inputs[shading.EMISSIVE + 1] * present,
                                  inputs[shading.EMISSIVE + 2] * present)
        return
    if not cos_toward_viewer > 0:
        out[0] = out[1] = out[2] = 0.0
        return
    radiance = lights.light_radiance
    r, g, b = radiance[light, 0], radiance[light, 1], radiance[light, 2]
    if lights.light_shaping[light, SHAPED] > 0:
        fr, fg, fb = shaping_factor(lights, light, ex, ey, ez)
        r, g, b = r * fr, g * fg, b * fb
    texture = lights.light_texture[light]
    if texture >= 0:
        corners, w = geometry.corner_positions, 1.0 - u - v
        qx = w * corners[triangle, 0, 0] + u * corners[triangle, 1, 0] + v * corners[triangle, 2, 0]
        qy = w * corners[triangle, 0, 1] + u * corners[triangle, 1, 1] + v * corners[triangle, 2, 1]
        qz = w * corners[triangle, 0, 2] + u * corners[triangle, 1, 2] + v * corners[triangle, 2, 2]
        m = lights.light_from_world[light]
        x = m[0, 0] * qx + m[0, 1] * qy + m[0, 2] * qz + m[0, 3]
        y = m[1, 0] * qx + m[1, 1] * qy + m[1, 2] * qz + m[1, 3]
        # UsdLux: the image's top-left corner at (+X, +Y), bottom-right at (−X, −Y)
        s = 0.5 - x / lights.light_size[light, SHAPE_WIDTH]
        t = 0.5 + y / lights.light_size[light, SHAPE_HEIGHT]
        i00, i10, i01, i11, fx, fy = textures.footprint(lights.texture_info, texture, s, t, 2, 2)
        texels, channels = lights.texels, lights.texture_info[texture, textures.CHANNELS]
        r *= textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 0))
        g *= textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 1))
        b *= textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 2))
    out[0], out[1], out[2] = r, g, b


@inline
def shaping_factor(lights, light, ex, ey, ez):
    """Per-channel factor (fr, fg, fb) ShapingAPI applies to light `light`'s emission in unit
    world direction (ex, ey, ez) (see the module docstring); (1, 1, 1) for unshaped lights."""
    row = lights.light_shaping[light]
    if row[SHAPED] == 0:
        return 1.0, 1.0, 1.0
    cos_theta = min(max(ex * row[AXIS] + ey * row[AXIS + 1] + ez * row[AXIS + 2], -1.0), 1.0)
    fr = fg = fb = 1.0
    if row[FOCUS] > 0:
        focus = abs(cos_theta) ** row[FOCUS]
        fr = row[TINT] + (1.0 - row[TINT]) * focus
        fg = row[TINT + 1] + (1.0 - row[TINT + 1]) * focus
        fb = row[TINT + 2] + (1.0 - row[TINT + 2]) * focus
    theta = math.acos(cos_theta)
    start, end = row[CONE_START], row[CONE_END]
    if end > start:
        ramp = min(max((theta - start) / (end - start), 0.0), 1.0)
        scale = 1.0 - ramp * ramp * (3.0 - 2.0 * ramp)
    else:
        scale = 1.0 if theta <= end else 0.0
    profile = np.int64(row[IES_PROFILE])
    if profile >= 0 and scale > 0:
        scale *= ies_intensity(lights, light, profile, row[IES_ANGLE_SCALE], ex, ey, ez) * row[IES_FACTOR]
    return fr * scale, fg * scale, fb * scale


@inline
def _bracket(angles, start, count, x):
    """(i, f): angles[start + i] ≤ x ≤ angles[start + i + 1] at fraction f; i = −1 when x is
    outside [angles[start], angles[start + count − 1]]."""
    if count == 1:
        return (0, 0.0) if x == angles[start] else (-1, 0.0)
    if x < angles[start] or x > angles[start + count - 1]:
        return -1, 0.0
    i = min(pick(angles, start, count, x) - 1, count - 2)  # the first angle above x, minus one
    i = max(i, 0)
    low, high = angles[start + i], angles[start + i + 1]
    return i, (x - low) / (high - low) if high > low else 0.0


@inline
def ies_intensity(lights, light, profile, angle_scale, ex, ey, ez):
    """Candela of IES `profile` in unit world direction (ex, ey, ez) of light `light`: θ from
    the light's −Z, scaled by angleScale (UsdLux: θ/s for s > 0, (θ − π)/−s + π for s < 0),
    φ the azimuth about Z of the direction toward the light (hdEmbree's convention),
    bilinear in the profile's table, 0 outside its vertical angles."""
    m = lights.light_from_world[light]
    lx = m[0, 0] * ex + m[0, 1] * ey + m[0, 2] * ez
    ly = m[1, 0] * ex + m[1, 1] * ey + m[1, 2] * ez
    lz = m[2, 0] * ex + m[2, 1] * ey + m[2, 2] * ez
    lx, ly, lz = normalized(lx, ly, lz, 1e-30)
    theta = math.acos(min(max(-lz, -1.0), 1.0))
    if angle_scale > 0:
        theta = theta / angle_scale
    elif angle_scale < 0:
        theta = (theta - math.pi) / -angle_scale + math.pi
    theta = min(max(theta, 0.0), math.pi)
    phi = math.atan2(-ly, -lx)
    if phi < 0:
        phi += 2 * math.pi
    info = lights.ies_info[profile]
    v_start, v_count, h_start, h_count, table = info[0], info[1], info[2], info[3], info[4]
    vi, vf = _bracket(lights.ies_angles, v_start, v_count, theta)
    hi, hf = _bracket(lights.ies_angles, h_start, h_count, phi)
    if vi < 0 or hi < 0:
        return 0.0
    candela = lights.ies_candela
    v_next = min(vi + 1, v_count - 1)
    h_next = min(hi + 1, h_count - 1)
    near = candela[table + hi * v_count + vi] * (1 - vf) + candela[table + hi * v_count + v_next] * vf
    far = candela[table + h_next * v_count + vi] * (1 - vf) + candela[table + h_next * v_count + v_next] * vf
    return near * (1 - hf) + far * hf


@inline
def lit(lights, light, triangle):
    """Whether light `light` (−1: an emissive surface) lights the geometry of `triangle`
    (−1: the camera, which sees every light) under light linking."""
    if light < 0 or triangle < 0 or len(lights.link_group) == 0:
        return True
    return lights.link_lit[lights.link_group[triangle], light]


@inline
def blocks(lights, light, triangle):
    """Whether `triangle` casts a shadow from light `light` (−1: an emissive surface) under
    shadow linking."""
    if light < 0 or len(lights.link_group) == 0:
        return True
    return lights.link_blocks[lights.link_group[triangle], light]


@inline
def response(lights, light, lobe):
    """UsdLux's diffuse or specular multiplier of light `light` (−1: an emissive surface) for
    light reaching a path through `lobe` (bsdf.DIFFUSE, another lobe, or −1: the camera)."""
    if light < 0 or lobe < 0:
        return 1.0
    return lights.light_response[light, 0 if lobe == bsdf.DIFFUSE else 1]


@inline
def found_by_hit(lights, light, depth, previous_triangle, previous_lobe, previous_singular):
    """The factor of what a path finds by hitting light `light` (−1: an emissive surface):
    0 where the camera may not see it (depth 0), where light linking keeps it from the
    geometry the path left, and where only light sampling finds it (restricted shadow
    links) unless the path came off a singular lobe; else its diffuse/specular multiplier."""
    if light < 0:
        return 1.0
    if depth == 0:
        return 1.0 if lights.camera_visible[light] else 0.0
    if lights.sampled_only[light] and not previous_singular:
        return 0.0
    if not lit(lights, light, previous_triangle):
        return 0.0
    return response(lights, light, previous_lobe)


@inline
def cone_pdf(probability, cos_max):
    """Solid-angle density of a distant light's cone (sampled uniformly), with its source
    probability."""
    return probability / (2 * math.pi * (1 - cos_max))


@inline
def group_of(lights, triangle):
    """The link group of `triangle` (−1: the camera): what selects a shading point's lights."""
    if triangle < 0 or len(lights.link_group) == 0:
        return 0
    return lights.link_group[triangle]


@inline
def triangle_pdf(lights, group, triangle, distance, cos_light, area):
    """Solid-angle density with which NEE from link group `group` picks a point seen at
    `distance` on `triangle` under |cos_light|."""
    area_probability = lights.area_probability[group]
    if area_probability == 0:
        return 0.0
    area_density = area_probability * lights.triangle_probability[group, triangle] / area[triangle]
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
def sample(lights, geometry, materials, group, px, py, pz, u0, u1, u2, u3, registers, inputs, scratch):
    """One light sample toward point (px, py, pz) of link group `group` (group_of; its
    group must have lights: group_has_lights) from uniforms u0 (source), u1, u2
    (position), u3 (triangle). Returns (direction x, y, z unit toward the light; distance,
    metres, inf for distant and dome; radiance r, g, b arriving (irradiance at normal
    incidence for a delta light, point, line or distant, already divided by its
    probability); pdf, solid angle, with the light's selection, inf for a delta; light index, −1 for an emissive surface; triangle
    sampled, −1 for distant and dome). pdf 0: no sample."""
    source_cdf = lights.source_cdf[group]
    source = pick(source_cdf, 0, len(source_cdf), u0)
    kind, item = lights.source_kind[source], lights.source_item[source]
    if kind == AREA:
        triangle_cdf = lights.triangle_cdf[group]
        chosen = lights.emitter_triangles[pick(triangle_cdf, 0, len(triangle_cdf), u3)]
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
        emitted(chosen, bu, bv, -dx, -dy, -dz, cos_light, geometry, lights, materials, registers, inputs, scratch)
        pdf = triangle_pdf(lights, group, chosen, distance, cos_light, geometry.area)
        return (dx, dy, dz, distance, scratch[0], scratch[1], scratch[2], pdf, geometry.triangle_light[chosen],
                chosen)
    if kind == POINT:
        light = lights.point_light[item]
        segment = lights.point_segment[item]
        qx = lights.point_center[item, 0] + segment[0] * (u1 - 0.5)
        qy = lights.point_center[item, 1] + segment[1] * (u1 - 0.5)
        qz = lights.point_center[item, 2] + segment[2] * (u1 - 0.5)
        ox, oy, oz = qx - px, qy - py, qz - pz
        distance = math.sqrt(ox * ox + oy * oy + oz * oz)
        dx, dy, dz = normalized(ox, oy, oz, 1e-12)
        length = math.sqrt(segment[0] * segment[0] + segment[1] * segment[1] + segment[2] * segment[2])
        broadside = 1.0
        if length > 0:  # a segment's silhouette shrinks as |sin| of the angle to its axis
            along = (dx * segment[0] + dy * segment[1] + dz * segment[2]) / length
            broadside = math.sqrt(max(1.0 - along * along, 0.0))
        fr, fg, fb = shaping_factor(lights, light, -dx, -dy, -dz)
        # irradiance at normal incidence: intensity / distance², by the light's probability
        scale = lights.point_scale[item] * broadside / max(distance * distance, 1e-12) / lights.point_probability[group, item]
        radiance = lights.light_radiance
        return (dx, dy, dz, distance, radiance[light, 0] * fr * scale, radiance[light, 1] * fg * scale,
                radiance[light, 2] * fb * scale, math.inf, light, -1)
    if kind == DISTANT:
        light = lights.distant_light[item]
        ax, ay, az = lights.distant_direction[item, 0], lights.distant_direction[item, 1], lights.distant_direction[item, 2]
        r, g, b = lights.distant_radiance[item, 0], lights.distant_radiance[item, 1], lights.distant_radiance[item, 2]
        probability = lights.distant_probability[group, item]
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
    pdf = lights.dome_probability[group, item] * dome_pdf(lights, item, dx, dy, dz)
    return dx, dy, dz, math.inf, r, g, b, pdf, lights.dome_light[item], -1
