"""The whole Σ of every recorded contribution (TraceSettings.record_sigma, trace/sigma.py).

* Σ from the tracer equals covariance/path.py's chain run here on vertices built from the
  known geometry: the hit point of each record's camera ray (camera_rays reproduces it from
  the record's pixel and sample) on a flat floor under a point light (exact: the light end
  is known) and under a small rect light (its centre standing in for the sampled point);
  diffuse and GGX lobes.
* On render/striped.usda the direction-aware condition S11 ≫ S22 or S22 ≫ S11 holds on the
  stripes and not on the checker, whose norm T is the same.
* Without record_sigma nothing changes: sigma None, norms and rgb identical.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pxr_layers.covariance import ggx_bandwidth, pack_upper
from pxr_layers.covariance.path import SurfaceVertex, area_light_covariance, path_covariance
from pxr_layers.jobs.frame import render_frame
from pxr_layers.lpe.conditions import MUCH_GREATER_FACTOR
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest
from pxr_layers.stage import load_stage
from pxr_layers.trace.integrator import TraceSettings
from pxr_layers.trace.stages.camera import camera_rays

from test_render_physics import camera_prim, preview_surface, stage_text, write
from tracing import trace_image

LIGHT_HEIGHT = 1.0
ROUGHNESS = 0.5  # GGX α = roughness² = 0.25
RESOLUTION = 12
SPP = 2


def floor_stage(tmp_path, light: str, glossy: bool):
    """A 4 × 4 m floor at y = 0 seen obliquely (camera at (0, 1.5, 2) looking at the origin),
    Lambertian 0.5 or Lambertian + GGX."""
    look = preview_surface("floor", diffuseColor=("color3f", "(0.5, 0.5, 0.5)"), useSpecularWorkflow=("int", "1"),
                           specularColor=("color3f", "(0.5, 0.5, 0.5)" if glossy else "(0, 0, 0)"),
                           roughness=("float", str(ROUGHNESS if glossy else 1.0)))
    body = """
    def Mesh "floor" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]
        rel material:binding = </World/Looks/floor>
    }
""" + light
    camera = camera_prim(20, 10, translate=(0, 1.5, 2.0), rotate=(-36.8699, 0, 0))
    return load_stage(write(tmp_path, "floor.usda", stage_text(body, look, camera)))


POINT_LIGHT = f"""
    def SphereLight "bulb"
    {{
        float inputs:intensity = 10
        float inputs:radius = 0.05
        bool treatAsPoint = 1
        double3 xformOp:translate = (0.3, {LIGHT_HEIGHT}, -0.2)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
"""

RECT_SIZE = 0.01
RECT_LIGHT = f"""
    def RectLight "panel"
    {{
        float inputs:intensity = 5000
        float inputs:width = {RECT_SIZE}
        float inputs:height = {RECT_SIZE}
        double3 xformOp:translate = (0.3, {LIGHT_HEIGHT}, -0.2)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
"""
LIGHT_POSITION = np.array([0.3, LIGHT_HEIGHT, -0.2])


def traced(stage, **settings):
    """The tracer's stages: (Traced, its batches, its integrator) for the records of each batch."""
    scene, spec = stage
    settings = TraceSettings(spp=SPP, max_depth=1, norm_bounces=2, record_paths=True, **settings)
    result = trace_image(scene, spec, settings, resolution=(RESOLUTION, RESOLUTION), threads=1)
    return result, result.batches, result.integrator


def first_lobes(records, vocabulary) -> np.ndarray:
    """(r,) the lobe label of each record's first event ('' when not a surface event)."""
    names = []
    for sequence in records.sequences:
        labels = vocabulary.event(sequence[0]).labels if sequence else set()
        names.append(next(iter(labels & {"diffuse", "specular"}), ""))
    return np.array(names)[records.path_class] if names else np.zeros(0, str)


def expected_sigma(integrator, records, lobe, light_area, light_normal):
    """Σ leaving the floor (r, 10) for one-bounce records, built from the geometry here."""
    spp = integrator.settings.spp
    paths = records.pixel * spp + records.sample
    rays = camera_rays(integrator.camera, integrator.key, (integrator.width, integrator.height), spp, 0,
                       integrator.width * integrator.height * spp)
    origin = rays.origin[paths].astype(np.float64)
    direction = rays.direction[paths].astype(np.float64)
    point = origin - (origin[:, 1] / direction[:, 1])[:, None] * direction  # on y = 0
    to_light = LIGHT_POSITION - point
    distance = np.linalg.norm(to_light, axis=1)
    toward_light = (to_light / distance[:, None]).T
    toward_eye = -direction.T
    n = len(paths)
    normal = np.repeat(np.array([[0.0], [1.0], [0.0]]), n, axis=1)
    bandwidth = np.where(lobe == "specular", ggx_bandwidth(ROUGHNESS**2), 0.0)
    vertex = SurfaceVertex.flat(toward_light, toward_eye, np.linalg.norm(point - origin, axis=1), normal,
                                bandwidth=bandwidth)
    emitted, x_axis = area_light_covariance(light_area, -toward_light,
                                            None if light_normal is None else np.repeat(light_normal[:, None], n, 1))
    return pack_upper(path_covariance(emitted, x_axis, -toward_light, distance, [vertex]).leaving[0])


@pytest.mark.parametrize("glossy", [False, True], ids=["diffuse", "glossy"])
def test_sigma_under_a_point_light_is_the_chain_of_the_known_geometry(tmp_path, glossy):
    result, batches, integrator = traced(floor_stage(tmp_path, POINT_LIGHT, glossy), record_sigma=True)
    checked = set()
    for batch in batches:
        records = batch.records
        lobe = first_lobes(records, result.vocabulary)
        lit = lobe != ""
        assert lit.sum() > 0
        expected = expected_sigma(integrator, _subset(records, lit), lobe[lit], 0.0, None)
        actual = records.sigma[lit, 0].astype(np.float64)
        scale = np.abs(expected).max(axis=1, keepdims=True)
        assert np.all(np.abs(actual - expected) <= 2e-4 * scale), np.abs(actual - expected).max()
        assert np.all(records.sigma[lit, 1] == 0)  # the light event
        assert np.all(records.sigma[~lit] == 0)
        checked.update(lobe[lit].tolist())
    assert checked == ({"diffuse", "specular"} if glossy else {"diffuse"})


def test_sigma_under_a_small_rect_light_is_the_chain_of_its_centre(tmp_path):
    """The sampled point on a 1 cm light is within 7 mm of its centre, 1.2 m or more away:
    the chain of the centre is within 2 % of every record's Σ (both NEE and light hits)."""
    result, batches, integrator = traced(floor_stage(tmp_path, RECT_LIGHT, False), record_sigma=True)
    for batch in batches:
        records = batch.records
        lobe = first_lobes(records, result.vocabulary)
        lit = lobe != ""
        assert lit.sum() > 0
        expected = expected_sigma(integrator, _subset(records, lit), lobe[lit], RECT_SIZE**2, np.array([0, -1.0, 0]))
        actual = records.sigma[lit, 0].astype(np.float64)
        scale = np.abs(expected).max(axis=1, keepdims=True)
        assert np.all(np.abs(actual - expected) <= 0.02 * scale), (np.abs(actual - expected) / scale).max()


def _subset(records, keep):
    return dataclasses.replace(records, pixel=records.pixel[keep], sample=records.sample[keep])


def test_without_record_sigma_nothing_changes(tmp_path):
    stage = floor_stage(tmp_path, RECT_LIGHT, True)
    plain, plain_batches, _ = traced(stage)
    with_sigma, sigma_batches, _ = traced(stage, record_sigma=True)
    np.testing.assert_array_equal(plain.rgba, with_sigma.rgba)
    for off, on in zip(plain_batches, sigma_batches):
        assert off.records.sigma is None
        assert on.records.sigma.shape == on.records.norms.shape[:2] + (10,)
        assert on.records.sigma.dtype == np.float32
        np.testing.assert_array_equal(off.records.norms, on.records.norms)
        np.testing.assert_array_equal(off.records.rgb, on.records.rgb)
        np.testing.assert_array_equal(off.records.path_class, on.records.path_class)


STRIPED_RESOLUTION = (64, 64)


@pytest.fixture(scope="module")
def striped(shipped_scene, tmp_path_factory) -> PathIndex:
    """render_frame's index of render/striped.usda, with each record's Σ."""
    request = RenderRequest(stage=shipped_scene("striped.usda"), resolution=STRIPED_RESOLUTION, spp=4,
                            norm_bounces=2, index_mode="records", index_covariance="sigma", previews=False)
    return PathIndex(render_frame(request, output=tmp_path_factory.mktemp("striped"), threads=2).index_path)


def first_bounce_sigma(striped: PathIndex, obj: str) -> tuple[np.ndarray, np.ndarray]:
    """Σ (k, 10) and T (k,) of the first event of the records whose first event is a
    diffuse bounce on `obj`."""
    wanted = [path_class.id for path_class in striped.classes
              if len(path_class.events) > 1 and {obj, "diffuse"} <= path_class.events[1].labels]
    chunks = list(striped.records(wanted))
    sigma = np.concatenate([chunk.sigma[:, 0] for chunk in chunks])
    texture = np.concatenate([chunk.norms[:, 0, 1].astype(np.float64) for chunk in chunks])
    return sigma, texture


def much_greater_either_way(sigma: np.ndarray) -> np.ndarray:
    s11, s22 = sigma[:, 0], sigma[:, 4]  # xx, yy
    return (s11 > MUCH_GREATER_FACTOR * s22) | (s22 > MUCH_GREATER_FACTOR * s11)


def test_stripes_are_anisotropic_and_the_checker_is_not(striped):
    stripes, stripes_t = first_bounce_sigma(striped, "stripes")
    checker, checker_t = first_bounce_sigma(striped, "checker")
    assert len(stripes) > 500 and len(checker) > 500
    assert much_greater_either_way(stripes).mean() > 0.9  # measured 1.0 (S22/S11 ≥ 130 on 99 %)
    assert much_greater_either_way(checker).mean() < 0.1  # measured 0.0 (S22/S11 1.7-2.9)
    # on the stripes it is ŷ, the axis in the plane of view direction and normal
    assert np.mean(stripes[:, 4] > MUCH_GREATER_FACTOR * stripes[:, 0]) > 0.9
    # the norm T cannot tell them apart (both 5 cycles/m sinusoids: √(0.4/0.9)·5 ≈ 3.33 cycles/m)
    assert np.median(stripes_t) == pytest.approx(np.median(checker_t), rel=0.05)
