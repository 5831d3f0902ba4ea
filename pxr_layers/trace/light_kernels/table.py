"""The light tables kernels read: the contract between the host side, which builds them once
per frame (trace/lights.py, after Cycles' scene/light.cpp), and the per-lane functions of
this package (after Cycles' kernel/light/, whose tables kernel/types.h declares)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

AREA, DISTANT, DOME, POINT, SPHERE = range(5)  # source kinds (LightArrays.source_kind)

# Columns of EmissionTable.shaping, one row per light.
SHAPED = 0  # 1: the light has a LightShaping (0: every factor is 1)
AXIS = 1  # 3 columns: the light's −Z axis in world space, unit
CONE_START, CONE_END = 4, 5  # radians: the smoothstep's ramp, cone·(1 − softness) .. cone
FOCUS = 6
TINT = 7  # 3 columns: focusTint
IES_PROFILE = 10  # row of ies_info, −1: none
IES_ANGLE_SCALE = 11
IES_FACTOR = 12  # 1 / the profile's power under ies:normalize, else 1
SHAPING_FIELDS = 13

SHAPE_WIDTH, SHAPE_HEIGHT = 0, 1  # columns of EmissionTable.size


class EmissionTable(NamedTuple):
    """What each light sends (per light: lights = len(SceneData.lights)). The host estimates
    the lights' powers from it before it builds the sampling tables (LightArrays.emission).

    radiance         : (lights, 3) float32 radiance of each light (its shape's, for area lights)
    shaping          : (lights, SHAPING_FIELDS) float64 ShapingAPI rows (columns above)
    light_from_world : (lights, 3, 4) float64 affine map from world metres to the light's
                       local frame (its linear part also takes IES directions there)
    size             : (lights, 2) float64 a rect's width and height, local units
    texture          : (lights,) int64 a rect's colour map in the atlas (texture_info), −1 none
    ies_info         : (p, 5) int64 per IES profile: offset and count of its vertical angles
                       in ies_angles, offset and count of its horizontal angles, offset of
                       its (H, V) candela table in ies_candela
    ies_angles, ies_candela : flat float64 tables (radians, candela)
    texels, texture_info : the domes' and rects' textures (textures.py atlas)
    """

    radiance: np.ndarray
    shaping: np.ndarray
    light_from_world: np.ndarray
    size: np.ndarray
    texture: np.ndarray
    ies_info: np.ndarray
    ies_angles: np.ndarray
    ies_candela: np.ndarray
    texels: np.ndarray
    texture_info: np.ndarray


class LightArrays(NamedTuple):
    """What kernels read of the lights of a frame.

    emission         : EmissionTable, what each light sends
    light_response   : (lights, 2) float64 the diffuse and specular multipliers
    camera_visible   : (lights,) bool camera rays see the light
    sampled_only     : (lights,) bool found by light sampling alone (restricted shadow links)
    link_group       : (t,) int32 each triangle's link group, or (0,) when no light is linked
                       (group_of: every triangle and the camera then in group 0)
    link_lit, link_blocks : (groups, lights) bool: the group's geometry is lit by / blocks
                       the light

    Light selection is per link group G (one group without linking): a shading point picks
    only among the lights that light it, so linking costs no noise. Every `*_probability`
    and cdf below has the groups on its first axis.

    group_has_lights : (G,) bool some light lights the group
    emitter_triangles: (e,) int32 triangles the area source samples, triangle_cdf (G, e)
                       float64 over them
    triangle_probability : (G, t) float32 probability of each triangle among the emitters
                       (0 for the triangles of spheres sampled by solid angle)
    area_probability : (G,) float64 probability of the area source
    light_sphere     : (lights,) int64 each light's row among the spheres below, −1 none
    sphere_*         : per sphere light sampled by solid angle (S,): light index, centre
                       (S, 3) metres, inner_radius (S,) metres (a ball about the centre inside
                       its tessellated shape: the cone sampled), outer_radius (S,) metres (a
                       ball about the centre around the shape: where shadow rays end; both
                       within a float32 rounding margin of the shape), probability (G, S)
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
    source_kind (s,) int64 AREA / DISTANT / DOME / POINT / SPHERE, source_item (s,) index
    among its kind, source_cdf (G, s) float64
    """

    emission: EmissionTable
    light_response: np.ndarray
    camera_visible: np.ndarray
    sampled_only: np.ndarray
    link_group: np.ndarray
    link_lit: np.ndarray
    link_blocks: np.ndarray
    group_has_lights: np.ndarray
    emitter_triangles: np.ndarray
    triangle_cdf: np.ndarray
    triangle_probability: np.ndarray
    area_probability: np.ndarray
    light_sphere: np.ndarray
    sphere_light: np.ndarray
    sphere_center: np.ndarray
    sphere_inner_radius: np.ndarray
    sphere_outer_radius: np.ndarray
    sphere_probability: np.ndarray
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
