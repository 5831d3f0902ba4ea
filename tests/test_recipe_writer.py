"""Recipes written as USD layers: they read back as the same products, author only what is
particular to them, compose over a shot, and extract the same pixels as the command line."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pxr_layers.cli.main import main
from pxr_layers.errors import RecipeError
from pxr_layers.recipe import IndexSettings, Layer, Product, Recipe, per_light_layers
from pxr_layers.stage import load_recipe, open_shot
from pxr_layers.stage.recipe_writer import valid_prim_name, write_recipe

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "render" / "cornell.usda"
CAMERA = "/World/Camera"  # cornell's
SMALL = ["--spp", "2", "--resolution", "24", "24", "--max-depth", "3", "--quiet"]


def product(name: str = "look", layers=(Layer("diffuse", source_name="C<RD>.*"),), **fields) -> Product:
    return Product(name=name, output_name=f"{name}.exr", camera=CAMERA, resolution=(24, 24),
                   layers=tuple(layers), **fields)


RECIPES = {
    "graded layers": Recipe(products=(product(layers=(
        Layer("diffuse", source_name="C<RD>.*", exposure=1.5, tint=(1, 0.85, 0.7), group="passes"),
        Layer("glossy", source_name="C<R[^D]>.*", exposure=-0.25, group="passes"),
        Layer("key", source_name="C.*<L.'ceilingLight'>", pixel_type="half", preview=False),
        Layer("walls", source_name="C<RD'redWall'>.*|C<RD'greenWall'>.*", compression="piz", tint=(0.5, 1, 2)),
    )),)),
    "product settings": Recipe(products=(product(
        layers=(Layer("diffuse", source_name="C<RD>.*", pixel_type="half", compression="dwaa"),
                Layer("flat", source_name="C<R.>@(|S_C| = 0).*", pixel_type="float"),
                Layer("depth", "raw", "depth", data_type="float", preview=False, group="data")),
        pixel_type="half", compression="dwaa", index=IndexSettings(bounces=8, covariance="sigma", mode="records"),
        view="Un-tone-mapped", contact_sheet=False, denoise=True),)),
    "colour settings": Recipe(products=(product(
        ocio_config="ocio://cg-config-v2.2.0_aces-v1.3_ocio-v2.4", display="Display P3 - Display",
        rendering_space="lin_srgb"),)),
    "two products": Recipe(products=(
        product("passes", layers=(Layer("diffuse", source_name="C<RD>.*"), Layer("key", source_name="C.*"))),
        product("split", layers=(Layer("diffuse", source_name="C<RD>.*"), Layer("key", source_name="C<RD>[LO]")),
                pixel_type="half"),
    )),
    "shared layer": Recipe(products=(
        product("passes", layers=(Layer("diffuse", source_name="C<RD>.*"), Layer("glossy", source_name="C<RG>.*"))),
        product("more", layers=(Layer("diffuse", source_name="C<RD>.*"),)),
    )),
    "beauty var": Recipe(products=(product(layers=(Layer("color", "raw", "color"),
                                                   Layer("emission", source_name="C[LO]"))),)),
}


def unplaced(product: Product) -> Product:
    return dataclasses.replace(product, prim_path="",
                               layers=tuple(dataclasses.replace(layer, prim_path="") for layer in product.layers))


def read_over_cornell(recipe_file: Path) -> Recipe:
    """The recipe as `pxr-layers extract --recipe FILE` reads it (cli/extract.py _recipe):
    the file composed over the index's stage, then Shot.recipe."""
    return open_shot(CORNELL, recipe_layers=[recipe_file]).recipe()


@pytest.mark.parametrize("case", RECIPES)
def test_a_written_recipe_reads_back_as_the_same_products(tmp_path, case):
    recipe = RECIPES[case]
    written = write_recipe(tmp_path / "my_look.usda", recipe)
    assert written == tmp_path / "my_look.usda"
    back = read_over_cornell(written)
    assert [unplaced(p) for p in back.products] == [unplaced(p) for p in recipe.products]
    assert back.settings_path == "/Render/my_look/Settings"
    assert all(layer.prim_path.startswith("/Render/my_look/Vars/") for p in back.products for layer in p.layers)


def test_the_cases_author_every_attribute_of_the_schema(tmp_path):
    """So that an attribute added to schemas/schema.usda cannot be left out of the writer
    unnoticed (perLight aside: per-light layers are written as vars)."""
    from pxr_layers.stage import schema

    text = "".join(write_recipe(tmp_path / f"case{number}.usda", recipe).read_text()
                   for number, recipe in enumerate(RECIPES.values()))
    for api in (schema.VAR_API, schema.PRODUCT_API):
        for name in set(schema.property_names(api)) - {"pxrLayers:perLight"}:
            assert f" {name} = " in text, name


def test_products_with_different_layers_of_one_name_get_a_scope_each_and_shared_ones_one_var(tmp_path):
    clashing = read_over_cornell(write_recipe(tmp_path / "a.usda", RECIPES["two products"]))
    assert [layer.prim_path for layer in clashing.product("split").layers] == [
        "/Render/a/Vars/split/diffuse", "/Render/a/Vars/split/key"]
    shared = read_over_cornell(write_recipe(tmp_path / "b.usda", RECIPES["shared layer"]))
    assert shared.product("more").layers[0].prim_path == shared.product("passes").layers[0].prim_path \
        == "/Render/b/Vars/diffuse"


def test_only_what_differs_from_the_defaults_is_authored(tmp_path):
    text = write_recipe(tmp_path / "plain.usda", Recipe(products=(product(),))).read_text()
    assert "pxrLayers:" not in text.replace('"PxrLayersProductAPI"', "").replace('"PxrLayersVarAPI"', "")
    assert 'prepend apiSchemas = ["PxrLayersProductAPI"]' in text and 'prepend apiSchemas = ["PxrLayersVarAPI"]' in text
    for always in ('renderSettingsPrimPath = "/Render/plain/Settings"', 'uniform token dataType = "color3f"',
                   'uniform token sourceType = "lpe"', 'uniform string sourceName = "C<RD>.*"',
                   'token productName = "look.exr"', "rel camera = </World/Camera>",
                   "uniform int2 resolution = (24, 24)"):
        assert always in text, always
    graded = write_recipe(tmp_path / "graded.usda", RECIPES["graded layers"]).read_text()
    assert graded.count("pxrLayers:preview:exposure") == 2 and graded.count("pxrLayers:preview:tint") == 2
    assert graded.count("pxrLayers:pixelType") == 1 and graded.count("pxrLayers:compression") == 1


def test_different_views_go_on_each_product_and_the_shots_own_render_prims_are_untouched(tmp_path):
    wide = dataclasses.replace(product("wide"), resolution=(32, 16), output_name="wide.exr")
    recipe = Recipe(products=(product(), wide))
    back = read_over_cornell(write_recipe(tmp_path / "views.usda", recipe))
    assert [(p.camera, p.resolution) for p in back.products] == [(CAMERA, (24, 24)), (CAMERA, (32, 16))]
    # The shot's /Render/Settings, products and vars compose as before (its own recipe).
    shot_alone = load_recipe(CORNELL)
    composed_own = open_shot(CORNELL, recipe_layers=[tmp_path / "views.usda"]).recipe(settings="/Render/Settings")
    assert composed_own == dataclasses.replace(shot_alone, file=composed_own.file)


def test_per_light_layers_are_frozen_as_vars(tmp_path):
    lights = per_light_layers(["ceilingLight"])
    recipe = Recipe(products=(product(layers=lights, per_light="lights"),))
    back = read_over_cornell(write_recipe(tmp_path / "lights.usda", recipe)).product()
    assert back.per_light == "none"
    assert [dataclasses.replace(layer, prim_path="") for layer in back.layers] == list(lights)


def test_floats_read_back_as_their_float32(tmp_path):
    recipe = Recipe(products=(product(layers=(Layer("third", source_name="C.*", exposure=1 / 3, tint=(0.1, 0.2, 0.3)),)),))
    layer = read_over_cornell(write_recipe(tmp_path / "thirds.usda", recipe)).product().layers[0]
    assert layer.exposure == 0.33333334 and layer.tint == (0.1, 0.2, 0.3)


def test_a_product_name_that_is_no_prim_name_is_refused_and_nothing_is_written(tmp_path):
    recipe = Recipe(products=(dataclasses.replace(product(), name="my-look"),))
    with pytest.raises(RecipeError, match="'my-look' is not a USD identifier"):
        write_recipe(tmp_path / "my-look.usda", recipe)
    assert list(tmp_path.iterdir()) == []


def test_a_file_name_that_is_no_identifier_still_gives_a_scope(tmp_path):
    back = read_over_cornell(write_recipe(tmp_path / "my-look.usda", Recipe(products=(product(),))))
    assert back.settings_path == "/Render/my_look/Settings"


def test_rewriting_a_recipe_that_an_open_stage_holds_is_read_anew(tmp_path):
    path = tmp_path / "again.usda"
    write_recipe(path, Recipe(products=(product(),)))
    held = open_shot(CORNELL, recipe_layers=[path])  # keeps the layer open in this process
    assert held.recipe().product().layer_names == ("diffuse",)
    write_recipe(path, Recipe(products=(product(layers=(Layer("emission", source_name="C[LO]"),)),)))
    assert read_over_cornell(path).product().layer_names == ("emission",)
    assert not [name for name in tmp_path.iterdir() if name.name.startswith(".")]  # no temporaries left


@pytest.fixture(scope="module")
def cornell_index(tmp_path_factory) -> Path:
    """The shipped Cornell box rendered at 24 × 24, 2 spp: a path index in well under a second."""
    folder = tmp_path_factory.mktemp("writer")
    assert main(["render", str(CORNELL), "-o", str(folder), *SMALL]) == 0
    return folder / "cornell.pxlidx"


def parts(path: Path) -> dict[str, np.ndarray]:
    """Part name → its pixels: (h, w, 4) for the beauty, (h, w, 3) for a layer (the binding
    groups NAME.R/G/B into one channel NAME)."""
    found = {}
    for part in OpenEXR.File(str(path)).parts:
        channel = part.channels.get("RGBA") or part.channels[part.name()]
        found[part.name()] = channel.pixels
    return found


def test_extract_with_a_written_recipe_gives_the_command_lines_pixels(cornell_index, tmp_path):
    layers = {"diffuse": "C<RD>.*", "direct": "C<RD>[LO]", "key": "C.*<L.'ceilingLight'>"}
    recipe = Recipe(products=(product("look", layers=(
        Layer("diffuse", source_name=layers["diffuse"], exposure=1, tint=(1, 0.9, 0.8)),
        Layer("direct", source_name=layers["direct"], group="passes"),
        Layer("key", source_name=layers["key"], pixel_type="half"),
    )),))
    written = write_recipe(tmp_path / "look.usda", recipe)
    assert main(["extract", str(cornell_index), "--recipe", str(written), "-o", str(tmp_path / "recipe"),
                 "--no-previews", "--quiet"]) == 0
    flags = [argument for name, text in layers.items() for argument in ("--layer", f"{name}={text}")]
    assert main(["extract", str(cornell_index), *flags, "-o", str(tmp_path / "flags.exr"), "--no-previews",
                 "--quiet"]) == 0
    from_recipe, from_flags = parts(tmp_path / "recipe" / "look.exr"), parts(tmp_path / "flags.exr")
    assert list(from_recipe) == ["rgba", "diffuse", "direct", "key"] == list(from_flags)
    assert from_recipe["diffuse"].sum() > 0 and from_recipe["direct"].sum() > 0
    for name in ("rgba", "diffuse", "direct"):
        np.testing.assert_array_equal(from_recipe[name], from_flags[name])  # same index, same sums: bit for bit
    assert from_recipe["key"].dtype == np.float16
    np.testing.assert_array_equal(from_recipe["key"], from_flags["key"].astype(np.float16))


@pytest.mark.parametrize("text, name", [("my-look", "my_look"), ("3look", "_look"), ("été", "__t__"),
                                        ("look_2", "look_2")])
def test_valid_prim_name_makes_any_text_a_usd_identifier(text, name):
    from pxr import Sdf

    assert valid_prim_name(text) == name and Sdf.Path.IsValidIdentifier(name)


# Text a recipe carries into a USD layer (an LPE's quoted label, a group, a display): whatever
# its characters (quotes, '@', newlines, '#usda', braces), the layer holds it as data and reads
# back equal, with no prim or attribute it did not ask for (issue 33: what we write that
# another program interprets).
HOSTILE_TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="'\\\x00"), max_size=24)


@settings(deadline=None, derandomize=True, database=None, max_examples=30)
@given(label=HOSTILE_TEXT.filter(bool), group=HOSTILE_TEXT)
def test_hostile_text_in_a_recipe_is_data_in_the_usd_layer(tmp_path_factory, label, group):
    folder = tmp_path_factory.mktemp("hostile_recipe")
    recipe = Recipe(products=(product(layers=(
        Layer("key", source_name=f"C.*<L.'{label}'>", group=group),)),))
    written = write_recipe(folder / "look.usda", recipe)
    back = read_over_cornell(written)
    assert [unplaced(p) for p in back.products] == [unplaced(p) for p in recipe.products]
    from pxr import Sdf

    prims = []
    Sdf.Layer.FindOrOpen(str(written)).Traverse("/", lambda path: prims.append(path) if path.IsPrimPath() else None)
    assert sorted(map(str, prims)) == ["/Render", "/Render/look", "/Render/look/Products",
                                       "/Render/look/Products/look", "/Render/look/Settings",
                                       "/Render/look/Vars", "/Render/look/Vars/key"]
