"""What a light sends toward a direction: its radiance times the UsdLux ShapingAPI factor
(cone, focus, IES profile), as the UsdLux documentation says and hdEmbree, its reference
implementation, evaluates it.

θ is the angle between the light's −Z axis and the emission direction; focus multiplies by
lerp(|cos θ|^focus, focusTint, 1), the cone by 1 − smoothstep(θ; cone·(1 − softness), cone)
(a hard cut at the cone without softness), an IES profile by its candela at (θ scaled by
angleScale, φ), φ the azimuth about the light's Z of the direction toward the light, as
hdEmbree takes it, divided by the profile's power under ``normalize``.

Every function reads the EmissionTable (``emission``) only, so the host can estimate the
lights' powers from it before it builds the sampling tables.
"""

from __future__ import annotations

import math

import numpy as np

from ...compiled import inline
from ..vectors import normalized
from .distribution import pick
from .table import AXIS, CONE_END, CONE_START, FOCUS, IES_ANGLE_SCALE, IES_FACTOR, IES_PROFILE, SHAPED, TINT


@inline
def light_emission(emission, light, ex, ey, ez):
    """Radiance (r, g, b) light `light` sends in unit world direction (ex, ey, ez) from any
    point of its front: its radiance times shaping_factor (no colour map)."""
    radiance = emission.radiance
    r, g, b = radiance[light, 0], radiance[light, 1], radiance[light, 2]
    if emission.shaping[light, SHAPED] == 0:
        return r, g, b
    fr, fg, fb = shaping_factor(emission, light, ex, ey, ez)
    return r * fr, g * fg, b * fb


@inline
def shaping_factor(emission, light, ex, ey, ez):
    """Per-channel factor (fr, fg, fb) ShapingAPI applies to light `light`'s emission in unit
    world direction (ex, ey, ez) (see the module docstring); (1, 1, 1) for unshaped lights."""
    row = emission.shaping[light]
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
        scale *= ies_intensity(emission, light, profile, row[IES_ANGLE_SCALE], ex, ey, ez) * row[IES_FACTOR]
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
def ies_intensity(emission, light, profile, angle_scale, ex, ey, ez):
    """Candela of IES `profile` in unit world direction (ex, ey, ez) of light `light`: θ from
    the light's −Z, scaled by angleScale (UsdLux: θ/s for s > 0, (θ − π)/−s + π for s < 0),
    φ the azimuth about Z of the direction toward the light (hdEmbree's convention),
    bilinear in the profile's table, 0 outside its vertical angles."""
    m = emission.light_from_world[light]
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
    info = emission.ies_info[profile]
    v_start, v_count, h_start, h_count, table = info[0], info[1], info[2], info[3], info[4]
    vi, vf = _bracket(emission.ies_angles, v_start, v_count, theta)
    hi, hf = _bracket(emission.ies_angles, h_start, h_count, phi)
    if vi < 0 or hi < 0:
        return 0.0
    candela = emission.ies_candela
    v_next = min(vi + 1, v_count - 1)
    h_next = min(hi + 1, h_count - 1)
    near = candela[table + hi * v_count + vi] * (1 - vf) + candela[table + hi * v_count + v_next] * vf
    far = candela[table + h_next * v_count + vi] * (1 - vf) + candela[table + h_next * v_count + v_next] * vf
    return near * (1 - hf) + far * hf
