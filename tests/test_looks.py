"""Looks as studios author them, against known answers: normal maps, UsdTransform2d,
primvar readers, UDIM tiles, partial opacity, MaterialX standard_surface."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio

from pxr_layers.stage import load_stage
from pxr_layers.trace.shading import DIFFUSE, MaterialTable, inputs_at

from test_render_physics import GLASS_BALL_IN_UNIFORM_DOME, camera_prim, mean_rgb, preview_surface, stage_text, write


def write_image(path, pixels):
    """Write float pixels (h, w, c) with OpenImageIO (row 0 = top)."""
    pixels = np.asarray(pixels, np.float32)
    output = oiio.ImageOutput.create(str(path))
    output.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], oiio.FLOAT))
    output.write_image(pixels)
    output.close()


def write_udim_tiles(tmp_path):
    """maps/paint.1001.exr of 0.25 grey and maps/paint.1002.exr of 0.75."""
    (tmp_path / "maps").mkdir()
    for tile, value in ((1001, 0.25), (1002, 0.75)):
        write_image(tmp_path / "maps" / f"paint.{tile}.exr", np.full((2, 2, 3), value))


def plane(material: str, extra: str = "", name: str = "floor", height: float = 0.0) -> str:
    """A 100 m square in the y = height plane, normal +y, st (0, 0)–(1, 1) with ∂P/∂s = +x,
    ∂P/∂t = −z."""
    return f"""
    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-50, {height}, 50), (50, {height}, 50), (50, {height}, -50), (-50, {height}, -50)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
{extra}
        rel material:binding = </World/Looks/{material}>
    }}
"""


def sun(elevation: float, intensity: float = 3.0) -> str:
    """A delta distant light; the direction toward it is (0, sin e, −cos e)."""
    return f"""
    def DistantLight "sun"
    {{
        float inputs:angle = 0
        float inputs:intensity = {intensity}
        float3 xformOp:rotateXYZ = ({elevation - 180}, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
"""


LAMBERT = dict(useSpecularWorkflow=("int", "1"), specularColor=("color3f", "(0, 0, 0)"))


def textured_look(name: str, file: str, target: str, texture_inputs: str = "", output: str = "rgb",
                  st_source: str = "", **surface_inputs) -> str:
    """A UsdPreviewSurface whose `target` input reads a UsdUVTexture of `file`."""
    st = st_source or f"</World/Looks/{name}/uv.outputs:result>"
    return f"""
        def Material "{name}"
        {{
            token outputs:surface.connect = </World/Looks/{name}/Surface.outputs:surface>
            def Shader "Surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                {"normal3f" if target == "normal" else "color3f" if output == "rgb" else "float"} inputs:{target}.connect = </World/Looks/{name}/texture.outputs:{output}>
{"".join(f"                {kind} inputs:{key} = {value}{chr(10)}" for key, (kind, value) in surface_inputs.items())}                token outputs:surface
            }}
            def Shader "uv"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }}
            def Shader "texture"
            {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @{file}@
                float2 inputs:st.connect = {st}
{texture_inputs}
                float3 outputs:rgb
                float outputs:r
                float outputs:a
            }}
        }}
"""


def test_a_normal_map_of_known_slope_tilts_the_shading_as_analytic(tmp_path):
    """A tangent-space normal (0, sin a, cos a) on the plane turns the shading normal to
    (0, cos a, −sin a) in world space (the bitangent ∂P/∂t is −z): under a sun at
    elevation e, L = ρ/π·E·sin(e + a) instead of ρ/π·E·sin e."""
    tilt, elevation = math.radians(20), 60
    encoded = np.array([0.5, 0.5 + 0.5 * math.sin(tilt), 0.5 + 0.5 * math.cos(tilt)])
    write_image(tmp_path / "normal.exr", np.tile(encoded, (4, 4, 1)))
    look = textured_look("bumpy", "./normal.exr", "normal",
                         '                float4 inputs:scale = (2, 2, 2, 1)\n'
                         '                float4 inputs:bias = (-1, -1, -1, 0)\n'
                         '                token inputs:sourceColorSpace = "raw"\n',
                         diffuseColor=("color3f", "(0.6, 0.6, 0.6)"), **LAMBERT)
    path = write(tmp_path, "bumpy.usda", stage_text(plane("bumpy") + sun(elevation), look))
    rgb, _ = mean_rgb(path, spp=1, max_depth=1)
    np.testing.assert_allclose(rgb, 0.6 / math.pi * 3.0 * math.sin(math.radians(elevation) + tilt), rtol=1e-4)


def rotate_shader(material: str) -> str:
    """A UsdTransform2d "rotate" (90°) in Material `material`, reading its "uv" reader."""
    return f"""
            def Shader "rotate"
            {{
                uniform token info:id = "UsdTransform2d"
                float2 inputs:in.connect = </World/Looks/{material}/uv.outputs:result>
                float inputs:rotation = 90
                float2 outputs:result
            }}
"""


def test_a_90_degree_usd_transform2d_rotates_a_texture_exactly(tmp_path):
    """rotation = 90 maps st to (−t, s) (UsdPreviewSurface: scale, rotate, translate): with
    wrap repeat, the rotated lookups equal the unrotated texture at (1 − t, s)."""
    rng = np.random.default_rng(3)
    write_image(tmp_path / "grid.exr", rng.uniform(0, 1, (8, 8, 3)))
    rotate = rotate_shader("turned")
    looks = (textured_look("plain", "./grid.exr", "diffuseColor", '                token inputs:sourceColorSpace = "raw"\n')
             + textured_look("turned", "./grid.exr", "diffuseColor",
                             '                token inputs:sourceColorSpace = "raw"\n',
                             st_source="</World/Looks/turned/rotate.outputs:result>").replace(
                                 'def Shader "uv"', rotate + '            def Shader "uv"'))
    path = write(tmp_path, "turned.usda", stage_text(plane("plain") + plane("turned", name="other") + sun(60), looks))
    scene, _ = load_stage(path)
    table = MaterialTable(scene).arrays
    by_name = {material.name: index for index, material in enumerate(scene.materials)}
    st = rng.uniform(0, 1, (200, 2))
    turned = inputs_at(table, by_name["turned"], st)[:, DIFFUSE:DIFFUSE + 3]
    plain = inputs_at(table, by_name["plain"], np.stack([1 - st[:, 1], st[:, 0]], 1))[:, DIFFUSE:DIFFUSE + 3]
    np.testing.assert_allclose(turned, plain, atol=1e-5)
    assert not np.allclose(turned, inputs_at(table, by_name["plain"], st)[:, DIFFUSE:DIFFUSE + 3], atol=1e-2)


def test_udim_tiles_land_on_their_uv_squares(tmp_path):
    """tile = 1001 + ⌊s⌋ + 10·⌊t⌋; each tile is looked up at the fractional st."""
    write_udim_tiles(tmp_path)
    look = textured_look("tiled", "./maps/paint.<UDIM>.exr", "diffuseColor",
                         '                float4 inputs:fallback = (1, 0, 1, 1)\n')
    path = write(tmp_path, "udim.usda", stage_text(plane("tiled") + sun(60), look))
    scene, _ = load_stage(path)
    assert not scene.warnings
    values = inputs_at(MaterialTable(scene).arrays, 0, [[0.5, 0.5], [1.5, 0.5], [0.1, 1.5]])[:, DIFFUSE:DIFFUSE + 3]
    np.testing.assert_allclose(values, [[0.25] * 3, [0.75] * 3, [1, 0, 1]], atol=1e-6)


def test_partial_opacity_lets_half_of_a_uniform_dome_through(tmp_path):
    """A black, non-reflective plane of opacity 0.5 in front of the camera under a uniform
    dome of radiance 1: each pixel sees 0.5 of the dome, within 1 % in every pixel (the
    camera's presence choice is stratified over a pixel's samples, so no noise), and its
    alpha is 0.5."""
    looks = preview_surface("veil", diffuseColor=("color3f", "(0, 0, 0)"), opacity=("float", "0.5"), **LAMBERT)
    body = plane("veil") + '\n    def DomeLight "sky"\n    {\n        float inputs:intensity = 1\n    }\n'
    path = write(tmp_path, "veil.usda", stage_text(body, looks))
    _, result = mean_rgb(path, spp=16, max_depth=4, resolution=(32, 32))
    np.testing.assert_allclose(result.rgba[..., :3], 0.5, rtol=0.01)
    np.testing.assert_allclose(result.rgba[..., 3], 0.5)  # alpha: half of each pixel's samples stop on it


def test_a_half_present_surface_casts_exactly_half_a_shadow(tmp_path):
    """Shadow rays pass a partly present surface with transmittance 1 − opacity, no noise:
    the floor under a veil of opacity 0.25 gets 0.75 of the sun (spp 1, no randomness in
    direct light from a delta light)."""
    looks = (preview_surface("grey", diffuseColor=("color3f", "(0.5, 0.5, 0.5)"), **LAMBERT)
             + preview_surface("veil", opacity=("float", "0.25"), **LAMBERT))
    veil = plane("veil", name="veil", height=1.0).replace("(-50, 1.0, 50), (50, 1.0, 50), (50, 1.0, -50), (-50, 1.0, -50)",
                                                          "(-500, 1.0, 500), (500, 1.0, 500), (500, 1.0, -500), (-500, 1.0, -500)")
    camera = camera_prim(50, 10, translate=(0, 0.5, 0), rotate=(-90, 0, 0))
    path = write(tmp_path, "shadow.usda", stage_text(plane("grey") + veil + sun(90), looks, camera))
    rgb, _ = mean_rgb(path, spp=1, max_depth=1)
    np.testing.assert_allclose(rgb, 0.5 / math.pi * 3.0 * 0.75, rtol=1e-4)


def test_a_primvar_reader_colour_equals_the_same_constant_colour(tmp_path):
    """displayColor read by a UsdPrimvarReader_float3 into diffuseColor renders the same
    image, sample for sample, as that colour authored as a constant."""
    reader = """
        def Material "painted"
        {
            token outputs:surface.connect = </World/Looks/painted/Surface.outputs:surface>
            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </World/Looks/painted/colour.outputs:result>
                token outputs:surface
            }
            def Shader "colour"
            {
                uniform token info:id = "UsdPrimvarReader_float3"
                string inputs:varname = "displayColor"
                float3 inputs:fallback = (1, 0, 1)
                float3 outputs:result
            }
        }
"""
    colour = '        color3f[] primvars:displayColor = [(0.1, 0.6, 0.2)] (interpolation = "constant")\n'
    constant = preview_surface("painted", diffuseColor=("color3f", "(0.1, 0.6, 0.2)"))
    images = []
    for name, look in (("reader", reader), ("constant", constant)):
        path = write(tmp_path, f"{name}.usda", stage_text(plane("painted", colour) + sun(50), look))
        images.append(mean_rgb(path, spp=4, max_depth=2)[1].rgba)
    np.testing.assert_allclose(images[0], images[1], rtol=1e-5, atol=1e-7)
    assert images[0][..., 1].mean() > 3 * images[0][..., 0].mean()  # green, not the magenta fallback


def _standard_surface(name: str, inputs: str) -> str:
    return f"""
        def Material "{name}"
        {{
            token outputs:mtlx:surface.connect = </World/Looks/{name}/Surface.outputs:out>
            def Shader "Surface"
            {{
                uniform token info:id = "ND_standard_surface_surfaceshader"
{inputs}
                token outputs:out
            }}
        }}
"""


def test_a_standard_surface_with_only_base_colour_renders_as_the_equivalent_preview_surface(tmp_path):
    """standard_surface's defaults (base 1, specular_roughness 0.2, specular_IOR 1.5) with
    base_color c are UsdPreviewSurface diffuseColor c, roughness 0.2, ior 1.5: the same
    image, sample for sample."""
    mtlx = _standard_surface("look", "                color3f inputs:base_color = (0.7, 0.3, 0.1)")
    preview = preview_surface("look", diffuseColor=("color3f", "(0.7, 0.3, 0.1)"), roughness=("float", "0.2"),
                              ior=("float", "1.5"))
    images = []
    for name, look in (("mtlx", mtlx), ("preview", preview)):
        path = write(tmp_path, f"{name}.usda", stage_text(plane("look") + sun(40), look))
        scene, _ = load_stage(path)
        assert not scene.warnings, scene.warnings
        images.append(mean_rgb(path, spp=4, max_depth=3)[1].rgba)
    np.testing.assert_allclose(images[0], images[1], rtol=1e-4, atol=1e-6)


def test_standard_surface_transmission_is_clear_glass_in_a_uniform_dome(tmp_path):
    """White furnace for refraction: a standard_surface sphere with transmission 1 neither
    absorbs nor emits, so under a uniform dome every pixel sees the dome's radiance."""
    look = _standard_surface("glass", "                float inputs:transmission = 1\n"
                                      "                float inputs:specular_roughness = 0\n"
                                      "                float inputs:base = 1")
    body = GLASS_BALL_IN_UNIFORM_DOME
    path = write(tmp_path, "glass.usda", stage_text(body, look, camera_prim(50, 20, translate=(0, 0, 4))))
    rgb, result = mean_rgb(path, spp=16, max_depth=12)
    assert result.rgba[8, 8, 3] == 1.0
    np.testing.assert_allclose(rgb, 1.0, rtol=0.01)


def test_occlusion_is_read_and_ignored_without_a_warning(tmp_path):
    write_image(tmp_path / "ao.exr", np.full((2, 2, 3), 0.5))
    look = textured_look("ao", "./ao.exr", "occlusion", output="r")
    path = write(tmp_path, "ao.usda", stage_text(plane("ao") + sun(60), look))
    scene, _ = load_stage(path)
    assert not scene.warnings


def test_materialx_udim_images_read_the_same_tiles(tmp_path):
    """A MaterialX image whose file has <UDIM> (flattened into UsdShade) picks tiles as
    UsdUVTexture does: base_color = the tile's texel (base 1)."""
    write_udim_tiles(tmp_path)
    look = f"""
        def Material "tiled"
        {{
            token outputs:mtlx:surface.connect = </World/Looks/tiled/Surface.outputs:out>
            def Shader "Surface"
            {{
                uniform token info:id = "ND_standard_surface_surfaceshader"
                color3f inputs:base_color.connect = </World/Looks/tiled/paint.outputs:out>
                token outputs:out
            }}
            def Shader "paint"
            {{
                uniform token info:id = "ND_image_color3"
                asset inputs:file = @./maps/paint.<UDIM>.exr@ (colorSpace = "lin_rec709")
                color3f outputs:out
            }}
        }}
"""
    path = write(tmp_path, "udim.usda", stage_text(plane("tiled") + sun(60), look))
    scene, _ = load_stage(path)
    assert not scene.warnings, scene.warnings
    values = inputs_at(MaterialTable(scene).arrays, 0, [[0.5, 0.5], [1.5, 0.5]])[:, DIFFUSE:DIFFUSE + 3]
    np.testing.assert_allclose(values, [[0.25] * 3, [0.75] * 3], atol=1e-6)


def test_a_normal_map_behind_a_rotation_is_perturbed_in_the_rotated_frame(tmp_path):
    """Rotated 90°, the normal map reads (u, v) = (−t, s): ∂P/∂u = −∂P/∂t = +z and
    ∂P/∂v = ∂P/∂s = +x, so the tangent-space (0, sin a, cos a) is (sin a, cos a, 0) in world
    space, and the sun in the y–z plane sees L = ρ/π·E·cos a·sin e."""
    tilt, elevation = math.radians(20), 60
    encoded = np.array([0.5, 0.5 + 0.5 * math.sin(tilt), 0.5 + 0.5 * math.cos(tilt)])
    write_image(tmp_path / "normal.exr", np.tile(encoded, (4, 4, 1)))
    rotate = rotate_shader("bumpy")
    look = textured_look("bumpy", "./normal.exr", "normal",
                         '                float4 inputs:scale = (2, 2, 2, 1)\n'
                         '                float4 inputs:bias = (-1, -1, -1, 0)\n'
                         '                token inputs:sourceColorSpace = "raw"\n',
                         st_source="</World/Looks/bumpy/rotate.outputs:result>",
                         diffuseColor=("color3f", "(0.6, 0.6, 0.6)"), **LAMBERT).replace(
                             'def Shader "uv"', rotate + '            def Shader "uv"')
    path = write(tmp_path, "bumpy.usda", stage_text(plane("bumpy") + sun(elevation), look))
    rgb, _ = mean_rgb(path, spp=1, max_depth=1)
    np.testing.assert_allclose(rgb, 0.6 / math.pi * 3.0 * math.cos(tilt) * math.sin(math.radians(elevation)),
                               rtol=1e-4)
