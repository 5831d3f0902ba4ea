"""Register the pxr-layers USD schema (``schemas/``) with USD, and read its definitions.

USD builds its schema registry once, the first time a process creates or opens a stage (or
asks the registry anything). Plugins registered after that are loaded, but their schemas
never reach the registry: ``ApplyAPI("PxrLayersVarAPI")`` fails and fallbacks are missing,
silently. So :func:`register` must run before the first stage; pxr-layers calls it when
``pxr_layers.stage`` (the only code that opens stages) is first imported. Importing ``pxr`` itself is harmless. Tools outside pxr-layers (usdview, a DCC)
should put :func:`schema_dir` on ``PXR_PLUGINPATH_NAME`` instead.
"""

from __future__ import annotations

import importlib.util
import logging
from functools import cache
from pathlib import Path

from pxr import Plug, Usd

from ..errors import RecipeError

logger = logging.getLogger(__name__)

VAR_API = "PxrLayersVarAPI"
PRODUCT_API = "PxrLayersProductAPI"
LIGHT_API = "PxrLayersLightAPI"
API_SCHEMAS = (VAR_API, PRODUCT_API, LIGHT_API)
ATTRIBUTE_PREFIX = "pxrLayers:"
"""The namespace of every attribute the API schemas define (``pxrLayers:pixelType``, ...)."""
SCHEMA_FILES = ("schema.usda", "generatedSchema.usda", "plugInfo.json")

_registered = False


def schema_dir() -> Path:
    """The folder holding plugInfo.json and generatedSchema.usda.

    Installed: the ``pxr_layers.schemas`` package data. Source checkout whose editable
    install predates that package: ``<checkout>/schemas``.
    """
    spec = importlib.util.find_spec("pxr_layers.schemas")
    candidates = []
    if spec is not None and spec.submodule_search_locations:
        candidates.extend(Path(location) for location in spec.submodule_search_locations)
    candidates.append(Path(__file__).resolve().parents[2] / "schemas")
    for folder in candidates:
        if (folder / "plugInfo.json").is_file() and (folder / "generatedSchema.usda").is_file():
            return folder
    raise RecipeError(
        "the pxr-layers USD schema is missing from the installation (looked in "
        + ", ".join(str(folder) for folder in candidates) + ")"
    )


def register() -> None:
    """Register the schema plugin with USD. Idempotent; cheap after the first call (~1 ms).

    Raises RecipeError when USD had already built its schema registry without it (a stage
    was opened before pxr-layers was imported): the message says how to fix that.
    """
    global _registered
    if _registered:
        return
    folder = schema_dir()
    Plug.Registry().RegisterPlugins(str(folder))
    if Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(VAR_API) is None:
        raise RecipeError(
            f"the pxr-layers USD schema was registered too late: this process opened a USD stage "
            f"before importing pxr_layers.recipe or pxr_layers.stage. Import them first, or set "
            f"PXR_PLUGINPATH_NAME={folder} before starting the process"
        )
    _registered = True
    logger.debug("registered the pxr-layers USD schema from %s", folder)


@cache
def _definition(api: str) -> Usd.PrimDefinition:
    register()
    definition = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(api)
    if definition is None:  # register() checked VAR_API; the others come from the same file
        raise RecipeError(f"the USD schema {api} is not registered")
    return definition


def property_names(api: str) -> tuple[str, ...]:
    """The attribute names an API schema defines, e.g. ``pxrLayers:pixelType``."""
    return tuple(str(name) for name in _definition(api).GetPropertyNames())


def fallback(api: str, attribute: str):
    """The schema's fallback value of ``attribute`` of ``api`` (Python value: bool, str, ...)."""
    value = _definition(api).GetAttributeFallbackValue(attribute)
    return tuple(value) if hasattr(value, "__len__") and not isinstance(value, str) else value


def allowed_tokens(api: str, attribute: str) -> tuple[str, ...]:
    """The allowedTokens of a token attribute of ``api`` (empty for other attributes)."""
    definition = _definition(api).GetAttributeDefinition(attribute)
    tokens = definition.GetMetadata("allowedTokens") if definition else None
    return tuple(str(token) for token in tokens) if tokens else ()
