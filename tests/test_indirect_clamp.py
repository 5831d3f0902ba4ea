"""The indirect sample clamp (``--clamp-indirect``): a firefly clamp on indirect light only.

The scene makes fireflies on purpose: a tiny, very bright sphere light above a glossy metal
floor, whose reflection lands on a diffuse wall (a caustic: camera → wall → floor → light,
found only by the rare wall samples that head for the highlight). The wall's and the floor's
direct light (light reaching the first visible hit) must come through untouched; every
contribution that reaches the path later must have its largest channel at most the clamp.
Clamped and unclamped renders trace the same paths (the clamp touches contributions, never
throughput or random numbers), so what the clamp leaves alone is compared bit for bit.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import OpenEXR
import pytest

from pxr_layers import lpe
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.paths.events import SCATTERING_TYPES, SCATTERINGS, SCATTER_STRAIGHT, path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

CLAMP = 2.0
RESOLUTION = (48, 32)
FLOAT32_ROUNDING = 1e-6  # relative: the scaled channels are rounded to float32 once

STAGE = """#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = 1
    defaultPrim = "World"
)
def Xform "World"
{
    def Scope "Looks"
    {
        def Material "mirror"
        {
            token outputs:surface.connect = </World/Looks/mirror/Surface.outputs:surface>
            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.9, 0.9, 0.9)
                float inputs:metallic = 1
                float inputs:roughness = 0.08
                token outputs:surface
            }
        }
        def Material "matte"
        {
            token outputs:surface.connect = </World/Looks/matte/Surface.outputs:surface>
            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.8, 0.6, 0.4)
                int inputs:useSpecularWorkflow = 1
                color3f inputs:specularColor = (0, 0, 0)
                token outputs:surface
            }
        }
    }
    def Mesh "floor" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-3, 0, 3), (3, 0, 3), (3, 0, -2), (-3, 0, -2)]
        rel material:binding = </World/Looks/mirror>
    }
    def Mesh "wall" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-3, 0, -2), (3, 0, -2), (3, 4, -2), (-3, 4, -2)]
        rel material:binding = </World/Looks/matte>
    }
    def SphereLight "spark"
    {
        float inputs:radius = 0.02
        float inputs:intensity = 30000
        double3 xformOp:translate = (0, 0.4, 0.6)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Camera "Camera"
    {
        float focalLength = 24
        float horizontalAperture = 36
        float verticalAperture = 24
        float2 clippingRange = (0.01, 1000)
        double3 xformOp:translate = (0, 1.6, 4.5)
        float3 xformOp:rotateXYZ = (-12, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
}
"""


def render(folder, clamp: float | None, index_mode: str = "records"):
    """render_frame's result of the spark scene (seed 3, 8 spp, depth 4) into `folder`,
    clamped at `clamp` (None: the flag not given), with its index."""
    stage = folder / "spark.usda"
    stage.write_text(STAGE)
    options = {} if clamp is None else {"clamp_indirect": clamp}
    request = RenderRequest(stage=stage, resolution=RESOLUTION, spp=8, max_depth=4, seed=3, norm_bounces=0,
                            index_mode=index_mode, index_covariance="norms", previews=False, **options)
    return render_frame(request, output=folder, threads=2)


def bounces(events) -> int:
    """The scattering events of a path (pass-through at cut-outs is not one)."""
    return sum(event.type in SCATTERING_TYPES and event.scatter != SCATTERINGS[SCATTER_STRAIGHT] for event in events)


def records_by_class(index: PathIndex) -> dict[str, tuple[int, np.ndarray, np.ndarray]]:
    """Per path class (its text): its bounces, and its records' pixels (r,) and rgb (r, 3),
    in the tracer's order."""
    pixels, colours = defaultdict(list), defaultdict(list)
    for chunk in index.records(norms=False):
        for class_id in np.unique(chunk.class_id):
            mine = chunk.class_id == class_id
            pixels[class_id].append(chunk.pixel[mine])
            colours[class_id].append(chunk.rgb[mine])
    return {path_text(index.classes[c].events): (bounces(index.classes[c].events), np.concatenate(pixels[c]),
                                                 np.concatenate(colours[c])) for c in pixels}


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    return {clamp: render(tmp_path_factory.mktemp(f"clamp{clamp}"), clamp) for clamp in (None, CLAMP)}


def test_indirect_contributions_are_clamped_and_direct_ones_untouched(renders):
    plain, clamped = (PathIndex(renders[clamp].index_path) for clamp in (None, CLAMP))
    before, after = records_by_class(plain), records_by_class(clamped)
    assert before.keys() == after.keys()  # the same paths: the clamp never zeroes a contribution

    indirect = [name for name, (depth, _, _) in after.items() if depth >= 2]
    largest = np.concatenate([after[name][2].max(axis=1) for name in indirect])
    assert largest.max() <= CLAMP * (1 + FLOAT32_ROUNDING)
    unclamped = np.concatenate([before[name][2].max(axis=1) for name in indirect])
    # the scene makes fireflies for the clamp to cut (deterministic: a fixed seed)
    assert (unclamped > CLAMP).sum() >= 5 and unclamped.max() > 100 * CLAMP
    for name in indirect:  # the hue is kept: each clamped record is the unclamped one scaled
        rgb_before, rgb_after = before[name][2].astype(np.float64), after[name][2].astype(np.float64)
        scale = np.minimum(1.0, CLAMP / rgb_before.max(axis=1))
        np.testing.assert_allclose(rgb_after, rgb_before * scale[:, None], rtol=2 * FLOAT32_ROUNDING)

    direct = [name for name, (depth, _, _) in after.items() if depth < 2]
    assert any(before[name][2].max() > CLAMP for name in direct), "direct light above the clamp, left as it is"
    for name in direct:
        assert np.array_equal(before[name][1], after[name][1]) and np.array_equal(before[name][2], after[name][2])

    beauty_before, beauty_after = (renders[clamp].rgba[..., :3] for clamp in (None, CLAMP))
    assert np.all(beauty_after <= beauty_before)
    assert beauty_after.sum() < 0.99 * beauty_before.sum()
    # A pixel none of whose indirect contributions was above the clamp is the same bytes.
    width = RESOLUTION[0]
    cut = np.zeros(RESOLUTION[0] * RESOLUTION[1], bool)
    for name in indirect:
        pixel, rgb = before[name][1], before[name][2]
        cut[pixel[rgb.max(axis=1) > CLAMP]] = True
    untouched = ~cut.reshape(-1, width)
    assert untouched.sum() > 100
    assert np.array_equal(beauty_after[untouched], beauty_before[untouched])


def assert_sums_to_beauty(layers: dict[str, np.ndarray], beauty: np.ndarray) -> None:
    total = np.sum([image.astype(np.float64) for image in layers.values()], axis=0)
    scale = np.maximum(np.abs(beauty), 1e-3 * beauty.max())
    assert np.max(np.abs(total - beauty) / scale) <= 1e-5


@pytest.mark.parametrize("index_mode", ["records", "merged"])
def test_layers_cut_from_a_clamped_index_sum_to_the_clamped_beauty(renders, tmp_path, index_mode):
    result = renders[CLAMP] if index_mode == "records" else render(tmp_path, CLAMP, index_mode)
    beauty = result.rgba[..., :3].astype(np.float64)
    index = PathIndex(result.index_path)
    assert_sums_to_beauty(extract(index, lpe.STANDARD_PASSES).layers, beauty)
    split = extract(index, {"direct": "C[LO]|C.[LO]", "indirect": "C..+[LO]"}).layers
    assert split["indirect"].sum() > 0
    assert_sums_to_beauty(split, beauty)


def exr_metadata(result) -> dict:
    (path,) = result.plan.outputs.values()
    return {key.removeprefix("pxrLayers/"): value for key, value in OpenEXR.File(str(path)).parts[0].header.items()
            if key.startswith("pxrLayers/")}


def test_the_clamp_is_recorded_in_the_exr_and_the_index(renders, tmp_path):
    clamped = renders[CLAMP]
    assert exr_metadata(clamped)["clampIndirect"] == repr(CLAMP)
    manifest = PathIndex(clamped.index_path).manifest
    assert manifest["clamp_indirect"] == CLAMP and manifest["clampIndirect"] == repr(CLAMP)

    for result in (renders[None], render(tmp_path, 0.0)):  # no flag, or 0: off, and nothing said
        assert "clampIndirect" not in exr_metadata(result)
        manifest = PathIndex(result.index_path).manifest
        assert "clamp_indirect" not in manifest and "clampIndirect" not in manifest
