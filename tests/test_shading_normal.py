"""Shading normals that tilt past the view: a strong normal map seen at a grazing angle.

The mirror reflection of the view direction about such a normal falls below the real
(geometric) surface, where no path may continue; the surface stage bends the normal so
that it does not (pxr_layers/trace/stages/surface.py, module docstring). These tests hold
the outcome to physics: a lit surface is never exactly black, and the bend creates no
energy (a lossless surface in a uniform dome of radiance 1 returns at most 1).

Every scene is a 100 m plane, normal +y, under a uniform dome of radiance 1, seen by a
camera 1 m above it looking down at 8° (every pixel sees the plane, 4°–12° below the
horizon), with a tangent-space normal map of 1.25 m texels each tilted 60° across the view (toward
+x or −x at random): past 45° across a grazing view, the mirror reflection of the view
falls below the surface while the normal still faces the viewer, as on a bevel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.trace.stages.surface import SPECULAR_CLEARANCE, bent_normal

from test_looks import plane, textured_look, write_image
from test_render_physics import camera_prim, mean_rgb, stage_text, write

TILT = math.radians(60)
GRAZING_CAMERA = camera_prim(100, 20, translate=(0, 1, 20), rotate=(-8, 0, 0))
UNIFORM_DOME = """
    def DomeLight "sky"
    {
        float inputs:intensity = 1
    }
"""
NORMAL_MAP_INPUTS = ('                float4 inputs:scale = (2, 2, 2, 1)\n'
                     '                float4 inputs:bias = (-1, -1, -1, 0)\n'
                     '                token inputs:wrapS = "repeat"\n'
                     '                token inputs:wrapT = "repeat"\n'
                     '                token inputs:sourceColorSpace = "raw"\n')


def write_tilted_normal_map(path, rng) -> None:
    """An 8×8 tangent-space normal map, each texel tilted TILT from the surface normal toward
    +x or −x at random, encoded as (n + 1) / 2."""
    across = rng.choice([-1.0, 1.0], (8, 8))
    normals = np.stack([math.sin(TILT) * across, np.zeros((8, 8)), np.full((8, 8), math.cos(TILT))], axis=-1)
    write_image(path, 0.5 + 0.5 * normals)


def normal_mapped_plane_stage(tmp_path, rng, **surface_inputs) -> "Path":
    """The stage of the module docstring, its plane's UsdPreviewSurface given
    `surface_inputs` (name=(type, value)) and the normal map, repeated every 10 m."""
    write_tilted_normal_map(tmp_path / "tilted.exr", rng)
    scale = """
            def Shader "tiling"
            {
                uniform token info:id = "UsdTransform2d"
                float2 inputs:in.connect = </World/Looks/bumpy/uv.outputs:result>
                float2 inputs:scale = (10, 10)
                float2 outputs:result
            }
"""
    look = textured_look("bumpy", "./tilted.exr", "normal", NORMAL_MAP_INPUTS,
                         st_source="</World/Looks/bumpy/tiling.outputs:result>", **surface_inputs)
    look = look.replace('def Shader "uv"', scale + '            def Shader "uv"')
    return write(tmp_path, "bumpy.usda", stage_text(plane("bumpy") + UNIFORM_DOME, look, GRAZING_CAMERA))


WHITE_METAL = dict(diffuseColor=("color3f", "(1, 1, 1)"), metallic=("float", "1"))
WHITE_LAMBERT = dict(diffuseColor=("color3f", "(1, 1, 1)"), useSpecularWorkflow=("int", "1"),
                     specularColor=("color3f", "(0, 0, 0)"))


def render(path, spp=16):
    """rgba (32, 48, 4) of the stage's beauty."""
    return mean_rgb(path, spp=spp, max_depth=4, resolution=(48, 32))[1].rgba


def test_a_white_mirror_with_a_grazing_normal_map_reflects_the_whole_dome(tmp_path, rng):
    """A white metal mirror (F = 1) reflects the dome of radiance 1 exactly, whatever its
    normals: every reflection leaves above the plane and reaches the sky, so every pixel
    is 1 (no black pixel, no energy gained)."""
    rgba = render(normal_mapped_plane_stage(tmp_path, rng, roughness=("float", "0"), **WHITE_METAL))
    assert np.all(rgba[..., 3] == 1), "every pixel sees the plane"
    np.testing.assert_allclose(rgba[..., :3], 1.0, rtol=1e-5)


def test_a_glossy_metal_with_a_grazing_normal_map_has_no_black_pixel(tmp_path, rng):
    """Low roughness (0.1): the lobe's centre stays above the geometric surface, so no
    pixel that sees the lit plane is exactly black; the tail below it is lost, so the plane
    returns less than the dome's 1, and never more (16 spp: a pixel's standard error is
    below 0.05)."""
    rgba = render(normal_mapped_plane_stage(tmp_path, rng, roughness=("float", "0.1"), **WHITE_METAL))
    assert np.all(rgba[..., 3] == 1), "every pixel sees the plane"
    luminance = rgba[..., :3].mean(axis=-1)
    assert luminance.min() > 0.1, f"darkest pixel {luminance.min()}"
    assert luminance.mean() <= 1.0 + 0.01
    assert luminance.max() <= 1.0 + 0.2


@pytest.mark.parametrize("name, surface", [("lambert", WHITE_LAMBERT),
                                           ("metal", dict(roughness=("float", "0.3"), **WHITE_METAL))])
def test_the_bend_creates_no_energy_in_a_furnace(tmp_path, rng, name, surface):
    """A white lossless surface (Lambertian of albedo 1, or metal with F = 1) under a uniform
    dome of radiance 1 returns at most 1: the mean over the 1,536 pixels at 64 spp has a
    relative standard error well below 1 %, each 8×8-pixel block's below 2 %."""
    rgba = render(normal_mapped_plane_stage(tmp_path, rng, **surface), spp=64)
    luminance = rgba[..., :3].mean(axis=-1)
    assert luminance.min() > 0, f"{name}: a black pixel"
    assert luminance.mean() <= 1.0 + 0.01, f"{name}: mean {luminance.mean()}"
    blocks = luminance.reshape(4, 8, 6, 8).mean(axis=(1, 3))
    assert blocks.max() <= 1.0 + 0.04, f"{name}: brightest 8×8 block {blocks.max()}"


def test_the_bent_normal_reflects_the_view_above_the_surface_and_moves_only_where_needed(rng):
    """For random view directions above a surface and random shading normals (any side):
    the result is a unit normal facing the viewer and the surface, whose mirror reflection
    of the view is at least min(SPECULAR_CLEARANCE, 0.9·cos θo) above the surface; a
    normal whose reflection already clears that is returned unchanged."""
    bend = bent_normal.py_func
    geometric = np.array([0.0, 0.0, 1.0])
    for _ in range(20000):
        view = rng.normal(size=3)
        view[2] = abs(view[2])
        view /= np.linalg.norm(view)
        shading = rng.normal(size=3)
        shading /= np.linalg.norm(shading)
        clearance = min(SPECULAR_CLEARANCE, 0.9 * view[2])
        reflected = 2 * shading.dot(view) * shading - view
        bent = np.array(bend(*shading, *geometric, *view))
        assert abs(np.linalg.norm(bent) - 1) < 1e-9
        assert bent.dot(view) > 0 and bent[2] > 0
        assert (2 * bent.dot(view) * bent - view)[2] >= clearance - 1e-9
        if shading.dot(view) > 0 and shading[2] > 0 and reflected[2] >= clearance:
            np.testing.assert_array_equal(bent, shading)
