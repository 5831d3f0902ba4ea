""":class:`~pxr_layers.recipe.model.Recipe` → a USD recipe layer that reads back as the same recipe.

The inverse of :mod:`.recipe_reader`: plain UsdRender (RenderSettings → RenderProduct →
RenderVar) with the pxr-layers API schemas applied, laid out as the presets are, under one
scope named after the file so that it composes over a shot without merging into the shot's
own ``/Render`` prims::

    /Render/<scope>/Settings            RenderSettings: products, camera, resolution
    /Render/<scope>/Products/<product>  RenderProduct + PxrLayersProductAPI
    /Render/<scope>/Vars/<layer>        RenderVar + PxrLayersVarAPI

The layer's ``renderSettingsPrimPath`` names the settings, so ``--recipe FILE`` (and
``load_recipe(shot, recipe_layers=[FILE])``) picks them. A var's ``dataType``,
``sourceType`` and ``sourceName`` are always authored (they are the layer); a
``pxrLayers:*`` attribute only when it differs from what the reader would take without it
(the schema's fallback, or for a var's pixel type and compression the product's), so a
recipe shows what is particular to it. Camera and resolution (and a pixel aspect ratio and
conform policy other than UsdRender's fallbacks) go on the settings when every product
shares them, else on each product.

What reads back differently:

* float attributes are USD ``float`` (32-bit): an exposure or tint reads back as the
  shortest decimal of its float32 (0.1 stays 0.1, 1/3 becomes 0.33333334);
* per-light layers are written as the vars they resolved to (the light list frozen when
  the recipe is written), so such a product reads back with ``per_light`` "none";
* a layer two products share (equal, in products of equal pixel type and compression) is
  one var both target; when two products have different vars of one name, every
  product's vars get their own scope, ``/Render/<scope>/Vars/<product>/<layer>``;
* ``prim_path`` is where the writer put the prim.

The camera is a relationship to the shot's camera prim: read the recipe composed over the
shot it was made for (as ``pxr-layers extract`` does when the index's stage is there).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Iterable
from pathlib import Path

from pxr import Gf, Sdf, Tf, Usd, UsdRender

from .. import __version__
from ..errors import RecipeError
from ..outputs import write_atomically
from ..recipe.model import (
    DEFAULT_CONFORM_POLICY,
    DEFAULT_PIXEL_ASPECT_RATIO,
    Layer,
    Product,
    Recipe,
    View,
    inherited_encoding,
)
from . import schema
from .opening import trapped_usd_diagnostics

logger = logging.getLogger(__name__)

_PREFIX = schema.ATTRIBUTE_PREFIX


def valid_prim_name(text: str) -> str:
    """``text`` made a USD identifier, a valid prim name: every character but ASCII letters,
    digits and ``_`` (and a leading digit) becomes ``_`` (``my-look`` → ``my_look``)."""
    return Tf.MakeValidIdentifier(text)


def write_recipe(path: str | os.PathLike, recipe: Recipe) -> Path:
    """Write ``recipe`` as a USD layer at ``path`` (``.usda``: text; ``.usd``/``.usdc``: crate).

    The prims go under ``/Render/<scope>``, scope = the file's stem made a USD identifier
    (:func:`valid_prim_name`: ``my-look.usda`` → ``my_look``). Product names must be USD identifiers (they are the
    product prims' names, and what the reader gives back as ``Product.name``); layer names
    already are. Written under a temporary name and renamed (:func:`write_atomically`);
    returns where the file is now (its temporary while an OutputSet holds it). Raises
    RecipeError for a product name that cannot be a prim name, OutputError when the file
    cannot be written.
    """
    path = Path(path)
    scope = Sdf.Path("/Render").AppendChild(valid_prim_name(path.stem))
    for product in recipe.products:
        if not Sdf.Path.IsValidIdentifier(product.name):
            raise RecipeError(f"product name {product.name!r} is not a USD identifier (letters, digits, _): "
                              "it would be the RenderProduct's prim name", file=str(path))
    with trapped_usd_diagnostics(str(path)):
        layer = _author(recipe, scope)

    def export(temporary: Path) -> None:
        with trapped_usd_diagnostics(str(path)):
            if not layer.Export(str(temporary)):
                raise OSError(f"USD could not export the layer to {temporary.name}")

    written = write_atomically(path, export)
    if written == path:
        # A layer of this path that this process holds open (a stage still alive) would
        # otherwise hide the new file from the next composition.
        with trapped_usd_diagnostics(str(path)):
            cached = Sdf.Layer.Find(str(path))
            if cached is not None:
                cached.Reload(force=True)
    logger.info("wrote the recipe %s: %d products under %s", path, len(recipe.products), scope)
    return written


def _author(recipe: Recipe, scope: Sdf.Path) -> Sdf.Layer:
    """An anonymous layer holding the recipe's prims under ``scope``."""
    layer = Sdf.Layer.CreateAnonymous(".usda")  # held here: the stage only borrows it
    stage = Usd.Stage.Open(layer)
    settings_path = scope.AppendChild("Settings")
    layer.pseudoRoot.SetInfo(UsdRender.Tokens.renderSettingsPrimPath, str(settings_path))
    layer.documentation = f"pxr-layers recipe, written by pxr-layers {__version__}."
    for path in (scope.GetParentPath(), scope):
        stage.DefinePrim(path, "Scope")
    settings = UsdRender.Settings.Define(stage, settings_path)
    for path in (scope.AppendChild("Products"), scope.AppendChild("Vars")):
        stage.DefinePrim(path, "Scope")

    views = {product.camera_view for product in recipe.products}
    shared_view = views.pop() if len(views) == 1 else None
    if shared_view is not None:
        _author_view(settings, shared_view)
    targets, vars_ = _placed_vars(recipe.products, scope.AppendChild("Vars"))
    product_paths = []
    for product in recipe.products:
        product_path = scope.AppendChild("Products").AppendChild(product.name)
        product_paths.append(product_path)
        render_product = _author_product(stage, product_path, product)
        if shared_view is None:
            _author_view(render_product, product.camera_view)
        render_product.CreateOrderedVarsRel().SetTargets(
            [targets[(product.name, _unplaced(layer_value))] for layer_value in product.layers])
    settings.CreateProductsRel().SetTargets(product_paths)
    for var_path, (layer_value, product) in vars_.items():
        _author_var(stage, var_path, layer_value, product)
    return layer


def _unplaced(layer: Layer) -> Layer:
    """The layer without where it was read from: what decides whether two layers are one var."""
    return dataclasses.replace(layer, prim_path="")


def _placed_vars(products: Iterable[Product], vars_scope: Sdf.Path
                 ) -> tuple[dict[tuple[str, Layer], Sdf.Path], dict[Sdf.Path, tuple[Layer, Product]]]:
    """Where every product's layers go: ((product name, layer) → var path, var path → (layer,
    the first product holding it)).

    Products share the var of a layer when the var would be authored alike for each: the
    layers are equal and so are the products' pixel type and compression (what a var
    inherits). Two different vars of one name put every product's vars in a scope of its own.
    """
    products = list(products)

    def definition(product: Product, layer: Layer) -> tuple:
        return _unplaced(layer), product.pixel_type, product.compression

    definitions: dict[str, set[tuple]] = {}
    for product in products:
        for layer in product.layers:
            definitions.setdefault(layer.name, set()).add(definition(product, layer))
    per_product = any(len(variants) > 1 for variants in definitions.values())
    targets: dict[tuple[str, Layer], Sdf.Path] = {}
    vars_: dict[Sdf.Path, tuple[Layer, Product]] = {}
    for product in products:
        for layer in map(_unplaced, product.layers):
            scope = vars_scope.AppendChild(product.name) if per_product else vars_scope
            path = scope.AppendChild(layer.name)
            targets[(product.name, layer)] = path
            vars_.setdefault(path, (layer, product))
    return targets, vars_


def _author_view(owner: UsdRender.SettingsBase, view: View) -> None:
    """The camera and resolution, and the pixel aspect ratio and conform policy unless they
    are UsdRender's fallbacks."""
    if view.camera:
        owner.CreateCameraRel().SetTargets([Sdf.Path(view.camera)])
    owner.CreateResolutionAttr(Gf.Vec2i(*view.resolution))
    if view.pixel_aspect_ratio != DEFAULT_PIXEL_ASPECT_RATIO:
        owner.CreatePixelAspectRatioAttr(view.pixel_aspect_ratio)
    if view.aspect_ratio_conform_policy != DEFAULT_CONFORM_POLICY:
        owner.CreateAspectRatioConformPolicyAttr(view.aspect_ratio_conform_policy)


def _author_product(stage: Usd.Stage, path: Sdf.Path, product: Product) -> UsdRender.Product:
    render_product = UsdRender.Product.Define(stage, path)
    render_product.GetPrim().ApplyAPI(schema.PRODUCT_API)
    render_product.CreateProductNameAttr(product.output_name)
    values = {
        "pixelType": product.pixel_type,
        "compression": product.compression,
        "index:bounces": product.index.bounces,
        "index:covariance": product.index.covariance,
        "index:mode": product.index.mode,
        "ocio:config": product.ocio_config,
        "ocio:display": product.display,
        "ocio:view": product.view,
        "ocio:renderingSpace": product.rendering_space,
        "contactSheet": product.contact_sheet,
        "denoise": product.denoise,
    }
    for short, value in values.items():
        _author_if_needed(render_product.GetPrim(), schema.PRODUCT_API, short, value)
    return render_product


def _author_var(stage: Usd.Stage, path: Sdf.Path, layer: Layer, product: Product) -> None:
    var = UsdRender.Var.Define(stage, path)
    stage.GetPrimAtPath(path.GetParentPath()).SetTypeName("Scope")  # Define made a per-product scope typeless
    var.GetPrim().ApplyAPI(schema.VAR_API)
    var.CreateDataTypeAttr(layer.data_type)
    var.CreateSourceTypeAttr(layer.source_type)
    var.CreateSourceNameAttr(layer.source_name)
    if layer.description:
        var.GetPrim().SetDocumentation(layer.description)
    # What the reader takes when the var does not author them.
    inherited_pixel_type, inherited_compression = inherited_encoding(layer.is_data, product.pixel_type,
                                                                     product.compression)
    values = {
        "pixelType": (layer.pixel_type, inherited_pixel_type),
        "compression": (layer.compression, inherited_compression),
        "preview": (layer.preview, None),
        "preview:exposure": (layer.exposure, None),
        "preview:tint": (layer.tint, None),
        "group": (layer.group, None),
    }
    for short, (value, inherited) in values.items():
        _author_if_needed(var.GetPrim(), schema.VAR_API, short, value, inherited)


def _author_if_needed(prim: Usd.Prim, api: str, short: str, value, inherited=None) -> None:
    """Author ``pxrLayers:<short>`` = ``value`` unless the reader would read that without it:
    ``inherited`` when given, else the schema's fallback."""
    name = _PREFIX + short
    default = inherited if inherited is not None else schema.fallback(api, name)
    if value == default:
        return
    definition = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(api).GetAttributeDefinition(name)
    attribute = prim.CreateAttribute(name, definition.GetTypeName(), custom=False,
                                     variability=definition.GetVariability())
    attribute.Set(Gf.Vec3f(*value) if short == "preview:tint" else value)
