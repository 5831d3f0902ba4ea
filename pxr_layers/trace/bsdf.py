"""UsdPreviewSurface as a sum of lobes, evaluated and sampled on batches.

All directions are in the local shading frame (z = shading normal turned toward the
viewer), pointing away from the surface; ``wo`` is toward the previous vertex.

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
from .vectors import dot, normalize

DIFFUSE, SPECULAR, COAT, GLASS = range(4)
GLOSSY_LOBES = (DIFFUSE, SPECULAR, COAT)  # the lobes a light sample can land in
SINGULAR_ALPHA = 1e-4
COAT_F0 = 0.04
INV_PI = np.float32(1 / np.pi)

# Scattering codes of LPE events.
SCATTER_DIFFUSE, SCATTER_GLOSSY, SCATTER_SINGULAR, SCATTER_STRAIGHT = "D", "G", "S", "s"


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance of (..., 3)."""
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


def schlick(f0: np.ndarray, f90: np.ndarray, cos: np.ndarray) -> np.ndarray:
    """Schlick Fresnel. f0 (n, 3), f90 (n, 1), cos (n,) -> (n, 3)."""
    weight = (1.0 - np.clip(cos, 0.0, 1.0)) ** 5
    return f0 + (f90 - f0) * weight[:, None]


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
    denominator = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * denominator * denominator)


def smith_g1(cos: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    a2 = alpha * alpha
    cos = np.maximum(cos, 1e-7)
    return 2.0 * cos / (cos + np.sqrt(a2 + (1.0 - a2) * cos * cos))


@dataclass
class Lobes:
    """Per-hit lobe parameters, prepared once per hit from the material inputs."""

    diffuse: np.ndarray  # (n, 3) weight of the Lambertian term (f = diffuse / π)
    specular_weight: np.ndarray  # (n, 1) opacity · (1 − c·Fc)
    f0: np.ndarray  # (n, 3)
    f90: np.ndarray  # (n, 1)
    alpha: np.ndarray  # (n,)
    coat_weight: np.ndarray  # (n,) opacity · c
    coat_alpha: np.ndarray  # (n,)
    glass_weight: np.ndarray  # (n,) 1 − opacity
    eta: np.ndarray  # (n,) n_inside/n_outside seen from wo's side
    probability: np.ndarray  # (n, 4) lobe selection probabilities (rows sum to 1 or 0)

    @property
    def specular_singular(self) -> np.ndarray:
        return self.alpha < SINGULAR_ALPHA

    @property
    def coat_singular(self) -> np.ndarray:
        return self.coat_alpha < SINGULAR_ALPHA


def prepare(inputs: SurfaceInputs, cos_o: np.ndarray, entering: np.ndarray) -> Lobes:
    """Lobe weights for viewing cosine cos_o (n,); entering (n,) bool: wo on the front side."""
    n = len(cos_o)
    metallic = np.clip(inputs.metallic, 0.0, 1.0)[:, None]
    r0 = ((1.0 - inputs.ior) / (1.0 + inputs.ior)) ** 2
    metallic_f0 = r0[:, None] * (1.0 - metallic) + inputs.diffuse_color * metallic
    f0 = np.where(inputs.use_specular_workflow[:, None], inputs.specular_color, metallic_f0).astype(FLOAT)
    f90 = (f0.max(axis=1, keepdims=True) > 0).astype(FLOAT)
    opacity = np.clip(inputs.opacity, 0.0, 1.0)
    clearcoat = np.clip(inputs.clearcoat, 0.0, 1.0)
    coat_fresnel = schlick(np.full((n, 3), COAT_F0, FLOAT), np.ones((n, 1), FLOAT), cos_o)[:, 0]
    base = (opacity * (1.0 - clearcoat * coat_fresnel))[:, None]
    specular_fresnel = schlick(f0, f90, cos_o)
    diffuse = base * (1.0 - metallic) * (1.0 - specular_fresnel) * np.clip(inputs.diffuse_color, 0.0, None)
    glass = np.where(inputs.opacity_threshold > 0, 0.0, 1.0 - opacity)
    weights = np.stack(
        [
            luminance(diffuse),
            base[:, 0] * luminance(specular_fresnel),
            opacity * clearcoat * coat_fresnel,
            glass,
        ],
        axis=1,
    ).astype(FLOAT)
    total = weights.sum(axis=1, keepdims=True)
    probability = np.where(total > 0, weights / np.maximum(total, 1e-30), 0.0).astype(FLOAT)
    alpha = np.maximum(np.clip(inputs.roughness, 0.0, 1.0) ** 2, 0.0).astype(FLOAT)
    coat_alpha = (np.clip(inputs.clearcoat_roughness, 0.0, 1.0) ** 2).astype(FLOAT)
    eta = np.where(entering, inputs.ior, 1.0 / inputs.ior).astype(FLOAT)
    return Lobes(
        diffuse=diffuse.astype(FLOAT),
        specular_weight=base.astype(FLOAT),
        f0=f0,
        f90=f90,
        alpha=alpha,
        coat_weight=(opacity * clearcoat).astype(FLOAT),
        coat_alpha=coat_alpha,
        glass_weight=glass.astype(FLOAT),
        eta=eta,
        probability=probability,
    )


def _ggx_eval(wo, wi, alpha, f0, f90):
    """GGX reflection: f (n, 3) and its VNDF sampling pdf (n,) for wo, wi (n, 3) local."""
    half = wo + wi
    half = normalize(half, 1e-12)
    cos_o, cos_i, cos_h = wo[:, 2], wi[:, 2], half[:, 2]
    d = ggx_d(cos_h, alpha)
    g1_o = smith_g1(cos_o, alpha)
    g1_i = smith_g1(cos_i, alpha)
    fresnel = schlick(f0, f90, dot(wo, half))
    valid = (cos_i > 0) & (cos_o > 0)
    f = np.where(valid[:, None], fresnel * (d * g1_o * g1_i / np.maximum(4 * cos_o * cos_i, 1e-12))[:, None], 0.0)
    pdf = np.where(valid, g1_o * d / np.maximum(4 * cos_o, 1e-12), 0.0)
    return f.astype(FLOAT), pdf.astype(FLOAT)


def evaluate(lobes: Lobes, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Non-singular lobes for a light direction.

    Returns f (n, 3 lobes, 3 rgb) for DIFFUSE, SPECULAR, COAT (zero for singular lobes and
    below the surface) and each lobe's effective sampling density (n, 3): its selection
    probability times its solid-angle pdf, as used by the MIS weights.
    """
    n = len(wo)
    cos_i = wi[:, 2]
    above = cos_i > 0
    f = np.zeros((n, 3, 3), FLOAT)
    pdf = np.zeros((n, 3), FLOAT)
    f[:, DIFFUSE] = np.where(above[:, None], lobes.diffuse * INV_PI, 0.0)
    pdf[:, DIFFUSE] = np.where(above, cos_i * INV_PI, 0.0) * lobes.probability[:, DIFFUSE]

    glossy = ~lobes.specular_singular & (lobes.probability[:, SPECULAR] > 0)
    if glossy.any():
        idx = np.flatnonzero(glossy)
        fs, ps = _ggx_eval(wo[idx], wi[idx], lobes.alpha[idx], lobes.f0[idx], lobes.f90[idx])
        f[idx, SPECULAR] = fs * lobes.specular_weight[idx]
        pdf[idx, SPECULAR] = ps * lobes.probability[idx, SPECULAR]
    coated = ~lobes.coat_singular & (lobes.probability[:, COAT] > 0)
    if coated.any():
        idx = np.flatnonzero(coated)
        m = len(idx)
        fc, pc = _ggx_eval(
            wo[idx], wi[idx], lobes.coat_alpha[idx], np.full((m, 3), COAT_F0, FLOAT), np.ones((m, 1), FLOAT)
        )
        f[idx, COAT] = fc * lobes.coat_weight[idx, None]
        pdf[idx, COAT] = pc * lobes.probability[idx, COAT]
    return f, pdf


@dataclass
class BsdfSample:
    """A sampled continuation for n lanes.

    direction : (n, 3) local, unit
    weight    : (n, 3) f·|cos|/pdf_effective (already divided by the lobe probability)
    pdf       : (n,) effective solid-angle density (0 for singular events: no MIS)
    lobe      : (n,) int8 DIFFUSE / SPECULAR / COAT / GLASS
    scatter   : (n,) '<U1' LPE scattering code D / G / S
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
    """Heitz 2018: a microfacet normal (n, 3) distributed as GGX's visible normals from wo."""
    a = alpha[:, None]
    stretched = np.concatenate([wo[:, :2] * a, wo[:, 2:]], axis=1)
    stretched = normalize(stretched)
    length2 = stretched[:, 0] ** 2 + stretched[:, 1] ** 2
    inv_len = np.where(length2 > 0, 1.0 / np.sqrt(np.maximum(length2, 1e-30)), 0.0)
    t1 = np.stack([-stretched[:, 1] * inv_len, stretched[:, 0] * inv_len, np.zeros_like(inv_len)], axis=1)
    t1[length2 <= 0] = (1.0, 0.0, 0.0)
    t2 = np.cross(stretched, t1)
    radius = np.sqrt(u1)
    phi = 2 * np.pi * u2
    p1 = radius * np.cos(phi)
    p2 = radius * np.sin(phi)
    s = 0.5 * (1.0 + stretched[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    normal = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * stretched
    normal = np.concatenate([normal[:, :2] * a, np.maximum(normal[:, 2:], 1e-7)], axis=1)
    return normalize(normal).astype(FLOAT)


def _reflect(wo: np.ndarray, normal: np.ndarray) -> np.ndarray:
    return 2.0 * dot(wo, normal)[:, None] * normal - wo


def sample(lobes: Lobes, wo: np.ndarray, u: np.ndarray) -> BsdfSample:
    """Choose a lobe and a direction. u : (n, 3) uniforms (lobe, then two for the direction)."""
    n = len(wo)
    cdf = np.cumsum(lobes.probability, axis=1)
    lobe = np.minimum((u[:, :1] >= cdf).sum(axis=1), 3).astype(np.int8)
    valid = cdf[:, -1] > 0
    direction = np.zeros((n, 3), FLOAT)
    weight = np.zeros((n, 3), FLOAT)
    pdf = np.zeros(n, FLOAT)
    scatter = np.full(n, SCATTER_DIFFUSE, dtype="<U1")
    transmit = np.zeros(n, bool)
    mirror = np.stack([-wo[:, 0], -wo[:, 1], wo[:, 2]], axis=1)

    lanes = np.flatnonzero(valid & (lobe == DIFFUSE))
    if len(lanes):
        radius = np.sqrt(u[lanes, 1])
        phi = 2 * np.pi * u[lanes, 2]
        z = np.sqrt(np.maximum(1.0 - u[lanes, 1], 0.0))
        direction[lanes] = np.stack([radius * np.cos(phi), radius * np.sin(phi), z], axis=1)
        # f·cos/pdf = (diffuse/π)·cos / (p·cos/π)
        weight[lanes] = lobes.diffuse[lanes] / lobes.probability[lanes, DIFFUSE, None]
        pdf[lanes] = z * INV_PI * lobes.probability[lanes, DIFFUSE]

    for which, alpha, layer_weight, f0, f90 in (
        (SPECULAR, lobes.alpha, lobes.specular_weight[:, 0], lobes.f0, lobes.f90),
        (COAT, lobes.coat_alpha, lobes.coat_weight, None, None),
    ):
        lanes = np.flatnonzero(valid & (lobe == which))
        if not len(lanes):
            continue
        m = len(lanes)
        lane_f0 = np.full((m, 3), COAT_F0, FLOAT) if f0 is None else f0[lanes]
        lane_f90 = np.ones((m, 1), FLOAT) if f90 is None else f90[lanes]
        probability = lobes.probability[lanes, which, None]
        singular = alpha[lanes] < SINGULAR_ALPHA
        wo_l = wo[lanes]
        normal = np.where(
            singular[:, None],
            np.array([0.0, 0.0, 1.0], FLOAT),
            _sample_ggx_visible_normal(wo_l, np.maximum(alpha[lanes], SINGULAR_ALPHA), u[lanes, 1], u[lanes, 2]),
        )
        wi = _reflect(wo_l, normal).astype(FLOAT)
        direction[lanes] = wi
        fresnel = schlick(lane_f0, lane_f90, dot(wo_l, normal))
        # VNDF sampling: f·cos/pdf = F·G1(wi) for the microfacet lobe; F for a mirror.
        g1_i = np.where(singular, 1.0, smith_g1(wi[:, 2], alpha[lanes]))
        weight[lanes] = np.where((wi[:, 2] > 0)[:, None], fresnel * g1_i[:, None], 0.0) * layer_weight[lanes, None] / probability
        if (~singular).any():
            _, lobe_pdf = _ggx_eval(wo_l, wi, np.maximum(alpha[lanes], SINGULAR_ALPHA), lane_f0, lane_f90)
            pdf[lanes] = np.where(singular, 0.0, lobe_pdf * probability[:, 0])
        scatter[lanes] = np.where(singular, SCATTER_SINGULAR, SCATTER_GLOSSY)
        valid[lanes] &= wi[:, 2] > 0

    lanes = np.flatnonzero(valid & (lobe == GLASS))
    if len(lanes):
        wo_l = wo[lanes]
        eta = lobes.eta[lanes]
        fresnel = fresnel_dielectric(wo_l[:, 2], eta)
        reflect = u[lanes, 1] < fresnel
        cos_t = np.sqrt(np.maximum(1.0 - (1.0 - wo_l[:, 2] ** 2) / eta**2, 0.0))
        refracted = -wo_l / eta[:, None] + (wo_l[:, 2] / eta - cos_t)[:, None] * np.array([0.0, 0.0, 1.0], FLOAT)
        direction[lanes] = np.where(reflect[:, None], mirror[lanes], refracted)
        # Radiance crossing into a denser medium is compressed by 1/eta² (pbrt's BTDF scale).
        scale = np.where(reflect, 1.0, 1.0 / eta**2) * lobes.glass_weight[lanes] / lobes.probability[lanes, GLASS]
        weight[lanes] = scale[:, None]
        scatter[lanes] = SCATTER_SINGULAR
        transmit[lanes] = ~reflect

    direction = normalize(direction, 1e-12).astype(FLOAT)
    return BsdfSample(direction, weight, pdf, lobe, scatter, transmit, valid)
