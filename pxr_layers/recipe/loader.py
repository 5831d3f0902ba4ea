"""USD recipe → :class:`~pxr_layers.recipe.model.Recipe`: find, flatten and validate.

A recipe is UsdRender: RenderSettings → RenderProduct (one EXR) → RenderVar (one layer),
with the pxr-layers API schemas (``schemas/schema.usda``) for what UsdRender lacks. It can
live in the shot stage itself, in a layer the shot sublayers or references, or in separate
recipe layers composed over the shot at load time (``recipe_layers``). Every problem is a
RecipeError naming the file, the prim and the attribute.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, UsdLux, UsdRender

from ..errors import RecipeError, StageError
from . import schema
from .expressions import check_expression, covariance_needs, normalise_expression
from .lights import per_light_layers
from .model import (
    COLOUR_DATA_TYPES,
    KNOWN_RAW_SOURCES,
    LOSSY_COMPRESSIONS,
    PER_LIGHT_MODES,
    IndexSettings,
    Layer,
    Product,
    Recipe,
)

schema.register()  # before this module (or anyone) opens a stage

logger = logging.getLogger(__name__)

SUPPORTED_LIGHTS = (
    UsdLux.RectLight, UsdLux.DiskLight, UsdLux.SphereLight, UsdLux.CylinderLight,
    UsdLux.DistantLight, UsdLux.DomeLight, UsdLux.DomeLight_1,
)
"""The light types the tracer renders (as pxr_layers.stage.lights); others get no layer."""

_PREFIX = "pxrLayers:"


def load_recipe(
    source: str | os.PathLike | Usd.Stage,
    settings_prim: str | None = None,
    *,
    recipe_layers: Sequence[str | os.PathLike] = (),
    camera: str | None = None,
    per_light: str | None = None,
    check_colour: bool = True,
) -> Recipe:
    """Read and validate the recipe of a stage.

    source        : the shot's USD file, or an open stage
    settings_prim : the RenderSettings prim to read; None → the ``renderSettingsPrimPath``
                    of the last recipe layer that sets one, else the stage's, else the
                    only RenderSettings prim of the stage
    recipe_layers : USD layers composed over the shot (sublayers of the session layer,
                    the first strongest), e.g. a preset of render/recipes/
    camera        : camera prim path overriding the products' and settings' camera
    per_light     : "none" | "lights" | "groups" overriding every product's
                    ``pxrLayers:perLight`` (the CLI's flag)
    check_colour  : check that the OCIO config, display, view and rendering space exist

    Each product's camera and resolution: the product's own, else its settings', else
    those of the stage's ``renderSettingsPrimPath`` settings (so a preset composed over a
    shot renders the shot's camera). No camera anywhere is an error.
    """
    if per_light is not None and per_light not in PER_LIGHT_MODES:
        raise RecipeError(f"unknown per-light mode {per_light!r} (allowed: {', '.join(PER_LIGHT_MODES)})")
    if isinstance(source, Usd.Stage):
        if recipe_layers:
            raise RecipeError("recipe_layers needs a file to open, not an open stage: sublayer them yourself")
        stage = source
    else:
        stage = _open(Path(source), [Path(layer) for layer in recipe_layers])
    file = stage.GetRootLayer().realPath or stage.GetRootLayer().identifier
    reader = _Reader(stage, file, camera, per_light, check_colour)
    settings = reader.find_settings(settings_prim, [Path(layer) for layer in recipe_layers])
    return reader.recipe(settings)


def has_recipe(path: str | os.PathLike) -> bool:
    """Whether the stage names render settings (``renderSettingsPrimPath``), as load_stage
    reads them; a stage without is rendered to its beauty alone."""
    stage = _open(Path(path), [])
    return bool(stage.GetMetadata("renderSettingsPrimPath"))


def _open(path: Path, recipe_layers: list[Path]) -> Usd.Stage:
    for layer in (path, *recipe_layers):
        if not layer.is_file():
            kind = StageError if layer == path else RecipeError
            raise kind("file not found", file=str(layer))
    try:
        root = Sdf.Layer.FindOrOpen(str(path))
        if recipe_layers:
            session = Sdf.Layer.CreateAnonymous("pxr_layers_recipes.usda")
            session.subLayerPaths = [str(layer.resolve()) for layer in recipe_layers]
            stage = Usd.Stage.Open(root, session, Usd.Stage.LoadNone)
        else:
            stage = Usd.Stage.Open(root, Usd.Stage.LoadNone)
    except Tf.ErrorException as error:
        raise RecipeError(f"cannot open as USD: {_tf_message(error)}", file=str(path)) from None
    if stage is None:
        raise RecipeError("cannot open as USD", file=str(path))
    errors = [str(error).strip().removesuffix("; skipping.") for error in stage.GetCompositionErrors()]
    if errors:
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise RecipeError(f"does not compose: {errors[0]}{more}", file=str(path))
    return stage


class _Reader:
    """Reads one stage's recipe prims; every error names ``file``, a prim and an attribute."""

    def __init__(self, stage: Usd.Stage, file: str, camera: str | None, per_light: str | None,
                 check_colour: bool):
        self.stage = stage
        self.file = file
        self.camera_override = camera
        self.per_light_override = per_light
        self.check_colour = check_colour
        self._lights: list[tuple[str, str, str]] | None = None

    def error(self, message: str, prim=None, attribute: str | None = None) -> RecipeError:
        path = str(prim.GetPath()) if isinstance(prim, Usd.Prim) else prim
        return RecipeError(message, file=self.file, prim=path, attribute=attribute)

    # -- settings -------------------------------------------------------------------------

    def find_settings(self, settings_prim: str | None, recipe_layers: list[Path]) -> UsdRender.Settings:
        if settings_prim is not None:
            return self._settings_at(settings_prim, "the requested settings")
        for layer_path in reversed(recipe_layers):
            layer = Sdf.Layer.FindOrOpen(str(layer_path))
            key = UsdRender.Tokens.renderSettingsPrimPath
            named = layer.pseudoRoot.GetInfo(key) if layer and layer.pseudoRoot.HasInfo(key) else ""
            if named:
                return self._settings_at(named, f"renderSettingsPrimPath of {layer_path}")
        named = self.stage.GetMetadata("renderSettingsPrimPath")
        if named:
            return self._settings_at(named, "the stage's renderSettingsPrimPath")
        found = [prim for prim in self.stage.Traverse() if prim.IsA(UsdRender.Settings)]
        if len(found) == 1:
            return UsdRender.Settings(found[0])
        if not found:
            raise self.error("no recipe: the stage has no RenderSettings prim")
        paths = ", ".join(str(prim.GetPath()) for prim in found)
        raise self.error(f"several RenderSettings prims ({paths}) and no renderSettingsPrimPath: name one")

    def _settings_at(self, path: str, role: str) -> UsdRender.Settings:
        prim = self._prim(path, role)
        if not prim.IsA(UsdRender.Settings):
            raise self.error(f"{role} is a {prim.GetTypeName() or 'typeless prim'}, not RenderSettings", prim)
        return UsdRender.Settings(prim)

    def _prim(self, path: str, role: str) -> Usd.Prim:
        if not Sdf.Path.IsValidPathString(str(path)) or not Sdf.Path(str(path)).IsAbsolutePath():
            raise self.error(f"{role}: not an absolute prim path: {path!r}")
        prim = self.stage.GetPrimAtPath(str(path))
        if not prim or not prim.IsActive():
            raise self.error(f"{role} does not exist", str(path))
        return prim

    def _stage_settings(self) -> UsdRender.Settings | None:
        settings = UsdRender.Settings.GetStageRenderSettings(self.stage)
        return settings if settings else None

    # -- recipe ---------------------------------------------------------------------------

    def recipe(self, settings: UsdRender.Settings) -> Recipe:
        prim = settings.GetPrim()
        self.check_unknown_attributes(prim, ())
        targets = settings.GetProductsRel().GetForwardedTargets()
        if not targets:
            raise self.error("names no RenderProduct", prim, "products")
        products = []
        for target in targets:
            product_prim = self.stage.GetPrimAtPath(target)
            if not product_prim or not product_prim.IsActive():
                raise self.error(f"target {target} does not exist", prim, "products")
            if not product_prim.IsA(UsdRender.Product):
                raise self.error(f"target {target} is a {product_prim.GetTypeName() or 'typeless prim'}, "
                                 "not a RenderProduct", prim, "products")
            products.append(self.product(settings, UsdRender.Product(product_prim)))
        try:
            return Recipe(products=tuple(products), settings_path=str(prim.GetPath()), file=self.file)
        except RecipeError as error:
            raise self.error(error.message, error.prim, error.attribute) from None

    def product(self, settings: UsdRender.Settings, product: UsdRender.Product) -> Product:
        prim = product.GetPrim()
        self.check_unknown_attributes(prim, schema.property_names(schema.PRODUCT_API), schema.PRODUCT_API)
        api = {name.removeprefix(_PREFIX): self.read(prim, schema.PRODUCT_API, name)
               for name in schema.property_names(schema.PRODUCT_API)}
        pixel_type = self.token(prim, schema.PRODUCT_API, "pixelType", api)
        compression = self.token(prim, schema.PRODUCT_API, "compression", api)
        per_light = self.token(prim, schema.PRODUCT_API, "perLight", api)
        vars_ = self.var_targets(product)
        # The override applies to products of light layers, not to products of data AOVs only.
        if self.per_light_override is not None and (api["perLight"][1] or any(
                str(UsdRender.Var(var).GetSourceTypeAttr().Get()) == "lpe" for var in vars_)):
            per_light = self.per_light_override
        self.token(prim, schema.PRODUCT_API, "index:covariance", api)
        bounces = int(api["index:bounces"][0])
        if bounces < 0:
            raise self.error(f"must be >= 0, not {bounces}", prim, _PREFIX + "index:bounces")
        index = IndexSettings(bounces=bounces, covariance=str(api["index:covariance"][0]))

        layers = [self.layer(target, prim, pixel_type, compression, index)
                  for target in vars_]
        if per_light != "none":
            layers.extend(self.light_layers(per_light, pixel_type, compression))
        self.check_duplicates(prim, layers)

        output_name = str(product.GetProductNameAttr().Get() or "") or f"{prim.GetName()}.exr"
        config = self.ocio_config(prim, api)
        display, view, space = (str(api[key][0]) for key in ("ocio:display", "ocio:view", "ocio:renderingSpace"))
        if self.check_colour:
            self.check_ocio(prim, config, display, view, space)
        try:
            return Product(
                name=prim.GetName(), output_name=output_name, camera=self.camera(settings, product),
                resolution=self.resolution(settings, product), layers=tuple(layers), index=index,
                ocio_config=config, display=display, view=view, rendering_space=space,
                contact_sheet=bool(api["contactSheet"][0]), pixel_type=pixel_type, compression=compression,
                per_light=per_light, prim_path=str(prim.GetPath()),
            )
        except RecipeError as error:
            raise self.error(error.message, error.prim, error.attribute) from None

    def var_targets(self, product: UsdRender.Product) -> list[Usd.Prim]:
        prim = product.GetPrim()
        found = []
        for target in product.GetOrderedVarsRel().GetForwardedTargets():
            var = self.stage.GetPrimAtPath(target)
            if not var or not var.IsActive():
                raise self.error(f"target {target} does not exist", prim, "orderedVars")
            if not var.IsA(UsdRender.Var):
                raise self.error(f"target {target} is a {var.GetTypeName() or 'typeless prim'}, not a RenderVar",
                                 prim, "orderedVars")
            found.append(var)
        return found

    def layer(self, prim: Usd.Prim, product_prim: Usd.Prim, product_pixel_type: str, product_compression: str,
              index: IndexSettings) -> Layer:
        var = UsdRender.Var(prim)
        self.check_unknown_attributes(prim, schema.property_names(schema.VAR_API), schema.VAR_API)
        api = {name.removeprefix(_PREFIX): self.read(prim, schema.VAR_API, name)
               for name in schema.property_names(schema.VAR_API)}
        source_type = str(var.GetSourceTypeAttr().Get())
        if source_type in ("primvar", "intrinsic"):
            raise self.error(f"source type {source_type!r} is not rendered by pxr-layers (use lpe or raw)",
                             prim, "sourceType")
        source_name = str(var.GetSourceNameAttr().Get() or "")
        if source_type == "lpe":
            source_name = normalise_expression(source_name)
        data_type = str(var.GetDataTypeAttr().Get())
        if data_type not in COLOUR_DATA_TYPES:
            # A data layer inherits only the product defaults that keep data exact.
            product_pixel_type = "float"
            if product_compression in LOSSY_COMPRESSIONS:
                product_compression = str(schema.fallback(schema.VAR_API, _PREFIX + "compression"))
        pixel_type = self.token(prim, schema.VAR_API, "pixelType", api, inherited=product_pixel_type)
        compression = self.token(prim, schema.VAR_API, "compression", api, inherited=product_compression)
        fields = {
            "name": prim.GetName(), "source_type": source_type, "source_name": source_name,
            "data_type": data_type, "pixel_type": pixel_type, "compression": compression,
            "preview": bool(api["preview"][0]), "exposure": _float32(api["preview:exposure"][0]),
            "tint": tuple(_float32(c) for c in api["preview:tint"][0]), "group": str(api["group"][0]),
            "prim_path": str(prim.GetPath()),
        }
        try:
            layer = Layer(**fields)
        except RecipeError as error:  # names the prim and attribute; add the file
            raise self.error(error.message, error.prim, error.attribute) from None
        if source_type == "lpe":
            compiled = check_expression(source_name, str(prim.GetPath()), "sourceName", file=self.file)
            uses, sigma = covariance_needs(compiled)
            if uses and index.bounces == 0:
                raise self.error(f"{source_name!r} has a covariance condition but the product's index keeps "
                                 "no covariance (pxrLayers:index:bounces = 0)", prim, "sourceName")
            if sigma and index.covariance != "sigma":
                raise self.error(f"{source_name!r} tests matrix entries (Sij), which needs "
                                 f"pxrLayers:index:covariance = \"sigma\" on {product_prim.GetPath()}",
                                 prim, "sourceName")
        elif source_name not in KNOWN_RAW_SOURCES:
            logger.warning("%s: raw var %s asks for %r, which the renderer does not know (known: %s)",
                           self.file, prim.GetPath(), source_name, ", ".join(sorted(KNOWN_RAW_SOURCES)))
        return layer

    def light_layers(self, mode: str, pixel_type: str, compression: str) -> tuple[Layer, ...]:
        lights = self.lights()
        names = [name for name, _, _ in lights]
        label = {path: (name if names.count(name) == 1 else path) for name, path, _ in lights}
        if mode == "lights":
            groups: dict[str, list[str]] = {
                (name if names.count(name) == 1 else path): [label[path]] for name, path, _ in lights
            }
        else:
            groups = {}
            for name, path, group in lights:
                key = group or (name if names.count(name) == 1 else path)
                groups.setdefault(key, []).append(label[path])
        if not lights:
            logger.warning("%s: per-light layers asked for, but the stage has no light", self.file)
        return per_light_layers(groups, pixel_type=pixel_type, compression=compression)

    def lights(self) -> list[tuple[str, str, str]]:
        """(name, path, light group) of every visible light the tracer renders."""
        if self._lights is None:
            self.stage.Load()  # lights may sit under payloads
            found = []
            predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
            for prim in self.stage.Traverse(predicate):
                if not any(prim.IsA(kind) for kind in SUPPORTED_LIGHTS):
                    continue
                if UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.invisible:
                    continue
                group = self.read(prim, schema.LIGHT_API, _PREFIX + "lightGroup")[0]
                found.append((prim.GetName(), str(prim.GetPath()), str(group or "")))
            self._lights = found
        return self._lights

    def check_duplicates(self, product_prim: Usd.Prim, layers: list[Layer]) -> None:
        seen: dict[str, Layer] = {}
        for layer in layers:
            if layer.name in seen:
                first = seen[layer.name].prim_path or "a per-light layer"
                second = layer.prim_path or "a per-light layer"
                raise self.error(f"duplicate layer name {layer.name!r}: {first} and {second} would write "
                                 "the same EXR part", product_prim, "orderedVars")
            seen[layer.name] = layer

    # -- attributes -----------------------------------------------------------------------

    def read(self, prim: Usd.Prim, api: str, name: str) -> tuple[object, bool]:
        """(value, authored) of an API schema attribute; the schema fallback when not authored.

        Works whether or not the API is applied (its fallback comes from the registry).
        """
        attribute = prim.GetAttribute(name)
        if attribute and attribute.HasAuthoredValue():
            value = attribute.Get()
            if value is not None:
                return (tuple(value) if hasattr(value, "__len__") and not isinstance(value, str) else value), True
        return schema.fallback(api, name), False

    def token(self, prim: Usd.Prim, api: str, short: str, values: dict, inherited: str | None = None) -> str:
        """A token attribute's value, checked against its allowedTokens; ``inherited`` replaces
        the fallback when the attribute is not authored."""
        value, authored = values[short]
        value = str(value) if authored or inherited is None else inherited
        allowed = schema.allowed_tokens(api, _PREFIX + short)
        if allowed and value not in allowed:
            raise self.error(f"unknown value {value!r} (allowed: {', '.join(allowed)})", prim, _PREFIX + short)
        return value

    def check_unknown_attributes(self, prim: Usd.Prim, known: Sequence[str], api: str | None = None) -> None:
        """A misspelt pxrLayers attribute is an error (it would be ignored silently)."""
        authored = [p.GetName() for p in prim.GetAuthoredProperties() if p.GetName().startswith(_PREFIX)]
        for name in authored:
            if name not in known:
                hint = ""
                close = _closest(name, known)
                if close:
                    hint = f" (did you mean {close}?)"
                where = f"a {api}" if api else "this prim"
                raise self.error(f"unknown attribute for {where}{hint}", prim, name)
        if authored and api and not prim.HasAPI(api):
            logger.warning("%s: %s has %s attributes but does not apply %s; read anyway",
                           self.file, prim.GetPath(), _PREFIX.rstrip(":"), api)

    def ocio_config(self, prim: Usd.Prim, api: dict) -> str:
        value, authored = api["ocio:config"]
        value = str(value)
        if not authored or "://" in value or os.path.isabs(value) or not value:
            return value
        # A relative config file: relative to the layer that authors it.
        for spec in prim.GetAttribute(_PREFIX + "ocio:config").GetPropertyStack(Usd.TimeCode.Default()):
            if spec.HasDefaultValue():
                return spec.layer.ComputeAbsolutePath(value)
        return value

    def check_ocio(self, prim: Usd.Prim, config: str, display: str, view: str, space: str) -> None:
        from ..layers.previews import ColourError, check_colour_settings

        try:
            check_colour_settings(config, display, view, space)
        except ColourError as error:
            raise self.error(error.message, prim, _PREFIX + f"ocio:{error.setting}") from None

    # -- camera and resolution --------------------------------------------------------------

    def camera(self, settings: UsdRender.Settings, product: UsdRender.Product) -> str:
        if self.camera_override is not None:
            prim = self._prim(self.camera_override, "the requested camera")
            return self._checked_camera(prim, None, "the requested camera")
        for owner in self._inheritance(settings, product):
            targets = owner.GetCameraRel().GetForwardedTargets()
            if targets:
                camera = self.stage.GetPrimAtPath(targets[0])
                if not camera or not camera.IsActive():
                    raise self.error(f"camera {targets[0]} does not exist", owner.GetPrim(), "camera")
                return self._checked_camera(camera, owner.GetPrim(), f"camera {targets[0]}")
        chain = " or ".join(str(owner.GetPath()) for owner in self._inheritance(settings, product))
        raise self.error(f"no camera: set rel camera on {chain}", product.GetPrim(), "camera")

    def _checked_camera(self, camera: Usd.Prim, owner: Usd.Prim | None, role: str) -> str:
        if not camera.IsA(UsdGeom.Camera):
            raise self.error(f"{role} is a {camera.GetTypeName() or 'typeless prim'}, not a Camera",
                             owner or camera, "camera" if owner else None)
        return str(camera.GetPath())

    def resolution(self, settings: UsdRender.Settings, product: UsdRender.Product) -> tuple[int, int]:
        for owner in self._inheritance(settings, product):
            attribute = owner.GetResolutionAttr()
            if attribute.HasAuthoredValue():
                value = attribute.Get()
                if value[0] <= 0 or value[1] <= 0:
                    raise self.error(f"must be positive, not {tuple(value)}", owner.GetPrim(), "resolution")
                return int(value[0]), int(value[1])
        value = settings.GetResolutionAttr().Get()
        return int(value[0]), int(value[1])

    def _inheritance(self, settings: UsdRender.Settings, product: UsdRender.Product):
        """Where a product's camera and resolution come from, strongest first."""
        owners = [UsdRender.SettingsBase(product.GetPrim()), UsdRender.SettingsBase(settings.GetPrim())]
        stage_settings = self._stage_settings()
        if stage_settings is not None and stage_settings.GetPath() != settings.GetPath():
            owners.append(UsdRender.SettingsBase(stage_settings.GetPrim()))
        return owners


def _closest(name: str, known: Sequence[str]) -> str | None:
    import difflib

    matches = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return matches[0] if matches else None


def _float32(value) -> float:
    """A float attribute as the shortest decimal that reads back as the same float32 (0.85,
    not 0.8500000238418579)."""
    return float(np.format_float_positional(np.float32(value), unique=True, trim="0"))


def _tf_message(error: Exception) -> str:
    """The quoted user-facing messages of a Tf.ErrorException, without C++ locations.

    The text is "\n\tError in 'F' at line N in file P : 'message'" per error, and the
    message itself may span lines.
    """
    messages = []
    for chunk in str(error).split("Error in ")[1:]:
        _, found, message = chunk.partition(" : '")
        if found:
            messages.append(" ".join(message.strip().removesuffix("'").split()))
    return "; ".join(messages) if messages else " ".join(str(error).split())
