"""UsdPreviewSurface as a sum of lobes, prepared, evaluated and sampled lane by lane.

All directions are in the local shading frame (z = shading normal turned toward the
viewer), pointing away from the surface; ``wo`` is toward the previous vertex.

    f = (1 − c·Fc(cos θo)) · (f_diffuse + f_specular + f_glass) + c · f_coat

(opacity, a presence, is not a lobe: the surface stage lets a fraction 1 − opacity of the
paths through unscattered.)

* diffuse  (D): (1 − metallic) · (1 − transmission) · (1 − Fs(cos θo)) · diffuseColor / π
* specular (G): GGX with α = roughness², Smith separable shadowing, Schlick Fresnel Fs
  with F0 = specularColor (specular workflow) or mix(((1 − ior)/(1 + ior))², diffuseColor,
  metallic) (metallic workflow). The spec's edge colour is white (F90 = 1), except that a
  zero F0 turns the lobe off: that is how artists author a pure Lambertian surface. Its
  weight loses the transmitted part's dielectric share, (1 − (1 − metallic)·transmission),
  since the glass lobe's exact Fresnel reflects for that part.
* coat     (G): GGX with α = clearcoatRoughness², F0 = 0.04, weight c = clearcoat.
* glass    (S): (1 − metallic) · transmission: a smooth dielectric of the material's ior
  (reflection or refraction, chosen by exact Fresnel; what is refracted is tinted by
  transmissionColor); a thin-walled one transmits without bending (eta = 1 for the
  direction, the ior's Fresnel kept).

A GGX lobe with α below SINGULAR_ALPHA is a perfect mirror (S): GGX's peak is then too
narrow to evaluate in float32 and no light sample could ever land in it.

Each lobe is sampled on its own (one-sample lobe selection with probabilities from each
lobe's albedo estimate) and the path is labelled with the lobe it took, so a
contribution always belongs to exactly one scattering event type.

A hit's lobes are one row of LOBE_FIELDS float32 values (``prepare`` fills it; columns
below), so a queue of hits holds them as one (n, LOBE_FIELDS) array. A hair material's row
(hair.py) holds hair.py's columns instead; its FIRST_LOBE column tells the two apart, and
``evaluate`` and ``sample`` turn to hair.py for it.
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import inline
from ..paths import events
from ..paths.events import SCATTER_DIFFUSE, SCATTER_GLOSSY, SCATTER_SINGULAR
from . import hair, shading
from .vectors import fresnel_dielectric, luminance_of, normalized

# The lobe ids are paths.events' (events carry them); short names for the kernels below.
DIFFUSE, SPECULAR, COAT, GLASS = events.LOBE_DIFFUSE, events.LOBE_SPECULAR, events.LOBE_COAT, events.LOBE_GLASS
GLOSSY_LOBES = (DIFFUSE, SPECULAR, COAT)  # the lobes a light sample can land in
SINGULAR_ALPHA = 1e-4
COAT_F0 = 0.04
MIN_IOR = 1e-3  # an ior of 0 or below is no medium: it would make F0 and eta infinite
INV_PI = 1 / math.pi

# Columns of a lobe row.
DIFFUSE_RGB = 0  # 3 columns: weight of the Lambertian term (f = diffuse / π)
SPECULAR_WEIGHT = 3  # (1 − c·Fc) · (1 − (1 − metallic)·transmission)
F0_RGB = 4  # 3 columns
F90 = 7
ALPHA = 8
COAT_WEIGHT = 9  # c
COAT_ALPHA = 10
GLASS_WEIGHT = 11  # (1 − c·Fc) · (1 − metallic) · transmission: reflection
GLASS_RGB = 12  # 3 columns: GLASS_WEIGHT · transmissionColor: refraction
ETA = 15  # n_inside / n_outside seen from wo's side, for Fresnel
BEND = 16  # the eta refraction bends by: ETA, or 1 for a thin wall
PROBABILITY = 17  # 4 columns: lobe selection probabilities (sum to 1, or 0 = absorb)
FIRST_LOBE = 25  # the id of light-sample slot 0's lobe: DIFFUSE for a surface, LOBE_HAIR_R for hair
LOBE_FIELDS = 26
assert hair.FIELDS <= FIRST_LOBE


@inline
def is_hair(row):
    """Whether a lobe row is a hair material's (hair.py)."""
    return row[FIRST_LOBE] == events.LOBE_HAIR_R


@inline
def slot_lobe(row, slot):
    """The lobe id of a light sample's slot `slot` (0–2, ``evaluate``'s f and pdf rows)."""
    return int(row[FIRST_LOBE]) + slot


@inline
def schlick(f0, f90, cos):
    weight = (1.0 - min(max(cos, 0.0), 1.0)) ** 5
    return f0 + (f90 - f0) * weight


@inline
def ggx_d(cos_h, alpha):
    a2 = alpha * alpha
    # The denominator is at least a2 (cos_h <= 1): it reaches 0 only for a mirror (a2 = 0),
    # whose D is a delta that callers sample apart; the floor keeps that lane 0, not 0/0.
    denominator = max(cos_h * cos_h * (a2 - 1.0) + 1.0, 1e-12)
    return a2 / (math.pi * denominator * denominator)


@inline
def smith_g1(cos, alpha):
    a2 = alpha * alpha
    cos = max(cos, 1e-7)
    return 2.0 * cos / (cos + math.sqrt(a2 + (1.0 - a2) * cos * cos))


@inline
def ggx_eval(wox, woy, woz, wix, wiy, wiz, alpha, f0r, f0g, f0b, f90):
    """GGX reflection: f (r, g, b) and its VNDF sampling pdf."""
    if wiz <= 0 or woz <= 0:
        return 0.0, 0.0, 0.0, 0.0
    hx, hy, hz = normalized(wox + wix, woy + wiy, woz + wiz, 1e-12)
    d = ggx_d(hz, alpha)
    g1_o = smith_g1(woz, alpha)
    scalar = d * g1_o * smith_g1(wiz, alpha) / max(4 * woz * wiz, 1e-12)
    cos_oh = wox * hx + woy * hy + woz * hz
    return (schlick(f0r, f90, cos_oh) * scalar, schlick(f0g, f90, cos_oh) * scalar,
            schlick(f0b, f90, cos_oh) * scalar, g1_o * d / max(4 * woz, 1e-12))


@inline
def prepare(lobes, lane, inputs, cos_o, entering, scatters):
    """Fill row `lane` of `lobes` from a hit's material inputs (shading.py columns), for
    viewing cosine cos_o; entering: wo is on the front side; a lane that may not scatter
    gets no lobe."""
    diffuse_r, diffuse_g, diffuse_b = inputs[shading.DIFFUSE], inputs[shading.DIFFUSE + 1], inputs[shading.DIFFUSE + 2]
    ior = max(inputs[shading.IOR], MIN_IOR)
    metallic = min(max(inputs[shading.METALLIC], 0.0), 1.0)
    transmission = (1.0 - metallic) * min(max(inputs[shading.TRANSMISSION], 0.0), 1.0)
    r0 = ((1.0 - ior) / (1.0 + ior)) ** 2
    if inputs[shading.USE_SPECULAR_WORKFLOW] > 0:
        f0r, f0g, f0b = inputs[shading.SPECULAR], inputs[shading.SPECULAR + 1], inputs[shading.SPECULAR + 2]
    else:
        f0r = r0 * (1.0 - metallic) + diffuse_r * metallic
        f0g = r0 * (1.0 - metallic) + diffuse_g * metallic
        f0b = r0 * (1.0 - metallic) + diffuse_b * metallic
    f90 = 1.0 if max(f0r, f0g, f0b) > 0 else 0.0
    clearcoat = min(max(inputs[shading.CLEARCOAT], 0.0), 1.0)
    coat_fresnel = schlick(COAT_F0, 1.0, cos_o)
    base = 1.0 - clearcoat * coat_fresnel
    fr, fg, fb = schlick(f0r, f90, cos_o), schlick(f0g, f90, cos_o), schlick(f0b, f90, cos_o)
    scale = base * (1.0 - metallic) - base * transmission
    dr = scale * (1.0 - fr) * max(diffuse_r, 0.0)
    dg = scale * (1.0 - fg) * max(diffuse_g, 0.0)
    db = scale * (1.0 - fb) * max(diffuse_b, 0.0)
    specular = base * (1.0 - transmission)
    glass = base * transmission
    gr = glass * max(inputs[shading.TRANSMISSION_COLOR], 0.0)
    gg = glass * max(inputs[shading.TRANSMISSION_COLOR + 1], 0.0)
    gb = glass * max(inputs[shading.TRANSMISSION_COLOR + 2], 0.0)
    w0 = luminance_of(dr, dg, db)
    w1 = specular * luminance_of(fr, fg, fb)
    w2 = clearcoat * coat_fresnel
    w3 = max(glass, luminance_of(gr, gg, gb))
    total = w0 + w1 + w2 + w3
    norm = 1.0 / total if total > 0 and scatters else 0.0
    row = lobes[lane]
    row[0], row[1], row[2] = dr, dg, db
    row[SPECULAR_WEIGHT] = specular
    row[4], row[5], row[6] = f0r, f0g, f0b
    row[F90] = f90
    row[ALPHA] = min(max(inputs[shading.ROUGHNESS], 0.0), 1.0) ** 2
    row[COAT_WEIGHT] = clearcoat
    row[COAT_ALPHA] = min(max(inputs[shading.CLEARCOAT_ROUGHNESS], 0.0), 1.0) ** 2
    row[GLASS_WEIGHT] = glass
    row[GLASS_RGB], row[GLASS_RGB + 1], row[GLASS_RGB + 2] = gr, gg, gb
    thin = inputs[shading.THIN_WALLED] > 0
    row[ETA] = ior if entering or thin else 1.0 / ior  # a thin sheet is entered from either side
    row[BEND] = 1.0 if thin else row[ETA]
    row[PROBABILITY], row[PROBABILITY + 1] = w0 * norm, w1 * norm
    row[PROBABILITY + 2], row[PROBABILITY + 3] = w2 * norm, w3 * norm
    row[FIRST_LOBE] = DIFFUSE


@inline
def prepare_hair(lobes, lane, inputs, wox, woy, woz, scatters):
    """hair.prepare, and the row marked as hair's."""
    hair.prepare(lobes, lane, inputs, wox, woy, woz, scatters)
    lobes[lane, FIRST_LOBE] = events.LOBE_HAIR_R


@inline
def evaluate(row, wox, woy, woz, wix, wiy, wiz, f, pdf):
    """The non-singular lobes of `row` for a light direction wi: f[slot, rgb] for DIFFUSE,
    SPECULAR, COAT (zero for singular lobes and below the surface) and pdf[slot], each
    lobe's effective sampling density (its selection probability times its solid-angle
    pdf), as the MIS weights need. A hair row gives hair.evaluate's R, TT, TRT instead
    (slot_lobe names them), whose f already holds the cosine."""
    if is_hair(row):
        hair.evaluate(row, wox, woy, woz, wix, wiy, wiz, f, pdf)
        return
    for lobe in range(3):
        pdf[lobe] = 0.0
        f[lobe, 0] = f[lobe, 1] = f[lobe, 2] = 0.0
    if wiz > 0:
        f[DIFFUSE, 0] = row[0] * INV_PI
        f[DIFFUSE, 1] = row[1] * INV_PI
        f[DIFFUSE, 2] = row[2] * INV_PI
        pdf[DIFFUSE] = wiz * INV_PI * row[PROBABILITY + DIFFUSE]
    if row[ALPHA] >= SINGULAR_ALPHA and row[PROBABILITY + SPECULAR] > 0:
        r, g, b, p = ggx_eval(wox, woy, woz, wix, wiy, wiz, row[ALPHA], row[4], row[5], row[6], row[F90])
        weight = row[SPECULAR_WEIGHT]
        f[SPECULAR, 0], f[SPECULAR, 1], f[SPECULAR, 2] = r * weight, g * weight, b * weight
        pdf[SPECULAR] = p * row[PROBABILITY + SPECULAR]
    if row[COAT_ALPHA] >= SINGULAR_ALPHA and row[PROBABILITY + COAT] > 0:
        r, g, b, p = ggx_eval(wox, woy, woz, wix, wiy, wiz, row[COAT_ALPHA], COAT_F0, COAT_F0, COAT_F0, 1.0)
        weight = row[COAT_WEIGHT]
        f[COAT, 0], f[COAT, 1], f[COAT, 2] = r * weight, g * weight, b * weight
        pdf[COAT] = p * row[PROBABILITY + COAT]


@inline
def _visible_normal(wox, woy, woz, alpha, u1, u2):
    """Heitz 2018: a microfacet normal distributed as GGX's visible normals from wo."""
    sx, sy, sz = normalized(wox * alpha, woy * alpha, woz, 1e-30)
    length2 = sx * sx + sy * sy
    if length2 <= 0:
        t1x, t1y = 1.0, 0.0
    else:
        inv_len = 1.0 / math.sqrt(length2)
        t1x, t1y = -sy * inv_len, sx * inv_len
    t2x, t2y, t2z = -sz * t1y, sz * t1x, sx * t1y - sy * t1x
    radius = math.sqrt(u1)
    phi = 2 * math.pi * u2
    p1 = radius * math.cos(phi)
    p2 = radius * math.sin(phi)
    s = 0.5 * (1.0 + sz)
    p2 = (1.0 - s) * math.sqrt(max(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = math.sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0))
    nx = p1 * t1x + p2 * t2x + p3 * sx
    ny = p1 * t1y + p2 * t2y + p3 * sy
    nz = p2 * t2z + p3 * sz
    return normalized(nx * alpha, ny * alpha, max(nz, 1e-7), 1e-30)


@inline
def sample(row, wox, woy, woz, u0, u1, u2):
    """Choose a lobe (u0) and a direction (u1, u2). Returns (wi x, y, z local unit;
    weight r, g, b = f·|cos|/pdf, already divided by the lobe probability; pdf, the
    effective solid-angle density, 0 for singular events: no MIS; lobe; scatter code;
    transmit: the direction crosses the surface; valid: False where the path ends).
    A hair row samples hair.sample."""
    if is_hair(row):
        return hair.sample(row, wox, woy, woz, u0, u1, u2)
    p_diffuse, p_specular = row[PROBABILITY + DIFFUSE], row[PROBABILITY + SPECULAR]
    p_coat, p_glass = row[PROBABILITY + COAT], row[PROBABILITY + GLASS]
    total = p_diffuse + p_specular + p_coat + p_glass
    lobe = 0
    cdf = p_diffuse
    if u0 >= cdf:
        lobe = 1
        cdf += p_specular
        if u0 >= cdf:
            lobe = 2
            cdf += p_coat
            if u0 >= cdf:
                lobe = 3
    while lobe > 0 and not row[PROBABILITY + lobe] > 0:  # u0 beyond a total rounded below 1
        lobe -= 1
    if not total > 0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, lobe, SCATTER_DIFFUSE, False, False
    if lobe == DIFFUSE:
        radius = math.sqrt(u1)
        phi = 2 * math.pi * u2
        z = math.sqrt(max(1.0 - u1, 0.0))
        x, y, z = normalized(radius * math.cos(phi), radius * math.sin(phi), z, 1e-12)
        # f·cos/pdf = (diffuse/π)·cos / (p·cos/π)
        return (x, y, z, row[0] / p_diffuse, row[1] / p_diffuse, row[2] / p_diffuse, z * INV_PI * p_diffuse,
                lobe, SCATTER_DIFFUSE, False, True)
    if lobe == GLASS:
        fresnel = fresnel_dielectric(woz, row[ETA])
        if u1 < fresnel:
            x, y, z = -wox, -woy, woz
            scale = row[GLASS_WEIGHT] / p_glass
            return x, y, z, scale, scale, scale, 0.0, lobe, SCATTER_SINGULAR, False, True
        eta = row[BEND]
        cos_t = math.sqrt(max(1.0 - (1.0 - woz * woz) / (eta * eta), 0.0))
        x, y, z = normalized(-wox / eta, -woy / eta, -woz / eta + woz / eta - cos_t, 1e-12)
        # Radiance crossing into a denser medium is compressed by 1/eta² (pbrt's BTDF scale).
        scale = 1.0 / (eta * eta) / p_glass
        return (x, y, z, row[GLASS_RGB] * scale, row[GLASS_RGB + 1] * scale, row[GLASS_RGB + 2] * scale, 0.0, lobe,
                SCATTER_SINGULAR, True, True)
    if lobe == SPECULAR:
        alpha, weight, probability = row[ALPHA], row[SPECULAR_WEIGHT], p_specular
        f0r, f0g, f0b, f90 = row[4], row[5], row[6], row[F90]
    else:
        alpha, weight, probability = row[COAT_ALPHA], row[COAT_WEIGHT], p_coat
        f0r, f0g, f0b, f90 = COAT_F0, COAT_F0, COAT_F0, 1.0
    singular = alpha < SINGULAR_ALPHA
    if singular:
        nx, ny, nz = 0.0, 0.0, 1.0
    else:
        nx, ny, nz = _visible_normal(wox, woy, woz, alpha, u1, u2)
    cos_oh = wox * nx + woy * ny + woz * nz
    x, y, z = normalized(2 * cos_oh * nx - wox, 2 * cos_oh * ny - woy, 2 * cos_oh * nz - woz, 1e-12)
    if not z > 0:
        return x, y, z, 0.0, 0.0, 0.0, 0.0, lobe, SCATTER_SINGULAR if singular else SCATTER_GLOSSY, False, False
    # VNDF sampling: f·cos/pdf = F·G1(wi) for the microfacet lobe; F for a mirror.
    g1_i = 1.0 if singular else smith_g1(z, alpha)
    scale = g1_i * weight / probability
    pdf = 0.0
    if not singular:
        pdf = ggx_eval(wox, woy, woz, x, y, z, alpha, f0r, f0g, f0b, f90)[3] * probability
    return (x, y, z, schlick(f0r, f90, cos_oh) * scale, schlick(f0g, f90, cos_oh) * scale,
            schlick(f0b, f90, cos_oh) * scale, pdf, lobe, SCATTER_SINGULAR if singular else SCATTER_GLOSSY,
            False, True)


@inline
def albedo(row, cos_o):
    """The reflectance (r, g, b) of the non-singular lobes of `row` toward the viewer at
    cosine cos_o (the denoiser's albedo guide): the diffuse weight, the specular and coat
    lobes' Fresnel; a hair row's hair.albedo."""
    if is_hair(row):
        return hair.albedo(row)
    r, g, b = row[DIFFUSE_RGB], row[DIFFUSE_RGB + 1], row[DIFFUSE_RGB + 2]
    if row[ALPHA] >= SINGULAR_ALPHA:
        weight = row[SPECULAR_WEIGHT]
        r += weight * schlick(row[F0_RGB], row[F90], cos_o)
        g += weight * schlick(row[F0_RGB + 1], row[F90], cos_o)
        b += weight * schlick(row[F0_RGB + 2], row[F90], cos_o)
    if row[COAT_ALPHA] >= SINGULAR_ALPHA:
        coat = row[COAT_WEIGHT] * schlick(COAT_F0, 1.0, cos_o)
        r, g, b = r + coat, g + coat, b + coat
    return r, g, b


@inline
def power_heuristic(chosen, other):
    """MIS weight of the strategy with density `chosen` against `other`; a delta strategy
    (infinite density) takes the whole weight."""
    a = min(chosen, 1e150) ** 2
    b = min(other, 1e150) ** 2
    return a / (a + b) if a + b > 0 else 0.0


def lobe_rows(count: int) -> np.ndarray:
    """An empty (count, LOBE_FIELDS) float32 table of lobe rows."""
    return np.zeros((count, LOBE_FIELDS), np.float32)
