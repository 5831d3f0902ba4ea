"""MaterialX's chiang_hair_bsdf (trace/hair.py) against what physics asks of a fibre.

* White furnace: a fibre without absorption and with white tints scatters all the light it
  intercepts, for every view direction, roughness and cuticle tilt (quadrature of S over the
  sphere and across the fibre's width); rendered, white hair under a white sky vanishes.
* Reciprocity: averaged across the fibre's width (as a pixel sees it), swapping the
  directions changes nothing on the specular cone θi = −θo, where the lobes live.
* Sampling: the estimator's mean is each lobe's albedo, and the density it reports is the
  one evaluation gives (the MIS weights rely on it).
* The lobes are events: R, TT (a transmission) and TRT layers with the rest add up to the
  beauty, and a fibre backlit by a light shows TT.
"""

from __future__ import annotations

import numpy as np
import pytest

from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest
from pxr_layers.stage import load_stage
from pxr_layers.paths.events import LOBE_HAIR_R
from pxr_layers.trace import hair

from camera_scenes import centimetre_stage

SINES, SINE_WEIGHTS = np.polynomial.legendre.leggauss(160)  # sin θi: dω = d(sin θ) dφ
OFFSETS, OFFSET_WEIGHTS = np.polynomial.legendre.leggauss(24)  # h across the fibre
AZIMUTHS = 192


def direction(theta: float, phi: np.ndarray) -> np.ndarray:
    """Unit vectors (n, 3) in the hair frame at longitudinal angle θ and azimuths φ."""
    phi = np.atleast_1d(phi)
    return np.stack([np.full(len(phi), np.sin(theta)), np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi)], -1)


def at_offset(theta: float, h: float, turn: float = 0.0) -> np.ndarray:
    """wo at θ whose offset across the fibre is h (hair.py: h = −y/|(y, z)|), its azimuth turned by `turn`."""
    return direction(theta, np.arccos(-h) + turn)[0]


def albedo(inputs: np.ndarray, theta_o: float) -> np.ndarray:
    """∫ S dωi (3 lobes, rgb), averaged over h ∈ [−1, 1]: the fraction of the light a fibre
    intercepts from wo that it scatters, per lobe."""
    phi = (np.arange(AZIMUTHS) + 0.5) * 2 * np.pi / AZIMUTHS
    sines = np.repeat(SINES, AZIMUTHS)
    cosines = np.sqrt(1 - sines ** 2)
    azimuths = np.tile(phi, len(SINES))
    wi = np.stack([sines, cosines * np.cos(azimuths), cosines * np.sin(azimuths)], -1)
    weights = np.repeat(SINE_WEIGHTS, AZIMUTHS) * 2 * np.pi / AZIMUTHS
    total = np.zeros((3, 3))
    for h, weight in zip(OFFSETS, OFFSET_WEIGHTS):
        f, _ = hair.scattering(inputs, np.broadcast_to(at_offset(theta_o, h), wi.shape), wi)
        total += 0.5 * weight * np.einsum("nlc,n->lc", f, weights)
    return total


LOOKS = {
    "default": {},
    "smooth, tilted": {"roughness_r": (0.004, 0.05), "roughness_tt": (0.001, 0.05), "roughness_trt": (0.016, 0.05),
                       "cuticle_angle": 0.55},
    "rough": {"roughness_r": (0.6, 0.9), "roughness_tt": (0.15, 0.9), "roughness_trt": (1.0, 0.9),
              "cuticle_angle": 0.4, "ior": 1.3},
}


@pytest.mark.parametrize("look", LOOKS)
@pytest.mark.parametrize("theta_o", [0.0, 0.6, 1.2, 1.45])
def test_white_hair_scatters_all_it_intercepts(look, theta_o):
    scattered = albedo(hair.inputs_row(**LOOKS[look]), theta_o).sum(axis=0)
    np.testing.assert_allclose(scattered, 1.0, atol=2e-4)


def test_absorbing_hair_keeps_less_and_its_colour():
    """Melanin-like absorption (red least): less is scattered, red most, and the lobes that
    cross the fibre (TT, TRT) lose more than R, which never enters it."""
    white = albedo(hair.inputs_row(), 0.3)
    brown = albedo(hair.inputs_row(absorption=(0.4, 0.9, 2.0)), 0.3)
    total = brown.sum(axis=0)
    assert np.all(total < 1.0) and total[0] > total[1] > total[2]
    np.testing.assert_allclose(brown[0], white[0], rtol=1e-6)  # R: Fresnel only
    assert np.all(brown[1:] < 0.8 * white[1:])


@pytest.mark.parametrize("theta", [0.15, 0.5, 0.9])
def test_reciprocal_across_the_fibre_on_the_specular_cone(theta):
    """S averaged over the fibre's width is the same with wo and wi swapped, for wi on the
    cone θi = −θo and any azimuth between them (no cuticle tilt)."""
    inputs = hair.inputs_row(absorption=(0.3, 0.6, 1.2), tint_tt=(0.8, 0.9, 1.0))
    for dphi in (0.4, 1.3, 2.6, np.pi - 0.1):
        forward = backward = 0.0
        for h, weight in zip(OFFSETS, OFFSET_WEIGHTS):
            wo = at_offset(theta, h)
            wi = direction(-theta, np.arctan2(wo[2], wo[1]) + dphi)[0]
            forward = forward + weight * hair.scattering(inputs, wo[None], wi[None])[0][0].sum(axis=0)
            wi = at_offset(-theta, h)
            wo = direction(theta, np.arctan2(wi[2], wi[1]) + dphi)[0]
            backward = backward + weight * hair.scattering(inputs, wi[None], wo[None])[0][0].sum(axis=0)
        np.testing.assert_allclose(forward, backward, rtol=1e-6)


def test_sampling_estimates_each_lobe_and_reports_its_density():
    inputs = hair.inputs_row(absorption=(0.2, 0.5, 1.0), tint_r=(1.0, 0.8, 0.6), cuticle_angle=0.55)
    rng = np.random.default_rng(7)
    count, theta = 300_000, 0.4
    h = rng.uniform(-1, 1, count)
    wo = np.stack([np.full(count, np.sin(theta)), np.cos(theta) * -h, np.cos(theta) * np.sqrt(1 - h * h)], -1)
    wi, weight, density, lobe, valid = hair.sampled(inputs, wo, rng.random((count, 3)))
    assert valid.all()
    expected = albedo(inputs, theta)
    for k in range(3):
        chosen = lobe == LOBE_HAIR_R + k
        np.testing.assert_allclose(weight[chosen].sum(axis=0) / count, expected[k], rtol=0.02, atol=2e-4)
    _, pdf = hair.scattering(inputs, wo[:5000], wi[:5000])
    np.testing.assert_allclose(pdf[np.arange(5000), lobe[:5000] - LOBE_HAIR_R], density[:5000],
                               rtol=1e-9)


HAIR_LOOK = """
    def Material "hair"
    {{
        token outputs:mtlx:surface.connect = </World/hair/Surface.outputs:out>
        def Shader "Surface"
        {{
            uniform token info:id = "ND_surface"
            token inputs:bsdf.connect = </World/hair/Fibre.outputs:out>
            token outputs:out
        }}
        def Shader "Fibre"
        {{
            uniform token info:id = "ND_chiang_hair_bsdf"
            float2 inputs:roughness_R.connect = </World/hair/Roughness.outputs:roughness_R>
            float2 inputs:roughness_TT.connect = </World/hair/Roughness.outputs:roughness_TT>
            float2 inputs:roughness_TRT.connect = </World/hair/Roughness.outputs:roughness_TRT>
            {absorption}
            token outputs:out
        }}
        def Shader "Roughness"
        {{
            uniform token info:id = "ND_chiang_hair_roughness"
            float inputs:longitudinal = 0.2
            float inputs:azimuthal = 0.3
            float2 outputs:roughness_R
            float2 outputs:roughness_TT
            float2 outputs:roughness_TRT
        }}
        def Shader "Colour"
        {{
            uniform token info:id = "ND_chiang_hair_absorption_from_color"
            color3f inputs:color = (0.5, 0.3, 0.1)
            float inputs:azimuthal_roughness = 0.3
            vector3f outputs:absorption
        }}
    }}"""


def hair_stage(tmp_path, absorption: bool = False, light: str = "sky") -> str:
    """Three horizontal fibres (3 cm wide) 100 cm down −Z of a 50 mm camera, bound to a
    MaterialX chiang_hair_bsdf, under a white sky or lit from behind by a small sphere light."""
    connection = ("vector3f inputs:absorption_coefficient.connect = </World/hair/Colour.outputs:absorption>"
                  if absorption else "")
    lighting = ('def DomeLight "sky"\n    {\n        float inputs:intensity = 1\n    }' if light == "sky" else
                'def SphereLight "back"\n    {\n        float inputs:radius = 5\n        float inputs:intensity = 200\n'
                '        double3 xformOp:translate = (0, 0, -160)\n'
                '        uniform token[] xformOpOrder = ["xformOp:translate"]\n    }')
    return centimetre_stage(tmp_path / "hair.usda", f"""{HAIR_LOOK.format(absorption=connection)}
    {lighting}
    def BasisCurves "fibres" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        uniform token type = "linear"
        int[] curveVertexCounts = [2, 2, 2]
        point3f[] points = [(-20, -8, -100), (20, -8, -100), (-20, 0, -100), (20, 0, -100), (-20, 8, -100), (20, 8, -100)]
        float[] widths = [3] (interpolation = "constant")
        rel material:binding = </World/hair>
    }}""")


def test_the_materialx_hair_network_is_read(tmp_path):
    """chiang_hair_roughness (longitudinal 0.2, azimuthal 0.3) and
    chiang_hair_absorption_from_color feed the BSDF, as MaterialX defines them."""
    scene, _ = load_stage(hair_stage(tmp_path, absorption=True))
    (material,) = [m for m in scene.materials if m.hair]
    v = (0.726 * 0.2 + 0.812 * 0.04 + 3.7 * 0.2 ** 20) ** 2
    s = 0.265 * 0.3 + 1.194 * 0.09 + 5.372 * 0.3 ** 22
    assert material.hair_roughness_r == pytest.approx((v, s))
    assert material.hair_roughness_tt == pytest.approx((v * 0.25, s))
    assert material.hair_roughness_trt == pytest.approx((v * 4, s))
    fit = 5.969 - 0.215 * 0.3 + 2.532 * 0.09 - 10.73 * 0.027 + 5.574 * 0.0081 + 0.245 * 0.00243
    assert material.hair_absorption == pytest.approx(tuple((np.log(c) / fit) ** 2 for c in (0.5, 0.3, 0.1)))
    assert material.ior == pytest.approx(1.55) and material.hair_cuticle_angle == 0.5


def render(path, spp: int, max_depth: int):
    request = RenderRequest(stage=path, resolution=(48, 48), spp=spp, max_depth=max_depth, previews=False,
                            default_lights=False)
    return render_frame(request, output=path.parent)


def test_white_hair_vanishes_under_a_white_sky(tmp_path):
    """Every path ends in the sky of radiance 1; white hair neither absorbs nor creates."""
    result = render(hair_stage(tmp_path), spp=32, max_depth=24)
    rgb = result.rgba[..., :3].astype(np.float64)
    covered = result.rgba[..., 3] > 0.5
    assert covered.sum() > 40
    np.testing.assert_allclose(rgb[covered].mean(axis=0), 1.0, atol=0.01)
    assert np.abs(rgb - 1.0).max() < 0.25  # per pixel: noise only


def test_hair_lobes_are_layers_that_add_up(tmp_path):
    """R, TT (a transmission event) and TRT of the fibres, the sky seen directly and
    everything else partition the beauty; backlit, TT carries most of the fibres' light."""
    result = render(hair_stage(tmp_path, absorption=True, light="back"), spp=16, max_depth=4)
    index = PathIndex(result.index_path)
    passes = {"R": "C<R.'R'>.*", "TT": "C<T.'TT'>.*", "TRT": "C<R.'TRT'>.*", "seen": "C[LOB]"}
    layers = extract(index, {**passes, "all": "C.*", "TT as R": "C<R.'TT'>.*"}).layers
    total = sum(layers[name].astype(np.float64) for name in passes)
    np.testing.assert_allclose(total, layers["all"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(layers["all"], result.rgba[..., :3], rtol=1e-5, atol=1e-6)
    assert layers["TT as R"].sum() == 0
    energy = {name: float(layers[name].sum()) for name in ("R", "TT", "TRT")}
    assert min(energy.values()) > 0 and energy["TT"] > energy["R"] + energy["TRT"]


def test_a_bent_cubic_strand_shades_as_its_fine_polyline(tmp_path):
    """A hair's highlights follow its tangent: a ring drawn as a periodic B-spline of 8
    control points (each segment bending 45°) shades as the 128-segment periodic polyline
    through the same curve (each hit shaded with the curve's own tangent and radius, not its
    segment's chord). Periodic: no end caps to tell them apart."""
    angle = np.arange(8) * np.pi / 4
    control = 20.0 * np.stack([np.cos(angle), np.sin(angle)], 1)
    u = np.arange(16)[:, None] / 16
    weights = np.stack([(1 - u) ** 3, 3 * u ** 3 - 6 * u ** 2 + 4, -3 * u ** 3 + 3 * u ** 2 + 3 * u + 1, u ** 3]) / 6
    fine = np.concatenate([sum(weights[k] * control[(j + k) % 8] for k in range(4)) for j in range(8)])
    images = []
    for name, kind, points in (("bspline", "cubic", control), ("polyline", "linear", fine)):
        listed = ", ".join(f"({x:.4f}, {y:.4f}, -100)" for x, y in points)
        path = tmp_path / f"{name}.usda"
        path.write_text(hair_stage(tmp_path, absorption=True, light="back").read_text()
                        .replace('uniform token type = "linear"', f'uniform token type = "{kind}"\n'
                                 '        uniform token basis = "bspline"\n        uniform token wrap = "periodic"')
                        .replace("int[] curveVertexCounts = [2, 2, 2]", f"int[] curveVertexCounts = [{len(points)}]")
                        .replace(FIBRE_POINTS, f"point3f[] points = [{listed}]")
                        .replace("double3 xformOp:translate = (0, 0, -160)", "double3 xformOp:translate = (40, 60, 40)"))
        images.append(render(path, spp=64, max_depth=3).rgba.astype(np.float64))
    assert images[0][..., 3].sum() == pytest.approx(images[1][..., 3].sum(), rel=0.02)
    # 4 × 4-pixel blocks: 0.4 % apart at 256 spp (the segments' chords instead: 18 %)
    cubic, fine = (image[..., :3].reshape(12, 4, 12, 4, 3).sum(axis=(1, 3)) for image in images)
    assert np.abs(cubic - fine).sum() / fine.sum() < 0.05


FIBRE_POINTS = ("point3f[] points = [(-20, -8, -100), (20, -8, -100), (-20, 0, -100), (20, 0, -100), (-20, 8, -100), "
                "(20, 8, -100)]")
"""hair_stage's fibres' points."""
