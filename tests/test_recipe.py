"""Layer recipes: USD → frozen Recipe dataclasses, presets, per-light layers, and every error."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import pytest

from pxr_layers import lpe
from pxr_layers.errors import PxrLayersError, RecipeError, StageError
from pxr_layers.recipe import (
    BEAUTY_PART,
    DEFAULT_OCIO_CONFIG,
    PRESETS,
    IndexSettings,
    Layer,
    Product,
    Recipe,
    per_light_layers,
    preset,
)

from pxr_layers.stage import load_recipe  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHOWCASE = ROOT / "render" / "showcase.usda"
CORNELL = ROOT / "render" / "cornell.usda"


# --- a small shot with its recipe, written as USDA --------------------------------------


def var(name: str, source: str = "C.*", source_type: str = "lpe", data_type: str = "color3f",
        extra: str = "", api: bool = True) -> str:
    schemas = 'prepend apiSchemas = ["PxrLayersVarAPI"]' if api else ""
    return f"""
        def RenderVar "{name}" ({schemas})
        {{
            uniform token dataType = "{data_type}"
            uniform string sourceName = "{source}"
            uniform token sourceType = "{source_type}"
            {extra}
        }}"""


def shot(tmp_path: Path, vars_: list[str] | None = None, *, ordered: list[str] | None = None,
         product_extra: str = "", settings_extra: str = "rel camera = </World/cam>",
         metadata: str = 'renderSettingsPrimPath = "/Render/Settings"', lights: str = "",
         scopes: str = "", name: str = "shot.usda") -> Path:
    """A shot with a camera, lights, and /Render/Settings → product → vars (default: 2 layers)."""
    vars_ = vars_ if vars_ is not None else [var("diffuse", "C<RD>.*"), var("glossy", "C<RG>.*")]
    names = ordered if ordered is not None else [_name(v) for v in vars_]
    targets = ", ".join(f"<{n}>" if n.startswith("/") else f"</Render/Vars/{n}>" for n in names)
    text = f"""#usda 1.0
(
    {metadata}
)

def Xform "World"
{{
    def Camera "cam" {{}}
    def Xform "notACamera" {{}}
    def Scope "Lights"
    {{
        def RectLight "key" {{}}
        def SphereLight "fill" {{}}
        {lights}
    }}
}}

def Scope "Render"
{{
    def RenderSettings "Settings"
    {{
        {settings_extra}
        uniform int2 resolution = (64, 32)
        rel products = </Render/product>
    }}

    def RenderProduct "product" (prepend apiSchemas = ["PxrLayersProductAPI"])
    {{
        token productName = "shot.####.exr"
        rel orderedVars = [{targets}]
        {product_extra}
    }}

    def Scope "Vars"
    {{{"".join(vars_)}
    }}
    {scopes}
}}
"""
    path = tmp_path / name
    path.write_text(text)
    return path


def _name(var_text: str) -> str:
    return var_text.split('def RenderVar "', 1)[1].split('"', 1)[0]


# --- reading --------------------------------------------------------------------------


def test_a_recipe_in_the_shot_resolves_to_frozen_dataclasses(tmp_path):
    recipe = load_recipe(shot(tmp_path))
    assert recipe.settings_path == "/Render/Settings"
    assert recipe.file == str(tmp_path / "shot.usda")
    (product,) = recipe.products
    assert product.name == "product" and product.prim_path == "/Render/product"
    assert product.camera == "/World/cam"
    assert product.resolution == (64, 32)
    assert product.layer_names == ("diffuse", "glossy")
    assert product.expressions() == {"diffuse": "C<RD>.*", "glossy": "C<RG>.*"}
    diffuse = product.layer("diffuse")
    assert diffuse == Layer("diffuse", "lpe", "C<RD>.*", prim_path="/Render/Vars/diffuse")
    assert diffuse.channels == ("R", "G", "B") and not diffuse.is_data
    # schema fallbacks
    assert (product.pixel_type, product.compression, product.contact_sheet) == ("float", "zip", True)
    assert product.index == IndexSettings(5, "norms")
    assert product.ocio_config == DEFAULT_OCIO_CONFIG
    assert (product.display, product.view) == ("sRGB - Display", "ACES 1.0 - SDR Video")
    with pytest.raises(dataclasses.FrozenInstanceError):
        product.name = "other"


def test_authored_attributes_and_product_defaults_for_vars(tmp_path):
    vars_ = [
        var("key", "C.*<L.'key'>", extra="""
            uniform token pxrLayers:pixelType = "float"
            uniform token pxrLayers:compression = "piz"
            uniform bool pxrLayers:preview = 0
            uniform float pxrLayers:preview:exposure = -1.5
            uniform color3f pxrLayers:preview:tint = (1, 0.85, 0.7)
            uniform string pxrLayers:group = "lights"
        """),
        var("rest", "lpe:C.*[OB]"),
        var("depth", "depth", "raw", "float"),
    ]
    product_extra = """
        uniform token pxrLayers:pixelType = "half"
        uniform token pxrLayers:compression = "dwab"
        uniform int pxrLayers:index:bounces = 3
        uniform token pxrLayers:index:covariance = "sigma"
        uniform bool pxrLayers:contactSheet = 0
        uniform string pxrLayers:ocio:view = "Un-tone-mapped"
    """
    product = load_recipe(shot(tmp_path, vars_, product_extra=product_extra)).product()
    key, rest, depth = product.layers
    assert (key.pixel_type, key.compression, key.preview, key.exposure, key.tint, key.group) == (
        "float", "piz", False, -1.5, (1.0, 0.85, 0.7), "lights")
    # not authored on the var: the product's
    assert (rest.pixel_type, rest.compression) == ("half", "dwab")
    assert rest.source_name == "C.*[OB]"  # the lpe: prefix is dropped
    assert (product.pixel_type, product.compression) == ("half", "dwab")
    assert product.index == IndexSettings(3, "sigma")
    assert product.contact_sheet is False and product.view == "Un-tone-mapped"
    # a data layer never inherits half or a lossy compression
    assert depth.is_data and depth.channels == ("Z",)
    assert (depth.pixel_type, depth.compression) == ("float", "zip")


def test_a_data_layer_inherits_only_exact_product_defaults_but_refuses_authored_lossy_ones(tmp_path):
    product_extra = 'uniform token pxrLayers:compression = "piz"\n        uniform token pxrLayers:pixelType = "half"'
    depth = load_recipe(shot(tmp_path, [var("depth", "depth", "raw", "float")], product_extra=product_extra)).product().layer("depth")
    assert (depth.pixel_type, depth.compression) == ("float", "piz")
    path = shot(tmp_path, [var("depth", "depth", "raw", "float", extra='uniform token pxrLayers:compression = "dwaa"')])
    with pytest.raises(RecipeError, match=r"/Render/Vars/depth\.pxrLayers:compression: dwaa is lossy"):
        load_recipe(path)


def test_recipe_in_its_own_layer_sublayered_into_the_shot(tmp_path):
    recipe_layer = shot(tmp_path, name="recipe.usda", metadata="")
    shot_path = tmp_path / "shot_with_sublayer.usda"
    shot_path.write_text('#usda 1.0\n(\n    renderSettingsPrimPath = "/Render/Settings"\n'
                         '    subLayers = [@./recipe.usda@]\n)\n')
    recipe = load_recipe(shot_path)
    assert recipe.product().layer_names == ("diffuse", "glossy")
    assert recipe.file == str(shot_path) and recipe_layer.exists()


def test_recipe_in_its_own_layer_referenced_into_the_shot(tmp_path):
    # A reference maps only the paths under its root: the shot adds the camera.
    shot(tmp_path, name="recipe.usda", metadata="", settings_extra="")
    shot_path = tmp_path / "shot_with_reference.usda"
    shot_path.write_text("""#usda 1.0
(
    renderSettingsPrimPath = "/Render/Settings"
)
def Xform "World"
{
    def Camera "shotCam" {}
}
def Scope "Render" (references = @./recipe.usda@</Render>)
{
    over "Settings"
    {
        rel camera = </World/shotCam>
    }
}
""")
    product = load_recipe(shot_path).product()
    assert product.camera == "/World/shotCam"
    assert [layer.prim_path for layer in product.layers] == ["/Render/Vars/diffuse", "/Render/Vars/glossy"]


def test_light_passes_preset_over_a_shot_takes_the_shots_camera_and_resolution():
    recipe = load_recipe(SHOWCASE, recipe_layers=[preset("light_passes")])
    assert recipe.settings_path == "/Render/LightPasses/Settings"
    product = recipe.product()
    assert product.camera == "/World/Camera" and product.resolution == (256, 256)
    assert product.expressions() == lpe.STANDARD_PASSES
    assert all(layer.group == "passes" for layer in product.layers)


def test_light_passes_preset_works_on_the_cornell_box_too():
    recipe = load_recipe(CORNELL, "/Render/LightPasses/WithData", recipe_layers=[preset("light_passes")])
    passes, data = recipe.products
    assert passes.expressions() == lpe.STANDARD_PASSES
    assert [(layer.name, layer.source_type, layer.channels) for layer in data.layers] == [
        ("depth", "raw", ("Z",)), ("normal", "raw", ("X", "Y", "Z")),
        ("primId", "raw", ("id",)), ("instanceId", "raw", ("id",)),
    ]
    assert all(layer.is_data and layer.pixel_type == "float" and not layer.preview for layer in data.layers)
    assert data.contact_sheet is False


def test_showcase_preset_writes_the_papers_selections_in_its_notation():
    recipe = load_recipe(SHOWCASE, recipe_layers=[preset("showcase")])
    selections, lights = recipe.products
    assert selections.index.bounces == 8
    canonical = {layer.name: lpe.compile(layer.source_name).canonical for layer in selections.layers}
    assert canonical == {
        "texture_high": "C.*R@(|S_T| > 4.5)[LOB]",
        "texture_low": "C.*R@(|S_T| > 0 and |S_T| <= 4.5)[LOB]",
        "glossy_last": "C.*R@(|S_R| > 2)[LOB]",
        "flat": "CR@(|S_C| = 0).*",
        "curved": "CR@(|S_C| > 0).*",
    }
    # the panel halves: |S_T| = f sqrt(a / (1 + a)), a = 0.6 → 3.06 and 6.12 cycles/m
    high, low = (lpe.compile(selections.layer(n).source_name) for n in ("texture_high", "texture_low"))
    assert high.matches("C RD'texturedPanel'{C=0,T=6.12,R=0} L'key'")
    assert not high.matches("C RD'texturedPanel'{C=0,T=3.06,R=0} L'key'")
    assert low.matches("C RD'texturedPanel'{C=0,T=3.06,R=0} L'key'")
    assert lights.layer_names == ("light_key", "light_fill", "light_sky", "light_other")


def test_every_preset_resolves():
    for name in PRESETS:
        assert load_recipe(SHOWCASE, recipe_layers=[preset(name)]).products
    with pytest.raises(RecipeError, match="unknown recipe preset 'nope'"):
        preset("nope")


# --- per-light layers -----------------------------------------------------------------


def test_per_light_layers_from_names():
    layers = per_light_layers(["key", "fill"])
    assert [(layer.name, layer.source_name) for layer in layers] == [
        ("light_key", "C.*<L.'key'>"),
        ("light_fill", "C.*<L.'fill'>"),
        ("light_other", "C.*<L.[^'key''fill']>|C.*[OB]"),
    ]
    assert all(layer.group == "lights" for layer in layers)
    assert per_light_layers([])[0].source_name == "C.*[LOB]"


def test_per_light_layers_from_groups_and_fields():
    layers = per_light_layers({"rim": ["/World/rimA", "/World/rimB"], "key": ["key"]}, pixel_type="half")
    assert [(layer.name, layer.source_name) for layer in layers][:2] == [
        ("light_rim", "C.*<L.['/World/rimA''/World/rimB']>"),
        ("light_key", "C.*<L.'key'>"),
    ]
    assert all(layer.pixel_type == "half" for layer in layers)
    with pytest.raises(RecipeError, match="would both make layer 'light_key'"):
        per_light_layers(["/a/key", "/b/key"])


def test_per_light_layers_partition_the_paths_that_end_at_an_emitter():
    layers = per_light_layers({"warm": ["key", "fill"], "sky": ["sky"]})
    compiled = {layer.name: lpe.compile(layer.source_name) for layer in layers}
    paths = ["C L'key'", "C RD'floor' L'fill'", "C RD'floor' RG'box' L'sky'", "C RD'wall' L'other'",
             "C O'lamp'", "C RD'floor' B", "C B"]
    for path in paths:
        assert sum(expression.matches(path) for expression in compiled.values()) == 1, path


def test_per_light_attribute_on_the_product(tmp_path):
    recipe = load_recipe(shot(tmp_path, product_extra='uniform token pxrLayers:perLight = "lights"'))
    product = recipe.product()
    assert product.per_light == "lights"
    assert product.layer_names == ("diffuse", "glossy", "light_key", "light_fill", "light_other")


def test_per_light_by_group_and_the_cli_override(tmp_path):
    lights = """
        def DiskLight "rimA" (prepend apiSchemas = ["PxrLayersLightAPI"])
        {
            uniform string pxrLayers:lightGroup = "rim"
        }
        def DiskLight "rimB" (prepend apiSchemas = ["PxrLayersLightAPI"])
        {
            uniform string pxrLayers:lightGroup = "rim"
        }
        def DiskLight "hidden"
        {
            token visibility = "invisible"
        }
    """
    path = shot(tmp_path, lights=lights)
    grouped = load_recipe(path, per_light="groups").product()
    assert grouped.per_light == "groups"
    assert grouped.layer("light_rim").source_name == "C.*<L.['rimA''rimB']>"
    assert grouped.layer_names[2:] == ("light_key", "light_fill", "light_rim", "light_other")
    each = load_recipe(path, per_light="lights").product()
    assert each.layer_names[2:] == ("light_key", "light_fill", "light_rimA", "light_rimB", "light_other")
    assert load_recipe(path, per_light="none").product().layer_names == ("diffuse", "glossy")


def test_per_light_layer_colliding_with_a_var_is_a_duplicate(tmp_path):
    path = shot(tmp_path, [var("light_key", "C.*<L.'key'>")], product_extra='uniform token pxrLayers:perLight = "lights"')
    with pytest.raises(RecipeError, match=r"/Render/product\.orderedVars: duplicate layer name 'light_key'"):
        load_recipe(path)


# --- the dataclasses ------------------------------------------------------------------


def test_recipe_json_and_helpers():
    product = Product("beauty", "shot.####.exr", "/cam", (4, 2), (Layer("diffuse", "lpe", "C<RD>.*"),))
    recipe = Recipe((product,))
    data = json.loads(recipe.to_json())
    assert data["products"][0]["layers"][0]["source_name"] == "C<RD>.*"
    assert recipe.to_json() == Recipe((product,)).to_json()
    assert product.output_path(12, "out") == Path("out/shot.0012.exr")
    assert product.output_path() == Path("shot.####.exr")
    more = recipe.with_layers(per_light_layers(["key"]))
    assert more.product().layer_names == ("diffuse", "light_key", "light_other")
    with pytest.raises(RecipeError, match="duplicate layer name 'diffuse'"):
        recipe.with_layers([Layer("diffuse")])


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"name": "rgba"}, "reserved for the beauty"),
        ({"name": "a.b"}, "not an identifier"),
        ({"source_type": "primvar"}, "unknown source type"),
        ({"pixel_type": "double"}, "unknown pixel type"),
        ({"source_type": "raw", "source_name": "depth", "data_type": "float", "pixel_type": "half"}, "data layers stay float"),
        ({"source_type": "lpe", "data_type": "float"}, "an lpe layer is a colour"),
        ({"tint": (1, -1, 1)}, "three finite values"),
    ],
)
def test_layer_construction_validates(fields, message):
    with pytest.raises(RecipeError, match=message):
        Layer(**{"name": "layer", **fields})


# --- every bad recipe gives its error -------------------------------------------------


BAD_RECIPES = {
    "unknown source type": (
        {"vars_": [var("x", "C.*", source_type="fancy")]},
        r"/Render/Vars/x\.sourceType: unknown source type 'fancy'",
    ),
    "unsupported source type": (
        {"vars_": [var("x", "st", source_type="primvar")]},
        r"/Render/Vars/x\.sourceType: source type 'primvar' is not rendered",
    ),
    "bad expression": (
        {"vars_": [var("x", "C<RD.*")]},
        r"/Render/Vars/x\.sourceName: bad Light Path Expression: .*\n  C<RD\.\*\n +\^",
    ),
    "duplicate layer names": (
        {"vars_": [var("x")], "ordered": ["x", "/Render/Other/x"], "scopes": 'def Scope "Other"\n    {' + var("x") + "\n    }"},
        r"/Render/product\.orderedVars: duplicate layer name 'x': /Render/Vars/x and /Render/Other/x",
    ),
    "product with no vars": (
        {"vars_": [], "ordered": []},
        r"/Render/product\.orderedVars: the product has no layers",
    ),
    "camera that does not exist": (
        {"settings_extra": "rel camera = </World/nope>"},
        r"/Render/Settings\.camera: camera /World/nope does not exist",
    ),
    "camera that is not a camera": (
        {"settings_extra": "rel camera = </World/notACamera>"},
        r"/Render/Settings\.camera: camera /World/notACamera is a Xform, not a Camera",
    ),
    "unknown token": (
        {"vars_": [var("x", extra='uniform token pxrLayers:pixelType = "double"')]},
        r"/Render/Vars/x\.pxrLayers:pixelType: unknown value 'double' \(allowed: float, half\)",
    ),
    "half data layer": (
        {"vars_": [var("n", "normal", "raw", "normal3f", extra='uniform token pxrLayers:pixelType = "half"')]},
        r"/Render/Vars/n\.pxrLayers:pixelType: half on a data layer",
    ),
    "misspelt attribute": (
        {"vars_": [var("x", extra='uniform token pxrLayers:compresion = "zip"')]},
        r"/Render/Vars/x\.pxrLayers:compresion: unknown attribute .*did you mean pxrLayers:compression",
    ),
    "lpe with a non-colour dataType": (
        {"vars_": [var("x", data_type="float")]},
        r"/Render/Vars/x\.dataType: an lpe layer is a colour",
    ),
    "sigma condition with norms": (
        {"vars_": [var("x", "C<RD>S(S11 >> S22).*")]},
        r"/Render/Vars/x\.sourceName: .* needs pxrLayers:index:covariance = \"sigma\"",
    ),
    "condition without covariance": (
        {"vars_": [var("x", "C D C(|S_C| = 0) .*")], "product_extra": "uniform int pxrLayers:index:bounces = 0"},
        r"/Render/Vars/x\.sourceName: .* keeps no covariance",
    ),
    "unknown OCIO view": (
        {"product_extra": 'uniform string pxrLayers:ocio:view = "Filmic"'},
        r"/Render/product\.pxrLayers:ocio:view: view 'Filmic' is not a view of 'sRGB - Display'",
    ),
    "unknown OCIO config": (
        {"product_extra": 'uniform string pxrLayers:ocio:config = "ocio://no-such-config"'},
        r"/Render/product\.pxrLayers:ocio:config: cannot load OCIO config",
    ),
    "product name not an EXR": (
        {"product_extra": 'token productName = "shot.png"'},
        r"/Render/product\.productName: productName 'shot.png' must name an \.exr file",
    ),
    "orderedVars target that is not a var": (
        {"ordered": ["nope"]},
        r"/Render/product\.orderedVars: target /Render/Vars/nope does not exist",
    ),
}


@pytest.mark.parametrize("case", list(BAD_RECIPES))
def test_each_bad_recipe_gives_its_error(tmp_path, case):
    arguments, pattern = BAD_RECIPES[case]
    path = shot(tmp_path, **arguments)
    with pytest.raises(RecipeError, match=pattern) as caught:
        load_recipe(path)
    assert str(caught.value).startswith(f"{path}: ")
    assert isinstance(caught.value, PxrLayersError)


def test_a_recipe_without_a_camera_takes_the_stages_first_then_the_automatic_one(tmp_path):
    path = shot(tmp_path, settings_extra="")
    assert load_recipe(path).product().camera == "/World/cam"
    path.write_text(path.read_text().replace('def Camera "cam" {}', ''))
    assert load_recipe(path).product().camera == "/pxrLayers/autoCamera"


def test_settings_selection_errors(tmp_path):
    none = tmp_path / "empty.usda"
    none.write_text('#usda 1.0\ndef Xform "World" {}\n')
    beauty = load_recipe(none).product()  # no settings: the beauty alone, at the default view
    assert (beauty.output_name, beauty.layer_names, beauty.resolution) == ("empty.exr", ("color",), (512, 512))
    two = shot(tmp_path, metadata="")
    text = two.read_text().replace('def RenderSettings "Settings"', 'def RenderSettings "Other" { }\n    def RenderSettings "Settings"')
    two.write_text(text)
    with pytest.raises(RecipeError, match=r"several RenderSettings prims \(/Render/Other, /Render/Settings\)"):
        load_recipe(two)
    assert load_recipe(two, "/Render/Settings").settings_path == "/Render/Settings"
    with pytest.raises(RecipeError, match=r"/Render/Vars/diffuse: the requested settings is a RenderVar"):
        load_recipe(two, "/Render/Vars/diffuse")
    # Settings without products render the beauty alone, with their camera and resolution.
    assert load_recipe(two, "/Render/Other").product().layer_names == ("color",)


def test_missing_files(tmp_path):
    with pytest.raises(StageError, match="file not found"):
        load_recipe(tmp_path / "nope.usda")
    with pytest.raises(RecipeError, match="nope_recipe.usda: file not found"):
        load_recipe(SHOWCASE, recipe_layers=[tmp_path / "nope_recipe.usda"])


def test_camera_override_and_missing_api_warning(tmp_path, caplog):
    path = shot(tmp_path, [var("x", api=False, extra='uniform string pxrLayers:group = "g"')], settings_extra="")
    with caplog.at_level(logging.WARNING):
        product = load_recipe(path, camera="/World/cam").product()
    assert product.camera == "/World/cam" and product.layer("x").group == "g"
    assert "does not apply PxrLayersVarAPI" in caplog.text
    with pytest.raises(RecipeError, match="the requested camera does not exist"):
        load_recipe(path, camera="/World/nope")


def test_unknown_raw_source_warns(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        load_recipe(shot(tmp_path, [var("mystery", "mystery", "raw", "float")]))
    assert "raw var /Render/Vars/mystery asks for 'mystery'" in caplog.text


def test_beauty_part_name_is_reserved(tmp_path):
    with pytest.raises(RecipeError, match=rf"/Render/Vars/{BEAUTY_PART}: layer name 'rgba' is reserved"):
        load_recipe(shot(tmp_path, [var(BEAUTY_PART)]))


def test_a_preview_exposure_past_the_stated_stops_is_refused():
    """2^2000 overflows: a recipe's exposure of 2000 stops is a RecipeError naming the
    attribute, not an OverflowError when the preview is written."""
    from pxr_layers.errors import RecipeError
    from pxr_layers.recipe.model import MAX_PREVIEW_STOPS, Layer

    Layer("key", "lpe", "C.*", exposure=MAX_PREVIEW_STOPS)
    with pytest.raises(RecipeError, match="pxrLayers:preview:exposure.*within ±64"):
        Layer("key", "lpe", "C.*", exposure=2000.0)
