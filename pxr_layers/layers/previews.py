"""Colour-managed previews: each layer through an OCIO display/view to PNG, and a contact sheet.

The transform is PyOpenColorIO's CPU processor, built once per (config, display, view,
rendering space) and applied to whole arrays; OpenImageIO writes the PNGs and draws the
contact sheet's text (``ImageBufAlgo.render_text`` with the DroidSans font bundled in the
OpenImageIO wheel). Both libraries give identical results on the pinned built-in config,
but they bundle different OCIO versions, so the config is always named explicitly (see
:data:`pxr_layers.recipe.model.DEFAULT_OCIO_CONFIG`).

The EXR pixels are linear Rec.709 (sRGB primaries, D65): in the ACES studio and CG configs
that is the colour space ``Linear Rec.709 (sRGB)``, the default ``rendering_space``.

Data layers (depth, normals, ids) are not colours: their previews map the finite values to
0..1 (normals: 0.5 + 0.5·n; otherwise min..max per layer) without any colour transform.
"""

from __future__ import annotations

import logging
import errno
import math
import os
from collections.abc import Iterable, Mapping
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import RecipeError
from ..recipe.model import (
    BEAUTY_PART,
    DEFAULT_DISPLAY,
    DEFAULT_OCIO_CONFIG,
    DEFAULT_VIEW,
    RENDERING_SPACE,
    Layer,
    Product,
)
from ..colour import REC709_LUMINANCE
from ..outputs import write_atomically

logger = logging.getLogger(__name__)

HALF_MAX = float(np.finfo(np.float16).max)
"""65504, the largest finite half: where half EXR parts clamp, and what the previews (and the
inspector's display LUT) take +inf for."""
LUMINANCE_WEIGHTS = np.array(REC709_LUMINANCE, dtype=np.float64)
"""Rec.709 luminance of linear RGB: the 'energy' of a layer on the contact sheet."""
FONT = "DroidSans"
"""Bundled with the OpenImageIO wheel, so the sheet looks the same on every machine."""
FONT_SIZE = 13
LABEL_HEIGHT = 38
DESCRIPTION_LINES = 2
"""Lines of a layer's description under its tile on the contact sheet."""
MARGIN = 6
BACKGROUND = 32  # 8-bit grey behind the tiles
TEXT_COLOUR = (0.92, 0.92, 0.92)
DIM_TEXT_COLOUR = (0.65, 0.65, 0.65)


class ColourError(RecipeError):
    """An OCIO config, display, view or colour space that does not exist.

    ``setting`` is "config", "display", "view" or "renderingSpace" (the recipe attribute
    ``pxrLayers:ocio:<setting>``).
    """

    def __init__(self, message: str, setting: str):
        super().__init__(message, attribute=f"pxrLayers:ocio:{setting}")
        self.setting = setting


# --- OCIO ------------------------------------------------------------------------------


@lru_cache(maxsize=8)
def _config(uri: str):
    import PyOpenColorIO as ocio

    try:
        return ocio.Config.CreateFromFile(uri)
    except ocio.Exception as error:  # OCIO's one exception type, for every failure
        raise ColourError(f"cannot load OCIO config {uri!r}: {error}", "config") from None


def check_colour_settings(config: str = DEFAULT_OCIO_CONFIG, display: str = DEFAULT_DISPLAY,
                          view: str = DEFAULT_VIEW, rendering_space: str = RENDERING_SPACE) -> None:
    """Raise ColourError unless the config loads and has the display, view and colour space.

    The rendering space may be any name or alias the config knows.
    """
    loaded = _config(config)
    displays = list(loaded.getDisplays())
    if display not in displays:
        raise ColourError(f"display {display!r} is not in {config} (displays: {', '.join(displays)})", "display")
    views = list(loaded.getViews(display))
    if view not in views:
        raise ColourError(f"view {view!r} is not a view of {display!r} in {config} (views: {', '.join(views)})",
                          "view")
    if loaded.getColorSpace(rendering_space) is None:
        raise ColourError(f"colour space {rendering_space!r} is not in {config}", "renderingSpace")


def display_views(config: str = DEFAULT_OCIO_CONFIG, display: str = DEFAULT_DISPLAY) -> list[str]:
    """The views (view transforms) `config` offers for `display`, in its order."""
    return list(_config(config).getViews(display))


@lru_cache(maxsize=16)
def display_processor(config: str = DEFAULT_OCIO_CONFIG, display: str = DEFAULT_DISPLAY, view: str = DEFAULT_VIEW,
                      rendering_space: str = RENDERING_SPACE):
    """The CPU processor rendering space → (display, view), built once and cached."""
    import PyOpenColorIO as ocio

    check_colour_settings(config, display, view, rendering_space)
    processor = _config(config).getProcessor(rendering_space, display, view, ocio.TRANSFORM_DIR_FORWARD)
    return processor.getDefaultCPUProcessor()


def to_display(rgb: np.ndarray, processor=None, exposure: float = 0.0,
               tint: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """Linear RGB → 8-bit display RGB.

    rgb : (h, w, 3) or (h, w, 4) float, linear, in the rendering space (alpha ignored)
    processor : from :func:`display_processor` (None: the pinned default)
    exposure : stops; tint : linear RGB multiplier; both applied before the transform
    Returns (h, w, 3) uint8. NaN becomes 0, +inf the largest half value.
    """
    processor = processor or display_processor()
    gain = np.float32(2.0 ** float(exposure)) * np.asarray(tint, dtype=np.float32)
    pixels = np.ascontiguousarray(rgb[..., :3], dtype=np.float32) * gain
    np.nan_to_num(pixels, copy=False, nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)
    processor.applyRGB(pixels)
    return _quantise(pixels)


def data_to_display(values: np.ndarray) -> np.ndarray:
    """A data layer → (h, w, 3) uint8: normals as 0.5 + 0.5·n, anything else min..max → 0..1.

    values : (h, w) or (h, w, c) float; non-finite values show black.
    """
    values = np.asarray(values, dtype=np.float32)
    if values.ndim == 2:
        values = values[..., None]
    finite = np.isfinite(values)
    shown = np.where(finite, values, 0.0).astype(np.float32)
    if finite.any():
        low, high = float(shown[finite].min()), float(shown[finite].max())
        if values.shape[-1] == 3 and low >= -1.0001 and high <= 1.0001:
            shown = 0.5 + 0.5 * shown
        elif high > low:
            shown = (shown - low) / (high - low)
        else:
            shown = np.zeros_like(shown)
    shown = np.where(finite, shown, 0.0)
    if shown.shape[-1] == 1:
        shown = np.repeat(shown, 3, axis=-1)
    return _quantise(shown[..., :3])


def _quantise(pixels: np.ndarray) -> np.ndarray:
    return (np.clip(pixels, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


# --- files -----------------------------------------------------------------------------


PNG_COMPRESSION_LEVEL = 1
"""zlib level of the previews: half the time of OIIO's default (6) for 3 % more bytes (a
shot writes dozens of previews per frame)."""
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
"""The IEND chunk every complete PNG ends with."""


def write_png(path: str | os.PathLike, pixels: np.ndarray, description: str | None = None) -> Path:
    """Write (h, w, 3) uint8 pixels as an 8-bit PNG, atomically (with an ImageDescription)."""
    import OpenImageIO as oiio

    path = Path(path)
    buffer = oiio.ImageBuf(np.ascontiguousarray(pixels, dtype=np.uint8))
    buffer.specmod().attribute("png:compressionLevel", PNG_COMPRESSION_LEVEL)
    if description is not None:
        buffer.specmod().attribute("ImageDescription", description)

    def write(temporary: Path) -> None:
        if not buffer.write(str(temporary)):
            raise OSError(buffer.geterror())
        with open(temporary, "rb") as file:  # OIIO's PNG writer can report success on a full disk
            file.seek(max(0, temporary.stat().st_size - len(PNG_END)))
            if file.read() != PNG_END:
                raise OSError(errno.ENOSPC, "the PNG is cut short (is the disk full?)")

    write_atomically(path, write)
    return path


def _display_image(image: np.ndarray, layer: Layer | None, processor) -> np.ndarray:
    if layer is not None and layer.is_data:
        return data_to_display(image)
    if layer is None:
        return to_display(image, processor)
    return to_display(image, processor, layer.exposure, layer.tint)


def write_previews(directory: str | os.PathLike, stem: str, beauty: np.ndarray, images: Mapping[str, np.ndarray],
                   product: Product | None = None, shares: Mapping[str, float | None] | None = None) -> dict[str, Path]:
    """The PNG previews of a product: ``{stem}.rgba.png`` (the beauty), ``{stem}.{layer}.png``
    for every layer with ``preview`` on, and ``{stem}.contact.png`` if the product asks (and
    has layers).

    beauty : (h, w, 4|3) float32 linear; images : layer name → its pixels (as for
    :func:`pxr_layers.layers.multipart.write_multipart`); product : colour settings and
    per-layer grades (None: defaults, every layer previewed, a contact sheet); shares: the
    layers' :func:`energy_shares` if already known. Returns name → path (the contact sheet
    under ``"contact"``).
    """
    directory = Path(directory)
    settings = _colour_settings(product)
    processor = display_processor(*settings)
    layers = _layers_of(product, images)
    written = {BEAUTY_PART: write_png(directory / f"{stem}.{BEAUTY_PART}.png", to_display(beauty, processor))}
    for name, image in images.items():
        layer = layers[name]
        if layer.preview:
            written[name] = write_png(directory / f"{stem}.{name}.png", _display_image(image, layer, processor))
    if images and (product is None or product.contact_sheet):
        written["contact"] = write_contact_sheet(directory / f"{stem}.contact.png", beauty, images, product,
                                                 shares=shares)
    logger.info("wrote %d previews in %s", len(written), directory)
    return written


# --- contact sheet ---------------------------------------------------------------------


def energy_shares(beauty: np.ndarray, images: Mapping[str, np.ndarray],
                  layers: Mapping[str, Layer] | None = None) -> dict[str, float | None]:
    """Each colour layer's share of the beauty's energy (summed Rec.709 luminance), 0..1+.

    Data layers and an all-black beauty give None. Summed in float64.
    """
    total = image_energy(beauty)
    shares: dict[str, float | None] = {}
    for name, image in images.items():
        layer = (layers or {}).get(name)
        if (layer is not None and layer.is_data) or total == 0.0 or np.ndim(image) != 3 or image.shape[-1] < 3:
            shares[name] = None
        else:
            shares[name] = image_energy(image) / total
    return shares


PARTITION_TOLERANCE = 1e-4
"""Colour layers partition the beauty when they sum to it within this, relative to its peak."""


def layers_partition(beauty: np.ndarray, images: Iterable[np.ndarray]) -> bool:
    """The colour layers sum to the beauty: at every pixel and channel within
    PARTITION_TOLERANCE × the beauty's peak |R, G, B| (sums in float64); False for no layers.

    beauty : (h, w, 3 or 4) linear RGB(A); images : each (h, w, 3 or more), same h, w (R, G, B count)
    """
    rgb = np.asarray(beauty)[..., :3]
    layers = [np.asarray(image)[..., :3] for image in images]
    if not layers:
        return False
    total = np.sum(layers, axis=0, dtype=np.float64)
    peak = float(np.abs(rgb).max(initial=0.0))
    return bool(np.abs(total - rgb).max(initial=0.0) <= PARTITION_TOLERANCE * peak)


def image_energy(image: np.ndarray) -> float:
    """Σ Rec.709 luminance of (h, w, ≥3) linear rgb, float64 (NaN pixels left out)."""
    image = np.asarray(image)
    # One channel at a time: 10x faster than nansum over the (h, w, 3) view (a 1080p layer:
    # 4 against 40 ms); NaN, rare, then takes nansum's way.
    sums = np.array([image[..., channel].sum(dtype=np.float64) for channel in range(3)])
    if not np.isfinite(sums).all():
        sums = np.nansum(image[..., :3], axis=(0, 1), dtype=np.float64)
    return float(sums @ LUMINANCE_WEIGHTS)


def write_contact_sheet(path: str | os.PathLike, beauty: np.ndarray, images: Mapping[str, np.ndarray],
                        product: Product | None = None, *, tile_width: int = 256,
                        columns: int | None = None, shares: Mapping[str, float | None] | None = None) -> Path:
    """A grid of the beauty and every layer, each labelled with its name and energy share,
    and with its description (Layer.description, e.g. a suggested layer's explanation) in
    up to DESCRIPTION_LINES lines when any layer has one.

    Tiles are ``tile_width`` wide (the image's aspect kept, never upscaled), graded and
    transformed like the previews, ordered beauty first, then by group (in order of first
    appearance), then in recipe order. Returns the path of the PNG.
    """
    import OpenImageIO as oiio

    processor = display_processor(*_colour_settings(product))
    layers = _layers_of(product, images)
    if shares is None:
        shares = energy_shares(beauty, images, layers)
    height, width = np.shape(beauty)[:2]
    tile_w = min(tile_width, width)
    tile_h = max(1, round(height * tile_w / width))
    group_order = {group: rank for rank, group in enumerate(dict.fromkeys(layers[n].group for n in images))}
    names = sorted(images, key=lambda name: group_order[layers[name].group])
    entries = [(BEAUTY_PART, beauty, None, "beauty 100 %")]
    for name in names:
        share = shares[name]
        label = "data" if layers[name].is_data else ("n/a" if share is None else f"{100.0 * share:.1f} %")
        entries.append((name, images[name], layers[name], label))
    columns = columns or min(len(entries), max(1, math.ceil(math.sqrt(len(entries)))))
    rows = math.ceil(len(entries) / columns)
    described = any(layer is not None and layer.description for _, _, layer, _ in entries)
    line = FONT_SIZE + 4
    cell_w, cell_h = tile_w + MARGIN, tile_h + LABEL_HEIGHT + MARGIN + (DESCRIPTION_LINES * line if described else 0)
    sheet = np.full((rows * cell_h + MARGIN, columns * cell_w + MARGIN, 3), BACKGROUND, np.uint8)
    for index, (_, image, layer, _) in enumerate(entries):
        y, x = _cell_origin(index, columns, cell_w, cell_h)
        small = _shrink(np.asarray(image, dtype=np.float32), tile_w, tile_h)
        sheet[y : y + tile_h, x : x + tile_w] = _display_image(small, layer, processor)
    buffer = oiio.ImageBuf(sheet)
    text_ok = True
    for index, (name, _, _, label) in enumerate(entries):
        y, x = _cell_origin(index, columns, cell_w, cell_h)
        baseline = y + tile_h + FONT_SIZE + 3
        text_ok &= _text(buffer, x + 2, baseline, _fit(name, tile_w - 4), TEXT_COLOUR)
        text_ok &= _text(buffer, x + 2, baseline + line, label, DIM_TEXT_COLOUR)
        layer = entries[index][2]
        if text_ok and layer is not None and layer.description:
            for number, text in enumerate(_wrapped(layer.description, tile_w - 4, DESCRIPTION_LINES)):
                text_ok &= _text(buffer, x + 2, baseline + (number + 2) * line, text, DIM_TEXT_COLOUR)
    if not text_ok:
        logger.warning("contact sheet %s: OpenImageIO could not draw text (%s); tiles left unlabelled",
                       path, buffer.geterror() or "no font")
    return write_png(path, buffer.get_pixels(oiio.UINT8))


def _cell_origin(index: int, columns: int, cell_w: int, cell_h: int) -> tuple[int, int]:
    row, column = divmod(index, columns)
    return MARGIN + row * cell_h, MARGIN + column * cell_w


def _shrink(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-average ``image`` (h, w[, c]) to (height, width[, c]) (no-op at the same size)."""
    import OpenImageIO as oiio

    if image.shape[1] == width and image.shape[0] == height:
        return image
    squeeze = image.ndim == 2
    pixels = np.ascontiguousarray(np.nan_to_num(image[..., None] if squeeze else image, nan=0.0))
    channels = pixels.shape[-1]
    resized = oiio.ImageBufAlgo.resize(oiio.ImageBuf(pixels), roi=oiio.ROI(0, width, 0, height, 0, 1, 0, channels))
    out = resized.get_pixels(oiio.FLOAT).reshape(height, width, channels)
    return out[..., 0] if squeeze else out


def _text(buffer, x: int, y: int, text: str, colour) -> bool:
    import OpenImageIO as oiio

    return bool(oiio.ImageBufAlgo.render_text(buffer, x, y, text, FONT_SIZE, FONT, colour))


def _wrapped(text: str, width: int, lines: int) -> list[str]:
    """``text`` in at most ``lines`` lines of ``width`` pixels, word by word, the last one
    shortened with an ellipsis if the text goes on."""
    import OpenImageIO as oiio

    words, out = text.split(), []
    while words and len(out) < lines:
        taken = 1
        while taken < len(words) and oiio.ImageBufAlgo.text_size(" ".join(words[:taken + 1]), FONT_SIZE,
                                                                 FONT).width <= width:
            taken += 1
        if len(out) == lines - 1:
            taken = len(words)
        out.append(_fit(" ".join(words[:taken]), width))
        words = words[taken:]
    return out


def _fit(text: str, width: int) -> str:
    """``text`` shortened with an ellipsis to fit ``width`` pixels."""
    import OpenImageIO as oiio

    def fits(candidate: str) -> bool:
        return oiio.ImageBufAlgo.text_size(candidate, FONT_SIZE, FONT).width <= width

    if fits(text):
        return text
    while len(text) > 1 and not fits(text + "..."):
        text = text[:-1]
    return text + "..."


def _colour_settings(product: Product | None) -> tuple[str, str, str, str]:
    if product is None:
        return DEFAULT_OCIO_CONFIG, DEFAULT_DISPLAY, DEFAULT_VIEW, RENDERING_SPACE
    return product.ocio_config, product.display, product.view, product.rendering_space


def _layers_of(product: Product | None, images: Mapping[str, np.ndarray]) -> dict[str, Layer]:
    """The recipe Layer of each image; images without one are treated as colour layers."""
    known = {layer.name: layer for layer in product.layers} if product is not None else {}
    return {name: known.get(name) or Layer(name) for name in images}
