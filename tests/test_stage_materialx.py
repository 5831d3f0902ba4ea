"""MaterialX looks (stage/materialx/): documents and UsdShade networks → Material fields."""

import math
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade

from pxr_layers.shader_nodes import ShaderNode
from pxr_layers.stage.context import ReadContext
from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.materialx import MaterialXReader
from pxr_layers.stage.textures import TextureLibrary
from pxr_layers.texture_files import srgb_to_linear
from pxr_layers.trace.texture_cache import decoded


def _reader(stage=None, textures=None):
    stage = stage or Usd.Stage.CreateInMemory()
    diagnostics = Diagnostics()
    context = ReadContext(stage=stage, time=Usd.TimeCode.Default(), meters_per_unit=1.0, up_axis="Y",
                          xform_cache=UsdGeom.XformCache(), diagnostics=diagnostics, file="test.usda")
    textures = textures if textures is not None else TextureLibrary(diagnostics)
    return MaterialXReader(context, textures), diagnostics, textures


def _document(tmp_path: Path, body: str, name: str = "look.mtlx") -> str:
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?>\n<materialx version="1.39">\n{body}\n</materialx>\n')
    return str(path)


def _surface(shader: str, inputs: str, material: str = "M") -> str:
    return (f'<{shader} name="SR" type="surfaceshader">{inputs}</{shader}>'
            f'<surfacematerial name="{material}" type="material">'
            '<input name="surfaceshader" type="surfaceshader" nodename="SR" /></surfacematerial>')


def _write_image(path: Path, pixels: np.ndarray) -> str:
    height, width, channels = pixels.shape
    output = oiio.ImageOutput.create(str(path))
    output.open(str(path), oiio.ImageSpec(width, height, channels, oiio.UINT8))
    output.write_image(pixels.astype(np.uint8))
    output.close()
    return str(path)


def _texture(value) -> ShaderNode:
    """The texture lookup under an image output's channel swizzle."""
    assert isinstance(value, ShaderNode) and value.op == "swizzle"
    lookup = value.inputs[0]
    assert lookup.op == "texture"
    return lookup


def test_standard_surface_base_color_only_gives_the_translation_values(tmp_path):
    path = _document(tmp_path, _surface("standard_surface",
                                        '<input name="base_color" type="color3" value="0.2, 0.4, 0.6" />'))
    reader, diagnostics, _ = _reader()
    look = reader.from_document(path, "M", "/World/Mesh")
    fields = look.fields
    assert fields["diffuse_color"] == pytest.approx((0.2, 0.4, 0.6))  # base 1 · base_color
    assert fields["metallic"] == 0.0
    assert fields["roughness"] == pytest.approx(0.2)  # specular_roughness default
    assert fields["ior"] == pytest.approx(1.5)
    assert fields["clearcoat"] == 0.0 and fields["clearcoat_roughness"] == pytest.approx(0.1)
    assert fields["opacity"] == pytest.approx(1.0)
    assert fields["emissive_color"] == (0.0, 0.0, 0.0)
    assert fields["transmission"] == 0.0 and fields["thin_walled"] is False
    assert fields["normal"] is None
    assert look.uv_primvars == () and look.primvars == ()
    assert diagnostics.finish() == ()


def test_standard_surface_base_scales_and_coat_tints(tmp_path):
    inputs = ('<input name="base" type="float" value="0.5" />'
              '<input name="base_color" type="color3" value="1, 1, 1" />'
              '<input name="coat" type="float" value="1" />'
              '<input name="coat_color" type="color3" value="0.5, 1, 1" />'
              '<input name="transmission" type="float" value="0.75" />'
              '<input name="thin_walled" type="boolean" value="true" />')
    reader, _, _ = _reader()
    fields = reader.from_document(_document(tmp_path, _surface("standard_surface", inputs)), "M", "/m").fields
    assert fields["diffuse_color"] == pytest.approx((0.25, 0.5, 0.5))
    assert fields["clearcoat"] == pytest.approx((0.5 + 1 + 1) / 3)
    assert fields["transmission"] == 0.75 and fields["thin_walled"] is True


def test_image_node_reads_channels_wrap_and_colour_space(tmp_path):
    pixels = np.array([[[10, 128, 250], [0, 64, 255]]], dtype=np.uint8)
    _write_image(tmp_path / "albedo.png", pixels)
    body = ('<nodegraph name="NG">'
            '<image name="albedo" type="color3"><input name="file" type="filename" value="albedo.png" '
            'colorspace="srgb_texture" /><input name="uaddressmode" type="string" value="clamp" />'
            '<input name="vaddressmode" type="string" value="mirror" /></image>'
            '<image name="rough" type="float"><input name="file" type="filename" value="albedo.png" />'
            '<input name="default" type="float" value="0.25" />'
            '<input name="vaddressmode" type="string" value="constant" /></image>'
            '<output name="color" type="color3" nodename="albedo" />'
            '<output name="rough_out" type="float" nodename="rough" /></nodegraph>'
            + _surface("standard_surface",
                       '<input name="base_color" type="color3" nodegraph="NG" output="color" />'
                       '<input name="specular_roughness" type="float" nodegraph="NG" output="rough_out" />'))
    reader, diagnostics, textures = _reader()
    look = reader.from_document(_document(tmp_path, body), "M", "/m")
    color, rough = look.fields["diffuse_color"], look.fields["roughness"]
    assert color.values == (0.0, 1.0, 2.0, -1.0)
    assert rough.values == (0.0, -1.0, -1.0, -1.0)
    color_lookup, rough_lookup = _texture(color), _texture(rough)
    assert color_lookup.wrap == ("clamp", "mirror") and rough_lookup.wrap == ("repeat", "black")
    assert color_lookup.inputs[0] == ShaderNode("texcoord")
    assert rough_lookup.values == (0.25, 0.0, 0.0, 0.0)
    srgb, raw = (decoded(textures.images[lookup.tiles[0][1]]) for lookup in (color_lookup, rough_lookup))
    assert srgb[0, 0, :3] == pytest.approx(srgb_to_linear(pixels[0, 0] / 255.0), abs=1e-6)
    assert raw[0, 0, :3] == pytest.approx(pixels[0, 0] / 255.0, abs=1e-6)  # float images are not colour-managed
    assert look.uv_primvars == ("st",)
    assert diagnostics.finish() == ()


def test_tiledimage_uvtiling_is_one_affine2d(tmp_path):
    _write_image(tmp_path / "t.png", np.full((2, 2, 3), 100, np.uint8))
    body = ('<tiledimage name="tile" type="color3"><input name="file" type="filename" value="t.png" />'
            '<input name="uvtiling" type="vector2" value="2, 2" />'
            '<input name="uvoffset" type="vector2" value="0.5, 0" /></tiledimage>'
            + _surface("standard_surface", '<input name="base_color" type="color3" nodename="tile" />'))
    reader, _, _ = _reader()
    lookup = _texture(reader.from_document(_document(tmp_path, body), "M", "/m").fields["diffuse_color"])
    transform = lookup.inputs[0]
    assert transform.op == "affine2d" and transform.values == (2.0, 0.0, -0.5, 0.0, 2.0, 0.0)
    assert transform.inputs[0] == ShaderNode("texcoord")


def test_texcoord_index_and_geomprops_are_primvars(tmp_path):
    body = ('<texcoord name="uv1" type="vector2"><input name="index" type="integer" value="1" /></texcoord>'
            '<geompropvalue name="tint" type="color3"><input name="geomprop" type="string" value="tint" />'
            '<input name="default" type="color3" value="1, 0.5, 0.25" /></geompropvalue>'
            '<separate2 name="split" type="multioutput"><input name="in" type="vector2" nodename="uv1" />'
            '</separate2>'
            '<multiply name="scaled" type="color3"><input name="in1" type="color3" nodename="tint" />'
            '<input name="in2" type="float" nodename="split" output="outy" /></multiply>'
            + _surface("standard_surface", '<input name="base_color" type="color3" nodename="scaled" />'))
    reader, _, _ = _reader()
    look = reader.from_document(_document(tmp_path, body), "M", "/m")
    color = look.fields["diffuse_color"]
    assert color.op == "multiply"
    tint, y = color.inputs
    assert tint == ShaderNode("primvar", values=(1.0, 0.5, 0.25, 0.0), name="tint")
    assert y.op == "swizzle" and y.values == (0.0, 0.0, 0.0, 0.0)  # broadcast of …
    assert y.inputs[0].values == (1.0, -1.0, -1.0, -1.0)  # … channel y of st1
    assert y.inputs[0].inputs[0] == ShaderNode("primvar", values=(0.0,) * 4, name="st1")
    assert look.primvars == ("tint", "st1") and look.uv_primvars == ()


def test_math_and_normalmap(tmp_path):
    _write_image(tmp_path / "n.png", np.full((2, 2, 3), 128, np.uint8))
    body = ('<image name="nimg" type="vector3"><input name="file" type="filename" value="n.png" /></image>'
            '<normalmap name="nmap" type="vector3"><input name="in" type="vector3" nodename="nimg" />'
            '<input name="scale" type="float" value="0.5" /></normalmap>'
            '<constant name="k" type="float"><input name="value" type="float" value="0.25" /></constant>'
            '<power name="p" type="float"><input name="in1" type="float" nodename="k" />'
            '<input name="in2" type="float" value="0.5" /></power>'
            '<rotate2d name="r" type="vector2"><input name="in" type="vector2" value="1, 0" />'
            '<input name="amount" type="float" value="90" /></rotate2d>'
            '<extract name="ry" type="float"><input name="in" type="vector2" nodename="r" />'
            '<input name="index" type="integer" value="1" /></extract>'
            + _surface("standard_surface", '<input name="normal" type="vector3" nodename="nmap" />'
                       '<input name="specular_roughness" type="float" nodename="p" />'
                       '<input name="metalness" type="float" nodename="ry" />'))
    reader, diagnostics, _ = _reader()
    fields = reader.from_document(_document(tmp_path, body), "M", "/m").fields
    assert fields["roughness"] == pytest.approx(0.5)  # folded to a constant
    assert fields["metallic"] == pytest.approx(-1.0)  # (1, 0) by 90° as MaterialX rotates: (0, −1)
    normal = fields["normal"]
    assert normal.op == "multiply" and normal.inputs[1].values == (0.5, 0.5, 1.0, 0.0)
    decoded = normal.inputs[0]
    assert decoded.op == "subtract" and decoded.inputs[1].values[:3] == (1.0, 1.0, 1.0)
    assert decoded.inputs[0].op == "multiply" and decoded.inputs[0].inputs[1].values[:3] == (2.0, 2.0, 2.0)
    assert diagnostics.finish() == ()


def _usd_stage(tmp_path: Path, text: str) -> Usd.Stage:
    path = tmp_path / "scene.usda"
    path.write_text("#usda 1.0\n" + text)
    return Usd.Stage.Open(str(path))


def test_usd_network_expands_nodegraph_implemented_nodes(tmp_path):
    _write_image(tmp_path / "c.png", np.full((2, 2, 3), 200, np.uint8))
    stage = _usd_stage(tmp_path, '''
def Material "M"
{
    token outputs:mtlx:surface.connect = </M/Surface.outputs:surface>
    def Shader "Surface"
    {
        uniform token info:id = "ND_UsdPreviewSurface_surfaceshader"
        color3f inputs:diffuseColor.connect = </M/Graph.outputs:color>
        float inputs:roughness = 0.3
        token outputs:surface
    }
    def NodeGraph "Graph"
    {
        color3f outputs:color.connect = </M/Graph/Texture.outputs:rgb>
        def Shader "Texture"
        {
            uniform token info:id = "ND_UsdUVTexture"
            asset inputs:file = @c.png@ (colorSpace = "srgb_texture")
            float4 inputs:scale = (0.5, 0.5, 0.5, 1)
            string inputs:wrapS = "clamp"
            float2 inputs:st.connect = </M/Graph/Transform.outputs:out>
            color3f outputs:rgb
        }
        def Shader "Transform"
        {
            uniform token info:id = "ND_UsdTransform2d"
            float2 inputs:in.connect = </M/Graph/Reader.outputs:out>
            float2 inputs:scale = (3, 3)
            float2 outputs:out
        }
        def Shader "Reader"
        {
            uniform token info:id = "ND_UsdPrimvarReader_vector2"
            string inputs:varname = "uvmap"
            float2 outputs:out
        }
    }
}
''')
    reader, diagnostics, textures = _reader(stage)
    look = reader.from_usd(UsdShade.Material(stage.GetPrimAtPath("/M")))
    assert look.fields["roughness"] == pytest.approx(0.3)
    color = look.fields["diffuse_color"]
    assert color.op == "swizzle" and color.values == (0.0, 1.0, 2.0, -1.0)  # rgba → rgb (convert)
    scaled = color.inputs[0]
    assert scaled.op == "multiply" and scaled.inputs[1].values == (0.5, 0.5, 0.5, 1.0)
    lookup = scaled.inputs[0]
    assert lookup.op == "texture" and lookup.wrap == ("clamp", "periodic" and "repeat")
    assert textures.images[lookup.tiles[0][1]].path == str(tmp_path / "c.png")
    uv = lookup.inputs[0]
    # UsdTransform2d's graph: scale, rotate (0°), translate, all folded around the uv reader.
    assert ShaderNode("texcoord") in uv.walk()
    assert all(n.op in ("texcoord", "multiply", "affine2d", "add", "subtract", "constant", "swizzle")
               for n in uv.walk())
    assert look.uv_primvars == ("uvmap",)
    assert diagnostics.finish() == ()


def test_unsupported_nodes_note_once_and_use_defaults(tmp_path):
    body = ('<noise2d name="n1" type="float" /><noise2d name="n2" type="float" />'
            + _surface("standard_surface", '<input name="specular_roughness" type="float" nodename="n1" />'
                       '<input name="metalness" type="float" nodename="n2" />'))
    reader, diagnostics, _ = _reader()
    fields = reader.from_document(_document(tmp_path, body), "M", "/Mesh").fields
    assert fields["roughness"] == 0.0 and fields["metallic"] == 0.0
    warnings = diagnostics.finish()
    assert len(warnings) == 1 and "'noise2d'" in warnings[0] and "(n1)" in warnings[0] and "(n2)" in warnings[0]


def test_cyclic_graph_is_noted_not_a_recursion_error(tmp_path):
    body = ('<add name="a" type="float"><input name="in1" type="float" nodename="b" /></add>'
            '<add name="b" type="float"><input name="in1" type="float" nodename="a" /></add>'
            + _surface("standard_surface", '<input name="specular_roughness" type="float" nodename="a" />'))
    reader, diagnostics, _ = _reader()
    fields = reader.from_document(_document(tmp_path, body), "M", "/m").fields
    assert fields["roughness"] == 0.0
    assert any("cyclic" in warning for warning in diagnostics.finish())


def test_open_pbr_and_gltf_surfaces(tmp_path):
    open_pbr = _surface("open_pbr_surface", '<input name="base_color" type="color3" value="1, 0.5, 0" />'
                        '<input name="base_weight" type="float" value="0.5" />'
                        '<input name="emission_luminance" type="float" value="10" />'
                        '<input name="transmission_weight" type="float" value="1" />', "P")
    gltf = (_surface("gltf_pbr", '<input name="base_color" type="color3" value="0.1, 0.2, 0.3" />'
                     '<input name="alpha" type="float" value="0.4" />'
                     '<input name="alpha_mode" type="integer" value="1" />'
                     '<input name="alpha_cutoff" type="float" value="0.3" />', "G").replace('"SR"', '"SR2"'))
    path = _document(tmp_path, open_pbr + gltf)
    reader, diagnostics, _ = _reader()
    p = reader.from_document(path, "P", "/p").fields
    assert p["diffuse_color"] == pytest.approx((0.5, 0.25, 0.0))
    assert p["emissive_color"] == pytest.approx((10.0, 10.0, 10.0))
    assert p["transmission"] == 1.0 and p["roughness"] == pytest.approx(0.3)
    g = reader.from_document(path, "G", "/g").fields
    assert g["diffuse_color"] == pytest.approx((0.1, 0.2, 0.3))
    assert g["metallic"] == 1.0 and g["roughness"] == 1.0  # gltf_pbr's defaults
    assert g["opacity"] == pytest.approx(0.4) and g["opacity_threshold"] == pytest.approx(0.3)
    assert diagnostics.finish() == ()


def test_referenced_document_resolves_through_reference_and_payload(tmp_path):
    _document(tmp_path, _surface("standard_surface", '<input name="base_color" type="color3" value="1, 0, 0" />',
                                 "Red"), "red.mtlx")
    _document(tmp_path, _surface("standard_surface", '<input name="base_color" type="color3" value="0, 0, 1" />',
                                 "Blue"), "blue.mtlx")
    stage = _usd_stage(tmp_path, '''
def Xform "World"
{
    def Scope "Looks" (prepend references = [@./red.mtlx@</MaterialX/Materials>, @./blue.mtlx@</MaterialX/Materials>])
    {
    }
    def Scope "Payloaded" (prepend payload = @./red.mtlx@</MaterialX>)
    {
    }
}
''')
    reader, diagnostics, _ = _reader(stage)
    assert not stage.GetPrimAtPath("/World/Looks/Blue")
    assert reader.referenced(Sdf.Path("/World/Looks/Blue")) == (str(tmp_path / "blue.mtlx"), "Blue")
    assert reader.referenced(Sdf.Path("/World/Looks/Red")) == (str(tmp_path / "red.mtlx"), "Red")
    assert reader.referenced(Sdf.Path("/World/Payloaded/Materials/Red")) == (str(tmp_path / "red.mtlx"), "Red")
    assert reader.referenced(Sdf.Path("/World/Other/Red")) is None
    look = reader.from_document(*reader.referenced(Sdf.Path("/World/Looks/Blue")), "/World/Mesh")
    assert look.fields["diffuse_color"] == (0.0, 0.0, 1.0)
    assert reader.from_document(str(tmp_path / "red.mtlx"), "Green", "/World/Mesh") is None
    assert reader.from_document(str(tmp_path / "missing.mtlx"), "Red", "/World/Mesh") is None
    warnings = diagnostics.finish()
    assert len(warnings) == 2 and "Green" in warnings[0] and "missing.mtlx" in warnings[1]


# ---- the real assets ------------------------------------------------------------------------

def _is_texture(value) -> bool:
    return isinstance(value, ShaderNode) and any(n.op == "texture" for n in value.walk())


def test_open_chess_set_materials(shared_scenes):
    """The pawn's (glass tops, textured bodies), the knight's (no metallic map) and the
    board's documents, with their textures decoded; every piece is checked through the
    whole stage in test_shared_scenes.py."""
    import MaterialX as mx

    assets = shared_scenes / "usd-wg/full_assets/OpenChessSet/assets"
    files = [assets / f"{name}/{name}_mat.mtlx" for name in ("Pawn", "Knight", "Chessboard")]
    reader, diagnostics, textures = _reader()
    count = 0
    for path in files:
        document = mx.createDocument()
        mx.readFromXmlFile(document, str(path))
        for material in document.getMaterialNodes():
            fields = reader.from_document(str(path), material.getName(), "/chess").fields
            count += 1
            assert _is_texture(fields["roughness"]), material.getName()
            assert _is_texture(fields["normal"]), material.getName()
            if "_Top_" in material.getName() and "Chessboard" not in str(path):  # the glass tops
                assert fields["transmission"] == 1.0
            else:
                assert _is_texture(fields["diffuse_color"]), material.getName()
                shader = material.getInput("surfaceshader").getConnectedNode()
                if shader.getInput("metalness") is not None:  # the knights have no metallic map
                    assert _is_texture(fields["metallic"]), material.getName()
                else:
                    assert fields["metallic"] == 0.0
    assert count == 7
    assert diagnostics.finish() == ()
    assert len(textures.images) >= 10


def test_chess_pawn_through_usd_reference_with_real_textures(shared_scenes):
    stage = Usd.Stage.Open(str(shared_scenes / "usd-wg/full_assets/OpenChessSet/assets/Pawn/Pawn.usd"))
    reader, diagnostics, textures = _reader(stage)
    target = Sdf.Path("/Pawn/Materials/M_Pawn_Top_B")
    mtlx, name = reader.referenced(target)
    assert mtlx.endswith("Pawn/Pawn_mat.mtlx") and name == "M_Pawn_Top_B"
    fields = reader.from_document(mtlx, name, "/Pawn/Geom_Top/Render").fields
    assert fields["transmission"] == 1.0
    assert fields["transmission_color"] == pytest.approx((0.2995, 0.5, 0.450276))
    assert _is_texture(fields["roughness"]) and _is_texture(fields["normal"])
    assert len(textures.images) == 2 and diagnostics.finish() == ()


@pytest.mark.parametrize("model", ["", "_openpbr"])
def test_standard_shader_ball_example_materials(shared_scenes, model):
    folder = shared_scenes / "StandardShaderBall/example_materials"
    reader, diagnostics, _ = _reader()
    gold = reader.from_document(str(folder / f"gold{model}.mtlx"), "gold", "/ball").fields
    assert gold["metallic"] == 1.0 and gold["roughness"] == pytest.approx(0.01)
    red, green, blue = gold["diffuse_color"]
    assert red > green > blue and blue < 0.5 * red
    glass = reader.from_document(str(folder / f"glass{model}.mtlx"), "glass", "/ball").fields
    assert glass["transmission"] == 1.0 and glass["ior"] == pytest.approx(1.54107)
    for name in ("plastic", "bubblegum"):
        fields = reader.from_document(str(folder / f"{name}{model}.mtlx"), name, "/ball").fields
        assert fields["metallic"] == 0.0 and all(isinstance(v, float) for v in fields["diffuse_color"])
    assert diagnostics.finish() == ()


def test_standard_shader_ball_mtlx_variants_resolve(shared_scenes):
    stage = Usd.Stage.Open(str(shared_scenes / "StandardShaderBall/standard_shader_ball_scene.usda"))
    reader, _, _ = _reader(stage)
    examples = "/standard_shader_ball_scene/materials/examples/mtlx"
    if not stage.GetPrimAtPath(examples):
        pytest.skip("the example materials layer is not composed here")
    mtlx, name = reader.referenced(Sdf.Path(f"{examples}/gold"))
    assert os.path.basename(mtlx).startswith("gold") and name == "gold"


def test_material_x_test_flattened_usd_matches_its_documents(shared_scenes):
    folder = shared_scenes / "usd-wg/test_assets/MaterialXTest"
    stage = Usd.Stage.Open(str(folder / "basicTextured_flatten.usda"))
    usd_reader, _, usd_textures = _reader(stage)
    document_reader, _, document_textures = _reader()
    for name, document in (("USD_Plastic", "usd_preview_surface_plastic.mtlx"),
                           ("Tiled_Brass", "standard_surface_brass_tiled.mtlx")):
        from_usd = usd_reader.from_usd(UsdShade.Material(stage.GetPrimAtPath(f"/MaterialX/Materials/{name}")))
        from_document = document_reader.from_document(str(folder / document), name, "/teapot")
        assert from_usd.fields.keys() == from_document.fields.keys()
        for field, value in from_usd.fields.items():
            expected = from_document.fields[field]
            if isinstance(value, tuple):
                assert value == pytest.approx(expected), field
            elif isinstance(value, float):
                assert math.isclose(value, expected, rel_tol=1e-6), field
            else:
                assert value == expected, field
    assert [image.path for image in usd_textures.images] == [image.path for image in document_textures.images]
