"""Slow, obviously-correct covariance operators on ONE 4×4 Σ, to test the batched ones.

Written from COVARIANCE.md and the package docstring, not from ``operators.py``: each
event is its matrix spelled out and applied as ``A.T @ sigma @ A`` (or a plain sum),
each parameter is a Python float. Nothing here is vectorised or optimised.

The BRDF is the pseudo-inverse form, with one correction. COVARIANCE.md writes
Σ' = (Σ⁺ + B⁺)⁺; that is only right for an invertible Σ. For a singular Σ the spectrum
lives on the range of Σ, so the lobe's precision B⁺ must be restricted to that range
first: Σ' = (Σ⁺ + Π B⁺ Π)⁺ with Π = Σ Σ⁺. (Unrestricted, a rank-1 Σ would come out
of a glossy BRDF with full rank, which no convolution can do.) The lobe is a product
of a u factor and a v factor, applied one axis at a time; b = 0 is the limit, plain
Gaussian conditioning on zero frequency along that axis.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .operators import DIRECTIONAL_LIGHT_EXTENT, GRAZING_COS_EPS, POINT_LIGHT_EXTENT
from .vertex import VertexParams

FOUR_PI_SQUARED = 4.0 * np.pi**2
I2 = np.eye(2)
Z2 = np.zeros((2, 2))
# Relative cut-off for the rank of Σ in the BRDF's pseudo-inverses.
PINV_RCOND = 1e-10


def _blocks(top_left, top_right, bottom_left, bottom_right) -> np.ndarray:
    return np.block([[top_left, top_right], [bottom_left, bottom_right]])


def travel(sigma: np.ndarray, distance: float) -> np.ndarray:
    t = _blocks(I2, -distance * I2, Z2, I2)
    return t.T @ sigma @ t


def rotate(sigma: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])
    rotation = _blocks(r, Z2, Z2, r)
    return rotation.T @ sigma @ rotation


def project(sigma: np.ndarray, cos_theta: float) -> np.ndarray:
    p = np.diag([1.0, abs(cos_theta), 1.0, 1.0])
    return p @ sigma @ p


def inverse_project(sigma: np.ndarray, cos_theta: float, eps: float = GRAZING_COS_EPS) -> np.ndarray:
    p = np.diag([1.0, 1.0 / max(abs(cos_theta), eps), 1.0, 1.0])
    return p @ sigma @ p


def curvature(sigma: np.ndarray, k1: float, k2: float, sign: float = 1.0, angle: float = 0.0,
              sagittal_scale: float = 1.0) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])
    k = np.diag([sagittal_scale, 1.0]) @ r @ np.diag([k1, k2]) @ r.T
    shear = _blocks(I2, Z2, -sign * k, I2)
    return shear.T @ sigma @ shear


def mirror(sigma: np.ndarray) -> np.ndarray:
    s = np.diag([1.0, 1.0, -1.0, -1.0])
    return s @ sigma @ s


def reverse(sigma: np.ndarray) -> np.ndarray:
    s = np.diag([1.0, 1.0, -1.0, -1.0])
    return s @ sigma @ s


def lens(sigma: np.ndarray, focal_length: float) -> np.ndarray:
    shear = _blocks(I2, Z2, I2 / focal_length, I2)
    return shear.T @ sigma @ shear


def sensor(sigma: np.ndarray, pixel_size: float) -> np.ndarray:
    d = np.diag([pixel_size, pixel_size, 1.0, 1.0])
    return d @ sigma @ d


def texture(sigma: np.ndarray, block: np.ndarray) -> np.ndarray:
    return sigma + _blocks(block, Z2, Z2, Z2)


def occlusion(sigma: np.ndarray, block: np.ndarray) -> np.ndarray:
    return sigma + _blocks(block, Z2, Z2, Z2)


def cosine(sigma: np.ndarray, cos_theta: float, eps: float = GRAZING_COS_EPS) -> np.ndarray:
    cos2 = max(cos_theta**2, eps**2)
    window = np.diag([1.0 / FOUR_PI_SQUARED, 1.0 / (FOUR_PI_SQUARED * cos2)])
    return sigma + _blocks(Z2, Z2, Z2, window)


def _multiply_spectrum_by_gaussian(sigma: np.ndarray, axis: int, bandwidth: float) -> np.ndarray:
    """Product of the spectrum with exp(−ξ_axis² / (2b)): precision 1/b added on ``axis``.

    Σ' = (Σ⁺ + Π B⁺ Π)⁺ on the support of Σ, evaluated through a square root Σ = R Rᵀ
    (R = eigenvectors · √eigenvalues over the support) as R (I + Rᵀ B⁺ R)⁻¹ Rᵀ: the same
    matrix, since (R Rᵀ)⁺ restricted to range(R) inverts to it, but without squaring the
    condition number of Σ through two pseudo-inverses.
    """
    lobe_precision = np.zeros((4, 4))
    lobe_precision[axis, axis] = 1.0 / bandwidth
    eigenvalues, eigenvectors = np.linalg.eigh(sigma)
    support = eigenvalues > PINV_RCOND * max(eigenvalues.max(), 0.0)
    root = eigenvectors[:, support] * np.sqrt(eigenvalues[support])
    inner = np.eye(root.shape[1]) + root.T @ lobe_precision @ root
    return root @ np.linalg.inv(inner) @ root.T


def _condition_on_zero_frequency(sigma: np.ndarray, axis: int) -> np.ndarray:
    """Gaussian conditioning on ξ_axis = 0 (the b -> 0 limit): Σ − Σ e eᵀ Σ / (eᵀ Σ e)."""
    variance = sigma[axis, axis]
    if variance <= PINV_RCOND * max(np.trace(sigma), 1e-300):
        return sigma.copy()  # already no content on that axis
    column = sigma[:, axis]
    return sigma - np.outer(column, column) / variance


def brdf(sigma: np.ndarray, b_u: float, b_v: float) -> np.ndarray:
    """The lobe is a product of independent u and v factors, applied one axis at a time."""
    out = sigma.copy()
    for axis, bandwidth in ((2, b_u), (3, b_v)):
        if np.isinf(bandwidth):
            continue  # perfect mirror along this axis: nothing is blurred
        if bandwidth == 0.0:
            out = _condition_on_zero_frequency(out, axis)
        else:
            out = _multiply_spectrum_by_gaussian(out, axis, bandwidth)
    return out


def emitter(extent: float) -> np.ndarray:
    s = extent if extent > 0.0 else POINT_LIGHT_EXTENT
    spatial = 1.0 / (FOUR_PI_SQUARED * s * s)
    return np.diag([spatial, spatial, 0.0, 0.0])


def distant_emitter(angular_extent: float) -> np.ndarray:
    alpha = angular_extent if angular_extent > 0.0 else DIRECTIONAL_LIGHT_EXTENT
    angular = 1.0 / (FOUR_PI_SQUARED * alpha * alpha)
    return np.diag([0.0, 0.0, angular, angular])


def scatter(sigma: np.ndarray, vertex: VertexParams) -> np.ndarray:
    """One vertex with scalar parameters (``VertexParams.lane``), in the order of chain.scatter."""
    sigma = rotate(sigma, vertex.rotation_in)
    sigma = project(sigma, vertex.cos_in)
    sigma = reverse(sigma)
    sigma = curvature(sigma, vertex.k1, vertex.k2, +1.0, vertex.curvature_angle, abs(vertex.cos_in))
    sigma = texture(sigma, np.asarray(vertex.texture))
    if not (np.isinf(vertex.bandwidth_u) and np.isinf(vertex.bandwidth_v)):
        sigma = cosine(sigma, vertex.cos_in)
    sigma = mirror(sigma)
    sigma = brdf(sigma, vertex.bandwidth_u, vertex.bandwidth_v)
    sigma = curvature(sigma, vertex.k1, vertex.k2, -1.0, vertex.curvature_angle, abs(vertex.cos_in))
    sigma = rotate(sigma, vertex.rotation_out)
    sigma = inverse_project(sigma, vertex.cos_out)
    return travel(sigma, vertex.distance)


def chain(emitted: np.ndarray, distance_from_light: float, vertices: Sequence[VertexParams]) -> np.ndarray:
    sigma = travel(emitted, distance_from_light)
    for vertex in vertices:
        sigma = scatter(sigma, vertex)
    return sigma
