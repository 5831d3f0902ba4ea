"""Layer recipes: a shot's UsdRender settings → frozen, validated :class:`Recipe` dataclasses.

Entry points::

    recipe = load_recipe("shot.usda")                                  # the stage's own recipe
    recipe = load_recipe("shot.usda", recipe_layers=[preset("light_passes")])
    product = recipe.product()                                          # the first product
    product.expressions()            # {"emission": "C[LO]", ...}: what lpe.compile_layers takes
    extra = per_light_layers(["key", "fill"])                           # light_key, light_fill, light_other

Modules: ``model`` (the dataclasses, pure Python), ``lights`` (per-light layers),
``expressions`` (LPE checks through :mod:`pxr_layers.lpe`), ``schema`` (registers
``schemas/`` with USD), ``loader`` (reads USD), ``presets`` (render/recipes/).

Importing this package does not import pxr: ``load_recipe`` and the schema functions load
``loader`` / ``schema`` on first use, and loading ``loader`` registers the schema first.
The schema and attributes are documented in docs/recipes.md.
"""

from __future__ import annotations

from .lights import OTHER_LIGHTS_LAYER, per_light_layers
from .model import (
    BEAUTY_EXPRESSION,
    BEAUTY_PART,
    DEFAULT_DISPLAY,
    DEFAULT_OCIO_CONFIG,
    DEFAULT_VIEW,
    RENDERING_SPACE,
    IndexSettings,
    Layer,
    Product,
    Recipe,
)
from .presets import PRESETS, preset

_LAZY = {
    "load_recipe": ("loader", "load_recipe"),
    "register": ("schema", "register"),
    "schema_dir": ("schema", "schema_dir"),
}

__all__ = [
    "BEAUTY_EXPRESSION",
    "BEAUTY_PART",
    "DEFAULT_DISPLAY",
    "DEFAULT_OCIO_CONFIG",
    "DEFAULT_VIEW",
    "OTHER_LIGHTS_LAYER",
    "PRESETS",
    "RENDERING_SPACE",
    "IndexSettings",
    "Layer",
    "Product",
    "Recipe",
    "load_recipe",
    "per_light_layers",
    "preset",
    "register",
    "schema_dir",
]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attribute = _LAZY[name]
        value = getattr(importlib.import_module(f"{__name__}.{module}"), attribute)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
