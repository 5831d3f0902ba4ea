"""The tracer's texture cache (trace/texture_cache.py): textures held in their files'
precision, MIP-mapped, at the levels the frame needs, within a memory budget; lookups
filtered by their footprint."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from pxr_layers.jobs.frame import render_frame
from pxr_layers.request import RenderRequest
from pxr_layers.scene import Material, SceneData, TextureHeader, TextureImage
from pxr_layers.shader_nodes import ShaderNode
from pxr_layers.texture_files import MAX_TEXTURE_TEXELS, level_size, read_header, read_level, srgb_to_linear
from pxr_layers.trace import texture_cache
from pxr_layers.trace.shading import MaterialTable, inputs_at
from pxr_layers.trace.texture_cache import decoded, fit_levels, pyramid_bytes, resident_textures


def write(path: Path, pixels: np.ndarray, pixel_format) -> TextureImage:
    """`pixels` (h, w, c) written to `path`, and the lazy image the stage reader would make of it."""
    height, width, channels = pixels.shape
    output = oiio.ImageOutput.create(str(path))
    assert output.open(str(path), oiio.ImageSpec(width, height, channels, pixel_format)), oiio.geterror()
    assert output.write_image(pixels), output.geterror()
    output.close()
    return TextureImage(str(path), None, read_header(str(path)), "raw", "/World/look/tex")


@pytest.mark.parametrize("suffix, pixel_format, dtype, pool", [
    ("tif", oiio.UINT8, np.uint8, "u8"), ("tif", oiio.UINT16, np.uint16, "u16"), ("exr", oiio.HALF, np.float16, "u16"),
    ("exr", oiio.FLOAT, np.float32, "f32")])
def test_textures_stay_in_their_files_precision(tmp_path, suffix, pixel_format, dtype, pool):
    """8- and 16-bit and half texels are held as stored (half as its bits), float as float:
    the pools hold exactly the pyramid's bytes, and lookups read the values OIIO decodes."""
    rng = np.random.default_rng(1)
    values = rng.random((32, 48, 3))
    stored = (values * np.iinfo(dtype).max).astype(dtype) if np.issubdtype(dtype, np.integer) else values.astype(dtype)
    image = write(tmp_path / f"t.{suffix}", stored, pixel_format)
    assert image.header.stored == {np.uint8: "uint8", np.uint16: "uint16", np.float16: "half", np.float32: "float"}[dtype]
    resident = resident_textures([image])
    held = {"u8": resident.u8, "u16": resident.u16, "f32": resident.f32}
    assert held[pool].nbytes == pyramid_bytes(image, 0)
    assert all(array.size <= 1 for name, array in held.items() if name != pool)
    as_float = read_level(image.path, 0, "float")[1]
    np.testing.assert_array_equal(resident.finest_linear(0), as_float)


def test_srgb_is_decoded_at_lookup_and_alpha_stays_raw(tmp_path):
    rgba = np.array([[[128, 64, 255, 128]]], np.uint8)
    path = tmp_path / "rgba.png"
    output = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(1, 1, 4, oiio.UINT8)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    output.open(str(path), spec)
    output.write_image(rgba)
    output.close()
    image = TextureImage(str(path), None, read_header(str(path)), "sRGB")
    linear = decoded(image)
    np.testing.assert_allclose(linear[0, 0, :3], srgb_to_linear(rgba[0, 0, :3] / 255.0), atol=1e-6)
    assert linear[0, 0, 3] == pytest.approx(128 / 255, abs=1e-6)


def test_a_pyramid_is_two_by_two_box_averages_of_stored_values_down_to_one_texel(tmp_path):
    values = np.arange(5 * 6, dtype=np.uint8).reshape(5, 6, 1) * 8
    image = write(tmp_path / "t.png", values, oiio.UINT8)
    resident = resident_textures([image])
    rows = resident.levels[resident.info[0, texture_cache.FIRST_ROW]:][:resident.info[0, texture_cache.RESIDENT]]
    sizes = [(int(row[texture_cache.WIDTH]), int(row[texture_cache.HEIGHT])) for row in rows]
    assert sizes == [(6, 5), (3, 3), (2, 2), (1, 1)] == [level_size(6, 5, level) for level in range(4)]
    level1 = resident.u8[rows[1, texture_cache.OFFSET]:rows[1, texture_cache.OFFSET] + 9].reshape(3, 3)
    blocks = values[..., 0].astype(float)
    assert level1[0, 0] == round(blocks[0:2, 0:2].mean())
    assert level1[2, 2] == round(blocks[4:5, 4:6].mean())  # the odd last row: what is left


def test_lookups_choose_the_level_of_their_footprint_and_blend_two(tmp_path):
    """A one-texel checker: level 0 alternates 0 and 1, every coarser level is 0.5 (to 16-bit
    precision). A lookup one texel wide reads level 0; two texels wide or more, 0.5; √2
    texels, halfway between."""
    checker = ((np.indices((16, 16)).sum(axis=0) % 2) * 65535).astype(np.uint16)[..., None]
    image = write(tmp_path / "checker.png", checker, oiio.UINT16)
    lookup = ShaderNode("texture", (ShaderNode("texcoord"),), values=(0.0, 0.0, 0.0, 1.0), tiles=((0, 0),))
    scene = SceneData("test", 0.0, (), (Material("m", "/m", diffuse_color=lookup),), (), (image,))
    arrays = MaterialTable(scene).arrays
    centre = [[0.5 / 16, 0.5 / 16]]  # texel (0, 15) from the top: 15 + 0 is odd, 1
    for texels, expected in ((1.0, 1.0), (2.0, 0.5), (8.0, 0.5), (2 ** 0.5, 0.75)):
        value = inputs_at(arrays, 0, centre, footprint=texels / 16)[0, 0]
        assert value == pytest.approx(expected, abs=1e-4), texels
    assert arrays.texture_wanted[0] == 0  # the finest level asked for


def test_past_the_budget_the_largest_texture_is_held_coarser_with_a_warning(tmp_path, caplog):
    small = write(tmp_path / "small.png", np.zeros((256, 256, 3), np.uint8), oiio.UINT8)
    large = write(tmp_path / "large.png", np.zeros((1024, 1024, 3), np.uint8), oiio.UINT8)
    assert pyramid_bytes(large, 0) > 3 << 20 > pyramid_bytes(large, 1) + pyramid_bytes(small, 0)
    with caplog.at_level(logging.WARNING):
        assert fit_levels([small, large], [0, 0], 3) == [0, 1]
    (record,) = caplog.records
    assert record.getMessage() == (f"texture {large.path} (used by /World/look/tex): held at 512×512 texels, not the "
                                   "1024×1024 the frame asks for: the frame's textures pass the 3 MiB texture memory "
                                   "budget (--texture-memory)")


def test_a_level_past_the_texel_limit_is_held_at_the_first_that_fits(caplog):
    header = TextureHeader(8200, 8200, 1, "half", 1, (None, None))
    image = TextureImage("/textures/big.exr", None, header, "raw", "/World/look/tex")
    assert 8200 * 8200 > MAX_TEXTURE_TEXELS >= 4100 * 4100
    with caplog.at_level(logging.WARNING):
        assert fit_levels([image], [0], 1 << 20) == [1]
    assert caplog.records[0].getMessage().endswith(
        f"held at 4100×4100 texels, not the 8200×8200 the frame asks for: more than the {MAX_TEXTURE_TEXELS:,} "
        "texels a texture may hold")


def stage_text(folder: Path) -> Path:
    """A 1 m quad 2 m in front of the camera, textured seen.png, and another 1 km behind it
    (no path of a small frame reaches it), textured unseen.png, each 1024² (8-bit)."""
    for name in ("seen", "unseen"):
        write(folder / f"{name}.png", np.full((1024, 1024, 3), 200, np.uint8), oiio.UINT8)
    quads = []
    for name, z in (("seen", -2.0), ("unseen", 1000.0)):
        quads.append(f'''
    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-0.5, -0.5, {z}), (0.5, -0.5, {z}), (0.5, 0.5, {z}), (-0.5, 0.5, {z})]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
        uniform token subdivisionScheme = "none"
        rel material:binding = </World/Looks/{name}>
    }}''')
    looks = "".join(f'''
        def Material "{name}"
        {{
            token outputs:surface.connect = </World/Looks/{name}/surface.outputs:surface>
            def Shader "surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </World/Looks/{name}/tex.outputs:rgb>
                token outputs:surface
            }}
            def Shader "reader"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }}
            def Shader "tex"
            {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @./{name}.png@
                float2 inputs:st.connect = </World/Looks/{name}/reader.outputs:result>
                float3 outputs:rgb
            }}
        }}''' for name in ("seen", "unseen"))
    stage = folder / "shot.usda"
    stage.write_text(f'''#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{{
    def Camera "camera"
    {{
        float focalLength = 50
        float horizontalAperture = 36
        float verticalAperture = 36
    }}
    def DistantLight "sun"
    {{
        float inputs:intensity = 2
    }}{"".join(quads)}
    def Scope "Looks"
    {{{looks}
    }}
}}
''')
    return stage


def test_a_render_reads_only_the_textures_it_sees_at_the_level_it_needs(tmp_path, monkeypatch):
    reads = []
    monkeypatch.setattr(texture_cache, "read_level",
                        lambda path, level, stored=None: reads.append((Path(path).name, level)) or read_level(
                            path, level, stored))
    stage = stage_text(tmp_path)
    result = render_frame(RenderRequest(stage=stage, resolution=(64, 64), spp=4, keep_index=False, previews=False,
                                        camera="/World/camera"), output=tmp_path / "out")
    assert [name for name, _ in reads] == ["seen.png"]
    # 1024 texels over about 46 pixels: level 4 (64 texels) asked for, one finer held
    assert reads[0][1] == 3
    assert np.isfinite(result.rgba).all() and result.rgba[..., :3].max() > 0


def test_a_texture_gone_by_render_time_is_a_warning_and_the_render_goes_on(tmp_path, caplog):
    stage = stage_text(tmp_path)
    from pxr_layers.stage import load_stage
    scene, _ = load_stage(str(stage), camera="/World/camera")
    (tmp_path / "seen.png").unlink()
    seen = next(index for index, image in enumerate(scene.textures) if image.path.endswith("seen.png")
                and "unseen" not in image.path)
    with caplog.at_level(logging.WARNING):
        resident = resident_textures(scene.textures)
    assert resident.info[seen, texture_cache.RESIDENT] == 0
    assert any(record.getMessage().startswith(f"cannot read texture {scene.textures[seen].path} (used by ")
               for record in caplog.records)


def test_the_last_frames_pyramids_outlive_a_call_that_holds_no_file(tmp_path, monkeypatch):
    """A frame's visibility pre-pass holds no file-backed level; the pyramids the previous
    frame read stay for the next frame, which then reads no file."""
    image = write(tmp_path / "tex.tif", np.random.default_rng(1).random((16, 16, 3)).astype(np.float32), oiio.FLOAT)
    first = np.array(resident_textures([image], [0]).finest_linear(0))  # a frame
    resident_textures([image], [None])  # the next frame's pre-pass: nothing held
    reads = []
    original = texture_cache.read_level
    monkeypatch.setattr(texture_cache, "read_level", lambda *args, **kwargs: reads.append(args) or original(*args, **kwargs))
    again = resident_textures([image], [0]).finest_linear(0)  # the next frame
    assert reads == [], "the pyramid was read again from its file"
    np.testing.assert_array_equal(again, first)
