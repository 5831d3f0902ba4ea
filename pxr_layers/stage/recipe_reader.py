"""USD recipe → :class:`~pxr_layers.recipe.model.Recipe`: find, flatten and validate.

A recipe is UsdRender: RenderSettings → RenderProduct (one EXR) → RenderVar (one layer),
with the pxr-layers API schemas (``schemas/schema.usda``) for what UsdRender lacks. It can
live in the shot stage itself, in a layer the shot sublayers or references, or in separate
recipe layers composed over the shot (:func:`pxr_layers.stage.open_shot` composes them:
this module reads an open stage and never opens one). Every problem is a RecipeError
naming the file, the prim and the attribute.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from pxr import Kind, Sdf, Usd, UsdGeom, UsdRender

from ..errors import RecipeError
from ..recipe.expressions import check_expression, covariance_needs, normalise_expression
from ..recipe.lights import per_light_layers
from ..recipe.model import (
    BEAUTY_RAW_SOURCE,
    DEFAULT_CONFORM_POLICY,
    DEFAULT_PIXEL_ASPECT_RATIO,
    KNOWN_RAW_SOURCES,
    PER_LIGHT_MODES,
    IndexSettings,
    Layer,
    Product,
    Recipe,
    View,
    fitted_pixel_aspect,
    inherited_encoding,
    is_data_layer,
    view_problem,
)
from ..request import DEFAULT_RESOLUTION
from . import schema, values

logger = logging.getLogger(__name__)

_PREFIX = schema.ATTRIBUTE_PREFIX
_FULL_FRAME = (0.0, 0.0, 1.0, 1.0)
"""UsdRender's dataWindowNDC fallback: the whole image."""
_RENDERED_COLOUR_SPACES = ("", "lin_rec709_scene")
"""renderingColorSpace values the tracer honours: unset, or GfColorSpaceNames' LinearRec709."""


def find_settings(stage: Usd.Stage, file: str, settings_path: str | None,
                  recipe_layers: Sequence[str | os.PathLike] = ()) -> UsdRender.Settings | None:
    """The one rule for which RenderSettings prim applies, for the recipe and the read alike.

    ``settings_path`` if given (it must be a RenderSettings prim); else the
    ``renderSettingsPrimPath`` of the last recipe layer that names one; else the stage's;
    else the only RenderSettings prim of the stage; None when the stage has none (it
    renders its beauty alone). Several and none named is an error: which one is meant?
    """
    def settings_at(path: str, role: str) -> UsdRender.Settings:
        if not Sdf.Path.IsValidPathString(str(path)) or not Sdf.Path(str(path)).IsAbsolutePath():
            raise RecipeError(f"{role}: not an absolute prim path: {path!r}", file=file)
        prim = stage.GetPrimAtPath(str(path))
        if not prim or not prim.IsActive():
            raise RecipeError(f"{role} does not exist", file=file, prim=str(path))
        if not prim.IsA(UsdRender.Settings):
            raise RecipeError(f"{role} is a {prim.GetTypeName() or 'typeless prim'}, not RenderSettings",
                              file=file, prim=str(path))
        return UsdRender.Settings(prim)

    if settings_path is not None:
        return settings_at(settings_path, "the requested settings")
    key = UsdRender.Tokens.renderSettingsPrimPath
    for layer_path in reversed(list(recipe_layers)):
        layer = Sdf.Layer.FindOrOpen(os.fspath(layer_path))
        named = layer.pseudoRoot.GetInfo(key) if layer and layer.pseudoRoot.HasInfo(key) else ""
        if named:
            return settings_at(named, f"renderSettingsPrimPath of {layer_path}")
    named = stage.GetMetadata("renderSettingsPrimPath")
    if named:
        return settings_at(named, "the stage's renderSettingsPrimPath")
    found = [prim for prim in stage.Traverse() if prim.IsA(UsdRender.Settings)]
    if len(found) > 1:
        paths = ", ".join(str(prim.GetPath()) for prim in found)
        raise RecipeError(f"several RenderSettings prims ({paths}) and no renderSettingsPrimPath: "
                          "name one with --settings", file=file)
    return UsdRender.Settings(found[0]) if found else None


def read_recipe(stage: Usd.Stage, file: str, settings: UsdRender.Settings | None, *,
                default_camera: Callable[[], str], lights: Callable[[], list[tuple[str, str, str]]],
                camera: str | None = None, per_light: str | None = None, check_colour: bool = True,
                time: Usd.TimeCode = Usd.TimeCode.Default()) -> Recipe:
    """Read and validate the recipe of ``settings`` (None: the beauty alone).

    default_camera : the camera of a product whose product and settings name none
                     (the stage's first camera, else the automatic one)
    lights         : (name, path, light group) of every light the render sees, for per-light layers
    camera         : camera prim path overriding the products' and settings' camera
    per_light      : "none" | "lights" | "groups" overriding every product's
                     ``pxrLayers:perLight`` (the CLI's flag)
    check_colour   : check that the OCIO config, display, view and rendering space exist
    time           : when to read the camera's apertures (``adjustPixelAspectRatio``)

    Each product's camera, resolution, pixelAspectRatio and aspectRatioConformPolicy: the
    product's own, else its settings', else those of the stage's ``renderSettingsPrimPath``
    settings (so a preset composed over a shot renders the shot's camera), else UsdRender's
    fallbacks. ``adjustPixelAspectRatio`` is resolved here: the pixel aspect ratio at which
    the product's resolution covers the camera's aperture at ``time``. Settings without
    products, and no settings at all, give one product holding the beauty alone, ``STEM.exr``.

    UsdRender attributes pxr-layers cannot honour: a ``productType`` other than ``raster``
    is a RecipeError; a ``dataWindowNDC`` other than the full frame and a
    ``renderingColorSpace`` other than linear Rec.709 are logged as warnings (the full frame
    is rendered, in linear Rec.709).
    """
    if per_light is not None and per_light not in PER_LIGHT_MODES:
        raise RecipeError(f"unknown per-light mode {per_light!r} (allowed: {', '.join(PER_LIGHT_MODES)})")
    reader = _Reader(stage, file, camera, per_light, check_colour, default_camera, lights, time)
    return reader.recipe(settings)


class _Reader:
    """Reads one stage's recipe prims; every error names ``file``, a prim and an attribute."""

    def __init__(self, stage: Usd.Stage, file: str, camera: str | None, per_light: str | None,
                 check_colour: bool, default_camera: Callable[[], str],
                 lights: Callable[[], list[tuple[str, str, str]]], time: Usd.TimeCode):
        self.stage = stage
        self.time = time
        self.file = file
        self.camera_override = camera
        self.per_light_override = per_light
        self.check_colour = check_colour
        self.default_camera = default_camera
        self.lights = lights

    def error(self, message: str, prim=None, attribute: str | None = None) -> RecipeError:
        path = str(prim.GetPath()) if isinstance(prim, Usd.Prim) else prim
        return RecipeError(message, file=self.file, prim=path, attribute=attribute)

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

    def recipe(self, settings: UsdRender.Settings | None) -> Recipe:
        if settings is None:
            return self.beauty_only(None)
        prim = settings.GetPrim()
        self.check_unknown_attributes(prim, ())
        self.check_colour_space(settings)
        targets = settings.GetProductsRel().GetForwardedTargets()
        if not targets:
            return self.beauty_only(settings)
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

    def beauty_only(self, settings: UsdRender.Settings | None) -> Recipe:
        """No settings, or settings without products: the beauty alone, ``STEM.exr``, at the
        settings' view: camera, resolution, pixel aspect (without settings: the default camera,
        512 × 512, square pixels)."""
        stem = Path(self.file).stem
        view = self.camera_view(settings, None)
        product = Product(name=stem, output_name=f"{stem}.exr", layers=(Layer("color", "raw", BEAUTY_RAW_SOURCE),),
                          **view._asdict())
        settings_path = "" if settings is None else str(settings.GetPath())
        return Recipe(products=(product,), settings_path=settings_path, file=self.file)

    def product(self, settings: UsdRender.Settings, product: UsdRender.Product) -> Product:
        prim = product.GetPrim()
        self.check_unknown_attributes(prim, schema.property_names(schema.PRODUCT_API), schema.PRODUCT_API)
        product_type = product.GetProductTypeAttr()
        if product_type.HasAuthoredValue() and str(product_type.Get()) != "raster":
            raise self.error(f"productType {product_type.Get()!r}: pxr-layers writes raster products only "
                             "(multipart scanline EXRs)", prim, "productType")
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
        self.token(prim, schema.PRODUCT_API, "index:mode", api)
        bounces = int(api["index:bounces"][0])
        if bounces < 0:
            raise self.error(f"must be >= 0, not {bounces}", prim, _PREFIX + "index:bounces")
        index = IndexSettings(bounces=bounces, covariance=str(api["index:covariance"][0]),
                              mode=str(api["index:mode"][0]))

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
                name=prim.GetName(), output_name=output_name, **self.camera_view(settings, product)._asdict(),
                layers=tuple(layers), index=index,
                ocio_config=config, display=display, view=view, rendering_space=space,
                contact_sheet=bool(api["contactSheet"][0]), denoise=bool(api["denoise"][0]), pixel_type=pixel_type,
                compression=compression,
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
        inherited_pixel_type, inherited_compression = inherited_encoding(
            is_data_layer(source_type, source_name, data_type), product_pixel_type, product_compression)
        pixel_type = self.token(prim, schema.VAR_API, "pixelType", api, inherited=inherited_pixel_type)
        compression = self.token(prim, schema.VAR_API, "compression", api, inherited=inherited_compression)
        fields = {
            "name": prim.GetName(), "source_type": source_type, "source_name": source_name,
            "data_type": data_type, "pixel_type": pixel_type, "compression": compression,
            "preview": bool(api["preview"][0]), "exposure": _float32(api["preview:exposure"][0]),
            "tint": tuple(_float32(c) for c in api["preview:tint"][0]), "group": str(api["group"][0]),
            "prim_path": str(prim.GetPath()), "description": prim.GetDocumentation(),
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

    # -- the view: camera, resolution, pixel aspect ---------------------------------------

    def camera_view(self, settings: UsdRender.Settings | None, product: UsdRender.Product | None) -> View:
        """What ``product`` (None: the beauty-only product of ``settings``) renders: its
        camera, resolution, pixel aspect ratio and conform policy (see :func:`read_recipe`).
        Warns when the strongest ``dataWindowNDC`` is not the full frame."""
        owners = self._inheritance(settings, product)
        camera = self.camera(owners)
        resolution = DEFAULT_RESOLUTION if settings is None else self.resolution(owners)
        aspect_attribute, aspect_owner = self._strongest(owners, "pixelAspectRatio")
        pixel_aspect = (DEFAULT_PIXEL_ASPECT_RATIO if aspect_attribute is None
                        else values.real(aspect_attribute, Usd.TimeCode.Default(), self.file))
        policy_attribute, policy_owner = self._strongest(owners, "aspectRatioConformPolicy")
        policy = DEFAULT_CONFORM_POLICY if policy_attribute is None else str(policy_attribute.Get())
        problem = view_problem(pixel_aspect, policy)
        if problem:
            attribute, message = problem
            raise self.error(message, aspect_owner if attribute == "pixelAspectRatio" else policy_owner, attribute)
        if policy == "adjustPixelAspectRatio":
            pixel_aspect = self.fitted_pixel_aspect(camera, resolution, pixel_aspect)
        window_attribute, window_owner = self._strongest(owners, "dataWindowNDC")
        window = None if window_attribute is None else values.reals(window_attribute, Usd.TimeCode.Default(), 4,
                                                                     self.file)
        if window is not None and window != _FULL_FRAME:
            logger.warning("%s: %s.dataWindowNDC is (%s): dataWindowNDC is not supported; rendering the full frame",
                           self.file, window_owner.GetPath(), ", ".join(f"{v:g}" for v in window))
        return View(camera, resolution, pixel_aspect, policy)

    def camera(self, owners: list[UsdRender.SettingsBase]) -> str:
        if self.camera_override is not None:
            prim = self._prim(self.camera_override, "the requested camera")
            return self._checked_camera(prim, None, "the requested camera")
        for owner in owners:
            targets = owner.GetCameraRel().GetForwardedTargets()
            if targets:
                camera = self.stage.GetPrimAtPath(targets[0])
                if not camera or not camera.IsActive():
                    raise self.error(f"camera {targets[0]} does not exist", owner.GetPrim(), "camera")
                return self._checked_camera(camera, owner.GetPrim(), f"camera {targets[0]}")
        return self.default_camera()

    def _checked_camera(self, camera: Usd.Prim, owner: Usd.Prim | None, role: str) -> str:
        if not camera.IsA(UsdGeom.Camera):
            raise self.error(f"{role} is a {camera.GetTypeName() or 'typeless prim'}, not a Camera",
                             owner or camera, "camera" if owner else None)
        return str(camera.GetPath())

    def resolution(self, owners: list[UsdRender.SettingsBase]) -> tuple[int, int]:
        attribute, owner = self._strongest(owners, "resolution")
        if attribute is None:  # UsdRender's fallback
            attribute = owners[-1].GetResolutionAttr()
        value = attribute.Get()
        if value[0] <= 0 or value[1] <= 0:
            raise self.error(f"must be positive, not {tuple(value)}", owner, "resolution")
        return int(value[0]), int(value[1])

    def fitted_pixel_aspect(self, camera: str, resolution: tuple[int, int], authored: float) -> float:
        """adjustPixelAspectRatio: the pixel aspect at which ``resolution`` covers the
        apertures of ``camera`` at the reader's time; ``authored`` when they are not positive
        numbers (reading the camera refuses them later, naming them)."""
        geom = UsdGeom.Camera(self.stage.GetPrimAtPath(camera))
        aperture = (values.real(geom.GetHorizontalApertureAttr(), self.time, self.file),
                    values.real(geom.GetVerticalApertureAttr(), self.time, self.file))
        if not all(value is not None and math.isfinite(value) and value > 0.0 for value in aperture):
            return authored
        return fitted_pixel_aspect(aperture, resolution)

    def check_colour_space(self, settings: UsdRender.Settings) -> None:
        """Warns when the settings' renderingColorSpace is not linear Rec.709, the one the
        tracer renders in."""
        attribute = settings.GetPrim().GetAttribute("renderingColorSpace")
        if attribute and attribute.HasAuthoredValue() and str(attribute.Get()) not in _RENDERED_COLOUR_SPACES:
            logger.warning("%s: %s.renderingColorSpace is %r: not supported; rendering in linear Rec.709 "
                           "(lin_rec709_scene)", self.file, settings.GetPath(), str(attribute.Get()))

    @staticmethod
    def _strongest(owners: list[UsdRender.SettingsBase], name: str) -> tuple[Usd.Attribute | None, Usd.Prim | None]:
        """The UsdRender attribute ``name`` of the strongest owner that authors it, and that
        owner's prim; (None, None) when none does (UsdRender's fallback applies)."""
        for owner in owners:
            attribute = owner.GetPrim().GetAttribute(name)
            if attribute and attribute.HasAuthoredValue():
                return attribute, owner.GetPrim()
        return None, None

    def _inheritance(self, settings: UsdRender.Settings | None, product: UsdRender.Product | None):
        """Where a product's view (camera, resolution, pixel aspect...) comes from, strongest
        first: the product, its settings, the stage's renderSettingsPrimPath settings."""
        owners = [UsdRender.SettingsBase(owner.GetPrim()) for owner in (product, settings) if owner is not None]
        stage_settings = self._stage_settings()
        if stage_settings is not None and (settings is None or stage_settings.GetPath() != settings.GetPath()):
            owners.append(UsdRender.SettingsBase(stage_settings.GetPrim()))
        return owners


def model_prim_paths(stage: Usd.Stage) -> tuple[str, ...]:
    """The paths of the stage's models: prims (instance proxies included) whose ``kind`` is
    a model kind (component, group, assembly or one derived from them), in traversal order.
    CryptoAsset names each object after the nearest of them above it (or itself)."""
    models = []
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate)):
        kind = Usd.ModelAPI(prim).GetKind()
        if kind and Kind.Registry.IsA(kind, Kind.Tokens.model):
            models.append(str(prim.GetPath()))
    return tuple(models)


def _closest(name: str, known: Sequence[str]) -> str | None:
    import difflib

    matches = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return matches[0] if matches else None


def _float32(value) -> float:
    """A float attribute as the shortest decimal that reads back as the same float32 (0.85,
    not 0.8500000238418579)."""
    return float(np.format_float_positional(np.float32(value), unique=True, trim="0"))
