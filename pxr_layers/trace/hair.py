"""Hair: MaterialX's ``chiang_hair_bsdf`` (Chiang, Bitterli, Tappan and Burley 2016, "A
Practical and Controllable Hair and Fur Model for Production Path Tracing", after d'Eon et
al. 2011), prepared, evaluated and sampled lane by lane as bsdf.py does for surfaces.

The hair frame: x along the fibre (the curve's tangent, root to tip), z the fibre's normal
at the hit (toward the viewer), y = z × x. A direction's longitudinal angle θ has sin θ = x;
its azimuth is φ = atan2(z, y). The hit's offset across the fibre is h = sin γo ∈ [−1, 1]
(−y of wo's part across the fibre), which a round tube's hit point gives exactly.

    S(wo, wi) = Σ_p tint_p · A_p(θo, h) · M_p(θi, θo + m_p·α) · N_p(φi − φo)      (no cosine)

* p = 0 (R, reflected off the surface), 1 (TT, through the fibre), 2 (TRT, once reflected
  inside), 3 (everything higher, tinted as TRT; N_3 = 1/(2π)). Events carry R, TT and TRT
  (p ≥ 2) as their lobe (paths/events.py); TT is a transmission event, R and TRT reflections.
* A_p: Fresnel f at cos θo·cos γo and absorption T = exp(−σa · 2 cos γt / cos θt) along the
  refracted chord: A_0 = f, A_1 = (1 − f)² T, A_2 = A_1 T f, A_3 = A_2 T f / (1 − T f).
* M_p: d'Eon's longitudinal lobe of variance v_p (MaterialX's roughness_p.x, already a
  variance: chiang_hair_roughness makes it), centred on −(θo + m_p·α) with the cuticle tilt
  α = cuticle_angle·π − π/2 and m = (2, −1, −4) (MaterialX's lobe shifts); its θo is shifted
  rather than θi, so that M_p stays a normalised density of θi (MaterialX shifts θi: the
  same lobe centres).
* N_p: the trimmed logistic of scale s_p·√(π/8) (s_p = MaterialX's roughness_p.y) about
  Φ_p = 2p·γt − 2γo + pπ.

Energy: for σa = 0 and white tints Σ_p A_p = 1 and every M_p, N_p is normalised, so the
fibre scatters all the light it intercepts, for every wo (the white furnace,
tests/test_hair.py). Reciprocity: M_p (without tilt) and the h-averaged N_p are symmetric,
but A_p is taken at θo, as Chiang et al., MaterialX, pbrt and Cycles take it; so the BSDF is
reciprocal exactly where |θi| = |θo| (on the specular cone, where M_p peaks) and only
approximately elsewhere (docs/materials.md gives the measured asymmetry). Evaluating A_p
at the half difference angle would make it reciprocal everywhere but lose energy at grazing
angles; the model studios share is kept.

Sampling is pbrt's (exact for M_p and N_p): choose p by the luminance of tint_p·A_p, then θi
and φi. Each lobe R, TT, TRT is one event, with its own MIS density (p = 2 and 3 together
for TRT), as bsdf.py's lobes are.

The lobe row (bsdf.LOBE_FIELDS wide; bsdf.FIRST_LOBE is HAIR_R) holds what ``prepare``
computes from the material inputs and wo: the columns below.
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import inline, kernel
from ..paths import events
from . import shading
from .vectors import fresnel_dielectric, luminance_of

WEIGHT = 0  # 12 columns: tint_p · A_p (r, g, b) for p = 0, 1, 2, 3
VARIANCE = 12  # 3 columns: v of R, TT, TRT (p = 3 uses TRT's)
SCALE = 15  # 3 columns: the logistic scale s·√(π/8) of R, TT, TRT
TILT = 18  # the cuticle tilt α, radians
GAMMA_O = 19
GAMMA_T = 20
PROBABILITY = 21  # 4 columns: the probability of sampling p = 0 … 3 (sum 1, or 0: absorb)
FIELDS = 25

ORDERS = 4
TILT_STEPS = (2.0, -1.0, -4.0, 0.0)
"""m_p: the multiple of α each order's longitudinal centre is shifted by (MaterialX)."""
MIN_ROUGHNESS = 0.001
"""MaterialX's clamp of both roughness components, [0.001, 1]."""
SQRT_PI_OVER_8 = math.sqrt(math.pi / 8.0)
_LN2 = math.log(2.0)


@inline
def _clamp(x, low, high):
    return min(max(x, low), high)


@inline
def bessel_i0(x):
    """The modified Bessel function I0(x), x ≥ 0, by its power series (to float64)."""
    term = total = 1.0
    quarter = 0.25 * x * x
    k = 1.0
    while k < 200.0:
        term *= quarter / (k * k)
        total += term
        if term < 1e-17 * total:
            break
        k += 1.0
    return total


@inline
def log_bessel_i0(x):
    """log I0(x), x ≥ 0: the series, or its asymptotic expansion beyond 30 (error < 1e-8)."""
    if x <= 30.0:
        return math.log(bessel_i0(x))
    inverse = 1.0 / x
    return (x - 0.5 * math.log(2.0 * math.pi * x)
            + math.log(1.0 + inverse * (0.125 + inverse * (0.0703125 + inverse * 0.0732421875))))


@inline
def longitudinal(sin_i, cos_i, sin_o, cos_o, v):
    """d'Eon et al.'s M_p: a density of θi (∫ M cos θi dθi = 1) for variance v."""
    a = cos_i * cos_o / v
    b = sin_i * sin_o / v
    if v <= 0.1:  # 1/(2v sinh(1/v)) = exp(−1/v + ln 2 + ln(1/(2v))) to float64 there
        return math.exp(log_bessel_i0(a) - b - 1.0 / v + _LN2 + math.log(0.5 / v))
    return math.exp(-b) * bessel_i0(a) / (2.0 * v * math.sinh(1.0 / v))


@inline
def _logistic_cdf(x, s):
    return 1.0 / (1.0 + math.exp(-x / s))


@inline
def azimuthal(dphi, p, s, gamma_o, gamma_t):
    """N_p: the logistic of scale s about Φ_p, trimmed to [−π, π] (1/(2π) for p = 3)."""
    if p >= 3:
        return 0.5 / math.pi
    d = dphi - (2.0 * p * gamma_t - 2.0 * gamma_o + p * math.pi)
    d -= 2.0 * math.pi * math.floor((d + math.pi) / (2.0 * math.pi))
    e = math.exp(-abs(d) / s)
    density = e / (s * (1.0 + e) * (1.0 + e))
    return density / (_logistic_cdf(math.pi, s) - _logistic_cdf(-math.pi, s))


@inline
def _sample_azimuth(u, s):
    """A sample of the logistic of scale s trimmed to [−π, π], by inverting its CDF."""
    low = _logistic_cdf(-math.pi, s)
    x = -s * math.log(1.0 / (u * (_logistic_cdf(math.pi, s) - low) + low) - 1.0)
    return _clamp(x, -math.pi, math.pi)


@inline
def _tilted(sin_o, cos_o, p, alpha):
    """(sin, |cos|) of θo + m_p·α."""
    shift = TILT_STEPS[p] * alpha if p < 3 else 0.0
    c, s = math.cos(shift), math.sin(shift)
    return sin_o * c + cos_o * s, abs(cos_o * c - sin_o * s)


@inline
def prepare(lobes, lane, inputs, wox, woy, woz, scatters):
    """Fill row `lane` of `lobes` (the module's columns) from a hit's material inputs
    (shading.py's hair columns) for wo (local, unit); a lane that may not scatter gets no
    lobe."""
    row = lobes[lane]
    sin_o = _clamp(wox, -1.0, 1.0)
    cos_o = math.sqrt(max(1.0 - sin_o * sin_o, 0.0))
    across = math.sqrt(woy * woy + woz * woz)
    h = _clamp(-woy / across, -1.0, 1.0) if across > 0 else 0.0
    eta = max(inputs[shading.IOR], 1.0)
    sin_t = sin_o / eta
    cos_t = math.sqrt(max(1.0 - sin_t * sin_t, 1e-12))
    eta_p = math.sqrt(max(eta * eta - sin_o * sin_o, 0.0)) / max(cos_o, 1e-7)
    sin_gt = _clamp(h / eta_p, -1.0, 1.0)
    cos_gt = math.sqrt(max(1.0 - sin_gt * sin_gt, 0.0))
    fresnel = fresnel_dielectric(cos_o * math.sqrt(max(1.0 - h * h, 0.0)), eta)
    path = 2.0 * cos_gt / cos_t
    for channel in range(3):  # A_p per channel (the absorption T is the channel's), times tint_p
        t = math.exp(-max(inputs[shading.HAIR_ABSORPTION + channel], 0.0) * path)
        a = fresnel
        for p in range(ORDERS):
            if p == 1:
                a = (1.0 - fresnel) * (1.0 - fresnel) * t
            elif p == 2:
                a *= t * fresnel
            elif p == 3:
                a *= t * fresnel / max(1.0 - t * fresnel, 1e-12)
            row[WEIGHT + 3 * p + channel] = max(inputs[shading.HAIR_TINT + 3 * min(p, 2) + channel], 0.0) * a
    total = 0.0
    for p in range(ORDERS):
        weight = luminance_of(row[WEIGHT + 3 * p], row[WEIGHT + 3 * p + 1], row[WEIGHT + 3 * p + 2])
        row[PROBABILITY + p] = weight
        total += weight
    norm = 1.0 / total if total > 0 and scatters else 0.0
    for p in range(ORDERS):
        row[PROBABILITY + p] *= norm
    for order in range(3):
        roughness = shading.HAIR_ROUGHNESS + 2 * order
        row[VARIANCE + order] = _clamp(inputs[roughness], MIN_ROUGHNESS, 1.0)
        row[SCALE + order] = _clamp(inputs[roughness + 1], MIN_ROUGHNESS, 1.0) * SQRT_PI_OVER_8
    row[TILT] = _clamp(inputs[shading.HAIR_CUTICLE], 0.0, 1.0) * math.pi - 0.5 * math.pi
    row[GAMMA_O] = math.asin(h)
    row[GAMMA_T] = math.asin(sin_gt)


@inline
def _order_value(row, p, sin_o, cos_o, sin_i, cos_i, dphi):
    """M_p·N_p of order p for the directions' angles."""
    order = min(p, 2)
    tilted_sin, tilted_cos = _tilted(sin_o, cos_o, p, row[TILT])
    m = longitudinal(sin_i, cos_i, tilted_sin, tilted_cos, row[VARIANCE + order])
    return m * azimuthal(dphi, p, row[SCALE + order], row[GAMMA_O], row[GAMMA_T])


@inline
def _angles(wox, woy, woz, wix, wiy, wiz):
    sin_o, sin_i = _clamp(wox, -1.0, 1.0), _clamp(wix, -1.0, 1.0)
    return (sin_o, math.sqrt(max(1.0 - sin_o * sin_o, 0.0)), sin_i, math.sqrt(max(1.0 - sin_i * sin_i, 0.0)),
            math.atan2(wiz, wiy) - math.atan2(woz, woy))


@inline
def evaluate(row, wox, woy, woz, wix, wiy, wiz, f, pdf):
    """S of the lobes R, TT, TRT (f[0..2, rgb], no cosine: a fibre has no side) and each
    lobe's effective sampling density pdf[0..2], for a light direction wi."""
    sin_o, cos_o, sin_i, cos_i, dphi = _angles(wox, woy, woz, wix, wiy, wiz)
    for lobe in range(3):
        pdf[lobe] = 0.0
        f[lobe, 0] = f[lobe, 1] = f[lobe, 2] = 0.0
    for p in range(ORDERS):
        value = _order_value(row, p, sin_o, cos_o, sin_i, cos_i, dphi)
        lobe = min(p, 2)
        for channel in range(3):
            f[lobe, channel] += row[WEIGHT + 3 * p + channel] * value
        pdf[lobe] += row[PROBABILITY + p] * value


@inline
def sample(row, wox, woy, woz, u0, u1, u2):
    """Choose an order (u0, then reused for the azimuth) and a direction (u1, u2): bsdf.sample's
    return values, the lobe one of events.LOBE_HAIR_R/TT/TRT; transmit for TT."""
    total = 0.0
    for p in range(ORDERS):
        total += row[PROBABILITY + p]
    if not total > 0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, events.LOBE_HAIR_R, events.SCATTER_GLOSSY, False, False
    chosen, below = ORDERS - 1, 0.0
    for p in range(ORDERS):
        probability = row[PROBABILITY + p]
        if probability > 0 and (u0 < below + probability or p == ORDERS - 1):
            chosen = p
            break
        below += probability
    while not row[PROBABILITY + chosen] > 0:  # u0 beyond a total rounded below 1
        chosen -= 1
    u_azimuth = _clamp((u0 - below) / row[PROBABILITY + chosen], 0.0, 1.0 - 1e-7)
    sin_o = _clamp(wox, -1.0, 1.0)
    cos_o = math.sqrt(max(1.0 - sin_o * sin_o, 0.0))
    order = min(chosen, 2)
    tilted_sin, tilted_cos = _tilted(sin_o, cos_o, chosen, row[TILT])
    v = row[VARIANCE + order]
    u1 = max(u1, 1e-5)
    cos_theta = 1.0 + v * math.log(u1 + (1.0 - u1) * math.exp(-2.0 / v))
    sin_theta = math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))
    sin_i = _clamp(-cos_theta * tilted_sin + sin_theta * math.cos(2.0 * math.pi * u2) * tilted_cos, -1.0, 1.0)
    cos_i = math.sqrt(max(1.0 - sin_i * sin_i, 0.0))
    if chosen < 3:
        dphi = (2.0 * chosen * row[GAMMA_T] - 2.0 * row[GAMMA_O] + chosen * math.pi
                + _sample_azimuth(u_azimuth, row[SCALE + order]))
    else:
        dphi = 2.0 * math.pi * u_azimuth
    phi = math.atan2(woz, woy) + dphi
    x, y, z = sin_i, cos_i * math.cos(phi), cos_i * math.sin(phi)
    lobe = order
    r = g = b = density = 0.0
    for p in range(ORDERS):
        if min(p, 2) != lobe:
            continue
        value = _order_value(row, p, sin_o, cos_o, sin_i, cos_i, dphi)
        r += row[WEIGHT + 3 * p] * value
        g += row[WEIGHT + 3 * p + 1] * value
        b += row[WEIGHT + 3 * p + 2] * value
        density += row[PROBABILITY + p] * value
    if not density > 0:
        return x, y, z, 0.0, 0.0, 0.0, 0.0, events.LOBE_HAIR_R + lobe, events.SCATTER_GLOSSY, lobe == 1, False
    return (x, y, z, r / density, g / density, b / density, density, events.LOBE_HAIR_R + lobe,
            events.SCATTER_GLOSSY, lobe == 1, True)


@inline
def albedo(row):
    """The fibre's reflectance (r, g, b) toward the viewer: Σ_p tint_p·A_p (every lobe's)."""
    r = g = b = 0.0
    for p in range(ORDERS):
        r += row[WEIGHT + 3 * p]
        g += row[WEIGHT + 3 * p + 1]
        b += row[WEIGHT + 3 * p + 2]
    return r, g, b


@inline
def lobe_width(row, lobe):
    """The angular standard deviation (radians) of hair lobe `lobe` (0 R, 1 TT, 2 TRT): √v."""
    return math.sqrt(row[VARIANCE + lobe])


# -- for checks and tools: the kernels' own evaluation, vectorised over lanes

def inputs_row(tint_r=(1.0, 1.0, 1.0), tint_tt=(1.0, 1.0, 1.0), tint_trt=(1.0, 1.0, 1.0), ior=1.55,
               roughness_r=(0.1, 0.1), roughness_tt=(0.05, 0.05), roughness_trt=(0.2, 0.2), cuticle_angle=0.5,
               absorption=(0.0, 0.0, 0.0)) -> np.ndarray:
    """One material-input row (shading.MATERIAL_FIELDS,) float32 of a chiang_hair_bsdf
    (MaterialX's defaults unless given)."""
    row = np.zeros(shading.MATERIAL_FIELDS, np.float32)
    row[shading.HAIR], row[shading.IOR], row[shading.HAIR_CUTICLE] = 1.0, ior, cuticle_angle
    row[shading.HAIR_TINT:shading.HAIR_TINT + 9] = (*tint_r, *tint_tt, *tint_trt)
    row[shading.HAIR_ROUGHNESS:shading.HAIR_ROUGHNESS + 6] = (*roughness_r, *roughness_tt, *roughness_trt)
    row[shading.HAIR_ABSORPTION:shading.HAIR_ABSORPTION + 3] = absorption
    return row


def scattering(inputs: np.ndarray, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """S (n, 3 lobes R/TT/TRT, rgb) float64 and each lobe's sampling density (n, 3) for
    material inputs (MATERIAL_FIELDS,) and unit directions wo, wi (n, 3) in the hair frame."""
    wo, wi = np.asarray(wo, np.float64).reshape(-1, 3), np.asarray(wi, np.float64).reshape(-1, 3)
    f, pdf = np.zeros((len(wo), 3, 3)), np.zeros((len(wo), 3))
    _scattering_kernel(np.asarray(inputs, np.float32), wo, wi, np.zeros((1, FIELDS), np.float64), f, pdf)
    return f, pdf


def sampled(inputs: np.ndarray, wo: np.ndarray, u: np.ndarray):
    """Samples for wo (n, 3) and uniforms u (n, 3): wi (n, 3), weight S/pdf (n, 3), density
    (n,), lobe (n,) int (events' hair lobe ids), valid (n,) bool."""
    wo, u = np.asarray(wo, np.float64).reshape(-1, 3), np.asarray(u, np.float64).reshape(-1, 3)
    wi, weight, density = np.zeros((len(wo), 3)), np.zeros((len(wo), 3)), np.zeros(len(wo))
    lobe, valid = np.zeros(len(wo), np.int64), np.zeros(len(wo), bool)
    _sample_kernel(np.asarray(inputs, np.float32), wo, u, np.zeros((1, FIELDS), np.float64), wi, weight, density,
                   lobe, valid)
    return wi, weight, density, lobe, valid


@kernel
def _scattering_kernel(inputs, wo, wi, row, f, pdf):
    for lane in range(len(wo)):
        prepare(row, 0, inputs, wo[lane, 0], wo[lane, 1], wo[lane, 2], True)
        evaluate(row[0], wo[lane, 0], wo[lane, 1], wo[lane, 2], wi[lane, 0], wi[lane, 1], wi[lane, 2], f[lane],
                 pdf[lane])


@kernel
def _sample_kernel(inputs, wo, u, row, wi, weight, density, lobe, valid):
    for lane in range(len(wo)):
        prepare(row, 0, inputs, wo[lane, 0], wo[lane, 1], wo[lane, 2], True)
        x, y, z, r, g, b, p, chosen, _, _, ok = sample(row[0], wo[lane, 0], wo[lane, 1], wo[lane, 2], u[lane, 0],
                                                        u[lane, 1], u[lane, 2])
        wi[lane, 0], wi[lane, 1], wi[lane, 2] = x, y, z
        weight[lane, 0], weight[lane, 1], weight[lane, 2] = r, g, b
        density[lane], lobe[lane], valid[lane] = p, chosen, ok
