"""UsdRender's pixelAspectRatio end to end: a product's own (else its settings') reaches the
camera projection (a pixel is pixelAspectRatio times as wide as it is tall) and the
``pixelAspectRatio`` of every part of every EXR; products of one render must agree; bad
values are refused naming the prim; and the UsdRender attributes pxr-layers cannot honour
(dataWindowNDC, renderingColorSpace, productType) say so instead of being ignored."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest
from pxr import Usd

from pxr_layers.cli.main import main
from pxr_layers.errors import RecipeError, RenderSettingsError
from pxr_layers.layers.exr import header
from pxr_layers.layers.nuke import nuke_script
from pxr_layers.recipe.model import CONFORM_POLICIES, Layer, Product, Recipe
from pxr_layers.scene import Camera, RenderSpec
from pxr_layers.stage import load_recipe, load_stage
from pxr_layers.stage.recipe_writer import write_recipe
from pxr_layers.trace.camera import ThinLensCamera

FAST = ["--spp", "4", "--max-depth", "1", "--quiet", "--no-previews", "--no-index"]
VARS = {"color": "color3f", "depth": "float"}
"""The raw vars of every product of :func:`shot` (name = sourceName → dataType): two parts."""


def shot(settings: str = "", products: dict[str, str] | None = None, camera: str = "") -> str:
    """USD text: a camera 5 m from a ball of radius 0.5 under a distant light, and
    /Render/Settings (``settings``: its extra attributes) with one RenderProduct per entry of
    ``products`` (name → its extra attributes), each holding the beauty and a depth var."""
    products = {"shot": ""} if products is None else products
    targets = ", ".join(f"</Render/{name}>" for name in products)
    product_prims = "".join(f"""
    def RenderProduct "{name}"
    {{
        token productName = "{name}.exr"
        rel orderedVars = [{", ".join(f"</Render/Vars/{var}>" for var in VARS)}]
        {body}
    }}""" for name, body in products.items())
    var_prims = "".join(f"""
        def RenderVar "{name}"
        {{
            uniform token dataType = "{data_type}"
            uniform string sourceName = "{name}"
            uniform token sourceType = "raw"
        }}""" for name, data_type in VARS.items())
    return f"""#usda 1.0
(
    renderSettingsPrimPath = "/Render/Settings"
)
def Xform "World"
{{
    def Camera "cam"
    {{
        {camera}
        double3 xformOp:translate = (0, 0, 5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
    def Sphere "ball"
    {{
        double radius = 0.5
    }}
    def DistantLight "sun"
    {{
    }}
}}
def Scope "Render"
{{
    def RenderSettings "Settings"
    {{
        rel camera = </World/cam>
        rel products = [{targets}]
        {settings}
    }}
    {product_prims}
    def Scope "Vars"
    {{{var_prims}
    }}
}}
"""


def write_shot(tmp_path, text: str, name: str = "shot.usda"):
    path = tmp_path / name
    path.write_text(text)
    return path


def render(tmp_path, text: str, out: str = "out", *flags: str) -> tuple[int, object]:
    """`pxr-layers render` of the stage ``text`` (its products' resolution): (exit code, folder)."""
    folder = tmp_path / out
    code = main(["render", str(write_shot(tmp_path, text, f"{out}.usda")), "-o", str(folder), *FAST, *flags])
    return code, folder


def coverage(path) -> np.ndarray:
    """(h, w) float32: the beauty's alpha (what the ball covers of each pixel)."""
    return OpenEXR.File(str(path)).parts[0].channels["RGBA"].pixels[..., 3]


def extent(mask: np.ndarray) -> tuple[int, int]:
    """(columns, rows) in which the ball covers at least half of some pixel."""
    covered = mask >= 0.5
    return int(covered.any(axis=0).sum()), int(covered.any(axis=1).sum())


def pixel_aspects(path) -> list[float]:
    """Every part's PixelAspectRatio as OpenImageIO reads it."""
    image = oiio.ImageInput.open(str(path))
    assert image, oiio.geterror()
    found = []
    try:
        subimage = 0
        while image.seek_subimage(subimage, 0):
            found.append(image.spec().getattribute("PixelAspectRatio"))
            subimage += 1
    finally:
        image.close()
    return found


def test_two_to_one_pixels_render_the_view_of_twice_the_width_and_say_so_in_every_part(tmp_path):
    code, wide = render(tmp_path, shot(products={"shot": "uniform int2 resolution = (64, 32)"}), "square")
    assert code == 0
    code, squeezed = render(tmp_path, shot(products={"shot": """uniform int2 resolution = (32, 32)
        uniform float pixelAspectRatio = 2"""}), "anamorphic")
    assert code == 0
    square_mask, anamorphic_mask = coverage(wide / "shot.exr"), coverage(squeezed / "shot.exr")
    # Same view (image aspect 64·1/32 = 32·2/32): the ball spans the same rows, and half the
    # columns, each twice as wide; its area in pixels halves (tolerance: 4 spp at the edges).
    (square_columns, square_rows), (columns, rows) = extent(square_mask), extent(anamorphic_mask)
    assert square_columns == pytest.approx(square_rows, abs=1)  # round in square pixels
    assert rows == square_rows and columns == pytest.approx(square_columns / 2, abs=1)
    assert rows == pytest.approx(2 * columns, abs=2)
    assert anamorphic_mask.sum() == pytest.approx(square_mask.sum() / 2, rel=0.05)
    assert pixel_aspects(squeezed / "shot.exr") == [2.0, 2.0]  # rgba and depth
    assert pixel_aspects(wide / "shot.exr") == [1.0, 1.0]


def test_layers_cut_from_the_index_keep_the_renders_pixel_aspect(tmp_path):
    """The index's manifest says the pixel aspect it was rendered at: `extract` writes it, so
    the layers line up with the render's beauty in a compositor."""
    stage = write_shot(tmp_path, shot(products={"shot": """uniform int2 resolution = (16, 16)
        uniform float pixelAspectRatio = 2"""}))
    out = tmp_path / "out"
    flags = [flag for flag in FAST if flag != "--no-index"]
    assert main(["render", str(stage), "-o", str(out), *flags]) == 0
    cut = tmp_path / "cut.exr"
    assert main(["extract", str(out / "shot.pxlidx"), "--layer", "all=C.*", "-o", str(cut), "--quiet",
                 "--no-previews"]) == 0
    assert pixel_aspects(cut) == [2.0, 2.0]


def test_the_products_value_wins_over_the_settings_and_every_product_carries_it(tmp_path):
    text = shot("uniform float pixelAspectRatio = 1\n        uniform int2 resolution = (16, 8)",
                {"a": "uniform float pixelAspectRatio = 2", "b": "uniform float pixelAspectRatio = 2"})
    code, out = render(tmp_path, text)
    assert code == 0
    for name in ("a", "b"):
        assert pixel_aspects(out / f"{name}.exr") == [2.0, 2.0]
    recipe = load_recipe(write_shot(tmp_path, text), check_colour=False)
    assert [product.pixel_aspect_ratio for product in recipe.products] == [2.0, 2.0]
    _, spec = load_stage(tmp_path / "shot.usda")
    assert spec.pixel_aspect_ratio == 2.0


def test_settings_value_reaches_products_that_author_none(tmp_path):
    recipe = load_recipe(write_shot(tmp_path, shot("uniform float pixelAspectRatio = 1.5")), check_colour=False)
    assert recipe.product().pixel_aspect_ratio == 1.5
    assert recipe.shared_view().pixel_aspect_ratio == 1.5


def test_products_of_one_render_must_agree(tmp_path, capsys):
    text = shot("uniform int2 resolution = (16, 8)", {"a": "uniform float pixelAspectRatio = 2", "b": ""})
    code, out = render(tmp_path, text)
    assert code == 1 and not out.exists()
    error = capsys.readouterr().err
    assert "different cameras, resolutions, pixel aspect ratios" in error and "pixel aspect 2" in error
    assert "/Render/a" in error and "/Render/b" in error


@pytest.mark.parametrize("value", ["0", "-2", "nan", "inf"])
def test_a_pixel_aspect_that_is_not_a_positive_number_is_refused_naming_the_prim(tmp_path, value):
    with pytest.raises(RecipeError) as caught:
        load_recipe(write_shot(tmp_path, shot(products={"shot": f"uniform float pixelAspectRatio = {value}"})),
                    check_colour=False)
    assert (caught.value.prim, caught.value.attribute) == ("/Render/shot", "pixelAspectRatio")
    assert "must be a positive number" in str(caught.value)
    with pytest.raises(RecipeError) as caught:  # on the settings: the settings are named
        load_recipe(write_shot(tmp_path, shot(f"uniform float pixelAspectRatio = {value}")), check_colour=False)
    assert (caught.value.prim, caught.value.attribute) == ("/Render/Settings", "pixelAspectRatio")


def test_cli_names_the_prim_of_a_bad_pixel_aspect(tmp_path, capsys):
    code, _ = render(tmp_path, shot(products={"shot": "uniform float pixelAspectRatio = 0"}))
    assert code == 1
    assert "/Render/shot.pixelAspectRatio: is 0" in capsys.readouterr().err


def test_an_unknown_conform_policy_is_refused(tmp_path):
    with pytest.raises(RecipeError) as caught:
        load_recipe(write_shot(tmp_path, shot('uniform token aspectRatioConformPolicy = "stretch"')),
                    check_colour=False)
    assert (caught.value.prim, caught.value.attribute) == ("/Render/Settings", "aspectRatioConformPolicy")


def test_the_products_conform_policy_wins_over_the_settings(tmp_path):
    text = shot('uniform token aspectRatioConformPolicy = "cropAperture"',
                {"shot": 'uniform token aspectRatioConformPolicy = "adjustApertureHeight"'})
    _, spec = load_stage(write_shot(tmp_path, text))
    assert spec.aspect_ratio_conform_policy == "adjustApertureHeight"


def test_adjust_pixel_aspect_ratio_resolves_to_the_pixels_that_cover_the_aperture(tmp_path):
    text = shot('uniform int2 resolution = (16, 16)\n        uniform token aspectRatioConformPolicy = '
                '"adjustPixelAspectRatio"\n        uniform float pixelAspectRatio = 7',
                camera="float horizontalAperture = 20\n        float verticalAperture = 10")
    _, spec = load_stage(write_shot(tmp_path, text))
    assert spec.pixel_aspect_ratio == 2.0  # aperture 2:1 on a square image: the authored 7 is disregarded
    pinhole = ThinLensCamera.from_spec(spec)  # both apertures kept
    assert pinhole.half_width / pinhole.half_height == pytest.approx(2.0)


def test_camera_refuses_a_spec_it_cannot_project():
    camera = Camera("cam", "/cam", np.eye(4))
    for spec in (RenderSpec(camera, pixel_aspect_ratio=0.0), RenderSpec(camera, pixel_aspect_ratio=math.nan),
                 RenderSpec(camera, aspect_ratio_conform_policy="stretch")):
        with pytest.raises(RenderSettingsError):
            ThinLensCamera.from_spec(spec)


def test_the_camera_window_is_the_image_aspect_of_non_square_pixels():
    camera = Camera("cam", "/cam", np.eye(4), horizontal_aperture=36.0, vertical_aperture=24.0)
    for policy in ("expandAperture", "cropAperture", "adjustApertureWidth", "adjustApertureHeight"):
        pinhole = ThinLensCamera.from_spec(RenderSpec(camera, resolution=(30, 20), pixel_aspect_ratio=2.0,
                                                     aspect_ratio_conform_policy=policy))
        assert pinhole.half_width / pinhole.half_height == pytest.approx(30 * 2.0 / 20), policy


def test_product_validates_in_code_and_square_recipes_keep_their_json():
    product = Product("p", "p.exr", "/cam", (8, 8), (Layer("color", "raw", "color"),))
    assert "pixel_aspect_ratio" not in Recipe((product,)).to_json()  # pxrLayers/recipe unchanged for par 1
    anamorphic = Recipe((dataclasses.replace(product, pixel_aspect_ratio=2.0),))
    assert Recipe.from_json(anamorphic.to_json()) == anamorphic
    with pytest.raises(RecipeError, match="positive number"):
        dataclasses.replace(product, pixel_aspect_ratio=-1.0)
    with pytest.raises(RecipeError, match="unknown policy"):
        dataclasses.replace(product, aspect_ratio_conform_policy="stretch")


def test_square_pixels_write_the_bytes_openexr_writes_by_default(tmp_path):
    pixels = {"RGBA": np.zeros((2, 3, 4), np.float32)}
    explicit = header()
    assert explicit["pixelAspectRatio"] == 1.0
    implicit = {key: value for key, value in explicit.items() if key != "pixelAspectRatio"}
    OpenEXR.File(explicit, pixels).write(str(tmp_path / "explicit.exr"))
    OpenEXR.File(implicit, pixels).write(str(tmp_path / "implicit.exr"))
    assert (tmp_path / "explicit.exr").read_bytes() == (tmp_path / "implicit.exr").read_bytes()


def test_conform_policies_are_usd_renders():
    definition = Usd.SchemaRegistry().FindConcretePrimDefinition("RenderSettings")
    allowed = definition.GetAttributeDefinition("aspectRatioConformPolicy").GetMetadata("allowedTokens")
    assert set(CONFORM_POLICIES) == {str(token) for token in allowed}


def test_the_recipe_writer_keeps_the_pixel_aspect(tmp_path):
    write_shot(tmp_path, shot())
    product = Product("look", "look.exr", "/World/cam", (16, 8), (Layer("color", "raw", "color"),),
                      pixel_aspect_ratio=2.0, aspect_ratio_conform_policy="cropAperture")
    written = write_recipe(tmp_path / "look.usda", Recipe((product,)))
    back = load_recipe(tmp_path / "shot.usda", recipe_layers=[written], check_colour=False).product()
    assert (back.pixel_aspect_ratio, back.aspect_ratio_conform_policy) == (2.0, "cropAperture")


def test_nuke_scripts_declare_the_pixel_aspect(tmp_path, capsys):
    code, out = render(tmp_path, shot(products={"shot": """uniform int2 resolution = (16, 8)
        uniform float pixelAspectRatio = 2"""}))
    assert code == 0
    assert main(["nuke", str(out / "shot.exr")]) == 0
    script = (out / "shot.nk").read_text()
    assert '"16 8 0 0 16 8 2 pxrLayers_16x8_par2"' in script and '"16 8 0 0 16 8 2 "' in script
    square = nuke_script("a.exr", [], {}, resolution=(16, 8), partition=True)
    assert '"16 8 0 0 16 8 1 pxrLayers_16x8"' in square


def test_unsupported_usdrender_attributes_say_so(tmp_path, caplog):
    text = shot("uniform float4 dataWindowNDC = (0.25, 0, 1, 1)\n"
                '        uniform token renderingColorSpace = "lin_ap1_scene"')
    with caplog.at_level(logging.WARNING, logger="pxr_layers"):
        load_recipe(write_shot(tmp_path, text), check_colour=False)
    said = caplog.text
    assert "/Render/Settings.dataWindowNDC is (0.25, 0, 1, 1): dataWindowNDC is not supported; rendering the full " \
           "frame" in said
    assert "renderingColorSpace is 'lin_ap1_scene': not supported" in said
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pxr_layers"):
        load_recipe(write_shot(tmp_path, shot('uniform token renderingColorSpace = "lin_rec709_scene"')),
                    check_colour=False)
    assert not caplog.text
    with pytest.raises(RecipeError) as caught:
        load_recipe(write_shot(tmp_path, shot(products={"shot": 'uniform token productType = "deepRaster"'})),
                    check_colour=False)
    assert (caught.value.prim, caught.value.attribute) == ("/Render/shot", "productType")
