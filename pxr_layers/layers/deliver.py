"""Deliver a recipe: cut every product's layers from a path index in one pass, then write
each product's multipart EXR and its OCIO previews.

This is the last step of ``pxr-layers render``, all of ``pxr-layers extract --recipe``
and of every frame of a job: the same code writes the same files whichever runs it.

Where things go (:func:`plan_outputs`): each product's ``productName`` relative to the
output directory, with ``####`` replaced by the frame number (a name without ``#``
rendered at an explicit frame gets ``.FFFF`` before ``.exr``, so frames never overwrite
each other). An explicit ``.exr`` output path replaces the name of a recipe's only
product; an ``-o`` ending in another file's suffix (``cut.png``) is refused rather than made
a folder, and every output name goes through :func:`pxr_layers.outputs.check_output` (never
a device, FIFO or folder, never a file the command reads: :func:`index_inputs`). Previews go
beside each EXR as ``<exr stem>.<layer>.png`` plus ``<exr stem>.contact.png``.

A product's layers come from three places: ``lpe`` layers from the index (one automaton,
one read of the index for all products), the raw ``color`` var is the beauty (part 0,
not written twice), and the other raw vars (depth, normal, ids, Cryptomattes) from
``data``, the images the tracer rendered beside the beauty. Cryptomatte layers get no
preview and no energy share.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from .. import __version__, lpe
from ..errors import OutputError, PathIndexError, RecipeError
from ..inputs import input_problem
from ..outputs import check_output, folder_suffix_problem
from ..paths.reader import PathIndex
from ..recipe.model import EXR_SUFFIX, Layer, Product, Recipe
from .cryptomatte import Cryptomatte
from .extract import extract
from .exr import METADATA_PREFIX, read_exr
from .multipart import read_multipart, write_multipart
from .nuke import NUKE_SCRIPT_SUFFIX, write_product_script
from .previews import energy_shares, write_previews

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Delivered:
    """One product as written: its EXR, its previews (layer name → PNG, ``"contact"`` for
    the contact sheet), each colour layer's share of the beauty's energy, and its Nuke
    script (None unless asked for)."""

    product: Product
    exr: Path
    previews: dict[str, Path]
    shares: dict[str, float | None]
    nuke_script: Path | None = None


def frame_suffix(frame: float | None) -> str:
    """``.0012`` for frame 12, ``.12.5`` for a fractional time, ``""`` for the default time."""
    if frame is None or (isinstance(frame, float) and math.isnan(frame)):
        return ""
    return f".{frame:04.0f}" if float(frame).is_integer() else f".{frame:g}"


def product_path(product: Product, frame: float | None, directory: Path) -> Path:
    """Where ``product`` goes at ``frame``: its productName with ``#`` runs numbered, or
    ``.FFFF`` added before ``.exr`` when the name has no ``#`` and the frame is explicit."""
    suffix = frame_suffix(frame)
    if "#" in product.output_name or not suffix:
        return product.output_path(frame if suffix else None, directory)
    path = product.output_path(None, directory)
    return path.with_name(path.stem + suffix + path.suffix)


def output_target(output: str | os.PathLike | None, default: Path = Path(".")) -> tuple[Path, Path | None]:
    """(directory, explicit .exr path or None) from ``-o``; ``default`` when it is not given.

    Raises OutputError for an ``-o`` that names another kind of file (``cut.png``,
    ``shot.pxlidx``: :func:`~pxr_layers.outputs.folder_suffix_problem`) or an .exr that
    cannot be written (:func:`~pxr_layers.outputs.check_output`)."""
    text = os.fspath(output) if output is not None else ""
    if text.lower().endswith(EXR_SUFFIX):
        return Path(text).parent, check_output(text, "multipart EXR")
    problem = folder_suffix_problem(text) if text else None
    if problem:
        raise OutputError(f"{text}: {problem}: the products are multipart EXRs (give a folder for them, "
                          f"or one product's {EXR_SUFFIX} file)")
    return Path(text) if text else default, None


def plan_outputs(recipe: Recipe, frame: float | None, directory: Path, exr: Path | None = None) -> dict[str, Path]:
    """Product name → its EXR path. ``exr``: an explicit file for a one-product recipe.

    Raises OutputError when a product's EXR cannot be written there (a folder, a FIFO, a
    device, a file the command reads: :func:`~pxr_layers.outputs.check_output`), before any
    work is done for it."""
    if exr is not None:
        if len(recipe.products) != 1:
            names = ", ".join(product.name for product in recipe.products)
            raise RecipeError(f"-o names one file ({exr}) but the recipe writes {len(recipe.products)} products "
                              f"({names}): give a directory instead", prim=recipe.settings_path or None)
        outputs = {recipe.products[0].name: exr}
    else:
        outputs = {product.name: product_path(product, frame, directory) for product in recipe.products}
    for path in outputs.values():
        check_output(path, "multipart EXR")
    return outputs


def index_inputs(index: PathIndex) -> tuple[Path, ...]:
    """What a command that cuts layers from ``index`` reads or may read, for
    :func:`pxr_layers.outputs.reading`: the index, the render's EXR beside it
    (:func:`beauty_beside`) and the stage it was rendered from (its recipe's base; a look
    saved under the stage's name must not replace it). Some may not exist."""
    stage = index.manifest.get("stage")
    return (index.path, render_exr_path(index), *((Path(stage),) if stage else ()))


def render_exr_path(index: PathIndex) -> Path:
    """Where the render of ``index`` wrote its first product: the manifest's ``beauty``, else
    ``<index stem>.exr``, beside the index."""
    return index.path.parent / index.manifest.get("beauty", index.path.stem + EXR_SUFFIX)


def at_index_view(product: Product, index: PathIndex) -> Product:
    """``product`` at the camera, resolution and pixel aspect ratio of the render (what the
    index holds; an index without ``pixel_aspect_ratio`` has square pixels); logs when the
    product asked for another view."""
    resolution = tuple(index.manifest["resolution"])
    camera = index.manifest.get("camera", product.camera)
    pixel_aspect_ratio = float(index.manifest.get("pixel_aspect_ratio", 1.0))
    if product.resolution != resolution or product.camera != camera or product.pixel_aspect_ratio != pixel_aspect_ratio:
        log.info("%s asks for %s at %dx%d (pixel aspect %g); the index holds %s at %dx%d (pixel aspect %g), which "
                 "is what it gets", product.prim_path or product.name, product.camera, *product.resolution,
                 product.pixel_aspect_ratio, camera, *resolution, pixel_aspect_ratio)
    return dataclasses.replace(product, resolution=resolution, camera=camera, pixel_aspect_ratio=pixel_aspect_ratio)


def index_frame(index: PathIndex) -> float | None:
    """The frame the index was rendered at; None for the stage's default time."""
    frame = index.manifest.get("frame", "default")
    return None if frame == "default" else float(frame)


def raw_sources(recipe: Recipe) -> dict[str, Layer]:
    """The data AOVs the recipe needs from the tracer: source name → first layer asking."""
    needed: dict[str, Layer] = {}
    for product in recipe.products:
        for layer in product.layers:
            if layer.source_type == "raw" and not layer.is_beauty:
                needed.setdefault(layer.source_name, layer)
    return needed


def check_raw_sources(recipe: Recipe, available: tuple[str, ...], why: str) -> None:
    """RecipeError naming the first raw var whose source is not in ``available``."""
    for source, layer in raw_sources(recipe).items():
        if source not in available:
            known = ", ".join(("color", *available)) if available else "color only"
            raise RecipeError(f"raw var asks for {source!r}, which {why} (available: {known})",
                              file=recipe.file or None, prim=layer.prim_path or layer.name, attribute="sourceName")


def deliver(
    index: PathIndex | None,
    recipe: Recipe,
    beauty: np.ndarray,
    outputs: Mapping[str, Path],
    *,
    data: Mapping[str, np.ndarray | Cryptomatte] | None = None,
    metadata: Mapping[str, object] | None = None,
    previews: bool = True,
    nuke_scripts: bool = False,
    show_progress: bool = False,
    guides: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[Delivered]:
    """Extract, write and preview every product of ``recipe``.

    index   : the path index of the render (its resolution is the images'); None when
              the recipe has no lpe layer
    beauty  : (h, w, 4) float32 linear RGBA, part 0 of every product
    outputs : product name → EXR path (see :func:`plan_outputs`)
    data    : raw source name → (h, w) or (h, w, c) float32 image (depth, normal, ...), or
              the Cryptomatte of a Cryptomatte source (CryptoObject, ...)
    metadata: ``pxrLayers/<key>`` attributes on every part (stage, camera, spp, seed...)
    nuke_scripts : also write ``PRODUCT.nk`` beside each EXR (layers.nuke: what
              ``pxr-layers nuke PRODUCT.exr`` writes)
    guides  : the denoiser's (albedo, normal), each (h, w, 3), for the products that write
              their denoised twin ``PRODUCT.denoised.exr`` (Product.denoise;
              :func:`denoised_path`; layers.denoise), whose stack the previews then show;
              both gain the guides (GUIDE_LAYERS)
    """
    data = dict(data or {})
    check_raw_sources(recipe, tuple(data), "this render did not produce")
    expressions = {
        _key(product, layer): layer.source_name
        for product in recipe.products for layer in product.layers if layer.source_type == "lpe"
    }
    extracted = extract(index, expressions, show_progress=show_progress).layers if expressions else {}
    if recipe.denoises:  # the guides are raw parts of a denoised product (and of its twin)
        if guides is None:
            raise ValueError("the recipe has denoised products: deliver needs the render's guides")
        data.update(zip(GUIDE_SOURCES, guides))
    delivered = []
    for product in recipe.products:
        images = {}
        if product.denoise:
            product = dataclasses.replace(product, layers=product.layers + GUIDE_LAYERS)
        for layer in product.layers:
            if layer.source_type == "lpe":
                images[layer.name] = extracted[_key(product, layer)]
            elif not layer.is_beauty:
                images[layer.name] = data[layer.source_name]
        path = write_multipart(outputs[product.name], beauty, images, product, recipe=recipe, metadata=metadata)
        if product.denoise:
            beauty_shown, images = _denoised_twin(product, beauty, images, guides, outputs[product.name], recipe,
                                                  metadata)
        else:
            beauty_shown = beauty
        shown = {name: image for name, image in images.items() if not isinstance(image, Cryptomatte)}
        shares = energy_shares(beauty_shown, shown, {layer.name: layer for layer in product.layers})
        written = write_previews(path.parent, path.stem, beauty_shown, shown, product, shares) if previews else {}
        script = _nuke_script(outputs[product.name], beauty_shown, images, product) if nuke_scripts else None
        delivered.append(Delivered(product, path, written, shares, script))
    return delivered


GUIDE_SOURCES = ("denoiseAlbedo", "denoiseNormal")
GUIDE_LAYERS = tuple(Layer(name=source, source_type="raw", source_name=source, data_type=kind, preview=False,
                           group="denoise") for source, kind in zip(GUIDE_SOURCES, ("float3", "normal3f")))
"""The denoiser's guides (trace/guides.py) as the raw data parts every product of a denoised
render gains, last: ``denoiseAlbedo.X/Y/Z`` (albedo r, g, b) and ``denoiseNormal.X/Y/Z``;
``extract --denoise`` reads them back from the render's EXR."""

DENOISED_SUFFIX = ".denoised"
"""A product's denoised twin: ``X.denoised.exr`` beside ``X.exr``."""


def denoised_path(exr: Path) -> Path:
    """Where the denoised twin of the product ``exr`` goes."""
    return exr.with_name(exr.stem + DENOISED_SUFFIX + exr.suffix)


def _denoised_twin(product: Product, beauty: np.ndarray, images: dict, guides: tuple[np.ndarray, np.ndarray],
                   exr: Path, recipe: Recipe, metadata: Mapping[str, object] | None) -> tuple[np.ndarray, dict]:
    """Write the product's denoised twin beside ``exr``: the same parts, channels and
    headers, the beauty and the colour layers denoised (layers.denoise), data and
    Cryptomatte layers as they are. Returns its (beauty (h, w, 4), images)."""
    from .denoise import denoise_stack

    kinds = {layer.name: layer for layer in product.layers}
    colour = {name: image for name, image in images.items() if not isinstance(image, Cryptomatte)
              and not kinds[name].is_data}
    stack = denoise_stack(beauty, colour, *guides)
    twin_beauty = np.concatenate([stack.beauty, beauty[..., 3:]], axis=-1)
    twin = {**images, **stack.layers}
    twin_metadata = {**(metadata or {}), "denoised": f"oidn inputScale={stack.scale:.6g}"}
    write_multipart(denoised_path(exr), twin_beauty, twin, product, recipe=recipe, metadata=twin_metadata)
    return twin_beauty, twin


def _nuke_script(exr: Path, beauty: np.ndarray, images: Mapping[str, np.ndarray | Cryptomatte],
                 product: Product) -> Path:
    """Write the product's Nuke script, with unit grades, beside its EXR ``exr`` (the final
    path), reading its denoised twin when it has one (``beauty`` and ``images`` then the
    twin's); returns the script's final path."""
    kinds = {layer.name: layer for layer in product.layers}
    script = exr.with_suffix(NUKE_SCRIPT_SUFFIX)
    write_product_script(script, denoised_path(exr) if product.denoise else exr, beauty, {name: image for name, image in images.items() if not kinds[name].is_data},
                         {name: image.depth for name, image in images.items() if isinstance(image, Cryptomatte)},
                         product.pixel_aspect_ratio)
    return script


def _key(product: Product, layer: Layer) -> str:
    return f"{product.name}/{layer.name}"


def index_metadata(index: PathIndex, directory: Path) -> dict[str, object]:
    """The ``pxrLayers/`` metadata of products cut from `index` into `directory`: the
    render's facts, the index's path relative to the products, and its render id."""
    metadata = {"version": __version__, **{key: index.manifest[key] for key in
                                           ("stage", "camera", "frame", "spp", "maxDepth", "seed", "clampIndirect")
                                           if key in index.manifest}}
    metadata["index"] = os.path.relpath(index.path, directory)
    if "render_id" in index.manifest:
        metadata["renderId"] = index.manifest["render_id"]
    return metadata


def cryptomattes_beside(index: PathIndex) -> dict[str, Cryptomatte]:
    """The Cryptomattes of the render's EXR beside the index (its first product), by source
    (CryptoObject, ...): the index cannot give them (it keeps the light paths' records, not
    every camera sample's first hit). Empty when that EXR is missing or holds none; refused
    as :func:`beauty_beside` refuses it."""
    beside = _render_exr_beside(index, header_only=True)  # read_multipart reads it whole, once
    if beside is None:
        return {}
    image = read_multipart(beside[0])
    return {image.metadata[name]["source"]: matte for name, matte in image.cryptomattes.items()}


def guides_beside(index: PathIndex) -> tuple[np.ndarray, np.ndarray] | None:
    """The denoiser's guides (albedo, normal), each (h, w, 3), from the render's EXR beside
    the index (GUIDE_LAYERS: a render with --denoise keeps them); None when it has none."""
    beside = _render_exr_beside(index, header_only=True)
    if beside is None:
        return None
    parts = read_multipart(beside[0]).parts
    if not all(source in parts for source in GUIDE_SOURCES):
        return None
    return tuple(parts[source] for source in GUIDE_SOURCES)


def beauty_beside(index: PathIndex) -> np.ndarray:
    """The render's beauty EXR beside the index, else C.* from the index with alpha 1.

    Raises OutputError when that EXR cannot be read, PathIndexError when another render
    wrote it (its ``pxrLayers/renderId`` is not the index's ``render_id``: two renders into
    one folder): layers cut from this index would not sum to that beauty.
    """
    height_width = tuple(reversed(index.manifest["resolution"]))
    beside = _render_exr_beside(index, header_only=False)
    if beside is not None:
        rgba = beside[1].channels().get("RGBA")
        if rgba is not None and rgba.pixels.shape[:2] == height_width:
            return np.ascontiguousarray(rgba.pixels, dtype=np.float32)
    rgb = extract(index, {"beauty": lpe.BEAUTY}).layers["beauty"]
    return np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], axis=2)


def _render_exr_beside(index: PathIndex, *, header_only: bool) -> tuple[Path, OpenEXR.File] | None:
    """The EXR the render of ``index`` wrote beside it (:func:`render_exr_path`) and its
    contents (its headers only with ``header_only``); None when there is no such file.

    Raises OutputError when OpenEXR cannot read it, PathIndexError when its
    ``pxrLayers/renderId`` is not the index's ``render_id`` (another render wrote it).
    """
    beside = render_exr_path(index)
    if not beside.exists():
        return None
    try:
        problem = input_problem(beside, "multipart EXR")
        if problem is not None:  # a FIFO would block the read
            raise OutputError(problem)
        exr = read_exr(beside, header_only=header_only)  # a beauty cut short is refused, not read in part
    except Exception as error:  # the binding raises RuntimeError and others for a damaged file
        cause = str(error).removeprefix(f"{beside}: ")
        raise OutputError(f"{beside}: the render's EXR beside {index.path.name} cannot be read ({cause}); "
                          "remove it to rebuild the beauty from the index") from error
    expected = index.manifest.get("render_id")
    found = exr.header().get(METADATA_PREFIX + "renderId")
    if expected is not None and found != expected:
        raise PathIndexError(f"{beside.name} beside it comes from another render (renderId {found or 'none'}, "
                             f"the index's is {expected}): two renders wrote into this folder; render "
                             "again, or move that EXR away to rebuild the beauty from the index",
                             file=str(index.path))
    return beside, exr
