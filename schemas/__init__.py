"""The pxr-layers USD schema as package data (``pxr_layers.schemas``): no code, no pxr import.

``schema.usda`` is the source; ``generatedSchema.usda`` and ``plugInfo.json`` are produced
from it by ``regenerate.py`` (usdGenSchema) and registered with USD by
:func:`pxr_layers.recipe.schema.register`. See README.md here and docs/recipes.md.
"""
