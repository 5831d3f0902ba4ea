"""Batched covariance operators on Σ (n, 4, 4) float64, one local light field per lane.

Coordinates (x, y, u, v), the amplitude-spectrum convention, frames and units are
defined once in the package docstring (``pxr_layers.covariance``). Per-lane parameters
are (n,) arrays; scalars broadcast to every lane. Every operator returns a new array
and never modifies its input.

Geometric events are congruences Σ' = Aᵀ Σ A with a full 4×4 matrix A (p_old = A p_new);
the results are re-symmetrised so rounding cannot make Σ drift away from symmetric.
``reference.py`` holds a scalar, obviously-correct version of every operator here, and
the tests run one against the other.
"""

from __future__ import annotations

import numpy as np

SIGMA_DTYPE = np.float64

FOUR_PI_SQUARED = 4.0 * np.pi**2

# A point light has no extent, which would be an infinite spatial bandwidth. It is
# treated as a Gaussian emitter of std 0.1 mm: Σxx = Σyy = 1/(4π²·1e-8) ≈ 2.5e6
# cycles²/m², far above anything a surface or a pixel can resolve, yet finite so that
# later operators never meet inf - inf.
POINT_LIGHT_EXTENT = 1e-4  # metres
# The same for a distant light given with zero angular size (0.1 mrad; the sun is ~4.7 mrad).
DIRECTIONAL_LIGHT_EXTENT = 1e-4  # radians
# inverse_project divides by |cos θo|; this keeps grazing exits finite (≈ 0.06° from grazing).
GRAZING_COS_EPS = 1e-3

# pack_upper order: the upper triangle of Σ read row by row.
PACKED_ENTRY_NAMES = ("xx", "xy", "xu", "xv", "yy", "yu", "yv", "uu", "uv", "vv")
_UPPER_ROWS, _UPPER_COLS = np.triu_indices(4)

# 2×2 matrices whose determinant is below this fraction of trace² are treated as rank
# deficient by _pinv_sym2 (float64 cannot resolve a smaller eigenvalue ratio anyway).
_RANK_TOLERANCE = 1e-12


# --------------------------------------------------------------------------- helpers


def _as_sigma(sigma: np.ndarray) -> np.ndarray:
    """Σ as a float64 (n, 4, 4) array, or ValueError."""
    sigma = np.asarray(sigma, dtype=SIGMA_DTYPE)
    if sigma.ndim != 3 or sigma.shape[1:] != (4, 4):
        raise ValueError(f"sigma must have shape (n, 4, 4), got {sigma.shape}")
    return sigma


def _per_lane(value, n: int, name: str) -> np.ndarray:
    """A scalar or (n,) parameter as a float64 (n,) array."""
    value = np.asarray(value, dtype=SIGMA_DTYPE)
    if value.ndim == 0:
        return np.full(n, value, dtype=SIGMA_DTYPE)
    if value.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {value.shape}")
    return value


def _per_lane_block(block, n: int, name: str) -> np.ndarray:
    """A (2, 2) or (n, 2, 2) parameter as a float64 (n, 2, 2) array."""
    block = np.asarray(block, dtype=SIGMA_DTYPE)
    if block.shape == (2, 2):
        return np.broadcast_to(block, (n, 2, 2))
    if block.shape != (n, 2, 2):
        raise ValueError(f"{name} must have shape (2, 2) or ({n}, 2, 2), got {block.shape}")
    return block


def _identities(n: int) -> np.ndarray:
    """(n, 4, 4) identity matrices to fill in."""
    return np.broadcast_to(np.eye(4, dtype=SIGMA_DTYPE), (n, 4, 4)).copy()


def _symmetrized(matrices: np.ndarray) -> np.ndarray:
    return 0.5 * (matrices + np.swapaxes(matrices, -1, -2))


def _congruence(sigma: np.ndarray, new_to_old: np.ndarray) -> np.ndarray:
    """Aᵀ Σ A for A (n, 4, 4) mapping new primal coordinates to old ones."""
    return _symmetrized(np.swapaxes(new_to_old, -1, -2) @ sigma @ new_to_old)


def _rotation_2x2(angle: np.ndarray) -> np.ndarray:
    """r = [[c, −s], [s, c]] per lane, (n,) radians -> (n, 2, 2)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def _pinv_sym2(matrices: np.ndarray) -> np.ndarray:
    """Moore-Penrose pseudo-inverse of symmetric PSD 2×2 matrices, (n, 2, 2) -> (n, 2, 2).

    Closed form instead of np.linalg.pinv: full rank -> adjugate / det; rank one
    (M = λ q qᵀ, λ = trace) -> M / λ²; zero -> zero.
    """
    a, b, d = matrices[:, 0, 0], matrices[:, 0, 1], matrices[:, 1, 1]
    trace = a + d
    det = a * d - b * b
    full_rank = det > _RANK_TOLERANCE * trace * trace
    rank_one = ~full_rank & (trace > 0.0)
    safe_det = np.where(full_rank, det, 1.0)
    safe_trace = np.where(rank_one, trace, 1.0)
    adjugate = np.stack([np.stack([d, -b], axis=-1), np.stack([-b, a], axis=-1)], axis=-2)
    return np.where(
        full_rank[:, None, None],
        adjugate / safe_det[:, None, None],
        np.where(rank_one[:, None, None], matrices / (safe_trace**2)[:, None, None], 0.0),
    )


def _add_block(sigma: np.ndarray, block: np.ndarray, rows: slice) -> np.ndarray:
    out = sigma.copy()
    out[:, rows, rows] += block
    return out


_SPATIAL = slice(0, 2)
_ANGULAR = slice(2, 4)


# ------------------------------------------------------------------ geometric events


def travel(sigma: np.ndarray, distance) -> np.ndarray:
    """Free flight along the ray: Σ' = Tᵀ Σ T, T = [[I, −d·I], [0, I]].

    sigma : (n, 4, 4); distance : (n,) metres. The ray now at x left from x − d·u.
    """
    sigma = _as_sigma(sigma)
    d = _per_lane(distance, len(sigma), "distance")
    shear = _identities(len(sigma))
    shear[:, 0, 2] = -d
    shear[:, 1, 3] = -d
    return _congruence(sigma, shear)


def rotate(sigma: np.ndarray, angle) -> np.ndarray:
    """Re-express Σ in the frame turned by ``angle`` about the ray: Σ' = Rᵀ Σ R.

    sigma : (n, 4, 4); angle : (n,) radians. R = diag(r, r), r = [[c, −s], [s, c]]; the
    new axes are x̂' = c·x̂ + s·ŷ and ŷ' = −s·x̂ + c·ŷ (angles turn with the positions).
    """
    sigma = _as_sigma(sigma)
    r = _rotation_2x2(_per_lane(angle, len(sigma), "angle"))
    rotation = np.zeros((len(sigma), 4, 4), dtype=SIGMA_DTYPE)
    rotation[:, _SPATIAL, _SPATIAL] = r
    rotation[:, _ANGULAR, _ANGULAR] = r
    return _congruence(sigma, rotation)


def plane_of_incidence_angle(normal_x, normal_y) -> np.ndarray:
    """Angle for ``rotate`` that puts ŷ' in the plane of the ray and the surface normal.

    normal_x, normal_y : (n,) components of the unit normal along the current x̂, ŷ.
    Returns (n,) radians such that, after rotating, the normal has no x̂' component.
    At normal incidence (both zero) the angle is 0.
    """
    return np.arctan2(-np.asarray(normal_x, dtype=SIGMA_DTYPE), np.asarray(normal_y, dtype=SIGMA_DTYPE))


def project(sigma: np.ndarray, cos_theta) -> np.ndarray:
    """Projection onto the tangent plane: Σ' = P Σ P, P = diag(1, |cos θ|, 1, 1).

    The caller has rotated so that ŷ is in the plane of incidence (see the package
    docstring); a footprint stretches by 1/|cos θ| along t̂y. cos_theta : (n,).
    """
    sigma = _as_sigma(sigma)
    scale = _identities(len(sigma))
    scale[:, 1, 1] = np.abs(_per_lane(cos_theta, len(sigma), "cos_theta"))
    return _congruence(sigma, scale)


def inverse_project(sigma: np.ndarray, cos_theta, eps: float = GRAZING_COS_EPS) -> np.ndarray:
    """From the tangent plane to the ray leaving toward ω_o: P = diag(1, 1/max(|cos θo|, eps), 1, 1).

    The caller has rotated so that t̂y is in the plane of ω_o. cos_theta : (n,), eps keeps
    grazing exits finite. ``inverse_project(project(Σ, c), c) == Σ`` for |c| ≥ eps.
    """
    sigma = _as_sigma(sigma)
    scale = _identities(len(sigma))
    scale[:, 1, 1] = 1.0 / np.maximum(np.abs(_per_lane(cos_theta, len(sigma), "cos_theta")), eps)
    return _congruence(sigma, scale)


def curvature_matrix(k1, k2, angle=0.0) -> np.ndarray:
    """K = r diag(k1, k2) rᵀ in the tangent frame, (n,) 1/m and radians -> (n, 2, 2) 1/m.

    ``angle`` is measured from t̂x to the first principal direction (sense of ``rotate``).
    """
    k1 = np.atleast_1d(np.asarray(k1, dtype=SIGMA_DTYPE))
    k2 = np.broadcast_to(np.asarray(k2, dtype=SIGMA_DTYPE), k1.shape)
    r = _rotation_2x2(np.broadcast_to(np.asarray(angle, dtype=SIGMA_DTYPE), k1.shape))
    principal = np.zeros(k1.shape + (2, 2), dtype=SIGMA_DTYPE)
    principal[:, 0, 0] = k1
    principal[:, 1, 1] = k2
    return r @ principal @ np.swapaxes(r, -1, -2)


def curvature(sigma: np.ndarray, k1, k2, sign=1.0, angle=0.0, sagittal_scale=1.0) -> np.ndarray:
    """Local surface curvature: Σ' = Cᵀ Σ C, C = [[I, 0], [−sign·D·K, I]], K = curvature_matrix,
    D = diag(sagittal_scale, 1).

    sigma : (n, 4, 4); k1, k2 : (n,) principal curvatures, 1/m (positive: bowl facing the
    light, see the package docstring); angle : (n,) radians from t̂x to the first
    principal direction; sign : +1 before the BRDF, −1 after. Angles change by
    sign·D·K·s with the tangent offset s. sagittal_scale : (n,) the factor of the change
    across the plane of incidence (the u row): cos θ at a reflection, where a normal
    tilted by δ across the plane turns the reflected ray by 2·cos θ·δ, not 2δ (1: the
    source model's unforeshortened operator).
    """
    sigma = _as_sigma(sigma)
    n = len(sigma)
    k = curvature_matrix(_per_lane(k1, n, "k1"), _per_lane(k2, n, "k2"), _per_lane(angle, n, "angle"))
    k[:, 0, :] *= _per_lane(sagittal_scale, n, "sagittal_scale")[:, None]
    shear = _identities(n)
    shear[:, _ANGULAR, _SPATIAL] = -_per_lane(sign, n, "sign")[:, None, None] * k
    return _congruence(sigma, shear)


def _flip_angles(sigma: np.ndarray) -> np.ndarray:
    sigma = _as_sigma(sigma)
    flip = _identities(len(sigma))
    flip[:, 2, 2] = -1.0
    flip[:, 3, 3] = -1.0
    return _congruence(sigma, flip)


def mirror(sigma: np.ndarray) -> np.ndarray:
    """Mirror symmetry about the (local) normal: Σ' = S Σ S, S = diag(1, 1, −1, −1).

    Incident angles (of ω_i, after ``reverse`` and ``curvature(+K)``) become outgoing
    angles about the mirror direction. sigma : (n, 4, 4).
    """
    return _flip_angles(sigma)


def reverse(sigma: np.ndarray) -> np.ndarray:
    """Re-express the arriving field with the angles of ω_i = −(propagation direction).

    Same matrix as ``mirror`` (S = diag(1, 1, −1, −1)) but a different role: it converts
    the propagation convention of ``travel`` to the ω_i convention that the +K curvature
    and the mirror symmetry assume. Without it a flat mirror maps a diverging beam to a
    converging one. sigma : (n, 4, 4).
    """
    return _flip_angles(sigma)


def lens(sigma: np.ndarray, focal_length) -> np.ndarray:
    """Thin lens: angles change by −x/f, i.e. ``curvature`` with K = −I/f and sign +1.

    sigma : (n, 4, 4); focal_length : (n,) metres, inf = no lens. Imaging: travel(d1),
    lens(f), travel(d2) with 1/d1 + 1/d2 = 1/f maps the spatial block of an emitter by
    the magnification m = −d2/d1 (Σ spatial / m²) and empties the angular block.
    """
    sigma = _as_sigma(sigma)
    power = 1.0 / _per_lane(focal_length, len(sigma), "focal_length")
    shear = _identities(len(sigma))
    shear[:, 2, 0] = power
    shear[:, 3, 1] = power
    return _congruence(sigma, shear)


def sensor(sigma: np.ndarray, pixel_size) -> np.ndarray:
    """Spatial frequencies from cycles per metre to cycles per pixel: Σ' = D Σ D, D = diag(p, p, 1, 1).

    sigma : (n, 4, 4) at the sensor (or any plane); pixel_size : (n,) metres per pixel
    on that plane. Angular frequencies stay in cycles per radian.
    """
    sigma = _as_sigma(sigma)
    scale = _identities(len(sigma))
    p = _per_lane(pixel_size, len(sigma), "pixel_size")
    scale[:, 0, 0] = p
    scale[:, 1, 1] = p
    return _congruence(sigma, scale)


# --------------------------------------------------------------- products (add to Σ)


def texture(sigma: np.ndarray, block) -> np.ndarray:
    """Multiplication by a texture: Σ' = Σ + diag(T, 0), applied in the tangent frame.

    sigma : (n, 4, 4); block : (n, 2, 2) or (2, 2) T in cycles²/m² (amplitude moments of
    the texture over the footprint: ``texture_from_patch`` then ``texture_to_tangent``).
    """
    sigma = _as_sigma(sigma)
    return _add_block(sigma, _per_lane_block(block, len(sigma), "texture block"), _SPATIAL)


def occlusion(sigma: np.ndarray, block) -> np.ndarray:
    """Multiplication by a visibility window: Σ' = Σ + diag(O, 0).

    sigma : (n, 4, 4); block : (n, 2, 2) or (2, 2) O in cycles²/m² (``occlusion_block``).
    """
    sigma = _as_sigma(sigma)
    return _add_block(sigma, _per_lane_block(block, len(sigma), "occlusion block"), _SPATIAL)


def occlusion_block(radius) -> np.ndarray:
    """O for an unoccluded window treated as a Gaussian of std ``radius``: I / (4π² r²).

    radius : (n,) metres -> (n, 2, 2) cycles²/m².
    """
    radius = np.atleast_1d(np.asarray(radius, dtype=SIGMA_DTYPE))
    return (1.0 / (FOUR_PI_SQUARED * radius**2))[:, None, None] * np.eye(2)


def cosine(sigma: np.ndarray, cos_theta, eps: float = GRAZING_COS_EPS) -> np.ndarray:
    """The incident cosine factor as an angular window: Σ' = Σ + diag(0, 0, cu, cv).

    cos θ(u, v) ≈ cos(θi + v)·cos(u) around the central direction. Its log has second
    derivatives −1 in u and −1/cos²θi in v, so it is locally a Gaussian window of angular
    std 1 and |cos θi| (the linear term only shifts the window, which leaves the
    amplitude spectrum alone): cu = 1/(4π²), cv = 1/(4π² max(cos²θi, eps²)) cycles²/rad².
    It matters near grazing incidence; a perfect mirror has no cosine factor (the mirror
    BRDF's 1/cos cancels it), which ``chain.scatter`` respects.

    sigma : (n, 4, 4) in the tangent frame; cos_theta : (n,).
    """
    sigma = _as_sigma(sigma)
    cos2 = np.maximum(_per_lane(cos_theta, len(sigma), "cos_theta") ** 2, eps**2)
    window = np.zeros((len(sigma), 2, 2), dtype=SIGMA_DTYPE)
    window[:, 0, 0] = 1.0 / FOUR_PI_SQUARED
    window[:, 1, 1] = 1.0 / (FOUR_PI_SQUARED * cos2)
    return _add_block(sigma, window, _ANGULAR)


# ------------------------------------------------------------ convolution (the BRDF)


def brdf(sigma: np.ndarray, b_u, b_v) -> np.ndarray:
    """Angular low-pass by the BRDF lobe: Σ' = Σ − Σ Pᵀ (P Σ Pᵀ + diag(b))⁺ P Σ, P = [0 I].

    This is (Σ⁻¹ + diag(0, 0, 1/b_u, 1/b_v))⁻¹ in the Woodbury form, which needs no
    inverse of Σ, so rank-deficient Σ (emitters, mirrors) are fine. Per axis: b = inf
    leaves Σ unchanged (mirror), b = 0 conditions the spectrum on zero angular frequency
    (diffuse: the angular block and the space-angle block become 0).

    sigma : (n, 4, 4) after ``mirror``; b_u, b_v : (n,) cycles²/rad², ≥ 0, possibly inf.
    """
    sigma = _as_sigma(sigma)
    n = len(sigma)
    b = np.stack([_per_lane(b_u, n, "b_u"), _per_lane(b_v, n, "b_v")], axis=-1)
    if np.any(np.isnan(b)) or np.any(b < 0.0):
        raise ValueError("BRDF bandwidths must be >= 0 (inf for a perfect mirror)")
    # An infinite bandwidth adds nothing to the precision: drop that axis from the update
    # by zeroing its row and column, so the pseudo-inverse is zero there.
    finite = np.isfinite(b).astype(SIGMA_DTYPE)
    angular_plus_lobe = sigma[:, _ANGULAR, _ANGULAR].copy()
    angular_plus_lobe[:, [0, 1], [0, 1]] += np.where(np.isfinite(b), b, 0.0)
    angular_plus_lobe *= finite[:, :, None] * finite[:, None, :]
    with_angles = sigma[:, :, _ANGULAR]  # Σ Pᵀ, (n, 4, 2)
    update = with_angles @ _pinv_sym2(angular_plus_lobe) @ np.swapaxes(with_angles, -1, -2)
    return _symmetrized(sigma - update)


# ------------------------------------------------------------------------- emitters


def emitter(extent) -> np.ndarray:
    """Σ leaving a diffuse Gaussian emitter of std ``extent``: diag(σ², σ², 0, 0), σ² = 1/(4π²s²).

    extent : (n,) metres; values ≤ 0 mean a point light (POINT_LIGHT_EXTENT). Diffuse:
    radiance does not depend on direction, so the angular block is 0 (rank 2).
    Returns (n, 4, 4) in the emitter's ray frame, before the first ``travel``.
    """
    extent = np.atleast_1d(np.asarray(extent, dtype=SIGMA_DTYPE))
    extent = np.where(extent > 0.0, extent, POINT_LIGHT_EXTENT)
    sigma = np.zeros((len(extent), 4, 4), dtype=SIGMA_DTYPE)
    sigma[:, 0, 0] = sigma[:, 1, 1] = 1.0 / (FOUR_PI_SQUARED * extent**2)
    return sigma


def distant_emitter(angular_extent) -> np.ndarray:
    """Σ of a distant source of angular std α: diag(0, 0, σu², σu²), σu² = 1/(4π²α²).

    angular_extent : (n,) radians; values ≤ 0 mean DIRECTIONAL_LIGHT_EXTENT. Spatially
    constant, so the spatial block is 0. Returns (n, 4, 4).
    """
    alpha = np.atleast_1d(np.asarray(angular_extent, dtype=SIGMA_DTYPE))
    alpha = np.where(alpha > 0.0, alpha, DIRECTIONAL_LIGHT_EXTENT)
    sigma = np.zeros((len(alpha), 4, 4), dtype=SIGMA_DTYPE)
    sigma[:, 2, 2] = sigma[:, 3, 3] = 1.0 / (FOUR_PI_SQUARED * alpha**2)
    return sigma


# ----------------------------------------------------------------- lobes and texture


def phong_bandwidth(exponent) -> np.ndarray:
    """b = e / (4π²) cycles²/rad²: cos^e(θ) ≈ exp(−e θ²/2), an angular std of 1/√e."""
    return np.asarray(exponent, dtype=SIGMA_DTYPE) / FOUR_PI_SQUARED


def ggx_bandwidth(alpha) -> np.ndarray:
    """b = 1 / (4π² α²) cycles²/rad².

    Near its peak GGX is D ∝ 1 − 2θh²/α² ≈ exp(−2θh²/α²); in the reflected angle
    θ = 2θh that is exp(−θ²/(2α²)), an angular std of α.
    """
    return 1.0 / (FOUR_PI_SQUARED * np.asarray(alpha, dtype=SIGMA_DTYPE) ** 2)


def beckmann_bandwidth(alpha) -> np.ndarray:
    """b = 1 / (8π² α²) cycles²/rad².

    Beckmann is exp(−tan²θh/α²) ≈ exp(−θ²/(4α²)) in the reflected angle θ = 2θh, an
    angular std of √2·α: half the GGX bandwidth for the same α.
    """
    return 1.0 / (2.0 * FOUR_PI_SQUARED * np.asarray(alpha, dtype=SIGMA_DTYPE) ** 2)


def texture_from_patch(values: np.ndarray, texel_size) -> np.ndarray:
    """T of a texture patch: second moments of its amplitude spectrum, (2, 2) cycles²/unit².

    values : (h, w) samples a[i, j] at x = j·dx, y = i·dy covering the footprint — a
    periodic tile, or samples already multiplied by a window (otherwise the patch edges
    add spurious high frequencies). texel_size : (dx, dy) in metres, or in texture units
    to be mapped with ``texture_to_tangent``.

    T = Σξ ξ ξᵀ |â(ξ)| / Σξ |â(ξ)|, the convention of Σ, so Σ + T is the Σ of the textured
    light field. For 1 + a·cos(2π f0 x) this is a·f0²/(1 + a): the DC term has weight 1,
    each of the two side bands a/2. (The structure tensor ∫∇a∇aᵀ / (4π²∫a²) is the POWER
    moment instead, a²f0²/(2 + a²).)
    """
    values = np.asarray(values, dtype=SIGMA_DTYPE)
    if values.ndim != 2:
        raise ValueError(f"values must be a 2D patch, got shape {values.shape}")
    dx, dy = (float(size) for size in texel_size)
    amplitude = np.abs(np.fft.fft2(values))
    total = amplitude.sum()
    if total == 0.0:
        return np.zeros((2, 2), dtype=SIGMA_DTYPE)
    freq_y = np.fft.fftfreq(values.shape[0], d=dy)[:, None]
    freq_x = np.fft.fftfreq(values.shape[1], d=dx)[None, :]
    xx = (freq_x**2 * amplitude).sum() / total
    yy = (freq_y**2 * amplitude).sum() / total
    xy = (freq_x * freq_y * amplitude).sum() / total
    return np.array([[xx, xy], [xy, yy]], dtype=SIGMA_DTYPE)


def texture_to_tangent(block_uv, uv_from_tangent) -> np.ndarray:
    """Map T from texture units to the tangent frame: T_m = Jᵀ T_uv J.

    block_uv : (n, 2, 2) or (2, 2) cycles² per texture unit²; uv_from_tangent : (n, 2, 2)
    or (2, 2) Jacobian J = ∂(u_tex, v_tex)/∂(t_x, t_y) in texture units per metre.
    Returns cycles²/m², shaped like the broadcast of the inputs.
    """
    jacobian = np.asarray(uv_from_tangent, dtype=SIGMA_DTYPE)
    return np.swapaxes(jacobian, -1, -2) @ np.asarray(block_uv, dtype=SIGMA_DTYPE) @ jacobian


# ---------------------------------------------------------------- norms for the index


def reflectance_norm(b_u, b_v) -> np.ndarray:
    """R = √λmax(B) = √max(b_u, b_v) in cycles/rad; B = diag(b_u, b_v) is diagonal.

    Isotropic Phong: √e / 2π (R > 2 ⇔ e > 16π² ≈ 158); GGX: 1/(2πα); diffuse 0; mirror inf.
    """
    return np.sqrt(np.maximum(np.asarray(b_u, dtype=SIGMA_DTYPE), np.asarray(b_v, dtype=SIGMA_DTYPE)))


def texture_norm(block) -> np.ndarray:
    """T = √λmax(T block) in cycles per metre; block (..., 2, 2) -> (...).

    A cosine texture 1 + a·cos(2πx/p) gives √(a/(1+a))/p (≈ 0.71/p for a = 1). Multiply
    by a pixel footprint in metres for cycles per pixel.
    """
    block = np.asarray(block, dtype=SIGMA_DTYPE)
    a, b, d = block[..., 0, 0], block[..., 0, 1], block[..., 1, 1]
    largest = 0.5 * (a + d) + np.sqrt((0.5 * (a - d)) ** 2 + b * b)
    return np.sqrt(np.maximum(largest, 0.0))


def curvature_norm(k1, k2) -> np.ndarray:
    """C = max(|k1|, |k2|) in 1/m; 0 means locally planar."""
    return np.maximum(np.abs(np.asarray(k1, dtype=SIGMA_DTYPE)), np.abs(np.asarray(k2, dtype=SIGMA_DTYPE)))


def pack_upper(sigma: np.ndarray) -> np.ndarray:
    """The 10 unique entries of each Σ, (n, 4, 4) -> (n, 10), in PACKED_ENTRY_NAMES order."""
    return _as_sigma(sigma)[:, _UPPER_ROWS, _UPPER_COLS]


def unpack_upper(packed: np.ndarray) -> np.ndarray:
    """Inverse of pack_upper: (n, 10) -> symmetric (n, 4, 4)."""
    packed = np.asarray(packed, dtype=SIGMA_DTYPE)
    if packed.ndim != 2 or packed.shape[1] != len(PACKED_ENTRY_NAMES):
        raise ValueError(f"packed must have shape (n, 10), got {packed.shape}")
    sigma = np.zeros((len(packed), 4, 4), dtype=SIGMA_DTYPE)
    sigma[:, _UPPER_ROWS, _UPPER_COLS] = packed
    sigma[:, _UPPER_COLS, _UPPER_ROWS] = packed
    return sigma
