"""The resolved recipe: frozen, validated dataclasses that everything downstream reads.

Nothing here imports pxr. :func:`pxr_layers.stage.load_recipe` (``Shot.recipe``) builds
these from USD;
tests and the CLI may also build them directly (construction validates the same rules and
raises :class:`~pxr_layers.errors.RecipeError`).

The token tuples and fallbacks below repeat those of ``schemas/schema.usda`` (the source of
truth); ``tests/test_schema.py`` checks that they agree with the registered schema.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from ..errors import RecipeError
from ..outputs import confined_name_problem
from ..paths.format import MODES as INDEX_FORMAT_MODES

PIXEL_TYPES = ("float", "half")
COMPRESSIONS = ("none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab")
LOSSY_COMPRESSIONS = frozenset({"pxr24", "b44", "b44a", "dwaa", "dwab"})
"""Compressions that change float32 data: refused on data layers."""
SOURCE_TYPES = ("lpe", "raw")
"""The RenderVar sourceTypes pxr-layers renders (UsdRender also has primvar, intrinsic)."""
COVARIANCE_MODES = ("norms", "sigma")
INDEX_MODES = INDEX_FORMAT_MODES
"""How the path index keeps the light (paths/format.py): merged, the default, or records."""
MAX_PREVIEW_STOPS = 64
"""A preview's exposure, in stops, at most this far from 0: 2^64 brightens the faintest
float32 light to white and keeps the gain finite (2^128 overflows float32 to inf)."""
PER_LIGHT_MODES = ("none", "lights", "groups")
EXR_SUFFIX = ".exr"
"""What every product's file name ends with (its productName; ``-o`` when it names one
product's file rather than a folder): a product is a multipart OpenEXR."""
RECIPE_SUFFIXES = (".usda", ".usd", ".usdc")
"""The names a recipe is written under (``suggest -o``, the inspector's save): USD layers
that USD exports (.usda text, .usd and .usdc crate); a .usdz package is read-only to it."""

DEFAULT_PIXEL_TYPE = "float"
DEFAULT_COMPRESSION = "zip"
DEFAULT_INDEX_BOUNCES = 5
MAX_INDEX_BOUNCES = 64
"""The most events per path whose covariance norms the index keeps: each costs every record
6 bytes (C, T, R as float16), and light past 64 bounces is below any threshold an artist
sets (a path that long carries a 1e-6 share of a scene's light with albedos of 0.8)."""
DEFAULT_OCIO_CONFIG = "ocio://studio-config-v2.2.0_aces-v1.3_ocio-v2.4"
"""Pinned built-in config (OCIO >= 2.4). ``ocio://default`` and ``*-latest`` resolve to a
different config with each OCIO release, and OpenImageIO's wheel bundles another OCIO than
PyOpenColorIO: with 2.6.0 / OIIO 3.2.2 ``studio-config-latest`` is v5.0.0 in one, v4.0.0 in
the other."""
DEFAULT_DISPLAY = "sRGB - Display"
DEFAULT_VIEW = "ACES 1.0 - SDR Video"
RENDERING_SPACE = "Linear Rec.709 (sRGB)"
"""The colour space of the rendered pixels (linear, Rec.709 primaries, D65) in the ACES
studio and CG configs; its aliases there include ``lin_rec709_srgb`` and ``lin_srgb``."""

CONFORM_POLICIES = ("expandAperture", "cropAperture", "adjustApertureWidth", "adjustApertureHeight",
                    "adjustPixelAspectRatio")
"""UsdRender's aspectRatioConformPolicy tokens: how the camera's aperture is fitted to an image
of another aspect (trace/camera.py)."""
DEFAULT_CONFORM_POLICY = "expandAperture"
DEFAULT_PIXEL_ASPECT_RATIO = 1.0
"""UsdRender's fallbacks of aspectRatioConformPolicy and pixelAspectRatio (square pixels)."""

DEFAULT_CAMERA_PATH = "/World/Camera"
"""The camera of a product built from an index or image that names none (the camera of the
bundled scenes): a recipe written from it targets this prim."""

BEAUTY_PART = "rgba"
"""Name of part 0 of every product: the beauty, channels R, G, B, A."""
BEAUTY_EXPRESSION = "C.*"
BEAUTY_RAW_SOURCE = "color"
"""A raw var of this source is the beauty (Hydra's ``color`` AOV): written once, as part 0."""

COLOUR_DATA_TYPES = frozenset({"color3f", "color3h", "color3d", "color4f", "color4h", "color4d"})
"""RenderVar dataTypes of colour layers; every other dataType is a data layer."""
LPE_DATA_TYPES = frozenset({"color3f", "color3h", "color3d"})
VECTOR_DATA_TYPES = frozenset({"float3", "half3", "double3", "normal3f", "normal3h", "vector3f", "vector3h",
                               "point3f", "point3h"})
SCALAR_DATA_TYPES = frozenset({"float", "half", "double", "int", "uint", "int64", "uint64"})

RAW_CHANNELS = {
    "depth": ("Z",),
    "normal": ("X", "Y", "Z"),
    "Neye": ("X", "Y", "Z"),
    "Peye": ("X", "Y", "Z"),
    "primId": ("id",),
    "instanceId": ("id",),
    "elementId": ("id",),
}
"""Channel names of the Hydra AOVs a renderer fills for ``raw`` vars (``depth.Z``, ...)."""
CRYPTOMATTE_SOURCES = ("CryptoObject", "CryptoMaterial", "CryptoAsset")
"""The raw sources of Cryptomatte layers (ids of the prim path, the bound material's path,
the model root's path; docs/compositing.md). Such a layer ``NAME`` is written as the parts
``NAME00``, ``NAME01``, ... (channels R G B A = id, coverage, id, coverage)."""
DEFAULT_CRYPTOMATTE_DEPTH = 6
"""Ranks (ids per pixel) of a Cryptomatte layer: 6, three parts (the specification's suggestion)."""
MAX_CRYPTOMATTE_DEPTH = 24
"""The most ranks the Nuke gizmo keys: two per part, and it has 12 input-layer knobs
``in00`` ... ``in11`` (layers/nuke.py)."""
KNOWN_RAW_SOURCES = frozenset({BEAUTY_RAW_SOURCE, *RAW_CHANNELS, *CRYPTOMATTE_SOURCES})
CRYPTOMATTE_KINDS = {"object": "CryptoObject", "material": "CryptoMaterial", "asset": "CryptoAsset"}
"""The words of ``--cryptomatte object,material,asset`` and their sources."""
CRYPTOMATTE_DATA_TYPE = "float4"

LAYER_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
"""What a layer name is (an identifier: the EXR part and the RenderVar prim name); also
exactly the layer names Nuke keeps as they are (layers/nuke.py)."""


def channels_for(source_type: str, source_name: str, data_type: str) -> tuple[str, ...]:
    """EXR channel suffixes of a layer: ``("R", "G", "B")`` for colour, ``("Z",)`` for depth...

    lpe and colour dataTypes: R G B (A for color4*). raw: the Hydra AOV's convention
    (RAW_CHANNELS), R G B A for each part of a Cryptomatte source, else by dataType: X Y Z
    for vectors, Y for scalars.
    """
    if source_type == "raw" and source_name in CRYPTOMATTE_SOURCES:
        return ("R", "G", "B", "A")
    if source_type == "lpe" or data_type in COLOUR_DATA_TYPES:
        return ("R", "G", "B", "A") if data_type.startswith("color4") else ("R", "G", "B")
    if source_name in RAW_CHANNELS:
        return RAW_CHANNELS[source_name]
    if data_type in VECTOR_DATA_TYPES:
        return ("X", "Y", "Z")
    return ("Y",)


def is_data_layer(source_type: str, source_name: str, data_type: str) -> bool:
    """A data layer (a var of a non-colour dataType, or a Cryptomatte): float, lossless, no
    energy share, not in a colour stack. The one rule of :attr:`Layer.is_data`, the USD
    reader and files read back (:meth:`~pxr_layers.layers.multipart.MultipartImage.colour_layers`)."""
    return data_type not in COLOUR_DATA_TYPES or (source_type == "raw" and source_name in CRYPTOMATTE_SOURCES)


def inherited_encoding(data: bool, pixel_type: str, compression: str) -> tuple[str, str]:
    """The (pixel type, compression) a var that authors neither takes from its product's
    ``pixel_type`` and ``compression``: both for a colour layer; for a data layer (``data``,
    :func:`is_data_layer`) only what keeps data exact: float, and DEFAULT_COMPRESSION (the
    schema's fallback) in place of a lossy compression. The rule of the USD reader and writer."""
    if not data:
        return pixel_type, compression
    return "float", DEFAULT_COMPRESSION if compression in LOSSY_COMPRESSIONS else compression


def cryptomatte_parts(name: str, depth: int) -> tuple[str, ...]:
    """The EXR parts of the Cryptomatte layer ``name`` at ``depth`` ranks: ``NAME00``, ... (two ranks each)."""
    return tuple(f"{name}{part:02d}" for part in range((depth + 1) // 2))


def view_problem(pixel_aspect_ratio: float, conform_policy: str) -> tuple[str, str] | None:
    """The first rule a pixel aspect ratio and an aperture conform policy break, as (UsdRender
    attribute name, message); None when both are valid. Shared by :class:`Product`, the USD
    reader (which names the prim that authors the value) and trace/camera.py."""
    if not (math.isfinite(pixel_aspect_ratio) and pixel_aspect_ratio > 0.0):
        return ("pixelAspectRatio",
                f"is {pixel_aspect_ratio:g}: a pixel's width over its height must be a positive number")
    if conform_policy not in CONFORM_POLICIES:
        return "aspectRatioConformPolicy", f"unknown policy {conform_policy!r} (allowed: {', '.join(CONFORM_POLICIES)})"
    return None


def fitted_pixel_aspect(aperture: tuple[float, float], resolution: tuple[int, int]) -> float:
    """The pixel aspect ratio (pixel width / pixel height) at which an image of ``resolution``
    (width, height) in pixels covers exactly a camera ``aperture`` (horizontal, vertical, any
    one unit): what the ``adjustPixelAspectRatio`` conform policy uses (UsdRenderComputeSpec)."""
    return (aperture[0] / aperture[1]) * resolution[1] / resolution[0]


def layer_problems(layer: Layer) -> list[tuple[str, str]]:
    """Every rule ``layer`` breaks, as (USD attribute name, message); empty when valid.

    Shared by :class:`Layer` (which raises on the first) and the USD loader (which names the
    RenderVar prim and attribute).
    """
    problems: list[tuple[str, str]] = []
    if not LAYER_NAME.fullmatch(layer.name):
        problems.append(("", f"layer name {layer.name!r} is not an identifier (letters, digits, _)"))
    elif layer.name == BEAUTY_PART:
        problems.append(("", f"layer name {BEAUTY_PART!r} is reserved for the beauty (part 0)"))
    if layer.source_type not in SOURCE_TYPES:
        problems.append(("sourceType", (f"unknown source type {layer.source_type!r} (pxr-layers reads "
                                       f"{', '.join(SOURCE_TYPES)})")))
        return problems
    if not layer.source_name.strip():
        problems.append(("sourceName", "is empty"))
    if layer.source_type == "lpe" and layer.data_type not in LPE_DATA_TYPES:
        problems.append(("dataType", (f"an lpe layer is a colour: dataType must be one of "
                                     f"{', '.join(sorted(LPE_DATA_TYPES))}, not {layer.data_type!r}")))
    if layer.pixel_type not in PIXEL_TYPES:
        problems.append(("pxrLayers:pixelType", (f"unknown pixel type {layer.pixel_type!r} "
                                                f"(allowed: {', '.join(PIXEL_TYPES)})")))
    elif layer.is_data and layer.pixel_type == "half":
        problems.append(("pxrLayers:pixelType", (f"half on a data layer (dataType {layer.data_type}): "
                                                "data layers stay float")))
    if layer.compression not in COMPRESSIONS:
        problems.append(("pxrLayers:compression", (f"unknown compression {layer.compression!r} "
                                                  f"(allowed: {', '.join(COMPRESSIONS)})")))
    elif layer.is_data and layer.compression in LOSSY_COMPRESSIONS:
        problems.append(("pxrLayers:compression", (f"{layer.compression} is lossy: not allowed on a data "
                                                  f"layer (dataType {layer.data_type}); use zip, zips or piz")))
    if not (math.isfinite(layer.exposure) and abs(layer.exposure) <= MAX_PREVIEW_STOPS):
        problems.append(("pxrLayers:preview:exposure",
                         f"must be a finite number of stops within ±{MAX_PREVIEW_STOPS}, not {layer.exposure}"))
    if len(layer.tint) != 3 or not all(math.isfinite(c) and c >= 0 for c in layer.tint):
        problems.append(("pxrLayers:preview:tint", f"must be three finite values >= 0, not {layer.tint}"))
    return problems


@dataclass(frozen=True)
class Layer:
    """One layer of a product: one RenderVar, one EXR part named ``name``.

    name        : the RenderVar's prim name = the EXR part name (channels ``name.R`` ...)
    source_type : "lpe" (source_name is an extended Light Path Expression) or "raw" (a
                  renderer AOV such as depth, normal, primId)
    data_type   : the RenderVar's dataType; colour types make colour layers, the rest data
    pixel_type  : "float" (32-bit) or "half" (colour layers only)
    compression : OpenEXR compression of the part (lossy ones refused on data layers)
    preview     : write a PNG preview; exposure (stops) and tint (linear RGB multiplier)
                  grade the preview and the contact-sheet tile only
    group       : free-form group name (part metadata, contact-sheet order)
    prim_path   : the RenderVar it was read from; "" for generated layers
    description : one line on what the layer holds, for people ("the key light's light on
                  the floor"): the RenderVar's USD documentation (``doc`` metadata)
    """

    name: str
    source_type: str = "lpe"
    source_name: str = BEAUTY_EXPRESSION
    data_type: str = "color3f"
    pixel_type: str = DEFAULT_PIXEL_TYPE
    compression: str = DEFAULT_COMPRESSION
    preview: bool = True
    exposure: float = 0.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    group: str = ""
    prim_path: str = ""
    description: str = ""

    def __post_init__(self):
        object.__setattr__(self, "tint", tuple(float(c) for c in self.tint))
        object.__setattr__(self, "exposure", float(self.exposure))
        problems = layer_problems(self)
        if problems:
            attribute, message = problems[0]
            raise RecipeError(message, prim=self.prim_path or f"layer {self.name!r}", attribute=attribute or None)

    @property
    def is_data(self) -> bool:
        """A data layer (raw var of a non-colour dataType, or a Cryptomatte): float, lossless,
        no energy share (:func:`is_data_layer`)."""
        return is_data_layer(self.source_type, self.source_name, self.data_type)

    @property
    def is_cryptomatte(self) -> bool:
        """A Cryptomatte layer (raw var of a CRYPTOMATTE_SOURCES source): parts ``NAME00``, ..."""
        return self.source_type == "raw" and self.source_name in CRYPTOMATTE_SOURCES

    @property
    def is_beauty(self) -> bool:
        """The Hydra ``color`` AOV as a raw var: it is the beauty, which part 0 already holds."""
        return self.source_type == "raw" and self.source_name == BEAUTY_RAW_SOURCE

    @property
    def expression(self) -> str | None:
        """The Light Path Expression of an lpe layer, else None."""
        return self.source_name if self.source_type == "lpe" else None

    @property
    def channels(self) -> tuple[str, ...]:
        """EXR channel suffixes: the part holds ``f"{name}.{suffix}"`` for each."""
        return channels_for(self.source_type, self.source_name, self.data_type)


@dataclass(frozen=True)
class IndexSettings:
    """What the path index keeps, per path.

    bounces    : N, the events after the camera whose covariance is kept (conditions can
                 test events 1..N only); 0 keeps none
    covariance : "norms" (|S_C| 1/m, |S_T| cycles/m, |S_R| cycles/rad per event) or
                 "sigma" (also the whole 4×4 Σ, for conditions on S11, S22, ...)
    mode       : "merged" (one record per pixel, path class and covariance bin) or
                 "records" (one per contribution), paths/format.py
    """

    bounces: int = DEFAULT_INDEX_BOUNCES
    covariance: str = "norms"
    mode: str = INDEX_MODES[0]

    def __post_init__(self):
        if not isinstance(self.bounces, int) or not 0 <= self.bounces <= MAX_INDEX_BOUNCES:
            raise RecipeError(f"must be an integer from 0 to {MAX_INDEX_BOUNCES}, not {self.bounces!r}",
                              attribute="pxrLayers:index:bounces")
        if self.covariance not in COVARIANCE_MODES:
            raise RecipeError(f"unknown covariance {self.covariance!r} (allowed: {', '.join(COVARIANCE_MODES)})",
                              attribute="pxrLayers:index:covariance")
        if self.mode not in INDEX_MODES:
            raise RecipeError(f"unknown index mode {self.mode!r} (allowed: {', '.join(INDEX_MODES)})",
                              attribute="pxrLayers:index:mode")


class View(NamedTuple):
    """What the camera sees: the Product fields every product of one render shares.

    camera     : prim path of the UsdGeom.Camera
    resolution : (width, height) in pixels
    pixel_aspect_ratio, aspect_ratio_conform_policy : as :class:`Product`'s
    """

    camera: str
    resolution: tuple[int, int]
    pixel_aspect_ratio: float = DEFAULT_PIXEL_ASPECT_RATIO
    aspect_ratio_conform_policy: str = DEFAULT_CONFORM_POLICY


_VIEW_DEFAULTS = {"pixel_aspect_ratio": DEFAULT_PIXEL_ASPECT_RATIO,
                  "aspect_ratio_conform_policy": DEFAULT_CONFORM_POLICY}
"""Product fields that :meth:`Recipe.to_dict` leaves out at these values: the JSON of a recipe
of square pixels and the fallback policy (the EXR's ``pxrLayers/recipe``, a job's fingerprint)
is byte for byte what it was before the fields existed."""


@dataclass(frozen=True)
class Product:
    """One RenderProduct: one multipart EXR (part 0 ``rgba`` = beauty, then ``layers``).

    output_name     : the productName, e.g. ``shot.####.exr`` (see :meth:`output_path`)
    camera          : prim path of the UsdGeom.Camera
    resolution      : (width, height) in pixels
    index           : what the path index keeps
    ocio_config     : OCIO config URI or file of the previews; display, view: its display
                      and view; rendering_space: the colour space of the EXR pixels in it
    contact_sheet   : write a contact sheet of all layers
    denoise         : also write the denoised twin PRODUCT.denoised.exr (layers/denoise.py)
    pixel_type, compression : of the beauty part (and the default of the vars)
    per_light       : "none", "lights" or "groups": what per-light layers were added
    pixel_aspect_ratio : a pixel's width over its height (UsdRender pixelAspectRatio): the
                      image's aspect ratio is width × pixel_aspect_ratio / height, and every
                      EXR part says it in its ``pixelAspectRatio``; already resolved for
                      ``adjustPixelAspectRatio`` (:func:`fitted_pixel_aspect`)
    aspect_ratio_conform_policy : how the camera's aperture fits that image aspect
                      (CONFORM_POLICIES, UsdRender aspectRatioConformPolicy)
    """

    name: str
    output_name: str
    camera: str
    resolution: tuple[int, int]
    layers: tuple[Layer, ...]
    index: IndexSettings = field(default_factory=IndexSettings)
    ocio_config: str = DEFAULT_OCIO_CONFIG
    display: str = DEFAULT_DISPLAY
    view: str = DEFAULT_VIEW
    rendering_space: str = RENDERING_SPACE
    contact_sheet: bool = True
    denoise: bool = False
    pixel_type: str = DEFAULT_PIXEL_TYPE
    compression: str = DEFAULT_COMPRESSION
    per_light: str = "none"
    prim_path: str = ""
    pixel_aspect_ratio: float = DEFAULT_PIXEL_ASPECT_RATIO
    aspect_ratio_conform_policy: str = DEFAULT_CONFORM_POLICY

    def __post_init__(self):
        object.__setattr__(self, "layers", tuple(self.layers))
        object.__setattr__(self, "resolution", tuple(int(v) for v in self.resolution))
        object.__setattr__(self, "pixel_aspect_ratio", float(self.pixel_aspect_ratio))
        where = self.prim_path or f"product {self.name!r}"
        problem = view_problem(self.pixel_aspect_ratio, self.aspect_ratio_conform_policy)
        if problem:
            raise RecipeError(problem[1], prim=where, attribute=problem[0])
        if not self.layers:
            raise RecipeError("the product has no layers (orderedVars is empty and perLight is none)",
                              prim=where, attribute="orderedVars")
        seen: dict[str, Layer] = {}
        for layer in self.layers:
            if layer.name in seen:
                first = seen[layer.name].prim_path or "a generated layer"
                second = layer.prim_path or "a generated layer"
                raise RecipeError(f"duplicate layer name {layer.name!r}: {first} and {second} "
                                  "would write the same EXR part", prim=where, attribute="orderedVars")
            seen[layer.name] = layer
        if len(self.resolution) != 2 or min(self.resolution) <= 0:
            raise RecipeError(f"resolution must be two positive integers, not {self.resolution}",
                              prim=where, attribute="resolution")
        if self.pixel_type not in PIXEL_TYPES:
            raise RecipeError(f"unknown pixel type {self.pixel_type!r} (allowed: {', '.join(PIXEL_TYPES)})",
                              prim=where, attribute="pxrLayers:pixelType")
        if self.compression not in COMPRESSIONS:
            raise RecipeError(f"unknown compression {self.compression!r} (allowed: {', '.join(COMPRESSIONS)})",
                              prim=where, attribute="pxrLayers:compression")
        if self.per_light not in PER_LIGHT_MODES:
            raise RecipeError(f"unknown perLight {self.per_light!r} (allowed: {', '.join(PER_LIGHT_MODES)})",
                              prim=where, attribute="pxrLayers:perLight")
        if not self.output_name.lower().endswith(EXR_SUFFIX):
            raise RecipeError(f"productName {self.output_name!r} must name an {EXR_SUFFIX} file", prim=where,
                              attribute="productName")
        # Relative to the output folder and inside it, as a job's stem is: a recipe is data
        # from anywhere (a preset, a layer a colleague sent) and must not choose where files go.
        escape = confined_name_problem(self.output_name)
        if escape:
            raise RecipeError(f"productName {escape}", prim=where, attribute="productName")

    @property
    def camera_view(self) -> View:
        """What the camera sees for this product (one render feeds every product of a recipe)."""
        return View(self.camera, self.resolution, self.pixel_aspect_ratio, self.aspect_ratio_conform_policy)

    @property
    def layer_names(self) -> tuple[str, ...]:
        return tuple(layer.name for layer in self.layers)

    def layer(self, name: str) -> Layer:
        for layer in self.layers:
            if layer.name == name:
                return layer
        raise KeyError(f"product {self.name!r} has no layer {name!r} (layers: {', '.join(self.layer_names)})")

    def expressions(self) -> dict[str, str]:
        """Layer name → Light Path Expression, for the lpe layers, in recipe order."""
        return {layer.name: layer.source_name for layer in self.layers if layer.source_type == "lpe"}

    def output_path(self, frame: float | None = None, directory: str | Path | None = None) -> Path:
        """The EXR path: each run of ``#`` in output_name becomes the frame number padded to
        the run's length (``####`` → 0012), relative to ``directory`` (the name is relative:
        :func:`~pxr_layers.outputs.confined_name_problem`)."""
        name = self.output_name
        if frame is not None:
            number = round(frame)
            name = re.sub(r"#+", lambda run: f"{number:0{len(run.group())}d}", name)
        return Path(name) if directory is None else Path(directory) / name


@dataclass(frozen=True)
class Recipe:
    """A resolved recipe: the products of one RenderSettings prim.

    settings_path : the RenderSettings prim read ("" when built in code)
    file          : the root layer of the stage it was read from ("" when built in code)
    """

    products: tuple[Product, ...]
    settings_path: str = ""
    file: str = ""

    def __post_init__(self):
        object.__setattr__(self, "products", tuple(self.products))
        if not self.products:
            raise RecipeError("the recipe has no products", prim=self.settings_path or None, attribute="products")
        outputs: dict[str, str] = {}
        for product in self.products:
            other = outputs.setdefault(product.output_name, product.prim_path or product.name)
            if other != (product.prim_path or product.name):
                raise RecipeError(f"productName {product.output_name!r} is also written by {other}",
                                  prim=product.prim_path or product.name, attribute="productName")

    def product(self, name: str | None = None) -> Product:
        """The product called ``name`` (its prim name); None: the first product."""
        if name is None:
            return self.products[0]
        for product in self.products:
            if product.name == name:
                return product
        raise KeyError(f"no product {name!r} (products: {', '.join(p.name for p in self.products)})")

    def view(self) -> tuple[str, tuple[int, int]]:
        """The camera and resolution every product renders (one render feeds all products;
        :meth:`shared_view` says all it shares)."""
        return self.shared_view()[:2]

    def shared_view(self) -> View:
        """What every product renders: its camera, resolution, pixel aspect ratio and conform
        policy. One render feeds all products, so they must agree: RecipeError naming each
        product's view when they do not."""
        views = {product.camera_view for product in self.products}
        if len(views) > 1:
            described = "; ".join(f"{p.prim_path or p.name}: {p.camera} at {p.resolution[0]}x{p.resolution[1]}, "
                                  f"pixel aspect {p.pixel_aspect_ratio:g}, {p.aspect_ratio_conform_policy}"
                                  for p in self.products)
            raise RecipeError("the products ask for different cameras, resolutions, pixel aspect ratios or "
                              f"conform policies, and one render feeds them all ({described}): render them "
                              "with separate --settings", file=self.file or None, prim=self.settings_path or None)
        return views.pop()

    def to_dict(self) -> dict:
        """The recipe as plain values (``dataclasses.asdict``), without the view fields of a
        product at their fallbacks (_VIEW_DEFAULTS)."""
        values = dataclasses.asdict(self)
        for product in values["products"]:
            for key, fallback in _VIEW_DEFAULTS.items():
                if product[key] == fallback:
                    del product[key]
        return values

    def to_json(self) -> str:
        """Compact, key-sorted JSON of the whole recipe (the EXR's ``pxrLayers/recipe``)."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> Recipe:
        """The recipe :meth:`to_json` wrote (validated again). Raises RecipeError on JSON that
        is not such a recipe."""
        try:
            values = json.loads(text)
            products = tuple(
                Product(**{**product, "layers": tuple(Layer(**layer) for layer in product["layers"]),
                           "index": IndexSettings(**product["index"])})
                for product in values.pop("products"))
            return cls(products, **values)
        except (ValueError, TypeError, KeyError, AttributeError) as error:
            raise RecipeError(f"not a recipe written by pxr-layers ({error})") from None

    def with_cryptomattes(self, sources) -> Recipe:
        """A copy in which every product has a Cryptomatte layer of each of ``sources``
        (CRYPTOMATTE_SOURCES), named after it, unless it already has a layer of that source."""
        products = []
        for product in self.products:
            have = {layer.source_name for layer in product.layers if layer.is_cryptomatte}
            added = tuple(Layer(source, "raw", source, data_type=CRYPTOMATTE_DATA_TYPE, preview=False)
                          for source in dict.fromkeys(sources) if source not in have)
            products.append(dataclasses.replace(product, layers=product.layers + added))
        return dataclasses.replace(self, products=tuple(products))

    def with_denoise(self) -> Recipe:
        """A copy in which every product writes its denoised twin (``--denoise``)."""
        return dataclasses.replace(self, products=tuple(dataclasses.replace(product, denoise=True)
                                                        for product in self.products))

    @property
    def denoises(self) -> bool:
        """Whether some product writes a denoised twin (the render keeps the guides)."""
        return any(product.denoise for product in self.products)

    def with_layers(self, layers, product: str | None = None) -> Recipe:
        """A copy with ``layers`` appended to a product (None: every product).

        Raises RecipeError on a duplicate layer name.
        """
        layers = tuple(layers)
        products = tuple(
            dataclasses.replace(p, layers=p.layers + layers) if product in (None, p.name) else p
            for p in self.products
        )
        if product is not None:
            self.product(product)  # KeyError for an unknown name
        return dataclasses.replace(self, products=products)
