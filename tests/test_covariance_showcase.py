"""Per-bounce covariance norms C, T, R traced on render/showcase.usda.

The showcase is built so that the answers are known (render/README.md): only the sphere
(r = 0.4 m) is curved, only the panel is textured (stripes of exactly 5 and 10 cycles/m),
only glossyBox (roughness 0.2) and mirrorPanel (roughness 0.02) have sharp lobes. Every
test reads the first event of the records in the render's path index (render_frame's), so
it checks exactly what the index stores.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tracing import trace_image

from pxr_layers.covariance.texture_spectrum import TextureSpectrum
from pxr_layers.jobs.frame import render_frame
from pxr_layers.paths.events import EventVocabulary
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest
from pxr_layers.trace import bsdf
from pxr_layers.trace.bounce_norms import (
    SINGULAR_REFLECTANCE,
    lobe_reflectance,
    texture_spectrum,
)
from pxr_layers.trace.integrator import TraceSettings

RESOLUTION = (96, 96)
SETTINGS = TraceSettings(spp=4, max_depth=4, seed=3, norm_bounces=5, record_paths=True, first_bounce_norms=True)
SPHERE_CURVATURE = 1 / 0.4  # 1/m
STRIPE_AMPLITUDE = 0.3 / 0.5  # relative amplitude a of 0.5 + 0.3 sin(...)


@dataclasses.dataclass
class FirstEvents:
    """The first event of every recorded contribution."""

    pixel: np.ndarray  # (r,)
    obj: np.ndarray  # (r,) object name
    lobe: np.ndarray  # (r,) lobe name, '' for light events
    norms: np.ndarray  # (r, 3) C, T, R of event 1


def first_events(batches, vocabulary: EventVocabulary) -> FirstEvents:
    """The records of the tracer's batches."""
    pixel, obj, lobe, norms = [], [], [], []
    for batch in batches:
        records = batch.records
        first = [vocabulary.event(sequence[0]) for sequence in records.sequences]
        names = [first[index] for index in records.path_class.tolist()]
        pixel.append(records.pixel)
        obj.append([_object_of(event, vocabulary) for event in names])
        lobe.append([_lobe_of(event) for event in names])
        norms.append(records.norms[:, 0, :])
    return FirstEvents(np.concatenate(pixel), np.concatenate(obj), np.concatenate(lobe), np.concatenate(norms))


def indexed_first_events(index: PathIndex, vocabulary: EventVocabulary) -> FirstEvents:
    """The records of a path index (its classes' events start with the camera's)."""
    first = [path_class.events[1] for path_class in index.classes]
    objects = np.array([_object_of(event, vocabulary) for event in first])
    lobes = np.array([_lobe_of(event) for event in first])
    chunks = list(index.records())
    class_id = np.concatenate([chunk.class_id for chunk in chunks])
    return FirstEvents(np.concatenate([chunk.pixel for chunk in chunks]), objects[class_id], lobes[class_id],
                       np.concatenate([chunk.norms[:, 0, :] for chunk in chunks]))


def _object_of(event, vocabulary: EventVocabulary) -> str:
    names = event.labels & set(vocabulary.object_names + vocabulary.light_names)
    return next(iter(names), "")


def _lobe_of(event) -> str:
    return next(iter(event.labels & {"diffuse", "specular", "coat", "glass"}), "")


def render_showcase(stage, folder):
    """render_frame with SETTINGS: its result and the first events of its index."""
    request = RenderRequest(stage=stage, resolution=RESOLUTION, spp=SETTINGS.spp, max_depth=SETTINGS.max_depth,
                            seed=SETTINGS.seed, norm_bounces=SETTINGS.norm_bounces, index_mode="records",
                            index_covariance="norms", previews=False,
                            debug_covariance=True)  # the first-bounce norm pictures
    result = render_frame(request, output=folder, threads=2)
    assert result.plan.trace == SETTINGS
    return result, indexed_first_events(PathIndex(result.index_path), result.vocabulary)


@pytest.fixture(scope="module")
def showcase(shipped_scene, tmp_path_factory):
    return render_showcase(shipped_scene("showcase.usda"), tmp_path_factory.mktemp("showcase"))


def test_planar_surfaces_have_zero_curvature_and_the_sphere_one_over_r(showcase):
    _, first = showcase
    surface = first.lobe != ""
    on_sphere = surface & (first.obj == "curvedSphere")
    assert on_sphere.sum() > 100
    np.testing.assert_allclose(first.norms[on_sphere, 0], SPHERE_CURVATURE, rtol=0.05)
    elsewhere = surface & (first.obj != "curvedSphere")
    assert elsewhere.sum() > 1000
    assert np.all(first.norms[elsewhere, 0] == 0.0)


def test_twice_the_stripe_frequency_gives_twice_the_texture_norm(showcase):
    _, first = showcase
    on_panel = (first.lobe != "") & (first.obj == "texturedPanel")
    columns = first.pixel[on_panel] % RESOLUTION[0]
    left_edge, right_edge = columns.min(), columns.max()
    quarter = (right_edge - left_edge) / 4
    texture = first.norms[on_panel, 1]
    # the middle of each half, away from the seam and the panel's edges
    low = texture[np.abs(columns - (left_edge + quarter)) <= quarter / 3]
    high = texture[np.abs(columns - (right_edge - quarter)) <= quarter / 3]
    assert len(low) > 20 and len(high) > 20
    ratio = np.median(high) / np.median(low)
    assert ratio == pytest.approx(2.0, rel=0.15)
    # and the absolute value: a cosine 1 + a·cos(2πfx) has T = f·√(a/(1+a)) in cycles/m
    expected = 5.0 * np.sqrt(STRIPE_AMPLITUDE / (1 + STRIPE_AMPLITUDE))
    assert np.median(low) == pytest.approx(expected, rel=0.15)
    untextured = (first.lobe != "") & (first.obj != "texturedPanel")
    assert np.all(first.norms[untextured, 1] == 0.0)


def test_reflectance_norm_is_zero_on_diffuse_and_grows_as_roughness_falls(showcase):
    _, first = showcase
    reflectance = first.norms[:, 2]
    assert np.all(reflectance[first.lobe == "diffuse"] == 0.0)
    assert np.all(reflectance[(first.lobe != "") & (first.obj == "matteBox")] == 0.0)
    glossy = reflectance[(first.lobe == "specular") & (first.obj == "glossyBox")]
    mirror = reflectance[(first.lobe == "specular") & (first.obj == "mirrorPanel")]
    assert len(glossy) > 10 and len(mirror) > 10
    # GGX α = roughness²: R = 1/(2πα), to the precision the index stores (float16)
    np.testing.assert_allclose(glossy, 1 / (2 * np.pi * 0.2**2), rtol=2**-11)
    np.testing.assert_allclose(mirror, 1 / (2 * np.pi * 0.02**2), rtol=2**-11)
    assert mirror.min() > glossy.max() > 0


def test_reflectance_norm_is_strictly_monotonic_in_roughness():
    roughness = np.linspace(1.0, 0.0, 41)
    alpha = (roughness**2).astype(np.float32)
    lobes = bsdf.lobe_rows(len(alpha))
    lobes[:, bsdf.ALPHA] = lobes[:, bsdf.COAT_ALPHA] = alpha
    reflectance = lobe_reflectance(lobes, np.full(len(alpha), bsdf.SPECULAR))
    assert np.all(np.diff(reflectance[alpha >= bsdf.SINGULAR_ALPHA]) > 0)
    assert np.all(reflectance <= SINGULAR_REFLECTANCE)
    assert reflectance[-1] == pytest.approx(SINGULAR_REFLECTANCE)
    assert np.all(lobe_reflectance(lobes, np.full(len(alpha), bsdf.DIFFUSE)) == 0)


def test_debug_images_show_the_same_norms(showcase):
    result, _ = showcase
    norms = result.first_bounce_norms
    assert norms.shape == (*RESOLUTION[::-1], 3)
    assert np.nanmax(norms[..., 0]) == pytest.approx(SPHERE_CURVATURE, rel=1e-4)
    assert np.nanmin(norms[..., 0]) == 0.0


def test_norms_are_deterministic_across_threads_and_batches(shipped_scene, showcase):
    """The tracer's stages on one thread in batches of 4096 paths give the norms of the
    render (in one batch of DEFAULT_BATCH_PATHS), image and records."""
    from pxr_layers.stage import load_stage

    again = trace_image(*load_stage(shipped_scene("showcase.usda")), SETTINGS, resolution=RESOLUTION, threads=1,
                        batch_paths=4096)
    assert len(again.batches) > 1
    first_run, first = showcase
    np.testing.assert_array_equal(again.first_bounce_norms, first_run.first_bounce_norms)
    second = first_events(again.batches, again.vocabulary)
    # the index keeps a pixel's records class by class: compare them in one order
    order_a = np.lexsort((first.obj, first.norms[:, 2], first.norms[:, 1], first.norms[:, 0], first.pixel))
    order_b = np.lexsort((second.obj, second.norms[:, 2], second.norms[:, 1], second.norms[:, 0], second.pixel))
    np.testing.assert_array_equal(first.norms[order_a], second.norms[order_b])
    np.testing.assert_array_equal(first.obj[order_a], second.obj[order_b])


def test_texture_spectrum_of_a_cosine_matches_the_amplitude_moment():
    """1 + a·cos(2π f x) along s only: T_ss = a f²/(1 + a), nothing along t."""
    width, height, cycles, a = 512, 256, 16, 0.5
    s = (np.arange(width) + 0.5) / width
    row = 1 + a * np.cos(2 * np.pi * cycles * s)
    image = np.broadcast_to(row[None, :, None], (height, width, 3)).astype(np.float32)
    spectrum = TextureSpectrum.of_image(image)
    block = spectrum.lookup(np.array([[0.5], [0.5]]), np.array([1.0]))[0]
    assert block[0, 0] == pytest.approx(a * cycles**2 / (1 + a), rel=0.03)
    assert abs(block[1, 1]) < 1e-6 * block[0, 0]
    assert abs(block[0, 1]) < 1e-6 * block[0, 0]
    flat = TextureSpectrum.of_image(np.full((64, 64, 3), 0.3, np.float32))
    assert np.abs(flat.lookup(np.array([[0.2], [0.7]]), np.array([3.0]))).max() < 1e-9  # cycles²/uv²


def test_texture_spectra_are_remembered_by_content_across_frames():
    """A shot's frames reload the same texture: its spectrum is measured once per process."""
    rng = np.random.default_rng(7)
    image = rng.random((64, 128, 3), dtype=np.float32)
    first = texture_spectrum(image)
    assert texture_spectrum(image.copy()) is first  # same pixels, another array (the next frame's load)
    np.testing.assert_array_equal(first.blocks, TextureSpectrum.of_image(image).blocks)
    changed = image.copy()
    changed[3, 5, 0] += 0.5
    assert texture_spectrum(changed) is not first
    assert texture_spectrum(image.reshape(128, 64, 3)) is not first  # same bytes, another shape
    shared = image.copy()
    shared.flags.writeable = False  # as the stage reader's textures: hashed once, then known by identity
    assert texture_spectrum(shared) is first and texture_spectrum(shared) is first


def test_the_texture_norm_follows_the_uv_transform_of_the_texture(showcase, shipped_scene, tmp_path):
    """T reads the texture that drives diffuseColor through its UsdTransform2d: scaling the
    panel's st by 2 packs the 5 cycles/m stripes of its left quarter into 10 cycles/m."""
    scaled = tmp_path / "scaled.usda"
    scaled.write_text(f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
    subLayers = [@{shipped_scene("showcase.usda")}@]
)
over "World"
{{
over "Materials"
{{
over "checkerTexture"
{{
    def Shader "twice"
    {{
        uniform token info:id = "UsdTransform2d"
        float2 inputs:in.connect = </World/Materials/checkerTexture/stReader.outputs:result>
        float2 inputs:scale = (2, 2)
        float2 outputs:result
    }}
    over "diffuseTexture"
    {{
        float2 inputs:st.connect = </World/Materials/checkerTexture/twice.outputs:result>
    }}
}}
}}
}}
""")
    medians = []
    for events in (showcase[1], render_showcase(scaled, tmp_path / "scaled")[1]):
        on_panel = (events.lobe != "") & (events.obj == "texturedPanel")
        columns = events.pixel[on_panel] % RESOLUTION[0]
        left_edge, right_edge = columns.min(), columns.max()
        left_quarter = np.abs(columns - (left_edge + (right_edge - left_edge) / 8)) <= (right_edge - left_edge) / 24
        assert left_quarter.sum() > 20
        medians.append(np.median(events.norms[on_panel, 1][left_quarter]))
    assert medians[1] / medians[0] == pytest.approx(2.0, rel=0.15)
