"""Layer recipes: frozen, validated :class:`Recipe` dataclasses, their rules and presets.

Nothing here imports pxr: :func:`pxr_layers.stage.load_recipe` (or ``Shot.recipe``) reads a
recipe from a composed shot. Entry points::

    recipe = load_recipe("shot.usda")                                  # from pxr_layers.stage
    recipe = load_recipe("shot.usda", recipe_layers=[preset("light_passes")])
    product = recipe.product()                                          # the first product
    product.expressions()            # {"emission": "C[LO]", ...}: what lpe.compile_layers takes
    extra = per_light_layers(["key", "fill"])                           # light_key, light_fill, light_other

Modules: ``model`` (the dataclasses), ``lights`` (per-light layers), ``expressions`` (LPE
checks through :mod:`pxr_layers.lpe`), ``presets`` (render/recipes/). The USD schema and
its attributes are documented in docs/recipes.md.
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
    "per_light_layers",
    "preset",
]
