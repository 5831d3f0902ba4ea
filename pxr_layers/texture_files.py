"""Image files as textures read them, with OpenImageIO alone (no USD): headers, and the
stored values of one MIP level. The stage reader (stage/textures.py: lights' images, package
members) and the tracer's texture cache (trace/texture_cache.py: material textures) both
read files through here, so both bound them the same way.

Images are bounded (a 20000 × 20000 PNG of one colour is a 1 MB file that decodes to 4.8 GB
of float32): the header is read first, before any pixel. A file of more than
MAX_FILE_TEXELS is not decoded at all. A level is read, when the file holds it (a tiled EXR
or a ``maketx`` .tx), as stored; otherwise the finest level is read a band of rows at a time
and averaged over 2^level × 2^level blocks of stored values (what ``maketx`` does to build
its levels: 8-bit sRGB is averaged before it is decoded), so memory never holds more than
the level and one band.

Channels are read exactly as stored: OpenImageIO would premultiply PNG and TIFF colour by
alpha unless told otherwise, and UsdUVTexture reads channels as stored.
"""

from __future__ import annotations

import logging
import os

import numpy as np
import OpenImageIO as oiio

from .scene import FLOAT, TextureHeader, WrapMode

logger = logging.getLogger(__name__)

MAX_TEXTURE_TEXELS = 1 << 26
"""The most texels (width × height) a texture's finest level is held at in memory: 8192 × 8192,
1 GiB as RGBA float32. A larger file is read at the first level within it (a warning names it):
a 16k × 8k lat-long sky is read at 8k × 4k."""
MAX_FILE_TEXELS = 1 << 30
"""The most texels an image file may declare (32768 × 32768, the largest texture a paint
package exports) and still be read: decoding more takes tens of seconds before anything is
reduced, and a header claiming more is a decompression bomb or a damaged file."""
BAND_BYTES = 1 << 24
"""About how many bytes of rows a reduced read decodes at a time (16 MiB)."""

STORED_TYPES = ("uint8", "uint16", "half", "float")  # scene.TextureHeader.stored
"""How a file's values are kept in memory: 8- and 16-bit unsigned integers and half floats as
stored; any other format (32-bit integers, signed ones, doubles) as float32."""
_OIIO_TYPES = {"uint8": oiio.UINT8, "uint16": oiio.UINT16, "half": oiio.HALF, "float": oiio.FLOAT}
_NUMPY_TYPES = {"uint8": np.uint8, "uint16": np.uint16, "half": np.float16, "float": np.float32}
# OIIO's "wrapmodes" metadata ("s,t") uses RenderMan words; scene.py uses UsdUVTexture's.
_OIIO_WRAP: dict[str, WrapMode] = {
    "black": "black",
    "clamp": "clamp",
    "periodic": "repeat",
    "mirror": "mirror",
}


def level_size(width: int, height: int, level: int) -> tuple[int, int]:
    """(width, height) of MIP level `level` of a width × height image: halved per level,
    rounded up (a 2×2 block at the edge may hold one column or row), at least 1."""
    for _ in range(level):
        width, height = max(1, (width + 1) // 2), max(1, (height + 1) // 2)
    return width, height


def level_count(width: int, height: int) -> int:
    """Levels of a full pyramid, down to 1 × 1."""
    count = 1
    while width > 1 or height > 1:
        width, height = level_size(width, height, 1)
        count += 1
    return count


def open_image(path: str) -> oiio.ImageInput:
    """An ImageInput reading channels as stored (no premultiplication); OSError when OIIO cannot."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    image_input = oiio.ImageInput.open(path, config)
    if image_input is None:
        raise OSError(oiio.geterror() or "unreadable image")
    return image_input


def read_header(path: str) -> TextureHeader:
    """The header of the image file `path`; OSError when it cannot be a texture (unreadable,
    a volume, more than MAX_FILE_TEXELS)."""
    image_input = open_image(path)
    try:
        return _header(image_input)
    finally:
        image_input.close()


def _header(image_input: oiio.ImageInput) -> TextureHeader:
    spec = image_input.spec()
    width, height = spec.width, spec.height
    if spec.depth > 1:
        raise OSError(f"a volume image ({width}×{height}×{spec.depth}) is not a texture")
    if width * height > MAX_FILE_TEXELS:
        raise OSError(f"{width}×{height} texels: more than the {MAX_FILE_TEXELS:,} a texture file may have")
    if width <= 0 or height <= 0 or spec.nchannels <= 0:
        raise OSError(f"an empty image ({width}×{height}, {spec.nchannels} channels)")
    levels = 1
    while image_input.spec_dimensions(0, levels).width > 0:  # width 0 past the last level
        levels += 1
    basetype = spec.format.basetype
    stored = {oiio.UINT8: "uint8", oiio.UINT16: "uint16", oiio.HALF: "half"}.get(basetype, "float")
    wrap_modes: list[WrapMode | None] = [None, None]
    metadata = spec.get_string_attribute("wrapmodes")
    if metadata:
        words = metadata.split(",")
        words = words if len(words) == 2 else [words[0], words[0]]
        wrap_modes = [_OIIO_WRAP.get(word.strip()) for word in words]
    return TextureHeader(width, height, spec.nchannels, stored, levels, (wrap_modes[0], wrap_modes[1]))


def read_level(path: str, level: int, stored: str | None = None) -> tuple[TextureHeader, np.ndarray]:
    """The header of `path` and its MIP level `level` (0 the finest) as (h, w, c) values of the
    header's stored type, or of `stored` (STORED_TYPES: "float" reads 8- and 16-bit values
    scaled to [0, 1], as OIIO converts them), row 0 the top row of the file; c = min(channels, 4).
    OSError when the file cannot be read (read_header's reasons, or a failing decode)."""
    image_input = open_image(path)
    try:
        header = _header(image_input)
        stored = stored or header.stored
        channels = min(header.channels, 4)
        if level < header.file_levels:
            spec = image_input.spec_dimensions(0, level)
            pixels = image_input.read_image(0, level, 0, channels, _OIIO_TYPES[stored])
            if pixels is None:
                raise OSError(image_input.geterror() or "cannot decode pixels")
            pixels = np.asarray(pixels, _NUMPY_TYPES[stored]).reshape(spec.height, spec.width, channels)
        else:
            pixels = _read_averaged(image_input, header, level, channels, stored)
    finally:
        image_input.close()
    logger.debug("decoded %s level %d: %s %s", path, level, pixels.shape, stored)
    return header, pixels


def _read_averaged(image_input: oiio.ImageInput, header: TextureHeader, level: int, channels: int,
                   stored: str) -> np.ndarray:
    """Level `level` of a file that holds fewer: the finest level averaged over 2^level blocks
    (the blocks of the last row and column hold what is left), decoded a band of rows at a
    time in the file's own type, returned as `stored`."""
    width, height = header.width, header.height
    factor = 1 << level
    decoded_as = stored if stored != "float" else header.stored  # decode compactly, scale below
    scale = {"uint8": 1.0 / 255.0, "uint16": 1.0 / 65535.0}.get(decoded_as, 1.0) if stored == "float" else 1.0
    reduced = np.empty((-(-height // factor), -(-width // factor), channels), FLOAT)
    item = np.dtype(_NUMPY_TYPES[decoded_as]).itemsize
    strips_per_band = max(1, BAND_BYTES // (factor * width * channels * item))
    for first in range(0, height, factor * strips_per_band):
        last = min(first + factor * strips_per_band, height)
        band = image_input.read_scanlines(0, 0, first, last, 0, 0, channels, _OIIO_TYPES[decoded_as])
        if band is None:
            raise OSError(image_input.geterror() or "cannot decode pixels")
        band = np.asarray(band, _NUMPY_TYPES[decoded_as]).reshape(last - first, width, channels)
        means = block_means(band, factor)
        reduced[first // factor:first // factor + len(means)] = means * FLOAT(scale)
    return as_stored(reduced, stored)


def as_stored(values: np.ndarray, stored: str) -> np.ndarray:
    """float values of the stored type's scale (0–255 for uint8, 0–65535 for uint16) rounded
    and clipped into it."""
    if stored in ("uint8", "uint16"):
        top = 255 if stored == "uint8" else 65535
        return np.clip(np.rint(values), 0, top).astype(_NUMPY_TYPES[stored])
    return values.astype(_NUMPY_TYPES[stored])


def block_means(band: np.ndarray, factor: int) -> np.ndarray:
    """(⌈r/n⌉, ⌈w/n⌉, c) float32 means of the n × n blocks (``factor`` n) of the (r, w, c) ``band``;
    the blocks of its last row and column hold what is left. Summed one strided offset at a
    time (n vectorised additions per axis), far faster than numpy's reductions over short axes."""
    rows, width, channels = band.shape
    row_sums = np.zeros((-(-rows // factor), width, channels), FLOAT)
    for offset in range(min(factor, rows)):
        part = band[offset::factor]
        row_sums[:len(part)] += part
    sums = np.zeros((len(row_sums), -(-width // factor), channels), FLOAT)
    for offset in range(min(factor, width)):
        part = row_sums[:, offset::factor]
        sums[:, :part.shape[1]] += part
    row_counts = np.minimum(factor, rows - factor * np.arange(sums.shape[0])).astype(FLOAT)
    column_counts = np.minimum(factor, width - factor * np.arange(sums.shape[1])).astype(FLOAT)
    return sums / (row_counts[:, None, None] * column_counts[None, :, None])


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """The sRGB EOTF (IEC 61966-2-1), elementwise; values below 0 stay on the linear segment."""
    # np.maximum keeps the power's base positive so negative inputs cannot produce NaN.
    curved = ((np.maximum(values, 0.04045) + 0.055) / 1.055) ** 2.4
    return np.where(values <= 0.04045, values / 12.92, curved).astype(FLOAT)


def linear(pixels: np.ndarray, color_space: str) -> np.ndarray:
    """(h, w, c) stored values (float, 0–1 for integer files) → a new (h, w, min(c, 4)) linear
    float32 array: through the sRGB EOTF when `color_space` is "sRGB" (never alpha), a band of
    rows at a time so that the EOTF's temporaries stay small beside a large image."""
    channels = min(pixels.shape[2], 4)
    values = np.array(pixels[:, :, :channels], dtype=FLOAT)  # a copy: the decoded file stays as stored
    if color_space == "sRGB":
        colour = 3 if channels >= 3 else 1
        rows = max(1, BAND_BYTES // (4 * values.shape[1] * colour))
        for top in range(0, values.shape[0], rows):
            band = values[top:top + rows, :, :colour]
            band[...] = srgb_to_linear(band)
    return values


def repaired(pixels: np.ndarray, light_ceiling: float | None = None) -> int:
    """Replace, in the (h, w, c) float ``pixels``, the values no lookup can use by 0: NaN and
    infinities, and for the image of a light (``light_ceiling`` given) negative values too,
    lowering those above the ceiling to it. Returns how many texels (pixels, any channel)
    changed."""
    unusable = ~np.isfinite(pixels)
    too_bright = None
    if light_ceiling is not None:
        unusable |= pixels < 0.0
        too_bright = ~unusable & (pixels > light_ceiling)
    changed = unusable if too_bright is None else unusable | too_bright
    count = int(np.count_nonzero(changed.any(axis=2)))
    if count:
        pixels[unusable] = 0.0
        if too_bright is not None:
            pixels[too_bright] = light_ceiling
    return count


def file_identity(path: str) -> tuple | None:
    """What tells a file's content apart: path, device and inode, size, modification and
    change times (a copy that keeps the old mtime, cp -p or rsync -a, still changes ctime);
    None when it cannot be read."""
    try:
        status = os.stat(path)
    except OSError:
        return None
    return (path, status.st_dev, status.st_ino, status.st_size, status.st_mtime_ns, status.st_ctime_ns)
