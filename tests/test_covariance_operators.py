"""Covariance operators: COVARIANCE.md's validation cases, invariants, batched vs reference.

Every validation case runs twice: through the batched operators (one lane) and through
the scalar reference. Flatland cases use the (x, u) pair; the isotropic emitters make
the (y, v) pair identical, which is checked too. Numbers quoted by COVARIANCE.md are
rounded to 4 significant digits (40.5 to 3), so they are compared to within half a unit
of their last digit; the closed forms they come from are compared to 1e-12.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pxr_layers import covariance as cov
from pxr_layers.covariance import operators as ops
from pxr_layers.covariance import reference

FOUR_PI_SQUARED = 4.0 * np.pi**2
XU = (0, 2)
YV = (1, 3)


def _one_lane(batched_operator):
    """Run a batched operator on a single (4, 4) Σ with scalar parameters."""

    def run(sigma, *args, **kwargs):
        return batched_operator(np.asarray(sigma)[None], *args, **kwargs)[0]

    return run


BATCHED = SimpleNamespace(
    **{
        name: _one_lane(getattr(ops, name))
        for name in (
            "travel",
            "rotate",
            "project",
            "inverse_project",
            "curvature",
            "mirror",
            "reverse",
            "brdf",
            "texture",
            "occlusion",
            "cosine",
            "lens",
            "sensor",
        )
    },
    emitter=lambda extent: ops.emitter(extent)[0],
    distant_emitter=lambda angular_extent: ops.distant_emitter(angular_extent)[0],
    scatter=_one_lane(cov.scatter),
)


@pytest.fixture(params=["batched", "reference"])
def impl(request):
    return BATCHED if request.param == "batched" else reference


def pair_block(sigma: np.ndarray, pair: tuple[int, int]) -> np.ndarray:
    """The 2×2 flatland block of one (spatial, angular) pair."""
    return sigma[np.ix_(pair, pair)]


def cross_pair_entries(sigma: np.ndarray) -> np.ndarray:
    """Entries coupling the (x, u) pair to the (y, v) pair (zero for isotropic cases)."""
    return sigma[np.ix_(XU, YV)]


def assert_quoted(actual, quoted, last_digit: float) -> None:
    """A number printed in COVARIANCE.md matches to within half a unit of its last digit."""
    np.testing.assert_allclose(actual, quoted, rtol=0.0, atol=0.5 * last_digit)


def random_psd(rng, n: int, rank: int = 4) -> np.ndarray:
    """(n, 4, 4) random PSD Σ of the given rank, spatial entries ~10× the angular ones."""
    scale = np.array([10.0, 10.0, 1.0, 1.0])[None, :, None]
    factors = scale * rng.normal(size=(n, 4, rank))
    return factors @ np.swapaxes(factors, -1, -2)


def sigma_from_pairs(xu_block: np.ndarray) -> np.ndarray:
    """A 4×4 Σ carrying the same flatland 2×2 block in (x, u) and in (y, v)."""
    sigma = np.zeros((4, 4))
    sigma[np.ix_(XU, XU)] = xu_block
    sigma[np.ix_(YV, YV)] = xu_block
    return sigma


# ------------------------------------------------------------------ validation cases

SIGMA2_S005 = 1.0 / (FOUR_PI_SQUARED * 0.05**2)  # σ² of an emitter of std 5 cm, 10.13 cycles²/m²
ONES = np.array([[1.0, -1.0], [-1.0, 1.0]])


def test_case1_emitter_then_travel(impl):
    sigma = impl.travel(impl.emitter(0.05), 1.0)
    for pair in (XU, YV):
        np.testing.assert_allclose(pair_block(sigma, pair), SIGMA2_S005 * ONES, rtol=1e-12)
        assert_quoted(pair_block(sigma, pair), 10.13 * ONES, 0.01)
    np.testing.assert_array_equal(cross_pair_entries(sigma), 0.0)

    d = 2.5  # the closed form σ²[[1, −d], [−d, d²]] for another distance
    sigma = impl.travel(impl.emitter(0.05), d)
    np.testing.assert_allclose(pair_block(sigma, XU), SIGMA2_S005 * np.array([[1, -d], [-d, d * d]]), rtol=1e-12)


def test_case2_phong_lobe_diffuse_and_mirror(impl):
    arriving = impl.travel(impl.emitter(0.05), 1.0)
    b = cov.phong_bandwidth(100.0)
    assert_quoted(b, 2.533, 0.001)

    glossy = impl.brdf(arriving, b, b)
    closed_form = SIGMA2_S005 * b / (SIGMA2_S005 * 1.0**2 + b)
    for pair in (XU, YV):
        np.testing.assert_allclose(pair_block(glossy, pair), closed_form * ONES, rtol=1e-9)
        # COVARIANCE.md prints 2.027; σ²b/(σ²d² + b) = 2.0264, i.e. 2.026 to 4 digits.
        assert_quoted(pair_block(glossy, pair), 2.026 * ONES, 0.001)

    np.testing.assert_allclose(impl.brdf(arriving, 0.0, 0.0), 0.0, atol=1e-12)
    np.testing.assert_array_equal(impl.brdf(arriving, np.inf, np.inf), arriving)


def cosine_texture_patch(amplitude: float, frequency: float, direction=(1.0, 0.0), texels: int = 64, periods: int = 10):
    """Samples of 1 + a·cos(2π f0 (n·p)) over a square holding whole periods, and the texel size."""
    length = periods / frequency
    texel = length / texels
    coords = np.arange(texels) * texel
    x, y = np.meshgrid(coords, coords, indexing="xy")  # values[i, j] at (x_j, y_i)
    phase = 2.0 * np.pi * frequency * (direction[0] * x + direction[1] * y)
    return 1.0 + amplitude * np.cos(phase), texel


@pytest.mark.parametrize("amplitude", [1.0, 0.5])
def test_case3_cosine_texture_adds_its_amplitude_moment(impl, amplitude):
    f0 = 20.0
    patch, texel = cosine_texture_patch(amplitude, f0)
    block = cov.texture_from_patch(patch, (texel, texel))
    # Spectrum: weight 1 at DC, a/2 at ±f0 -> second moment a·f0²/(1 + a).
    expected = amplitude * f0**2 / (1.0 + amplitude)
    np.testing.assert_allclose(block, [[expected, 0.0], [0.0, 0.0]], atol=1e-9 * expected)
    if amplitude == 1.0:
        assert_quoted(block[0, 0], 200.0, 1.0)

    arriving = impl.travel(impl.emitter(0.05), 1.0)
    textured = impl.texture(arriving, block)
    delta = textured - arriving
    np.testing.assert_allclose(delta[0, 0], expected, rtol=1e-9)
    delta[0, 0] = 0.0
    np.testing.assert_allclose(delta, 0.0, atol=1e-9)


def test_case3_texture_along_a_diagonal_is_a_rank_one_block():
    f0, amplitude = 20.0, 1.0
    direction = np.array([3.0, 4.0]) / 5.0  # stays periodic on the patch: 6 and 8 periods
    patch, texel = cosine_texture_patch(amplitude, f0, direction, texels=128)
    block = cov.texture_from_patch(patch, (texel, texel))
    expected = amplitude * f0**2 / (1.0 + amplitude) * np.outer(direction, direction)
    np.testing.assert_allclose(block, expected, atol=1e-9 * f0**2)


def test_case3_power_structure_tensor_is_a_different_number():
    """COVARIANCE.md calls a·f0²/(1+a) "the power of the structure tensor", but
    ∫ a'² / (4π² ∫ a²) — the formula it gives for T — is the POWER-spectrum moment
    a²f0²/(2 + a²): 133.3 instead of 200 for a = 1. Only the amplitude moment
    (texture_from_patch) reproduces the documented +200 and T ≈ 0.71/p."""
    f0, amplitude = 20.0, 1.0
    x = np.linspace(0.0, 1.0 / f0, 4096, endpoint=False)
    a = 1.0 + amplitude * np.cos(2 * np.pi * f0 * x)
    gradient = -2 * np.pi * f0 * amplitude * np.sin(2 * np.pi * f0 * x)
    power_moment = np.mean(gradient**2) / (FOUR_PI_SQUARED * np.mean(a**2))
    np.testing.assert_allclose(power_moment, amplitude**2 * f0**2 / (2 + amplitude**2), rtol=1e-12)
    assert abs(power_moment - 200.0) > 60.0


def test_texture_from_texture_units_to_metres():
    patch, texel = cosine_texture_patch(1.0, 20.0)  # 20 cycles per texture unit
    block_uv = cov.texture_from_patch(patch, (texel, texel))
    uv_from_tangent = np.diag([2.0, 0.5])  # 2 texture units per metre along t̂x
    block_m = cov.texture_to_tangent(block_uv, uv_from_tangent)
    np.testing.assert_allclose(cov.texture_norm(block_m), 40.0 * np.sqrt(0.5), rtol=1e-9)
    assert cov.texture_from_patch(np.full((8, 8), 3.0), (0.1, 0.1)).max() == 0.0  # flat texture


@pytest.mark.parametrize("k", [2.0, -2.0])
def test_case4_curved_mirror_at_normal_incidence(impl, k):
    alpha = 0.05
    sigma = impl.distant_emitter(alpha)
    sigma = impl.project(sigma, 1.0)
    sigma = impl.reverse(sigma)
    sigma = impl.curvature(sigma, k, k, +1.0)
    sigma = impl.mirror(sigma)
    sigma = impl.brdf(sigma, np.inf, np.inf)
    sigma = impl.curvature(sigma, k, k, -1.0)
    sigma = impl.inverse_project(sigma, 1.0)

    sigma_u2 = 1.0 / (FOUR_PI_SQUARED * alpha**2)
    # k > 0 (concave, focusing) gives +2k: converging rays; the doc's ∓.
    closed_form = sigma_u2 * np.array([[4 * k * k, 2 * k], [2 * k, 1.0]])
    for pair in (XU, YV):
        np.testing.assert_allclose(pair_block(sigma, pair), closed_form, rtol=1e-12)
        assert_quoted(pair_block(sigma, pair)[0, 0], 162.1, 0.1)
        assert_quoted(pair_block(sigma, pair)[0, 1], np.sign(k) * 40.5, 0.1)
        assert_quoted(pair_block(sigma, pair)[1, 1], 10.13, 0.01)
    # Through the chain: a mirror vertex has no cosine factor, so the numbers are the same.
    vertex = cov.VertexParams(cos_in=1.0, cos_out=1.0, bandwidth_u=np.inf, bandwidth_v=np.inf, distance=0.0, k1=k, k2=k)
    np.testing.assert_allclose(impl.scatter(impl.distant_emitter(alpha), vertex), sigma, rtol=1e-12)


@pytest.mark.parametrize("k", [25.0, -25.0])
def test_case4_a_tube_mirror_curves_one_axis(impl, k):
    """A hair's tube (curvature k = 1/r around it, 0 along it): case 4's closed form across
    the tube, a flat mirror's along it."""
    alpha = 0.05
    sigma = impl.project(impl.distant_emitter(alpha), 1.0)
    sigma = impl.reverse(sigma)
    sigma = impl.curvature(sigma, k, 0.0, +1.0)
    sigma = impl.mirror(sigma)
    sigma = impl.brdf(sigma, np.inf, np.inf)
    sigma = impl.curvature(sigma, k, 0.0, -1.0)
    sigma = impl.inverse_project(sigma, 1.0)
    sigma_u2 = 1.0 / (FOUR_PI_SQUARED * alpha**2)
    np.testing.assert_allclose(pair_block(sigma, XU), sigma_u2 * np.array([[4 * k * k, 2 * k], [2 * k, 1.0]]),
                               rtol=1e-12)
    np.testing.assert_allclose(pair_block(sigma, YV), sigma_u2 * np.array([[0.0, 0.0], [0.0, 1.0]]), atol=1e-9)


def test_case5_thin_lens_returns_the_emitter(impl):
    emitted = impl.emitter(0.05)
    imaged = impl.travel(impl.lens(impl.travel(emitted, 1.0), 0.5), 1.0)
    np.testing.assert_allclose(imaged, emitted, atol=1e-9 * SIGMA2_S005)
    # The lens is curvature(−1/f): angles change by −x/f.
    arriving = impl.travel(emitted, 1.0)
    np.testing.assert_allclose(impl.lens(arriving, 0.5), impl.curvature(arriving, -2.0, -2.0, +1.0), rtol=1e-12)


def test_case5_magnification_scales_the_spatial_block(impl, rng):
    spatial = random_psd(rng, 1, rank=2)[0][:2, :2]
    emitted = np.zeros((4, 4))
    emitted[:2, :2] = spatial
    d1, f = 1.0, 2.0 / 3.0
    d2 = 1.0 / (1.0 / f - 1.0 / d1)  # 2 m: magnification m = −d2/d1 = −2
    imaged = impl.travel(impl.lens(impl.travel(emitted, d1), f), d2)
    scale = np.abs(spatial).max()
    # Frequencies shrink by |m|: Σ_spatial / m²; the sign of m cancels in a quadratic form.
    np.testing.assert_allclose(imaged[:2, :2], spatial / 4.0, atol=1e-9 * scale)
    np.testing.assert_allclose(imaged[:, 2:], 0.0, atol=1e-9 * scale)


# ------------------------------------------------------------------ case 6: invariants


def test_case6_determinant_is_conserved(impl, rng):
    sigma = random_psd(rng, 1)[0]
    det = np.linalg.det(sigma)
    for event in (
        lambda s: impl.travel(s, 1.7),
        lambda s: impl.curvature(s, 2.0, -0.5, +1.0, 0.3),
        lambda s: impl.curvature(s, 2.0, -0.5, -1.0, 0.3),
        lambda s: impl.rotate(s, 0.9),
        impl.mirror,
        impl.reverse,
        lambda s: impl.lens(s, 0.3),
    ):
        np.testing.assert_allclose(np.linalg.det(event(sigma)), det, rtol=1e-9)


def test_case6_rotation_keeps_trace_and_frobenius_norm(impl, rng):
    sigma = random_psd(rng, 1)[0]
    rotated = impl.rotate(sigma, 1.234)
    np.testing.assert_allclose(np.trace(rotated), np.trace(sigma), rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(rotated), np.linalg.norm(sigma), rtol=1e-12)
    np.testing.assert_allclose(impl.rotate(sigma, 2 * np.pi), sigma, atol=1e-12 * np.abs(sigma).max())
    np.testing.assert_allclose(
        impl.rotate(impl.rotate(sigma, 0.4), 0.7), impl.rotate(sigma, 1.1), atol=1e-12 * np.abs(sigma).max()
    )


@pytest.mark.parametrize("cos_theta", [1.0, 0.5, -0.3, 0.02])
def test_case6_projection_then_inverse_projection_is_identity(impl, rng, cos_theta):
    sigma = random_psd(rng, 1)[0]
    back = impl.inverse_project(impl.project(sigma, cos_theta), cos_theta)
    np.testing.assert_allclose(back, sigma, rtol=1e-12, atol=1e-12 * np.abs(sigma).max())


def test_case6_shears_undo_each_other(impl, rng):
    sigma = random_psd(rng, 1)[0]
    atol = 1e-12 * np.abs(sigma).max()
    np.testing.assert_allclose(impl.travel(impl.travel(sigma, 0.8), -0.8), sigma, atol=atol * 10)
    np.testing.assert_allclose(
        impl.curvature(impl.curvature(sigma, 1.5, -3.0, +1.0, 0.2), 1.5, -3.0, -1.0, 0.2), sigma, atol=atol * 10
    )
    np.testing.assert_allclose(impl.lens(impl.lens(sigma, 0.5), -0.5), sigma, atol=atol * 10)


# -------------------------------------------------------------------------- the BRDF


@pytest.mark.parametrize("rank", [4, 2, 1])
def test_brdf_woodbury_on_singular_sigma_matches_reference(rng, rank):
    sigma = random_psd(rng, 300, rank)
    b_choices = np.array([0.0, 0.05, 1.0, 20.0, np.inf])
    b_u = rng.choice(b_choices, size=300)
    b_v = rng.choice(b_choices, size=300)
    batched = ops.brdf(sigma, b_u, b_v)
    assert np.all(np.isfinite(batched))
    for lane in range(300):
        expected = reference.brdf(sigma[lane], b_u[lane], b_v[lane])
        scale = np.abs(sigma[lane]).max()
        np.testing.assert_allclose(batched[lane], expected, atol=1e-7 * scale)
    # Low-pass: never adds content (Σ − Σ' is PSD) and keeps the rank at most.
    removed = np.linalg.eigvalsh(sigma - batched)
    assert removed.min() > -1e-8 * np.abs(sigma).max()
    for lane in range(300):
        assert np.linalg.matrix_rank(batched[lane], tol=1e-8 * np.abs(sigma[lane]).max()) <= rank


def test_brdf_equals_the_inverse_form_on_full_rank_sigma(rng):
    sigma = random_psd(rng, 20)
    b_u, b_v = 0.7, 3.0
    direct = np.linalg.inv(np.linalg.inv(sigma) + np.diag([0.0, 0.0, 1.0 / b_u, 1.0 / b_v]))
    np.testing.assert_allclose(ops.brdf(sigma, b_u, b_v), direct, rtol=1e-8, atol=1e-10)


def test_diffuse_brdf_kills_every_angular_entry(rng):
    out = ops.brdf(random_psd(rng, 50), 0.0, 0.0)
    np.testing.assert_allclose(out[:, :, 2:], 0.0, atol=1e-8)


def test_plain_pseudo_inverse_form_is_wrong_for_singular_sigma():
    """(Σ⁺ + B⁺)⁺ as COVARIANCE.md writes it turns case 2's rank-1 Σ into a full-rank one."""
    arriving = ops.travel(ops.emitter(0.05), 1.0)[0]
    b = float(cov.phong_bandwidth(100.0))
    naive = np.linalg.pinv(np.linalg.pinv(arriving) + np.diag([0.0, 0.0, 1.0 / b, 1.0 / b]))
    assert np.linalg.matrix_rank(naive) == 4
    assert np.linalg.matrix_rank(ops.brdf(arriving[None], b, b)[0], rtol=1e-9) == 2
    assert not np.allclose(naive, ops.brdf(arriving[None], b, b)[0], atol=0.1)


def test_brdf_rejects_negative_bandwidth():
    with pytest.raises(ValueError, match="bandwidth"):
        ops.brdf(ops.emitter([0.1]), -1.0, 1.0)


# ------------------------------------------------------------ batched vs reference


def random_vertices(rng, n: int, min_cos: float = 0.05) -> cov.VertexParams:
    b_choices = np.array([0.0, 0.3, 2.5, 40.0, np.inf])
    isotropic_b = rng.choice(b_choices, size=n)
    return cov.VertexParams(
        cos_in=rng.uniform(min_cos, 1.0, n),
        cos_out=rng.uniform(min_cos, 1.0, n),
        bandwidth_u=isotropic_b,
        bandwidth_v=np.where(rng.random(n) < 0.3, rng.choice(b_choices, size=n), isotropic_b),
        distance=rng.uniform(0.1, 3.0, n),
        rotation_in=rng.uniform(-np.pi, np.pi, n),
        rotation_out=rng.uniform(-np.pi, np.pi, n),
        k1=rng.uniform(-3.0, 3.0, n),
        k2=rng.uniform(-3.0, 3.0, n),
        curvature_angle=rng.uniform(-np.pi, np.pi, n),
        texture=random_psd(rng, n, rank=2)[:, :2, :2] * rng.uniform(0.0, 1.0, (n, 1, 1)),
    )


@pytest.mark.parametrize("rank", [4, 2, 1])
def test_every_operator_matches_reference(rng, rank):
    n = 64
    sigma = random_psd(rng, n, rank)
    distance = rng.uniform(-3.0, 3.0, n)
    angle = rng.uniform(-np.pi, np.pi, n)
    cos_theta = rng.uniform(-1.0, 1.0, n)
    k1, k2 = rng.uniform(-4.0, 4.0, (2, n))
    sign = rng.choice([-1.0, 1.0], n)
    block = random_psd(rng, n, rank=2)[:, :2, :2]
    focal = rng.uniform(0.1, 5.0, n) * rng.choice([-1.0, 1.0], n)
    pixel = rng.uniform(1e-5, 1e-3, n)
    cases = {
        "travel": (ops.travel(sigma, distance), lambda i: reference.travel(sigma[i], distance[i])),
        "rotate": (ops.rotate(sigma, angle), lambda i: reference.rotate(sigma[i], angle[i])),
        "project": (ops.project(sigma, cos_theta), lambda i: reference.project(sigma[i], cos_theta[i])),
        "inverse_project": (
            ops.inverse_project(sigma, cos_theta),
            lambda i: reference.inverse_project(sigma[i], cos_theta[i]),
        ),
        "curvature": (
            ops.curvature(sigma, k1, k2, sign, angle),
            lambda i: reference.curvature(sigma[i], k1[i], k2[i], sign[i], angle[i]),
        ),
        "mirror": (ops.mirror(sigma), lambda i: reference.mirror(sigma[i])),
        "reverse": (ops.reverse(sigma), lambda i: reference.reverse(sigma[i])),
        "texture": (ops.texture(sigma, block), lambda i: reference.texture(sigma[i], block[i])),
        "occlusion": (ops.occlusion(sigma, block), lambda i: reference.occlusion(sigma[i], block[i])),
        "cosine": (ops.cosine(sigma, cos_theta), lambda i: reference.cosine(sigma[i], cos_theta[i])),
        "lens": (ops.lens(sigma, focal), lambda i: reference.lens(sigma[i], focal[i])),
        "sensor": (ops.sensor(sigma, pixel), lambda i: reference.sensor(sigma[i], pixel[i])),
    }
    for name, (batched, scalar) in cases.items():
        for lane in range(n):
            expected = scalar(lane)
            np.testing.assert_allclose(
                batched[lane], expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max(), err_msg=name
            )


def test_emitters_match_reference():
    extents = np.array([0.05, 0.3, 0.0])
    for lane, extent in enumerate(extents):
        np.testing.assert_allclose(ops.emitter(extents)[lane], reference.emitter(extent), rtol=1e-14)
        np.testing.assert_allclose(ops.distant_emitter(extents)[lane], reference.distant_emitter(extent), rtol=1e-14)


@pytest.mark.parametrize("rank", [4, 2])
def test_chain_matches_reference_chain(rng, rank):
    n = 100
    emitted = np.where(rng.random((n, 1, 1)) < 0.5, ops.emitter(rng.uniform(0.0, 0.2, n)), random_psd(rng, n, rank))
    distance_from_light = rng.uniform(0.1, 2.0, n)
    # Away from grazing: at cos θ ~ 0.05 a diffuse vertex is a Schur complement that
    # cancels ~8 digits, and both implementations are then only accurate relative to the
    # Σ inside the vertex, not to the small result (the single-operator tests cover grazing).
    vertices = [random_vertices(rng, n, min_cos=0.2) for _ in range(3)]
    batched = cov.chain(emitted, distance_from_light, vertices)
    assert batched.shape == (n, 4, 4) and np.all(np.isfinite(batched))
    for lane in range(n):
        expected = reference.chain(emitted[lane], distance_from_light[lane], [v.lane(lane) for v in vertices])
        np.testing.assert_allclose(batched[lane], expected, rtol=1e-6, atol=1e-7 * np.abs(expected).max())


# ------------------------------------------------------------ the chain's physics


def mirror_vertex(k: float = 0.0, cos_theta: float = 1.0, distance: float = 0.0) -> cov.VertexParams:
    return cov.VertexParams(
        cos_in=cos_theta, cos_out=cos_theta, bandwidth_u=np.inf, bandwidth_v=np.inf, distance=distance, k1=k, k2=k
    )


@pytest.mark.parametrize("cos_theta", [1.0, 0.6])
def test_flat_mirror_is_straight_travel_unfolded(impl, cos_theta):
    """Light reflected by a flat mirror looks like it kept going: travel d1 + d2."""
    emitted = impl.emitter(0.05)
    reflected = impl.scatter(impl.travel(emitted, 1.0), mirror_vertex(cos_theta=cos_theta, distance=0.7))
    np.testing.assert_allclose(reflected, impl.travel(emitted, 1.7), atol=1e-9 * SIGMA2_S005)


def test_concave_mirror_images_like_a_lens(impl):
    """Mirror equation 1/d1 + 1/d2 = 2k: k = 1, d1 = d2 = 1 returns the emitter (case 5 for a mirror)."""
    emitted = impl.emitter(0.05)
    imaged = impl.scatter(impl.travel(emitted, 1.0), mirror_vertex(k=1.0, distance=1.0))
    np.testing.assert_allclose(imaged, emitted, atol=1e-9 * SIGMA2_S005)


def test_doc_order_without_reverse_focuses_a_flat_mirror():
    """The vertex exactly as COVARIANCE.md lists it (no ``reverse``): after a flat mirror
    and a further travel equal to the first, the angular content vanishes, i.e. the
    emitter is imaged as if by a lens. That is why ``scatter`` adds ``reverse``."""
    sigma = ops.travel(ops.emitter([0.05]), 1.0)
    sigma = ops.mirror(ops.curvature(ops.project(sigma, 1.0), 0.0, 0.0, +1.0))
    sigma = ops.travel(ops.inverse_project(ops.curvature(ops.brdf(sigma, np.inf, np.inf), 0.0, 0.0, -1.0), 1.0), 1.0)
    np.testing.assert_allclose(sigma[0, 2:, 2:], 0.0, atol=1e-9)
    assert not np.allclose(sigma, ops.travel(ops.emitter([0.05]), 2.0))


def test_scatter_skips_the_cosine_only_on_perfect_mirrors():
    arriving = ops.travel(ops.emitter([0.05]), 1.0)
    glossy_x = cov.VertexParams(cos_in=0.5, cos_out=0.5, bandwidth_u=1e12, bandwidth_v=np.inf, distance=0.0)
    mirror = cov.VertexParams(cos_in=0.5, cos_out=0.5, bandwidth_u=np.inf, bandwidth_v=np.inf, distance=0.0)
    difference = cov.scatter(arriving, glossy_x) - cov.scatter(arriving, mirror)
    # A near-mirror lobe keeps almost everything; what differs is the cosine window.
    np.testing.assert_allclose(
        np.diag(difference[0])[2:], [1 / FOUR_PI_SQUARED, 1 / (FOUR_PI_SQUARED * 0.25)], rtol=1e-6
    )


# ------------------------------------------------------------------ norms and packing


def test_reflectance_norm_of_lobes():
    alpha = np.array([0.05, 0.2, 0.5])
    np.testing.assert_allclose(
        cov.reflectance_norm(cov.ggx_bandwidth(alpha), cov.ggx_bandwidth(alpha)), 1 / (2 * np.pi * alpha), rtol=1e-12
    )
    np.testing.assert_allclose(
        cov.reflectance_norm(cov.beckmann_bandwidth(alpha), 0.0), 1 / (2 * np.pi * np.sqrt(2) * alpha), rtol=1e-12
    )
    exponent = np.array([10.0, 100.0, 1000.0])
    np.testing.assert_allclose(
        cov.reflectance_norm(cov.phong_bandwidth(exponent), cov.phong_bandwidth(exponent)),
        np.sqrt(exponent) / (2 * np.pi),
        rtol=1e-12,
    )
    # "R > 2 ≈ Phong e > 160": the exact threshold is e = 16π² ≈ 157.9.
    assert (
        cov.reflectance_norm(cov.phong_bandwidth(160.0), 0.0)
        > 2
        > cov.reflectance_norm(cov.phong_bandwidth(157.0), 0.0)
    )
    assert cov.reflectance_norm(0.0, 0.0) == 0.0
    assert np.isinf(cov.reflectance_norm(np.inf, np.inf))


@pytest.mark.parametrize("amplitude", [1.0, 0.25])
def test_texture_norm_of_a_cosine_texture(amplitude):
    period = 0.05
    patch, texel = cosine_texture_patch(amplitude, 1.0 / period)
    norm = cov.texture_norm(cov.texture_from_patch(patch, (texel, texel)))
    np.testing.assert_allclose(norm, np.sqrt(amplitude / (1 + amplitude)) / period, rtol=1e-9)
    if amplitude == 1.0:
        assert_quoted(norm * period, 0.71, 0.01)  # COVARIANCE.md: ≈ 0.71/p


def test_texture_norm_is_the_largest_eigenvalue(rng):
    blocks = random_psd(rng, 50, rank=2)[:, :2, :2]
    np.testing.assert_allclose(cov.texture_norm(blocks), np.sqrt(np.linalg.eigvalsh(blocks)[:, -1]), rtol=1e-10)


def test_curvature_norm_and_matrix():
    np.testing.assert_array_equal(cov.curvature_norm([0.0, 2.0, -3.0], [0.0, -1.0, 1.0]), [0.0, 2.0, 3.0])
    k = cov.curvature_matrix([2.0], [-1.0], [0.6])[0]
    np.testing.assert_allclose(np.linalg.eigvalsh(k), [-1.0, 2.0], rtol=1e-12)
    first_direction = np.array([np.cos(0.6), np.sin(0.6)])
    np.testing.assert_allclose(k @ first_direction, 2.0 * first_direction, rtol=1e-12)


def test_pack_upper_round_trip_and_order(rng):
    sigma = random_psd(rng, 7)
    packed = cov.pack_upper(sigma)
    assert packed.shape == (7, 10)
    np.testing.assert_array_equal(cov.unpack_upper(packed), ops._symmetrized(sigma))
    index = {"x": 0, "y": 1, "u": 2, "v": 3}
    for column, name in enumerate(cov.PACKED_ENTRY_NAMES):
        np.testing.assert_array_equal(packed[:, column], sigma[:, index[name[0]], index[name[1]]])


# --------------------------------------------------------------- emitters and frames


def test_point_and_directional_lights_use_the_documented_constants():
    point = cov.emitter([0.0])[0]
    np.testing.assert_allclose(point[0, 0], 1 / (FOUR_PI_SQUARED * cov.POINT_LIGHT_EXTENT**2))
    assert point[0, 0] > 1e6 and np.all(point[2:, 2:] == 0.0)
    distant = cov.distant_emitter([-1.0])[0]
    np.testing.assert_allclose(distant[3, 3], 1 / (FOUR_PI_SQUARED * cov.DIRECTIONAL_LIGHT_EXTENT**2))
    assert np.all(distant[:2, :2] == 0.0)


def test_plane_of_incidence_angle_clears_the_normal_x_component(rng):
    normal = rng.normal(size=(100, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    angle = cov.plane_of_incidence_angle(normal[:, 0], normal[:, 1])
    new_x_component = np.cos(angle) * normal[:, 0] + np.sin(angle) * normal[:, 1]  # n · x̂'
    np.testing.assert_allclose(new_x_component, 0.0, atol=1e-12)
    assert cov.plane_of_incidence_angle(0.0, 0.0) == 0.0


def test_sensor_counts_cycles_per_pixel():
    sigma = ops.travel(ops.emitter([0.05]), 1.0)
    per_pixel = cov.sensor(sigma, 1e-3)
    np.testing.assert_allclose(per_pixel[0, 0, 0], sigma[0, 0, 0] * 1e-6)
    np.testing.assert_allclose(per_pixel[0, 0, 2], sigma[0, 0, 2] * 1e-3)
    np.testing.assert_allclose(per_pixel[0, 2, 2], sigma[0, 2, 2])


def test_occlusion_block_of_a_window():
    np.testing.assert_allclose(cov.occlusion_block([0.1])[0], np.eye(2) / (FOUR_PI_SQUARED * 0.01))


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="shape"):
        cov.travel(np.eye(4), 1.0)
    with pytest.raises(ValueError, match="distance"):
        cov.travel(np.zeros((3, 4, 4)), np.ones(2))
    with pytest.raises(ValueError, match="texture"):
        cov.texture(np.zeros((3, 4, 4)), np.zeros((2, 2, 2)))
