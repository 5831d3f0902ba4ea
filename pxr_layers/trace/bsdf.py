"""UsdPreviewSurface as a sum of lobes, evaluated and sampled on batches.

All directions are in the local shading frame (z = shading normal turned toward the
viewer), pointing away from the surface; ``wo`` is toward the previous vertex. Vectors
and colours are component-major (3, n) arrays (see vectors.py).

    f = opacity · [ (1 − c·Fc(cos θo)) · (f_diffuse + f_specular) + c · f_coat ]
        + (1 − opacity) · f_glass

* diffuse  (D): (1 − metallic) · (1 − Fs(cos θo)) · diffuseColor / π
* specular (G): GGX with α = roughness², Smith separable shadowing, Schlick Fresnel Fs
  with F0 = specularColor (specular workflow) or mix(((1 − ior)/(1 + ior))², diffuseColor,
  metallic) (metallic workflow). The spec's edge colour is white (F90 = 1), except that a
  zero F0 turns the lobe off: that is how artists author a pure Lambertian surface.
* coat     (G): GGX with α = clearcoatRoughness², F0 = 0.04, weight c = clearcoat.
* glass    (S): a smooth dielectric of the material's ior (reflection or refraction,
  chosen by exact Fresnel) for the translucent part when opacityThreshold = 0.

A GGX lobe with α below SINGULAR_ALPHA is a perfect mirror (S): GGX's peak is then too
narrow to evaluate in float32 and no light sample could ever land in it.

Each lobe is sampled on its own (one-sample lobe selection with probabilities from each
lobe's albedo estimate) and the path is labelled with the lobe it took, so a
contribution always belongs to exactly one scattering event type.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import FLOAT
from .shading import SurfaceInputs
from .vectors import dot, luminance, normalize

DIFFUSE, SPECULAR, COAT, GLASS = range(4)
GLOSSY_LOBES = (DIFFUSE, SPECULAR, COAT)  # the lobes a light sample can land in
SINGULAR_ALPHA = 1e-4
COAT_F0 = np.float32(0.04)
INV_PI = np.float32(1 / np.pi)

# LPE scattering of an event, as int8 codes into lpe.events.SCATTERINGS.
SCATTER_DIFFUSE, SCATTER_GLOSSY, SCATTER_SINGULAR, SCATTER_STRAIGHT = range(4)


def schlick(f0: np.ndarray, f90: np.ndarray, cos: np.ndarray) -> np.ndarray:
    """Schlick Fresnel. f0 (3, n) or (n,), f90 and cos (n,) -> shaped like f0."""
    weight = (1.0 - np.clip(cos, 0.0, 1.0)) ** 5
    return f0 + (f90 - f0) * weight


def fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Unpolarised Fresnel reflectance; eta = n_transmitted / n_incident. (n,) -> (n,)."""
    cos_i = np.clip(cos_i, 0.0, 1.0)
    sin2_t = (1.0 - cos_i**2) / eta**2
    total = sin2_t >= 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    r_parallel = (eta * cos_i - cos_t) / np.maximum(eta * cos_i + cos_t, 1e-12)
    r_perpendicular = (cos_i - eta * cos_t) / np.maximum(cos_i + eta * cos_t, 1e-12)
    return np.where(total, 1.0, 0.5 * (r_parallel**2 + r_perpendicular**2)).astype(FLOAT)


def ggx_d(cos_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    a2 = alpha * alpha
    # The denominator is at least a2 (cos_h <= 1): it reaches 0 only for a mirror (a2 = 0),
    # whose D is a delta that callers sample apart; the floor keeps that lane 0, not 0/0.
    denominator = np.maximum(cos_h * cos_h * (a2 - 1.0) + 1.0, 1e-12)
    return a2 / (np.pi * denominator * denominator)


def smith_g1(cos: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    a2 = alpha * alpha
    cos = np.maximum(cos, 1e-7)
    return 2.0 * cos / (cos + np.sqrt(a2 + (1.0 - a2) * cos * cos))


@dataclass
class Lobes:
    """Per-hit lobe parameters, prepared once per hit from the material inputs."""

    diffuse: np.ndarray  # (3, n) weight of the Lambertian term (f = diffuse / π)
    specular_weight: np.ndarray  # (n,) opacity · (1 − c·Fc)
    f0: np.ndarray  # (3, n)
    f90: np.ndarray  # (n,)
    alpha: np.ndarray  # (n,)
    coat_weight: np.ndarray  # (n,) opacity · c
    coat_alpha: np.ndarray  # (n,)
    glass_weight: np.ndarray  # (n,) 1 − opacity
    eta: np.ndarray  # (n,) n_inside/n_outside seen from wo's side
    probability: np.ndarray  # (4, n) lobe selection probabilities (sum to 1, or 0 = absorb)

    @property
    def specular_singular(self) -> np.ndarray:
        return self.alpha < SINGULAR_ALPHA

    @property
    def coat_singular(self) -> np.ndarray:
        return self.coat_alpha < SINGULAR_ALPHA


def prepare(inputs: SurfaceInputs, cos_o: np.ndarray, entering: np.ndarray) -> Lobes:
    """Lobe weights for viewing cosine cos_o (n,); entering (n,) bool: wo on the front side."""
    metallic = np.clip(inputs.metallic, 0.0, 1.0)
    r0 = ((1.0 - inputs.ior) / (1.0 + inputs.ior)) ** 2
    metallic_f0 = r0 * (1.0 - metallic) + inputs.diffuse_color * metallic
    f0 = np.where(inputs.use_specular_workflow, inputs.specular_color, metallic_f0).astype(FLOAT)
    f90 = (f0.max(axis=0) > 0).astype(FLOAT)
    opacity = np.clip(inputs.opacity, 0.0, 1.0)
    clearcoat = np.clip(inputs.clearcoat, 0.0, 1.0)
    coat_fresnel = schlick(COAT_F0, 1.0, cos_o)
    base = opacity * (1.0 - clearcoat * coat_fresnel)
    specular_fresnel = schlick(f0, f90, cos_o)
    diffuse = (base * (1.0 - metallic)) * (1.0 - specular_fresnel) * np.maximum(inputs.diffuse_color, 0.0)
    glass = np.where(inputs.opacity_threshold > 0, 0.0, 1.0 - opacity)
    weights = np.stack(
        [luminance(diffuse), base * luminance(specular_fresnel), opacity * clearcoat * coat_fresnel, glass]
    ).astype(FLOAT)
    total = weights.sum(axis=0)
    probability = (weights / np.where(total > 0, total, 1.0)).astype(FLOAT)
    return Lobes(
        diffuse=diffuse.astype(FLOAT),
        specular_weight=base.astype(FLOAT),
        f0=f0,
        f90=f90,
        alpha=(np.clip(inputs.roughness, 0.0, 1.0) ** 2).astype(FLOAT),
        coat_weight=(opacity * clearcoat).astype(FLOAT),
        coat_alpha=(np.clip(inputs.clearcoat_roughness, 0.0, 1.0) ** 2).astype(FLOAT),
        glass_weight=glass.astype(FLOAT),
        eta=np.where(entering, inputs.ior, 1.0 / inputs.ior).astype(FLOAT),
        probability=probability,
    )


def _ggx_eval(wo, wi, alpha, f0, f90):
    """GGX reflection for wo, wi (3, n) local: f (3, n) and its VNDF sampling pdf (n,)."""
    half = normalize(wo + wi, 1e-12)
    cos_o, cos_i = wo[2], wi[2]
    d = ggx_d(half[2], alpha)
    g1_o = smith_g1(cos_o, alpha)
    g1_i = smith_g1(cos_i, alpha)
    fresnel = schlick(f0, f90, dot(wo, half))
    valid = (cos_i > 0) & (cos_o > 0)
    scalar = np.where(valid, d * g1_o * g1_i / np.maximum(4 * cos_o * cos_i, 1e-12), 0.0)
    pdf = np.where(valid, g1_o * d / np.maximum(4 * cos_o, 1e-12), 0.0)
    return (fresnel * scalar).astype(FLOAT), pdf.astype(FLOAT)


def evaluate(lobes: Lobes, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Non-singular lobes for a light direction wi (3, n).

    Returns f (3 lobes, 3 rgb, n) for DIFFUSE, SPECULAR, COAT (zero for singular lobes and
    below the surface) and each lobe's effective sampling density (3 lobes, n): its
    selection probability times its solid-angle pdf, as the MIS weights need.
    """
    n = wo.shape[1]
    cos_i = wi[2]
    above = cos_i > 0
    f = np.zeros((3, 3, n), FLOAT)
    pdf = np.zeros((3, n), FLOAT)
    f[DIFFUSE] = lobes.diffuse * np.where(above, INV_PI, 0.0)
    pdf[DIFFUSE] = np.where(above, cos_i * INV_PI, 0.0) * lobes.probability[DIFFUSE]

    glossy = ~lobes.specular_singular & (lobes.probability[SPECULAR] > 0)
    if glossy.any():
        idx = np.flatnonzero(glossy)
        fs, ps = _ggx_eval(wo[:, idx], wi[:, idx], lobes.alpha[idx], lobes.f0[:, idx], lobes.f90[idx])
        f[SPECULAR][:, idx] = fs * lobes.specular_weight[idx]
        pdf[SPECULAR][idx] = ps * lobes.probability[SPECULAR][idx]
    coated = ~lobes.coat_singular & (lobes.probability[COAT] > 0)
    if coated.any():
        idx = np.flatnonzero(coated)
        fc, pc = _ggx_eval(wo[:, idx], wi[:, idx], lobes.coat_alpha[idx], COAT_F0, np.float32(1.0))
        f[COAT][:, idx] = fc * lobes.coat_weight[idx]
        pdf[COAT][idx] = pc * lobes.probability[COAT][idx]
    return f, pdf


@dataclass
class BsdfSample:
    """A sampled continuation for n lanes.

    direction : (3, n) local, unit
    weight    : (3, n) f·|cos|/pdf_effective (already divided by the lobe probability)
    pdf       : (n,) effective solid-angle density (0 for singular events: no MIS)
    lobe      : (n,) int8 DIFFUSE / SPECULAR / COAT / GLASS
    scatter   : (n,) int8 code into lpe.events.SCATTERINGS (D, G, S)
    transmit  : (n,) bool, the direction crosses the surface
    valid     : (n,) bool, False where the path ends (no lobe, below the horizon)
    """

    direction: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray
    lobe: np.ndarray
    scatter: np.ndarray
    transmit: np.ndarray
    valid: np.ndarray


def _sample_ggx_visible_normal(wo: np.ndarray, alpha: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Heitz 2018: a microfacet normal (3, n) distributed as GGX's visible normals from wo."""
    stretched = normalize(np.stack([wo[0] * alpha, wo[1] * alpha, wo[2]]))
    length2 = stretched[0] ** 2 + stretched[1] ** 2
    degenerate = length2 <= 0
    inv_len = 1.0 / np.sqrt(np.where(degenerate, 1.0, length2))
    t1 = np.stack([np.where(degenerate, 1.0, -stretched[1] * inv_len),
                   np.where(degenerate, 0.0, stretched[0] * inv_len),
                   np.zeros_like(inv_len)])
    t2 = np.stack([stretched[1] * t1[2] - stretched[2] * t1[1],
                   stretched[2] * t1[0] - stretched[0] * t1[2],
                   stretched[0] * t1[1] - stretched[1] * t1[0]])
    radius = np.sqrt(u1)
    phi = 2 * np.pi * u2
    p1 = radius * np.cos(phi)
    p2 = radius * np.sin(phi)
    s = 0.5 * (1.0 + stretched[2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    normal = p1 * t1 + p2 * t2 + p3 * stretched
    return normalize(np.stack([normal[0] * alpha, normal[1] * alpha, np.maximum(normal[2], 1e-7)])).astype(FLOAT)


def _reflect(wo: np.ndarray, normal: np.ndarray) -> np.ndarray:
    return 2.0 * dot(wo, normal) * normal - wo


def _lanes(mask: np.ndarray):
    """Indices of the True lanes, or a full slice when all are (saves a gather and scatter)."""
    return slice(None) if mask.all() else np.flatnonzero(mask)


def _count(lanes, n: int) -> int:
    return n if isinstance(lanes, slice) else len(lanes)


def sample(lobes: Lobes, wo: np.ndarray, u: np.ndarray) -> BsdfSample:
    """Choose a lobe and a direction. u : (3, n) uniforms (lobe, then two for the direction)."""
    n = wo.shape[1]
    cdf = np.cumsum(lobes.probability, axis=0)
    lobe = np.minimum((u[0] >= cdf).sum(axis=0), 3).astype(np.int8)
    valid = cdf[-1] > 0
    direction = np.zeros((3, n), FLOAT)
    weight = np.zeros((3, n), FLOAT)
    pdf = np.zeros(n, FLOAT)
    scatter = np.full(n, SCATTER_DIFFUSE, np.int8)
    transmit = np.zeros(n, bool)

    lanes = _lanes(valid & (lobe == DIFFUSE))
    if _count(lanes, n):
        radius = np.sqrt(u[1, lanes])
        phi = 2 * np.pi * u[2, lanes]
        z = np.sqrt(np.maximum(1.0 - u[1, lanes], 0.0))
        direction[:, lanes] = np.stack([radius * np.cos(phi), radius * np.sin(phi), z])
        # f·cos/pdf = (diffuse/π)·cos / (p·cos/π)
        probability = lobes.probability[DIFFUSE, lanes]
        weight[:, lanes] = lobes.diffuse[:, lanes] / probability
        pdf[lanes] = z * INV_PI * probability

    for which, alpha, layer_weight, f0, f90 in (
        (SPECULAR, lobes.alpha, lobes.specular_weight, lobes.f0, lobes.f90),
        (COAT, lobes.coat_alpha, lobes.coat_weight, None, None),
    ):
        lanes = _lanes(valid & (lobe == which))
        if not _count(lanes, n):
            continue
        lane_f0 = COAT_F0 if f0 is None else f0[:, lanes]
        lane_f90 = np.float32(1.0) if f90 is None else f90[lanes]
        probability = lobes.probability[which, lanes]
        lane_alpha = alpha[lanes]
        singular = lane_alpha < SINGULAR_ALPHA
        wo_l = wo[:, lanes]
        microfacet = _sample_ggx_visible_normal(wo_l, np.maximum(lane_alpha, SINGULAR_ALPHA), u[1, lanes], u[2, lanes])
        normal = np.where(singular, np.array([[0.0], [0.0], [1.0]], FLOAT), microfacet)
        wi = _reflect(wo_l, normal).astype(FLOAT)
        direction[:, lanes] = wi
        fresnel = schlick(lane_f0, lane_f90, dot(wo_l, normal))
        # VNDF sampling: f·cos/pdf = F·G1(wi) for the microfacet lobe; F for a mirror.
        g1_i = np.where(singular, 1.0, smith_g1(wi[2], lane_alpha))
        weight[:, lanes] = fresnel * np.where(wi[2] > 0, g1_i * layer_weight[lanes] / probability, 0.0)
        if (~singular).any():
            _, lobe_pdf = _ggx_eval(wo_l, wi, np.maximum(lane_alpha, SINGULAR_ALPHA), lane_f0, lane_f90)
            pdf[lanes] = np.where(singular, 0.0, lobe_pdf * probability)
        scatter[lanes] = np.where(singular, SCATTER_SINGULAR, SCATTER_GLOSSY)
        valid[lanes] &= wi[2] > 0

    lanes = _lanes(valid & (lobe == GLASS))
    if _count(lanes, n):
        wo_l = wo[:, lanes]
        eta = lobes.eta[lanes]
        fresnel = fresnel_dielectric(wo_l[2], eta)
        reflect = u[1, lanes] < fresnel
        cos_t = np.sqrt(np.maximum(1.0 - (1.0 - wo_l[2] ** 2) / eta**2, 0.0))
        refracted = -wo_l / eta
        refracted[2] += wo_l[2] / eta - cos_t
        mirror = np.stack([-wo_l[0], -wo_l[1], wo_l[2]])
        direction[:, lanes] = np.where(reflect, mirror, refracted)
        # Radiance crossing into a denser medium is compressed by 1/eta² (pbrt's BTDF scale).
        scale = np.where(reflect, 1.0, 1.0 / eta**2) * lobes.glass_weight[lanes] / lobes.probability[GLASS, lanes]
        weight[:, lanes] = scale
        scatter[lanes] = SCATTER_SINGULAR
        transmit[lanes] = ~reflect

    direction = normalize(direction, 1e-12).astype(FLOAT)
    return BsdfSample(direction, weight, pdf, lobe, scatter, transmit, valid)
