"""The pxr-layers USD schema: generated files up to date, registration, Python constants in step."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pxr_layers.recipe import Layer, Product, model
from pxr_layers.stage import schema

ROOT = Path(__file__).resolve().parents[1]
SCHEMAS = ROOT / "schemas"


def run_python(code: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter (USD's registries are per process)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=120, cwd=ROOT, check=False)


def test_generated_files_match_schema_usda(tmp_path):
    if importlib.util.find_spec("jinja2") is None:
        pytest.skip("usdGenSchema needs jinja2 (pip install jinja2, or the test extra)")
    spec = importlib.util.spec_from_file_location("regenerate", SCHEMAS / "regenerate.py")
    regenerate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(regenerate)
    generated = regenerate.generate(tmp_path)
    stale = regenerate.stale_files(generated)
    assert not stale, "schemas/ is stale; run python schemas/regenerate.py\n" + "".join(stale.values())
    assert '"@PLUG_INFO' not in generated["plugInfo.json"]


def test_schema_files_ship_together():
    folder = schema.schema_dir()
    for name in schema.SCHEMA_FILES:
        assert (folder / name).is_file(), name


def test_registration_in_a_fresh_process():
    result = run_python("""
        import sys
        import pxr_layers, pxr_layers.recipe, pxr_layers.request, pxr_layers.scene
        assert "pxr" not in sys.modules, "importing pxr_layers, its recipes or requests must not import pxr"
        import pxr_layers.stage  # registers the schema
        from pxr import Usd, UsdRender
        stage = Usd.Stage.CreateInMemory()
        var = UsdRender.Var.Define(stage, "/v").GetPrim()
        product = UsdRender.Product.Define(stage, "/p").GetPrim()
        assert var.ApplyAPI("PxrLayersVarAPI") and product.ApplyAPI("PxrLayersProductAPI")
        assert not var.CanApplyAPI("PxrLayersProductAPI")
        print(var.GetAttribute("pxrLayers:pixelType").Get(), product.GetAttribute("pxrLayers:index:bounces").Get())
    """)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["float", "5"]


def test_registering_after_usd_built_its_schema_registry_is_a_clear_error():
    result = run_python("""
        from pxr import Usd
        Usd.Stage.CreateInMemory().DefinePrim("/x", "Xform")
        from pxr_layers.errors import RecipeError
        try:
            import pxr_layers.stage
        except RecipeError as error:
            print(error)
    """)
    assert result.returncode == 0, result.stderr
    assert "registered too late" in result.stdout and "PXR_PLUGINPATH_NAME" in result.stdout


def test_register_is_idempotent():
    schema.register()
    schema.register()
    from pxr import Usd

    assert all(Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(api) for api in schema.API_SCHEMAS)


def test_python_constants_equal_the_schema():
    tokens = schema.allowed_tokens
    assert tokens(schema.VAR_API, "pxrLayers:pixelType") == model.PIXEL_TYPES
    assert tokens(schema.PRODUCT_API, "pxrLayers:pixelType") == model.PIXEL_TYPES
    assert tokens(schema.VAR_API, "pxrLayers:compression") == model.COMPRESSIONS
    assert tokens(schema.PRODUCT_API, "pxrLayers:compression") == model.COMPRESSIONS
    assert tokens(schema.PRODUCT_API, "pxrLayers:index:covariance") == model.COVARIANCE_MODES
    assert tokens(schema.PRODUCT_API, "pxrLayers:perLight") == model.PER_LIGHT_MODES

    layer = Layer("x")
    fallback = schema.fallback
    assert fallback(schema.VAR_API, "pxrLayers:pixelType") == layer.pixel_type
    assert fallback(schema.VAR_API, "pxrLayers:compression") == layer.compression
    assert fallback(schema.VAR_API, "pxrLayers:preview") is layer.preview
    assert fallback(schema.VAR_API, "pxrLayers:preview:exposure") == layer.exposure
    assert fallback(schema.VAR_API, "pxrLayers:preview:tint") == layer.tint
    assert fallback(schema.VAR_API, "pxrLayers:group") == layer.group

    product = Product("p", "p.exr", "/cam", (1, 1), (layer,))
    assert fallback(schema.PRODUCT_API, "pxrLayers:pixelType") == product.pixel_type
    assert fallback(schema.PRODUCT_API, "pxrLayers:compression") == product.compression
    assert fallback(schema.PRODUCT_API, "pxrLayers:index:bounces") == product.index.bounces
    assert fallback(schema.PRODUCT_API, "pxrLayers:index:covariance") == product.index.covariance
    assert fallback(schema.PRODUCT_API, "pxrLayers:ocio:config") == product.ocio_config
    assert fallback(schema.PRODUCT_API, "pxrLayers:ocio:display") == product.display
    assert fallback(schema.PRODUCT_API, "pxrLayers:ocio:view") == product.view
    assert fallback(schema.PRODUCT_API, "pxrLayers:ocio:renderingSpace") == product.rendering_space
    assert fallback(schema.PRODUCT_API, "pxrLayers:contactSheet") is product.contact_sheet
    assert fallback(schema.PRODUCT_API, "pxrLayers:denoise") is product.denoise
    assert fallback(schema.PRODUCT_API, "pxrLayers:perLight") == product.per_light
    assert fallback(schema.LIGHT_API, "pxrLayers:lightGroup") == ""


def test_the_user_documentation_covers_every_attribute_and_token():
    docs = (ROOT / "docs" / "recipes.md").read_text()
    for api in schema.API_SCHEMAS:
        assert api in docs
        for name in schema.property_names(api):
            assert f"`{name}`" in docs, name
            for token in schema.allowed_tokens(api, name):
                assert f"`{token}`" in docs, (name, token)
