"""The light tables of a frame, built once on the host (after Cycles' scene/light.cpp); the
per-lane functions that read them are in light_kernels/, one module per light type.

Five kinds of sources:

* emitting triangles, one "area" source: the tessellated area lights (one-sided, or outward
  for cylinders) and triangles of emissive materials (two-sided); a triangle is picked in
  proportion to its area × an estimate of its power (the emission averaged over points and
  cosine-weighted directions, so a narrow cone or an IES profile is sampled in proportion to
  what it sends).
* sphere lights, each its own source, sampled by solid angle (light_kernels/sphere.py) when
  their tessellation is round enough and BSDF rays may find them too (an ellipsoid, or a
  light with restricted shadow links, has its triangles join the area source), with the
  power of their triangles.
* positional delta lights: spheres with ``treatAsPoint`` (a point) and cylinders with
  ``treatAsLine`` (a segment), with the power of the shape they stand for.
* distant lights: a delta direction (angle = 0) or a cone of directions.
* dome lights: a lat-long map sampled from a piecewise-constant distribution over it,
  weighted by luminance × sin θ (:class:`DomeDistribution`).

One light per shading point is picked from a discrete distribution over the sources in
proportion to an estimate of their power, per link group (light linking): a shading point
picks only among the lights that light it. ``LightSampler`` builds the per-light emission
table first (light_kernels.EmissionTable: what the power estimates read), then the whole
``LightArrays`` once.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..compiled import inline, kernel, scratch
from ..scene import FLOAT, IesProfile, Light, SceneData
from . import shading, textures
from .light_kernels import EmissionTable, LightArrays, emitted
from .light_kernels.distribution import uniform_cone
from .light_kernels.point import broadside
from .light_kernels.shaping import shaping_factor
from .light_kernels.table import (
    AREA, AXIS, CONE_END, CONE_START, DISTANT, DOME, FOCUS, IES_ANGLE_SCALE, IES_FACTOR, IES_PROFILE, POINT,
    SHAPED, SHAPING_FIELDS, SPHERE, TINT,
)
from .shading import MaterialArrays, MaterialTable
from .vectors import luminance, luminance_of
from .world import GeometryArrays, World

log = logging.getLogger(__name__)

DOME_GRID = (64, 128)  # (rows, columns) of the dome's sampling distribution at most
POWER_SAMPLES = 128  # (point, direction) pairs averaged to estimate a shaped or textured emitter's power
# a light triangle or point whose estimate falls below this fraction of its unshaped power
# keeps that much: every part of a light stays reachable by light sampling
POWER_FLOOR = 1e-4
# A sphere light is sampled by solid angle when the ball inside its tessellation has at least
# this fraction of the radius of the ball around it (a UV sphere's: 0.996); below, the rim
# the cone misses, left to BSDF sampling alone, would be noisy (an ellipsoid): area sampling.
ROUND_ENOUGH = 0.99
# Margin of the spheres' radii relative to their coordinates: the inner ball stays inside the
# tessellation and the outer one around it, through float32 vertices and Embree's rounding.
RADIUS_MARGIN = 1e-6


def _cumulative(weights: np.ndarray) -> np.ndarray:
    cdf = np.cumsum(weights, dtype=np.float64)
    return cdf / cdf[-1]


class DomeDistribution:
    """Piecewise-constant sampling of a lat-long dome (OpenEXR orientation, +Y up; see
    light_kernels/dome.py for the pixel ↔ direction map).

    cell_probability : (rows, columns) float64, sums to 1; row_cdf (rows,); column_cdf
                       (rows, columns), each row's own cdf
    mean_luminance   : luminance of the radiance averaged over the map's texels
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
        mean_texel = 1.0 if pixels is None else float(luminance(np.moveaxis(textures.rgb_view(pixels), -1, 0)).mean())
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


@dataclass
class SolidAngleSpheres:
    """The sphere lights sampled by solid angle (S of them; LightArrays.sphere_*).

    light : (S,) int64 light indices; center (S, 3) float64 metres; inner_radius,
    outer_radius (S,) float64 metres: the balls about the centre inside and around the
    light's tessellation."""

    light: np.ndarray
    center: np.ndarray
    inner_radius: np.ndarray
    outer_radius: np.ndarray

    @classmethod
    def of(cls, lights: tuple[Light, ...], world: World) -> SolidAngleSpheres:
        # a light only light sampling finds (restricted shadow links: no MIS with BSDF hits)
        # keeps area sampling, which covers the rim of its shape that the inner cone misses
        spheres = np.array([index for index, light in enumerate(lights)
                            if light.kind == "sphere" and light.shadow_link is None], np.int64)
        # each sphere's triangles, from one sort of the triangles of every sphere
        shape = np.flatnonzero(np.isin(world.triangle_light, spheres))
        shape = shape[np.argsort(world.triangle_light[shape], kind="stable")]
        owner = world.triangle_light[shape]
        starts, stops = np.searchsorted(owner, spheres), np.searchsorted(owner, spheres, side="right")
        balls = [(index, _sphere_balls(lights[index], world.vertices[world.triangles[shape[start:stop]]]))
                 for index, start, stop in zip(spheres, starts, stops)]
        rows = [(index, *ball) for index, ball in balls if ball is not None]
        return cls(np.array([index for index, _, _, _ in rows], np.int64),
                   np.array([center for _, center, _, _ in rows], np.float64).reshape(-1, 3),
                   np.array([inner for _, _, inner, _ in rows], np.float64),
                   np.array([outer for _, _, _, outer in rows], np.float64))


def _sphere_balls(light: Light, corners: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """(centre (3,) metres, inner radius, outer radius) of a sphere light whose tessellation
    has triangles with `corners` (k, 3 corners, 3) float32, metres, when it is round enough
    to sample by solid angle (ROUND_ENOUGH); None otherwise (it is then area-sampled).

    The inner radius is the nearest face plane's distance from the centre: world.py's UV
    sphere is convex, and so is its image under any transform, so that ball is inside it."""
    center = np.asarray(light.world_from_light, np.float64)[:3, 3]
    corners = corners.astype(np.float64) - center
    # face normals in float64 (the world's are float32), wound outward like the world's
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(cross, axis=1)
    faces = length > 0  # zero-area triangles have no plane
    if not faces.any():
        return None
    plane_offset = np.einsum("ki,ki->k", cross[faces] / length[faces, None], corners[faces, 0])
    # float32 vertices are off by up to an ulp of their coordinates: the balls keep clear of that
    slack = RADIUS_MARGIN * (float(np.abs(center).max()) + float(np.abs(corners).max()))
    inner = float(plane_offset.min()) - slack  # negative for faces turned inward
    outer = float(np.linalg.norm(corners, axis=2).max()) + slack
    if inner < ROUND_ENOUGH * outer:
        log.debug("sphere light %s: area-sampled (inner/outer radius %.4f)", light.path, inner / outer)
        return None
    return center, inner, outer


def _shaping_row(light: Light, ies_row: int) -> np.ndarray:
    """EmissionTable.shaping row of `light` (see the column constants of light_kernels.table)."""
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


def _oriented(light: Light) -> bool:
    """Whether the light's transform keeps every axis (no scale of 0): a distant light's
    direction and a dome's orientation are read from it."""
    axes = np.linalg.norm(np.asarray(light.world_from_light, np.float64)[:3, :3], axis=0)
    return bool(np.isfinite(axes).all() and (axes > 0).all())


def _light_from_world(light: Light) -> np.ndarray:
    """(4, 4) float64 the inverse of the light's transform; a light scaled to nothing (a
    scale of 0: no area, it sends nothing, and darkness says so) has none, and gets the
    pseudo-inverse (its emission table row is never read for a point it could light)."""
    world_from_light = np.asarray(light.world_from_light, np.float64)
    try:
        return np.linalg.inv(world_from_light)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(world_from_light)


def _emission_table(scene: SceneData) -> tuple[EmissionTable, np.ndarray]:
    """(EmissionTable of `scene`'s lights, atlas_index (lights,) int64: each light's image in
    its texture atlas, −1 for none)."""
    lights = scene.lights
    profiles = [light.shaping.ies for light in lights if light.shaping and light.shaping.ies is not None]
    ies_rows = {id(profile): row for row, profile in enumerate(profiles)}
    ies_info, ies_angles, ies_candela = _ies_tables(profiles)
    textured = [light.kind in ("rect", "dome") and light.texture is not None for light in lights]
    texels, texture_info = textures.pack([scene.textures[light.texture].pixels
                                          for light, has in zip(lights, textured) if has])
    atlas_index = np.where(textured, np.cumsum(textured) - 1, -1).astype(np.int64)
    inverse = [_light_from_world(light)[:3] for light in lights]
    shaping = [_shaping_row(light, ies_rows.get(id(light.shaping.ies), -1) if light.shaping else -1)
               for light in lights]
    table = EmissionTable(
        radiance=np.array([light.radiance for light in lights], FLOAT).reshape(-1, 3),
        shaping=np.array(shaping, np.float64).reshape(-1, SHAPING_FIELDS),
        light_from_world=np.array(inverse, np.float64).reshape(-1, 3, 4),
        size=np.array([(light.width, light.height) for light in lights], np.float64).reshape(-1, 2),
        texture=np.where([light.kind == "rect" for light in lights], atlas_index, -1).astype(np.int64),
        ies_info=ies_info, ies_angles=ies_angles, ies_candela=ies_candela, texels=texels, texture_info=texture_info)
    return table, atlas_index


class LightSampler:
    """Picks lights in proportion to an estimate of their power; builds ``arrays``
    (LightArrays) once.

    triangle_emits      : (t,) bool the triangles rays find emission on (light shapes and
                          emissive surfaces)
    object_link_group   : (objects,) int32 each object's light link group, (0,) when no
                          light is linked (an instance's placed rows take its object's)
    has_lights          : some light sends something
    has_infinite_lights : some dome or distant cone (escaped rays find them)
    darkness            : why the lights will light nothing (no light sends anything, naming
                          each light's reason; or every light that sends something has
                          inputs:diffuse and inputs:specular 0), one line; None when some
                          light lights the scene
    """

    def __init__(self, scene: SceneData, world: World, materials: MaterialTable, geometry: GeometryArrays):
        lights = scene.lights
        emissive_material = np.concatenate([materials.emissive, [False]])  # index -1 → False
        surface_emitter = (world.triangle_light < 0) & emissive_material[world.triangle_material]
        if surface_emitter[len(world.triangles):].any():  # the stage never instances an emitter
            raise ValueError("an instanced surface has an emissive material: emitters are sampled as flat rows only")
        self.triangle_emits = surface_emitter | (world.triangle_light >= 0)  # (t,) bool
        emission, atlas_index = _emission_table(scene)
        group, self.object_link_group, lit_table, blocks_table = _link_groups(scene, world)
        groups = len(lit_table)
        # lights that light each group; the appended last column: emissive surfaces (light −1) light every group
        lit_or_surface = np.concatenate([lit_table, np.ones((groups, 1), bool)], axis=1)

        # (kind, index among its kind, power (G,) for each link group)
        sources: list[tuple[int, int, np.ndarray]] = []
        spheres = SolidAngleSpheres.of(lights, world)
        triangles = np.flatnonzero(self.triangle_emits).astype(np.int32)
        triangle_power = _triangle_power(triangles, world, geometry, materials.arrays, emission)
        triangle_light = world.triangle_light[triangles]
        for item, light in enumerate(spheres.light):  # a sphere sends what its triangles send
            sources.append((SPHERE, item, triangle_power[triangle_light == light].sum() * lit_table[:, light]))
        area = (triangle_power > 0) & ~np.isin(triangle_light, spheres.light)
        emitter_triangles = triangles[area]
        group_power = np.where(lit_or_surface[:, triangle_light[area]], triangle_power[area], 0.0)  # (G, e)
        area_power = group_power.sum(axis=1)
        if len(emitter_triangles):
            sources.append((AREA, 0, area_power))
        triangle_probability = np.zeros((groups, len(world.area)), FLOAT)
        triangle_probability[:, emitter_triangles] = group_power / np.maximum(area_power, 1e-300)[:, None]

        point_light, point_center, point_segment, point_scale = _positional(lights)
        point_power = _point_power(emission, point_light, point_segment, point_scale)
        sources.extend((POINT, item, power * lit_table[:, point_light[item]]) for item, power in enumerate(point_power))
        scene_area = np.pi * world.radius**2
        # (lights,) each light's power estimate, and the emissive surfaces': what darkness reads
        lit = triangle_light >= 0
        light_power = np.bincount(triangle_light[lit], triangle_power[lit], minlength=len(lights)).astype(np.float64)
        np.add.at(light_power, point_light, point_power)
        surface_power = float(triangle_power[~lit].sum())
        distant: list[DistantLight] = []
        domes: list[DomeDistribution] = []
        for index, light in enumerate(lights):
            rotation = np.asarray(light.world_from_light, np.float64)[:3, :3]
            if light.kind in ("distant", "dome") and not _oriented(light):
                continue  # scaled to nothing, it has no direction: it sends nothing (darkness says so)
            if light.kind == "distant":
                toward = rotation @ np.array([0.0, 0.0, 1.0])
                half_angle = np.radians(np.clip(light.angle, 0.0, 360.0) / 2)
                one = DistantLight(index, (toward / np.linalg.norm(toward)).astype(FLOAT),
                                   np.asarray(light.radiance, FLOAT), float(np.cos(half_angle)))
                light_power[index] += float(luminance(one.irradiance)) * scene_area
                sources.append((DISTANT, len(distant), float(luminance(one.irradiance)) * scene_area * lit_table[:, index]))
                distant.append(one)
            elif light.kind == "dome":
                orthonormal = rotation / np.linalg.norm(rotation, axis=0, keepdims=True)
                pixels = None if light.texture is None else scene.textures[light.texture].pixels
                dome = DomeDistribution(index, light.radiance, pixels, orthonormal.T)
                light_power[index] += dome.mean_luminance * np.pi * scene_area
                sources.append((DOME, len(domes), dome.mean_luminance * np.pi * scene_area * lit_table[:, index]))
                domes.append(dome)

        # (G, s): each source's power for each link group; sources no group can use are left out
        power = np.array([source_power for _, _, source_power in sources], np.float64).reshape(-1, groups).T
        useful = power.sum(axis=0) > 0
        sources = [source for source, keep in zip(sources, useful) if keep]
        power = power[:, useful]
        total = power.sum(axis=1)
        self.has_lights = bool(sources)
        self.darkness = darkness(scene, world, light_power * lit_table.any(axis=0), surface_power,
                                 bool(surface_emitter.any()), self.has_lights)
        self.has_infinite_lights = bool(domes or any(not d.is_delta for d in distant))
        probability = power / np.maximum(total, 1e-300)[:, None]
        column = {(kind, item): at for at, (kind, item, _) in enumerate(sources)}

        def of(kind: int, count: int) -> np.ndarray:
            """(G, count) probability of each source of `kind` (0 for those left out)."""
            out = np.zeros((groups, count))
            for item in range(count):
                if (kind, item) in column:
                    out[:, item] = probability[:, column[kind, item]]
            return out

        light_sphere = np.full(len(lights), -1, np.int64)
        light_sphere[spheres.light] = np.arange(len(spheres.light))
        rows = np.array([dome.shape[0] for dome in domes], np.int64)
        cols = np.array([dome.shape[1] for dome in domes], np.int64)
        self.arrays = LightArrays(
            emission=emission,
            light_response=np.array([(light.diffuse, light.specular) for light in lights], np.float64).reshape(-1, 2),
            camera_visible=np.array([light.camera_visible for light in lights], bool),
            sampled_only=np.array([light.shadow_link is not None for light in lights], bool),
            link_group=group, link_lit=lit_table, link_blocks=blocks_table,
            group_has_lights=total > 0,
            emitter_triangles=emitter_triangles,
            triangle_cdf=np.array([_cumulative(row) if row.sum() > 0 else np.ones(len(row))
                                   for row in (group_power if len(emitter_triangles) else np.ones((groups, 1)))]),
            triangle_probability=triangle_probability,
            area_probability=np.ascontiguousarray(of(AREA, 1)[:, 0]),
            light_sphere=light_sphere,
            sphere_light=spheres.light, sphere_center=spheres.center,
            sphere_inner_radius=spheres.inner_radius, sphere_outer_radius=spheres.outer_radius,
            sphere_probability=of(SPHERE, len(spheres.light)),
            point_light=point_light, point_center=point_center, point_segment=point_segment, point_scale=point_scale,
            point_probability=of(POINT, len(point_light)),
            distant_direction=np.array([d.direction for d in distant], np.float64).reshape(-1, 3),
            distant_radiance=np.array([d.radiance for d in distant], np.float64).reshape(-1, 3),
            distant_cos_max=np.array([d.cos_max for d in distant], np.float64),
            distant_light=np.array([d.light_index for d in distant], np.int64),
            distant_probability=of(DISTANT, len(distant)),
            dome_radiance=np.array([d.radiance for d in domes], np.float64).reshape(-1, 3),
            dome_rotation=np.array([d.light_from_world for d in domes], np.float64).reshape(-1, 3, 3),
            dome_texture=np.array([atlas_index[d.light_index] for d in domes], np.int64),
            dome_rows=rows, dome_columns=cols,
            dome_cell_offset=np.cumsum(rows * cols) - rows * cols,  # where each dome's cells start
            dome_row_offset=np.cumsum(rows) - rows,
            dome_light=np.array([d.light_index for d in domes], np.int64),
            dome_probability=of(DOME, len(domes)),
            dome_cell_probability=_flat([d.cell_probability for d in domes]),
            dome_column_cdf=_flat([d.column_cdf for d in domes]),
            dome_row_cdf=_flat([d.row_cdf for d in domes]),
            source_kind=np.array([kind for kind, _, _ in sources] or [AREA], np.int64),
            source_item=np.array([item for _, item, _ in sources] or [0], np.int64),
            source_cdf=np.array([_cumulative(row) if row.sum() > 0 else np.ones(len(row))
                                 for row in (power if sources else np.ones((groups, 1)))]),
        )


DARK_LIGHTS_NAMED = 4
"""Lights a darkness warning names with their reasons at most (then "and N more")."""


def darkness(scene: SceneData, world: World, light_power: np.ndarray, surface_power: float,
             emissive_surfaces: bool, has_lights: bool) -> str | None:
    """Why the lights of ``scene`` will light nothing, as the tracer sees them (one line),
    or None when some light lights the scene.

    light_power   : (lights,) float64 each light's power estimate (0 when linked to nothing)
    surface_power : the emissive surfaces' power estimate
    emissive_surfaces : some triangle has an emissive material
    has_lights    : some source has power (LightSampler.has_lights)

    Either nothing sends anything (each light's reason: it emits 0, its image is black, it
    has no size, its light link holds nothing; or there is no light at all), or every light
    that does has inputs:diffuse and inputs:specular 0, and only lights seen directly show.
    """
    lights = scene.lights
    if has_lights:
        sending = np.flatnonzero(light_power > 0)
        if surface_power > 0 or not len(sending) or any(lights[i].diffuse or lights[i].specular for i in sending):
            return None
        return (f"every light that sends light has inputs:diffuse and inputs:specular 0 "
                f"({_named([lights[i].path for i in sending])}): they light nothing, only a light seen "
                "directly shows")
    if not world.triangle_count:
        return None  # nothing to light: a dome seen directly is the picture
    reasons = [f"{light.path} {_dark_reason(index, light, scene, world, light_power)}"
               for index, light in enumerate(lights)]
    if emissive_surfaces:
        reasons.append("the emissive surfaces send nothing (no area, or a black emission)")
    if not reasons:
        reasons = ["the renderer sees no light (an inactive or invisible light is none) and no emissive surface"]
    return f"no light emits anything: the image will be black ({_named(reasons, '; ')})"


def _dark_reason(index: int, light: Light, scene: SceneData, world: World, light_power: np.ndarray) -> str:
    """Why one light of no power sends nothing, as the tracer sees it."""
    radiance = np.asarray(light.radiance, np.float64)
    if not (radiance > 0).any():
        return "emits nothing (inputs:intensity × 2^inputs:exposure × inputs:color is 0)"
    if light.texture is not None and not (scene.textures[light.texture].pixels > 0).any():
        return "has a black image (inputs:texture:file)"
    if light.kind in ("point", "line"):
        if light.radius <= 0 or (light.kind == "line" and light.length <= 0):
            return "has no size (inputs:radius or inputs:length 0)"
    elif light.kind in ("distant", "dome"):
        if not _oriented(light):
            return "has no direction (a scale of 0)"
    elif not world.area[world.triangle_light == index].sum() > 0:
        return "has no area (inputs:width, height, radius or length 0, or a scale of 0)"
    if light.light_link is not None and light_power[index] == 0:
        return "lights nothing (its collection:lightLink includes no object)"
    return "sends nothing the renderer can sample"


def _named(items: list[str], separator: str = ", ") -> str:
    """The first DARK_LIGHTS_NAMED items, then how many more."""
    shown = separator.join(items[:DARK_LIGHTS_NAMED])
    return shown + (f"{separator}and {len(items) - DARK_LIGHTS_NAMED} more" if len(items) > DARK_LIGHTS_NAMED else "")


def _flat(values: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([np.ravel(v) for v in values]).astype(np.float64) if values else np.zeros(0)


def _ies_tables(profiles: list[IesProfile]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ies_info (p, 5) int64, ies_angles, ies_candela) of `profiles` (see EmissionTable)."""
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


def _positional(lights: tuple[Light, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The point and line lights: (their light indices (q,) int64, centres (q, 3) metres,
    segments (q, 3), intensity scales (q,) m²: see LightArrays.point_*)."""
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
    return (np.array(indices, np.int64), np.array(centers, np.float64).reshape(-1, 3),
            np.array(segments, np.float64).reshape(-1, 3), np.array(scales, np.float64))


def _link_groups(scene: SceneData, world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(link_group (t,) int32 per row (0 on prototype and scratch rows), object_group
    (objects,) int32, lit (groups, lights) bool, blocks (groups, lights) bool) of the lights'
    light and shadow links; ((0,), (0,), (1, lights) True, same) when no light is linked.
    Light shapes light nothing and block every light whose shadows are not linked."""
    lights = scene.lights
    if all(light.light_link is None and light.shadow_link is None for light in lights):
        return (np.zeros(0, np.int32), np.zeros(0, np.int32), np.ones((1, len(lights)), bool),
                np.ones((1, len(lights)), bool))
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
    object_group = object_group.reshape(-1).astype(np.int32)
    group = np.where(world.triangle_object >= 0, object_group[world.triangle_object], 0).astype(np.int32)
    return group, object_group, np.ascontiguousarray(unique[:, 0]), np.ascontiguousarray(unique[:, 1])


# -- power estimates (compiled, run once per frame while the tables are built)

def _triangle_power(triangles: np.ndarray, world: World, geometry: GeometryArrays, materials: MaterialArrays,
                    emission: EmissionTable) -> np.ndarray:
    """Power estimate (e,) float64 of emitting `triangles` (e,): area × the luminance of
    their mean emission (_mean_emission) × π, twice for two-sided emissive surfaces."""
    if not len(triangles):
        return np.zeros(0)
    sides = np.where(world.triangle_light[triangles] < 0, 2.0, 1.0)
    return world.area[triangles] * _mean_emission(triangles, geometry, materials, emission) * np.pi * sides


def _mean_emission(triangles: np.ndarray, geometry: GeometryArrays, materials: MaterialArrays,
                   emission: EmissionTable) -> np.ndarray:
    """Luminance (e,) of the radiance emitting triangles send, averaged over their area and
    cosine-weighted directions of their front ((1/π) ∫ L cos dω, from POWER_SAMPLES points
    and directions uniform over the light's cone where it is shaped or textured, from the
    centroid elsewhere)."""
    out = np.zeros(len(triangles), np.float64)
    _mean_emission_kernel(triangles, geometry, materials, emission, POWER_SAMPLES, scratch(shading.REGISTERS, 4),
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
def _spread_direction(emission, light, a, b):
    """A direction (ex, ey, ez) from (a, b) ∈ [0, 1)², uniform over the directions a shaped
    light can emit into (its cone about its axis, the whole sphere for an unshaped light or
    a cone of 180°), and that set's solid angle, sr: a narrow spotlight's power is then
    estimated from directions inside its cone, not from the few that fall there by chance."""
    shaping = emission.shaping
    cos_max = math.cos(shaping[light, CONE_END]) if shaping[light, SHAPED] > 0 else -1.0
    ex, ey, ez = uniform_cone(shaping[light, AXIS], shaping[light, AXIS + 1], shaping[light, AXIS + 2],
                              1.0 - cos_max, a, b)
    return ex, ey, ez, 2 * math.pi * (1.0 - cos_max)


@kernel
def _mean_emission_kernel(triangles, geometry, materials, emission, samples, registers, inputs, radiance, out):
    normal = geometry.geometric_normal
    third = 1.0 / 3.0
    for lane in range(len(triangles)):
        triangle = triangles[lane]
        light = geometry.triangle_light[triangle]
        nx, ny, nz = normal[triangle, 0], normal[triangle, 1], normal[triangle, 2]
        if not (light >= 0 and (emission.shaping[light, SHAPED] > 0 or emission.texture[light] >= 0)):
            emitted(triangle, third, third, nx, ny, nz, 1.0, geometry, emission, materials, registers, inputs, radiance)
            out[lane] = luminance_of(radiance[0], radiance[1], radiance[2])
            continue
        total = 0.0
        for k in range(samples):
            a, b = _hammersley(k, samples)
            ex, ey, ez, solid_angle = _spread_direction(emission, light, a, b)
            cos_out = ex * nx + ey * ny + ez * nz
            if cos_out <= 0:
                continue
            other = math.sqrt(b)  # a point uniform over the triangle
            emitted(triangle, a * other, 1.0 - other, ex, ey, ez, cos_out, geometry, emission, materials, registers,
                    inputs, radiance)
            # the mean over cosine-weighted directions, (1/π) ∫ L cos dω, from uniform ones
            total += luminance_of(radiance[0], radiance[1], radiance[2]) * cos_out * solid_angle / math.pi
        base = emission.radiance[light]
        out[lane] = max(total / samples, POWER_FLOOR * luminance_of(base[0], base[1], base[2]))


def _point_power(emission: EmissionTable, point_light: np.ndarray, point_segment: np.ndarray,
                 point_scale: np.ndarray) -> np.ndarray:
    """Power estimate (q,) of each positional delta light (LightArrays.point_* tables): its
    luminance times the shaping factor integrated over the directions it can emit into
    (POWER_SAMPLES² of them), times its intensity scale."""
    out = np.zeros(len(point_light), np.float64)
    _point_power_kernel(emission, point_light, point_segment, point_scale, POWER_SAMPLES * POWER_SAMPLES, out)
    return out


@kernel
def _point_power_kernel(emission, point_light, point_segment, point_scale, samples, out):
    for item in range(len(point_light)):
        light = point_light[item]
        segment = point_segment[item]
        radiance = emission.radiance[light]
        total = solid_angle = 0.0
        for k in range(samples):
            a, b = _hammersley(k, samples)
            ex, ey, ez, solid_angle = _spread_direction(emission, light, a, b)
            fr, fg, fb = shaping_factor(emission, light, ex, ey, ez)
            total += luminance_of(radiance[0] * fr, radiance[1] * fg, radiance[2] * fb) * broadside(segment, ex, ey, ez)
        unshaped = luminance_of(radiance[0], radiance[1], radiance[2]) * 4 * math.pi
        out[item] = max(total / samples * solid_angle, POWER_FLOOR * unshaped) * point_scale[item]
