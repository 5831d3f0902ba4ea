"""stage/: material binding, UsdPreviewSurface and UsdUVTexture → scene.Material and its shader-node trees."""

from __future__ import annotations

from dataclasses import dataclass

import os

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdRender, UsdShade, Vt

from pxr_layers.scene import DEFAULT_MATERIAL_PATH, Material
from pxr_layers.shader_nodes import ShaderNode
from pxr_layers.stage import load_stage
from pxr_layers.texture_files import read_level
from pxr_layers.trace import texture_cache
from pxr_layers.trace.shading import MaterialTable, inputs_at
from pxr_layers.trace.texture_cache import decoded

QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
STRIP_POINTS = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)]
STRIP_INDICES = [0, 1, 4, 3, 1, 2, 5, 4]
FLOAT = Sdf.ValueTypeNames.Float
COLOR = Sdf.ValueTypeNames.Color3f


@dataclass(frozen=True)
class TextureInput:
    """What a UsdUVTexture-driven input's tree is made of (see texture_input)."""

    texture: int
    channels: tuple[int, ...]
    scale: tuple[float, ...]
    bias: tuple[float, ...]
    wrap_s: str
    wrap_t: str


def texture_input(value, width: int) -> TextureInput:
    """Unpack the tree stage/materials.py builds for a UsdUVTexture output feeding an input
    of `width` components: swizzles of (texel · scale + bias), without a scale of 1 or a
    bias of 0."""
    assert isinstance(value, ShaderNode), value
    picked = (0, 1, 2, 3)  # component k of the input = component picked[k] of `node`
    node = value
    while node.op == "swizzle":
        picked = tuple(int(node.values[c]) if c >= 0 else c for c in picked)
        node = node.inputs[0]
    scale, bias = (1.0,) * 4, (0.0,) * 4  # identities are left out of the tree
    if node.op == "add":
        node, bias = node.inputs[0], node.inputs[1].values
    if node.op == "multiply":
        node, scale = node.inputs[0], node.inputs[1].values
    assert node.op == "texture" and len(node.tiles) == 1, node
    return TextureInput(node.tiles[0][1], picked[:width], scale, bias, *node.wrap)


def new_stage(tmp_path) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(tmp_path / "scene.usda"))
    UsdGeom.Camera.Define(stage, "/Camera")
    return stage


def load(stage: Usd.Stage, **kwargs):
    stage.GetRootLayer().Save()
    return load_stage(stage.GetRootLayer().realPath, **kwargs)


def quad(stage, path="/quad", points=QUAD):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateSubdivisionSchemeAttr("none")
    return mesh


def preview_material(stage, path, **inputs) -> tuple[UsdShade.Material, UsdShade.Shader]:
    """A Material whose outputs:surface is a UsdPreviewSurface; inputs are name=(type, value)."""
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    for name, (value_type, value) in inputs.items():
        shader.CreateInput(name, value_type).Set(value)
    return material, shader


def bind(prim, material, purpose=UsdShade.Tokens.allPurpose):
    UsdShade.MaterialBindingAPI.Apply(prim.GetPrim()).Bind(
        material, UsdShade.Tokens.weakerThanDescendants, purpose
    )


def material_of(scene, mesh_index=0, triangle=0) -> Material:
    return scene.materials[scene.meshes[mesh_index].triangle_material[triangle]]


def write_image(path, pixels: np.ndarray, pixel_format, **attributes) -> str:
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, pixel_format)
    for name, value in attributes.items():
        spec.attribute(name, value)
    output = oiio.ImageOutput.create(str(path))
    assert output.open(str(path), spec), oiio.geterror()
    assert output.write_image(pixels), output.geterror()
    output.close()
    return str(path)


def textured_material(stage, path, file, *, target="diffuseColor", output="rgb",
                      target_type=COLOR, varname="st", **texture_inputs):
    """A UsdPreviewSurface whose ``target`` input reads ``output`` of a UsdUVTexture."""
    material, surface = preview_material(stage, path)
    reader = UsdShade.Shader.Define(stage, f"{path}/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set(varname)
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    texture = UsdShade.Shader.Define(stage, f"{path}/Texture")
    texture.CreateIdAttr("UsdUVTexture")
    if file is not None:
        texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.ConnectableAPI(), "result"
    )
    types = {"scale": Sdf.ValueTypeNames.Float4, "bias": Sdf.ValueTypeNames.Float4,
             "fallback": Sdf.ValueTypeNames.Float4}
    for name, value in texture_inputs.items():
        texture.CreateInput(name, types.get(name, Sdf.ValueTypeNames.Token)).Set(value)
    texture_output = texture.CreateOutput(output, target_type)
    surface.CreateInput(target, target_type).ConnectToSource(texture_output)
    return material


def srgb_eotf(values):
    values = np.asarray(values, dtype=np.float64)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4)


# --- UsdPreviewSurface --------------------------------------------------------------------


def test_unauthored_inputs_take_the_preview_surface_fallbacks(tmp_path):
    stage = new_stage(tmp_path)
    material, _ = preview_material(stage, "/Looks/plain")
    bind(quad(stage), material)
    scene, _ = load(stage)
    assert material_of(scene) == Material(name="plain", path="/Looks/plain")
    defaults = Material(name="x", path="y")
    assert defaults.diffuse_color == (0.18, 0.18, 0.18) and defaults.roughness == 0.5
    assert defaults.ior == 1.5 and defaults.clearcoat_roughness == 0.01


def test_constant_inputs_are_read(tmp_path):
    stage = new_stage(tmp_path)
    material, _ = preview_material(
        stage, "/Looks/all",
        diffuseColor=(COLOR, (0.1, 0.2, 0.3)),
        emissiveColor=(COLOR, (1.0, 2.0, 3.0)),
        roughness=(FLOAT, 0.25),
        metallic=(FLOAT, 1.0),
        specularColor=(COLOR, (0.5, 0.5, 0.5)),
        useSpecularWorkflow=(Sdf.ValueTypeNames.Int, 1),
        ior=(FLOAT, 1.33),
        opacity=(FLOAT, 0.5),
        opacityThreshold=(FLOAT, 0.1),
        clearcoat=(FLOAT, 0.75),
        clearcoatRoughness=(FLOAT, 0.2),
    )
    bind(quad(stage), material)
    got = material_of(load(stage)[0])
    assert got.diffuse_color == pytest.approx((0.1, 0.2, 0.3))
    assert got.emissive_color == pytest.approx((1.0, 2.0, 3.0))
    assert got.specular_color == pytest.approx((0.5, 0.5, 0.5))
    assert got.use_specular_workflow is True
    for field, value in {"roughness": 0.25, "metallic": 1.0, "ior": 1.33, "opacity": 0.5, "opacity_threshold": 0.1,
                         "clearcoat": 0.75, "clearcoat_roughness": 0.2}.items():
        assert getattr(got, field) == pytest.approx(value), field


def test_connections_are_followed_through_node_graphs_and_interface_inputs(tmp_path):
    stage = new_stage(tmp_path)
    material = UsdShade.Material.Define(stage, "/Looks/wrapped")
    tint = material.CreateInput("tint", COLOR)
    tint.Set((0.9, 0.1, 0.1))
    graph = UsdShade.NodeGraph.Define(stage, "/Looks/wrapped/Graph")
    shader = UsdShade.Shader.Define(stage, "/Looks/wrapped/Graph/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", COLOR).ConnectToSource(tint)
    graph_output = graph.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    graph_output.ConnectToSource(shader.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    material.CreateSurfaceOutput().ConnectToSource(graph_output)
    bind(quad(stage), material)
    assert material_of(load(stage)[0]).diffuse_color == pytest.approx((0.9, 0.1, 0.1))


# --- binding ------------------------------------------------------------------------------


def test_full_purpose_binding_is_preferred_over_all_purpose(tmp_path):
    stage = new_stage(tmp_path)
    everyday, _ = preview_material(stage, "/Looks/everyday")
    final, _ = preview_material(stage, "/Looks/final")
    mesh = quad(stage)
    bind(mesh, everyday)
    bind(mesh, final, UsdShade.Tokens.full)
    scene, spec = load(stage)
    assert spec.material_binding_purposes == ("full", "")
    assert material_of(scene).path == "/Looks/final"


def test_render_settings_binding_purposes_are_honoured(tmp_path):
    stage = new_stage(tmp_path)
    everyday, _ = preview_material(stage, "/Looks/everyday")
    final, _ = preview_material(stage, "/Looks/final")
    mesh = quad(stage)
    bind(mesh, everyday)
    bind(mesh, final, UsdShade.Tokens.full)
    settings = UsdRender.Settings.Define(stage, "/Render/Preview")
    settings.CreateMaterialBindingPurposesAttr([UsdShade.Tokens.allPurpose])
    scene, spec = load(stage, settings="/Render/Preview")
    assert spec.material_binding_purposes == ("",)
    assert material_of(scene).path == "/Looks/everyday"


def test_binding_on_an_ancestor_applies_to_descendants(tmp_path):
    stage = new_stage(tmp_path)
    material, _ = preview_material(stage, "/Looks/shared")
    group = UsdGeom.Xform.Define(stage, "/Group")
    bind(group, material)
    quad(stage, "/Group/a")
    quad(stage, "/Group/b")
    scene, _ = load(stage)
    assert [material_of(scene, i).path for i in range(2)] == ["/Looks/shared"] * 2
    assert len(scene.materials) == 1  # converted once


def test_geom_subsets_give_per_face_materials(tmp_path):
    stage = new_stage(tmp_path)
    body, _ = preview_material(stage, "/Looks/body")
    trim, _ = preview_material(stage, "/Looks/trim")
    mesh = UsdGeom.Mesh.Define(stage, "/strip")
    mesh.CreatePointsAttr(STRIP_POINTS)
    mesh.CreateFaceVertexCountsAttr([4, 4])
    mesh.CreateFaceVertexIndicesAttr(STRIP_INDICES)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # two faces, four triangles
    bind(mesh, body)
    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    subset = binding.CreateMaterialBindSubset("trim_faces", Vt.IntArray([1]))
    bind(subset, trim)
    scene, _ = load(stage)
    names = [scene.materials[i].name for i in scene.meshes[0].triangle_material]
    assert names == ["body", "body", "trim", "trim"]


def test_unbound_meshes_get_a_default_material_tinted_by_display_color(tmp_path):
    stage = new_stage(tmp_path)
    quad(stage, "/grey")
    for path in ("/red_a", "/red_b"):
        quad(stage, path).CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(1, 0, 0)])
    scene, _ = load(stage)
    by_path = {mesh.path: scene.materials[mesh.triangle_material[0]] for mesh in scene.meshes}
    assert by_path["/grey"] == Material(name="default", path=DEFAULT_MATERIAL_PATH)
    assert by_path["/red_a"].diffuse_color == (1.0, 0.0, 0.0)
    assert by_path["/red_a"].path == DEFAULT_MATERIAL_PATH
    assert len(scene.materials) == 2  # the two red meshes share one default
    for mesh in scene.meshes:
        assert ((mesh.triangle_material >= 0) & (mesh.triangle_material < 2)).all()


def test_renderer_specific_materials_warn_once_and_use_the_default(tmp_path):
    stage = new_stage(tmp_path)
    for name in ("ri_a", "ri_b"):
        material = UsdShade.Material.Define(stage, f"/Looks/{name}")
        shader = UsdShade.Shader.Define(stage, f"/Looks/{name}/Surface")
        shader.CreateIdAttr("PxrSurface")
        material.CreateSurfaceOutput("ri").ConnectToSource(
            shader.CreateOutput("out", Sdf.ValueTypeNames.Token)
        )
        mesh = quad(stage, f"/{name}")
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(0, 0, 1)])
        bind(mesh, material)
    scene, _ = load(stage)
    assert all(material_of(scene, i).path == DEFAULT_MATERIAL_PATH for i in range(2))
    assert material_of(scene).diffuse_color == (0.0, 0.0, 1.0)
    warnings = [w for w in scene.warnings if "UsdPreviewSurface" in w]
    assert len(warnings) == 1
    assert "/Looks/ri_a" in warnings[0] and "/Looks/ri_b" in warnings[0]


# --- UsdUVTexture -------------------------------------------------------------------------

PNG_VALUES = np.array(
    [[[0, 64, 128], [255, 10, 200]],
     [[30, 90, 240], [5, 250, 100]]], dtype=np.uint8
)


def test_8bit_png_is_decoded_as_srgb_by_auto_and_kept_by_raw(tmp_path):
    png = write_image(tmp_path / "colour.png", PNG_VALUES, oiio.UINT8)
    stage = new_stage(tmp_path)
    bind(quad(stage, "/auto"), textured_material(stage, "/Looks/auto", "colour.png"))
    bind(quad(stage, "/raw", [(x, y + 2, z) for x, y, z in QUAD]),
         textured_material(stage, "/Looks/raw", "colour.png", sourceColorSpace="raw"))
    bind(quad(stage, "/srgb", [(x, y + 4, z) for x, y, z in QUAD]),
         textured_material(stage, "/Looks/srgb", "colour.png", sourceColorSpace="sRGB"))
    scene, _ = load(stage)
    by_mesh = {mesh.path: scene.materials[mesh.triangle_material[0]] for mesh in scene.meshes}
    auto, raw, srgb = (texture_input(by_mesh[p].diffuse_color, 3) for p in ("/auto", "/raw", "/srgb"))
    assert auto.channels == (0, 1, 2)
    assert auto.texture == srgb.texture != raw.texture  # one image per file + colour space
    assert len(scene.textures) == 2
    stored = PNG_VALUES.astype(np.float64) / 255.0
    image = scene.textures[auto.texture]
    assert image.path == png and image.pixels is None  # read by the tracer, at the levels it needs
    assert image.header.stored == "uint8" and image.color_space == "sRGB"
    pixels = decoded(image)
    assert pixels.shape == (2, 2, 3)  # the file's channels, no alpha added
    assert pixels.dtype == np.float32
    np.testing.assert_allclose(pixels, srgb_eotf(stored), atol=1e-6)
    np.testing.assert_allclose(decoded(scene.textures[raw.texture]), stored, atol=1e-6)
    # row 0 is the top row of the file
    np.testing.assert_allclose(decoded(scene.textures[raw.texture])[0, 1, 0], 1.0)


def test_the_next_frame_takes_the_texture_levels_of_the_last_unless_the_file_changed(tmp_path, monkeypatch):
    """A shot's frames read the same files: the tracer's texture cache keeps the last frame's
    levels (by file identity), in each colour space, and a rewritten file is read again."""
    reads = []
    monkeypatch.setattr(texture_cache, "read_level", lambda *args: reads.append(args) or read_level(*args))
    png = write_image(tmp_path / "colour.png", PNG_VALUES, oiio.UINT8)
    stage = new_stage(tmp_path)
    bind(quad(stage), textured_material(stage, "/Looks/auto", "colour.png"))
    first, _ = load(stage)
    texture_cache.resident_textures(first.textures)
    second, _ = load(stage)
    texture_cache.resident_textures(second.textures)
    assert len(reads) == 1
    bind(quad(stage, "/raw", [(x, y + 2, z) for x, y, z in QUAD]),
         textured_material(stage, "/Looks/raw", "colour.png", sourceColorSpace="raw"))
    both, _ = load(stage)  # the remembered sRGB levels, and the same file held for raw lookups
    resident = texture_cache.resident_textures(both.textures)
    assert len(reads) == 2
    np.testing.assert_allclose(resident.finest_linear(1)[:, :, :3], PNG_VALUES / 255.0, atol=1e-6)
    brighter = np.minimum(PNG_VALUES.astype(np.int64) + 5, 255).astype(np.uint8)
    write_image(png, brighter, oiio.UINT8)
    os.utime(png, ns=(0, 0))  # a new modification time even on a coarse clock
    changed, _ = load(stage)
    np.testing.assert_allclose(decoded(changed.textures[1])[:, :, :3], brighter / 255.0, atol=1e-6)


def test_srgb_decoding_leaves_alpha_alone(tmp_path):
    rgba = np.array([[[128, 128, 128, 128]]], dtype=np.uint8)
    # OIIO would un-premultiply on write without this hint
    write_image(tmp_path / "rgba.png", rgba, oiio.UINT8, **{"oiio:UnassociatedAlpha": 1})
    stage = new_stage(tmp_path)
    bind(quad(stage), textured_material(stage, "/Looks/m", "rgba.png", target="opacity",
                                        output="a", target_type=FLOAT))
    scene, _ = load(stage)
    opacity = texture_input(material_of(scene).opacity, 1)
    assert opacity.channels == (3,)
    pixels = decoded(scene.textures[opacity.texture])
    assert pixels[0, 0, 3] == pytest.approx(128 / 255, abs=1e-6)  # alpha as stored
    assert pixels[0, 0, 0] == pytest.approx(srgb_eotf(128 / 255), abs=1e-6)  # not premultiplied


def test_float_exr_is_raw_and_grey_images_expand_to_rgb(tmp_path):
    values = np.array([[[0.5, 2.0, -1.0]]], dtype=np.float32)
    write_image(tmp_path / "hdr.exr", values, oiio.FLOAT)
    grey = np.array([[[200]]], dtype=np.uint8)
    write_image(tmp_path / "grey.png", grey, oiio.UINT8)
    stage = new_stage(tmp_path)
    bind(quad(stage, "/hdr"), textured_material(stage, "/Looks/hdr", "hdr.exr"))
    bind(quad(stage, "/grey", [(x, y + 2, z) for x, y, z in QUAD]),
         textured_material(stage, "/Looks/grey", "grey.png"))
    scene, _ = load(stage)
    by_mesh = {mesh.path: scene.materials[mesh.triangle_material[0]] for mesh in scene.meshes}
    hdr = decoded(scene.textures[texture_input(by_mesh["/hdr"].diffuse_color, 3).texture])
    np.testing.assert_allclose(hdr[0, 0], [0.5, 2.0, -1.0])
    grey_pixels = decoded(scene.textures[texture_input(by_mesh["/grey"].diffuse_color, 3).texture])
    # one channel is not a colour image: auto keeps it raw, and stores it as one channel
    np.testing.assert_allclose(grey_pixels[0, 0], [200 / 255], atol=1e-6)
    table = MaterialTable(scene).arrays  # ... which lookups read as grey rgb, alpha 1
    grey_index = next(i for i, m in enumerate(scene.materials) if m.path == "/Looks/grey")
    np.testing.assert_allclose(inputs_at(table, grey_index, [[0.5, 0.5]])[0, :3], [200 / 255] * 3, atol=1e-6)


def test_scale_bias_channels_and_wrap_modes(tmp_path):
    write_image(tmp_path / "data.exr", np.ones((2, 2, 3), np.float32), oiio.FLOAT,
                wrapmodes="clamp,mirror")
    stage = new_stage(tmp_path)
    bind(quad(stage, "/explicit"), textured_material(
        stage, "/Looks/explicit", "data.exr", target="roughness", output="g",
        target_type=FLOAT, scale=(2, 3, 4, 5), bias=(0.1, 0.2, 0.3, 0.4),
        wrapS="mirror", wrapT="black"))
    bind(quad(stage, "/metadata", [(x, y + 2, z) for x, y, z in QUAD]), textured_material(
        stage, "/Looks/metadata", "data.exr", target="metallic", output="r",
        target_type=FLOAT))
    bind(quad(stage, "/grey_colour", [(x, y + 4, z) for x, y, z in QUAD]), textured_material(
        stage, "/Looks/grey_colour", "data.exr", output="b", target_type=FLOAT))
    scene, _ = load(stage)
    by_mesh = {mesh.path: scene.materials[mesh.triangle_material[0]] for mesh in scene.meshes}
    explicit = texture_input(by_mesh["/explicit"].roughness, 1)
    assert explicit.channels == (1,)
    assert explicit.scale == (2, 3, 4, 5) and explicit.bias == pytest.approx((0.1, 0.2, 0.3, 0.4))
    assert (explicit.wrap_s, explicit.wrap_t) == ("mirror", "black")
    from_file = texture_input(by_mesh["/metadata"].metallic, 1)
    assert from_file.channels == (0,)
    assert (from_file.wrap_s, from_file.wrap_t) == ("clamp", "mirror")  # useMetadata
    assert texture_input(by_mesh["/grey_colour"].diffuse_color, 3).channels == (2, 2, 2)


def test_useMetadata_without_metadata_repeats(tmp_path):
    write_image(tmp_path / "plain.png", PNG_VALUES, oiio.UINT8)
    stage = new_stage(tmp_path)
    bind(quad(stage), textured_material(stage, "/Looks/m", "plain.png"))
    diffuse = texture_input(material_of(load(stage)[0]).diffuse_color, 3)
    assert (diffuse.wrap_s, diffuse.wrap_t) == ("repeat", "repeat")


def test_uvs_come_from_the_primvar_the_material_reads(tmp_path):
    write_image(tmp_path / "t.png", PNG_VALUES, oiio.UINT8)
    stage = new_stage(tmp_path)
    mesh = quad(stage)
    primvars = UsdGeom.PrimvarsAPI(mesh)
    primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                           UsdGeom.Tokens.vertex).Set([(0, 0)] * 4)
    primvars.CreatePrimvar("uvmap", Sdf.ValueTypeNames.TexCoord2fArray,
                           UsdGeom.Tokens.vertex).Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    bind(mesh, textured_material(stage, "/Looks/m", "t.png", varname="uvmap"))
    scene, _ = load(stage)
    np.testing.assert_allclose(scene.meshes[0].uvs[0], [(0, 0), (1, 0), (1, 1)])


def test_missing_texture_warns_once_and_uses_the_fallback(tmp_path):
    stage = new_stage(tmp_path)
    for index, name in enumerate(("a", "b")):
        bind(quad(stage, f"/{name}", [(x, y + 2 * index, z) for x, y, z in QUAD]),
             textured_material(stage, f"/Looks/{name}", "maps/missing.png",
                               fallback=(1.0, 0.5, 0.25, 1.0), scale=(2, 2, 2, 1)))
    scene, _ = load(stage)
    assert material_of(scene).diffuse_color == pytest.approx((2.0, 1.0, 0.5))
    assert scene.textures == ()
    missing = [w for w in scene.warnings if "missing.png" in w]
    assert len(missing) == 1
    assert str(tmp_path / "maps" / "missing.png") in missing[0] and "/Looks/" in missing[0]


def test_unreadable_texture_warns_and_uses_the_default_fallback(tmp_path):
    (tmp_path / "broken.png").write_bytes(b"this is not a png")
    stage = new_stage(tmp_path)
    bind(quad(stage), textured_material(stage, "/Looks/m", "broken.png"))
    scene, _ = load(stage)
    assert material_of(scene).diffuse_color == (0.0, 0.0, 0.0)  # fallback (0, 0, 0, 1)
    assert any("broken.png" in w and "/Looks/m/Texture" in w for w in scene.warnings)


def test_display_color_inherits_from_ancestors_and_dangling_bindings_warn(tmp_path):
    stage = new_stage(tmp_path)
    model = UsdGeom.Xform.Define(stage, "/Model")
    UsdGeom.PrimvarsAPI(model).CreatePrimvar(
        "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant
    ).Set([(0, 1, 0)])
    mesh = quad(stage, "/Model/body")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).GetDirectBindingRel().SetTargets(
        ["/Looks/missing"]
    )
    scene, _ = load(stage)
    assert material_of(scene).diffuse_color == (0.0, 1.0, 0.0)
    assert any("/Model/body -> /Looks/missing" in w for w in scene.warnings)
