"""Light linking (``collection:lightLink``), shadow linking (``collection:shadowLink``),
camera visibility and the diffuse/specular multipliers, per lane.

Links are per-triangle link groups (LightArrays.link_group). A light whose shadows only some
geometry casts is found by light sampling alone (weight 1, no MIS), because a BSDF ray
toward it stops at geometry its shadow rays pass through; only singular (mirror, glass)
paths, which light sampling cannot take, receive it by hitting it.
"""

from __future__ import annotations

from ...compiled import inline
from .. import bsdf


@inline
def group_of(lights, triangle):
    """The link group of `triangle` (−1: the camera): what selects a shading point's lights."""
    if triangle < 0 or len(lights.link_group) == 0:
        return 0
    return lights.link_group[triangle]


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
