"""Recipe presets shipped in ``render/recipes/`` (package data of ``pxr_layers.render``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from ..errors import RecipeError

PRESETS = {
    "light_passes": "the standard light passes of docs/lpe.md (they add up to the beauty), any shot",
    "showcase": "the seed paper's covariance selections on render/showcase.usda",
}
"""Preset name → what it holds; the file is ``render/recipes/<name>.usda``."""


def preset(name: str) -> Path:
    """The path of a shipped recipe preset, e.g. ``preset("light_passes")``."""
    if name not in PRESETS:
        raise RecipeError(f"unknown recipe preset {name!r} (presets: {', '.join(PRESETS)})")
    return Path(str(resources.files("pxr_layers.render").joinpath("recipes", f"{name}.usda")))
