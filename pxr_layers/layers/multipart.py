"""The deliverable: one multipart OpenEXR per recipe product, as compositors read it.

Part 0 is named ``rgba`` and holds the beauty as R, G, B, A. Then one part per layer, in
recipe order, named after the layer, with channels ``<layer>.R/G/B`` (data layers:
``depth.Z``, ``normal.X/Y/Z``, ``primId.id``; see :attr:`pxr_layers.recipe.Layer.channels`).
Every part has the same data window (the image size), the same Rec.709 chromaticities and
the product's ``pixelAspectRatio`` (a pixel's width over its height), no ``view`` attribute
(mono), its own pixel type and compression from the recipe, and string metadata under
``pxrLayers/``:

* every part: ``pxrLayers/version`` and the caller's metadata (spp, seed, frame, stage...);
  ``pxrLayers/sourceType``, ``pxrLayers/expression`` (lpe layers; ``C.*`` on the beauty)
  or ``pxrLayers/source`` (raw layers), ``pxrLayers/dataType``, ``pxrLayers/group``;
* part 0 also: ``pxrLayers/recipe`` (the resolved recipe as JSON) and
  ``pxrLayers/expressions`` (JSON layer name → expression).

A Cryptomatte layer ``NAME`` (layers/cryptomatte.py) is written as the parts ``NAME00``,
``NAME01``, ... (channels ``NAME00.R/G/B/A``, float32), each with ``pxrLayers/cryptomatte``
= NAME and the type's ``cryptomatte/<key>/name|hash|conversion|manifest`` attributes, which
part 0 carries too (the Nuke gizmo reads the first part's metadata).

Written with ``OpenEXR.File([OpenEXR.Part(...), ...])`` under a temporary name, then renamed.
Note: the OpenEXR 3.5 Python binding ignores numpy strides (a non-contiguous view such as
``rgb[..., 0]`` is written as if it were contiguous, i.e. wrong pixels, silently), so every
channel handed to it here is a contiguous array.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenEXR

from .. import __version__
from ..errors import OutputError
from ..inputs import input_problem
from ..outputs import write_atomically
from ..recipe.model import (
    BEAUTY_EXPRESSION,
    BEAUTY_PART,
    DEFAULT_PIXEL_ASPECT_RATIO,
    Layer,
    Product,
    Recipe,
    channels_for,
    cryptomatte_parts,
    is_data_layer,
)
from .cryptomatte import ATTRIBUTE_PREFIX, Cryptomatte, header_attributes, type_key
from .exr import METADATA_PREFIX, header, read_exr, use_cores
from .previews import HALF_MAX

logger = logging.getLogger(__name__)

COMPRESSION = {
    "none": OpenEXR.NO_COMPRESSION,
    "rle": OpenEXR.RLE_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
    "zip": OpenEXR.ZIP_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "pxr24": OpenEXR.PXR24_COMPRESSION,
    "b44": OpenEXR.B44_COMPRESSION,
    "b44a": OpenEXR.B44A_COMPRESSION,
    "dwaa": OpenEXR.DWAA_COMPRESSION,
    "dwab": OpenEXR.DWAB_COMPRESSION,
}
"""Recipe compression token → OpenEXR enum."""
DTYPE = {"float": np.float32, "half": np.float16}


def write_multipart(
    path: str | os.PathLike,
    beauty: np.ndarray,
    layers: Mapping[str, np.ndarray],
    product: Product | None = None,
    *,
    recipe: Recipe | str | None = None,
    spp: int | None = None,
    seed: int | None = None,
    frame: float | None = None,
    metadata: Mapping[str, object] | None = None,
) -> Path:
    """Write the beauty and the layers of one product as a multipart EXR; returns the path.

    beauty   : (h, w, 4) float32 linear RGBA (part 0 ``rgba``)
    layers   : layer name → (h, w, c) float32 (c = the layer's channel count, 3 for a
               colour layer) or (h, w) for one channel; same h, w as the beauty; a
               :class:`~pxr_layers.layers.cryptomatte.Cryptomatte` for a Cryptomatte layer
    product  : the recipe product: part order, channel names, pixel types, compressions,
               expressions and every part's ``pixelAspectRatio``. With a product,
               ``layers`` must hold exactly its layers but the beauty's raw ``color`` var,
               which is part 0 (not written twice).
               None: parts in the mapping's order, float32, ZIP, channels R G B (3),
               R G B A (4) or Y (1), square pixels.
    recipe   : the resolved Recipe (or its JSON), stored as ``pxrLayers/recipe`` on part 0
    spp, seed, frame : written as ``pxrLayers/spp``, ``/seed``, ``/frame`` on every part
    metadata : extra ``pxrLayers/<key>`` string attributes on every part (stage, camera,
               maxDepth, ...); values are written with str()

    Half parts hold values clamped to ±65504. Raises ValueError for arrays that do not fit
    the recipe, OutputError when the file cannot be written.
    """
    path = Path(path)
    beauty = np.asarray(beauty)
    if beauty.ndim != 3 or beauty.shape[2] != 4:
        raise ValueError(f"beauty must be (h, w, 4) RGBA, got shape {beauty.shape}")
    height, width = beauty.shape[:2]
    specs = _layer_specs(layers, product)

    run = {key: value for key, value in (("spp", spp), ("seed", seed), ("frame", frame)) if value is not None}
    common = {"version": __version__, **run, **{str(k): v for k, v in (metadata or {}).items()}}
    beauty_type = product.pixel_type if product else "float"
    beauty_compression = product.compression if product else "zip"
    pixel_aspect = product.pixel_aspect_ratio if product else DEFAULT_PIXEL_ASPECT_RATIO

    def new_header(compression: str) -> dict:
        return header(COMPRESSION[compression], common, pixel_aspect_ratio=pixel_aspect)

    head = new_header(beauty_compression)
    head[METADATA_PREFIX + "sourceType"] = "lpe"
    head[METADATA_PREFIX + "expression"] = BEAUTY_EXPRESSION
    if recipe is not None:
        head[METADATA_PREFIX + "recipe"] = recipe if isinstance(recipe, str) else recipe.to_json()
    head[METADATA_PREFIX + "expressions"] = json.dumps(
        {spec.name: spec.source_name for spec in specs if spec.source_type == "lpe"}, separators=(",", ":")
    )
    parts = [OpenEXR.Part(head, {"RGBA": _pixels(beauty, beauty_type)}, BEAUTY_PART)]

    for spec in specs:
        if spec.is_cryptomatte:
            attributes = _cryptomatte_attributes(spec, layers[spec.name], (height, width))
            head.update(attributes)
            for number, part in enumerate(cryptomatte_parts(spec.name, layers[spec.name].depth)):
                part_header = new_header(spec.compression)
                part_header.update({METADATA_PREFIX + "sourceType": spec.source_type,
                                    METADATA_PREFIX + "source": spec.source_name,
                                    METADATA_PREFIX + "dataType": spec.data_type, METADATA_PREFIX + "group": spec.group,
                                    METADATA_PREFIX + "cryptomatte": spec.name, **attributes})
                pixels = layers[spec.name].part_pixels(number)
                channels = {f"{part}.{suffix}": _pixels(pixels[..., index], "float")
                            for index, suffix in enumerate(spec.channels)}
                parts.append(OpenEXR.Part(part_header, channels, part))
            continue
        image = np.asarray(layers[spec.name])
        if image.ndim == 2:
            image = image[..., None]
        if image.shape != (height, width, len(spec.channels)):
            raise ValueError(
                f"layer {spec.name!r}: expected shape {(height, width, len(spec.channels))} "
                f"(channels {', '.join(spec.channels)}), got {np.asarray(layers[spec.name]).shape}"
            )
        part_header = new_header(spec.compression)
        part_header[METADATA_PREFIX + "sourceType"] = spec.source_type
        part_header[METADATA_PREFIX + ("expression" if spec.source_type == "lpe" else "source")] = spec.source_name
        part_header[METADATA_PREFIX + "dataType"] = spec.data_type
        part_header[METADATA_PREFIX + "group"] = spec.group
        channels = {
            f"{spec.name}.{suffix}": _pixels(image[..., index], spec.pixel_type)
            for index, suffix in enumerate(spec.channels)
        }
        parts.append(OpenEXR.Part(part_header, channels, spec.name))

    use_cores()

    def write(temporary: Path) -> None:
        try:
            OpenEXR.File(parts).write(str(temporary))
        except (RuntimeError, ValueError, TypeError) as error:  # the binding's own failures
            raise OutputError(f"{path}: OpenEXR cannot write the file ({error})") from error

    write_atomically(path, write)
    logger.info("wrote %s: %d parts, %d x %d", path, len(parts), width, height)
    return path


def _layer_specs(layers: Mapping[str, np.ndarray], product: Product | None) -> list[Layer]:
    """The recipe Layer of each image, in part order (defaults when there is no product)."""
    if product is None:
        # Without a recipe, each image is a raw var named after itself (colour for 3 or 4
        # channels, a float data layer for 1).
        specs = []
        for name, image in layers.items():
            channels = 1 if np.ndim(image) == 2 else np.shape(image)[-1]
            data_type = {3: "color3f", 4: "color4f"}.get(channels, "float")
            specs.append(Layer(name, "raw", name, data_type=data_type))
        return specs
    parts = [layer for layer in product.layers if not layer.is_beauty]
    missing = [layer.name for layer in parts if layer.name not in layers]
    extra = [name for name in layers if name not in {layer.name for layer in parts}]
    if missing or extra:
        raise ValueError(
            f"the images do not match product {product.name!r}: "
            + "; ".join(filter(None, [missing and f"missing {', '.join(missing)}",
                                      extra and f"not in the recipe {', '.join(extra)}"]))
        )
    return parts


def _cryptomatte_attributes(spec: Layer, image, size: tuple[int, int]) -> dict[str, str]:
    """The header attributes of the Cryptomatte layer ``spec``; ValueError if ``image`` is not
    a Cryptomatte of the image's size."""
    if not isinstance(image, Cryptomatte) or image.ids.shape[:2] != size or image.coverage.shape != image.ids.shape:
        found = image.ids.shape if isinstance(image, Cryptomatte) else type(image).__name__
        raise ValueError(f"layer {spec.name!r}: expected a Cryptomatte of {size[1]}x{size[0]} pixels, got {found}")
    return header_attributes(spec.name, image.manifest)


def _pixels(values: np.ndarray, pixel_type: str) -> np.ndarray:
    """A C-contiguous array of the part's pixel type (the binding ignores strides)."""
    dtype = DTYPE[pixel_type]
    if dtype is np.float16:
        values = np.clip(values, -HALF_MAX, HALF_MAX)
    return np.ascontiguousarray(values, dtype=dtype)


@dataclass(frozen=True)
class MultipartImage:
    """A product written by :func:`write_multipart`, read back.

    beauty : (h, w, 4) float32, part 0
    parts  : layer name → (h, w, c) float32 in channel order (``Layer.channels``), in part order
    metadata : layer name → its ``pxrLayers/`` attributes without the prefix (sourceType,
               expression or source, dataType, group, ...); a Cryptomatte layer's are its first part's
    recipe : the resolved Recipe stored on part 0, or None (a file written without one)
    cryptomattes : Cryptomatte layer name → its ranks and manifest (its parts ``NAME00``, ...
               are not in ``parts``)
    beauty_metadata : part 0's ``pxrLayers/`` attributes without the prefix (renderId, index,
               spp, ...; the recipe and the expressions apart)
    pixel_aspect_ratio : part 0's ``pixelAspectRatio``: a pixel's width over its height
    """

    path: Path
    beauty: np.ndarray
    parts: dict[str, np.ndarray]
    metadata: dict[str, dict[str, str]]
    recipe: Recipe | None
    cryptomattes: dict[str, Cryptomatte] = field(default_factory=dict)
    beauty_metadata: dict[str, str] = field(default_factory=dict)
    pixel_aspect_ratio: float = DEFAULT_PIXEL_ASPECT_RATIO

    def colour_layers(self) -> dict[str, np.ndarray]:
        """The colour layers (lpe layers and raw vars of a colour dataType; not data layers,
        :func:`~pxr_layers.recipe.model.is_data_layer`; a part of another writer without
        three channels is not one), in part order: name → (h, w, 3) float32 R, G, B (a color4
        layer's alpha dropped)."""
        colour = {}
        for name, image in self.parts.items():
            meta = self.metadata.get(name, {})
            source_type = meta.get("sourceType", "raw")
            data = is_data_layer(source_type, meta.get("source", name), meta.get("dataType", "color3f"))
            if not data and image.shape[-1] >= 3:
                colour[name] = image[..., :3]
        return colour


def read_multipart(path: str | os.PathLike) -> MultipartImage:
    """Read a multipart EXR of pxr-layers (any part types, as float32).

    Raises OutputError naming the file when it cannot be read whole (:func:`~.exr.read_exr`:
    damaged, or its last bytes cut off), part 0 is not an RGBA
    beauty, or a Cryptomatte part lacks a channel ``NAME.R/G/B/A`` or a readable manifest.
    """
    path = Path(path)
    # before OpenEXR, whose C library prints its own line for a missing file (and blocks on a FIFO)
    problem = input_problem(path, "multipart EXR")
    if problem is not None:
        raise OutputError(f"{path}: {problem}")
    exr = read_exr(path, separate_channels=True)  # whole: a file cut short is refused, not read in part
    first = exr.parts[0]
    if sorted(first.channels) != ["A", "B", "G", "R"]:
        raise OutputError(f"{path}: part 0 is not an RGBA beauty (channels {', '.join(sorted(first.channels))})")
    beauty = np.stack([first.channels[c].pixels for c in "RGBA"], axis=-1).astype(np.float32)
    parts, metadata = {}, {}
    crypto_parts: dict[str, list[np.ndarray]] = {}
    manifests: dict[str, dict[str, str]] = {}
    for part in exr.parts[1:]:
        name = part.name()
        attributes = {key[len(METADATA_PREFIX):]: str(value) for key, value in part.header.items()
                      if key.startswith(METADATA_PREFIX)}
        if "cryptomatte" in attributes:
            layer = attributes["cryptomatte"]
            metadata.setdefault(layer, attributes)
            stored = part.header.get(f"{ATTRIBUTE_PREFIX}{type_key(layer)}/manifest", "{}")
            manifests[layer] = _manifest(path, name, stored)
            missing = [f"{name}.{c}" for c in "RGBA" if f"{name}.{c}" not in part.channels]
            if missing:
                raise OutputError(f"{path}: the Cryptomatte part {name!r} has no channel {', '.join(missing)} "
                                  f"(it has {', '.join(sorted(part.channels)) or 'none'})")
            crypto_parts.setdefault(layer, []).append(
                np.stack([part.channels[f"{name}.{c}"].pixels for c in "RGBA"], axis=-1).astype(np.float32))
            continue
        suffixes = channels_for(attributes.get("sourceType", "raw"), attributes.get("expression")
                                or attributes.get("source", name), attributes.get("dataType", "color3f"))
        channels = [f"{name}.{suffix}" for suffix in suffixes]
        if not all(channel in part.channels for channel in channels):  # not our layout: file order
            channels = sorted(part.channels)
        parts[name] = np.stack([part.channels[c].pixels for c in channels], axis=-1).astype(np.float32)
        metadata[name] = attributes
    stored = first.header.get(METADATA_PREFIX + "recipe")
    cryptomattes = {layer: Cryptomatte.from_parts(pieces, manifests[layer]) for layer, pieces in crypto_parts.items()}
    beauty_metadata = {key[len(METADATA_PREFIX):]: str(value) for key, value in first.header.items()
                       if key.startswith(METADATA_PREFIX) and key[len(METADATA_PREFIX):] not in ("recipe", "expressions")}
    return MultipartImage(path, beauty, parts, metadata, Recipe.from_json(stored) if stored else None, cryptomattes,
                          beauty_metadata, float(first.header.get("pixelAspectRatio", DEFAULT_PIXEL_ASPECT_RATIO)))


def _manifest(path: Path, part: str, text: str) -> dict[str, str]:
    """A Cryptomatte part's manifest (JSON name → id hex); OutputError naming the file and part
    when it is not a JSON object."""
    try:
        manifest = json.loads(text)
    except json.JSONDecodeError as error:
        raise OutputError(f"{path}: the Cryptomatte manifest of part {part!r} is not JSON ({error})") from None
    if not isinstance(manifest, dict):
        raise OutputError(f"{path}: the Cryptomatte manifest of part {part!r} is not a JSON object of names")
    return manifest
