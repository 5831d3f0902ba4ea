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

A JPEG's header is read from its markers, up to its first scan, without OpenImageIO: OIIO's
open decodes every scan of a progressive JPEG before it says anything (40 ms for a 2048² map;
0.05 ms for a baseline one). That reading checks what libjpeg checks before the first scan (the
frame, the tables' lengths, ids and codes, the sampling, the first scan's parameters) and hands
any file it does not know well (arithmetic-coded, lossless, 12-bit, CMYK, two channels, anything
odd) to OIIO. The rest of a progressive file (its later scans, its coded data) is OIIO's open's
to refuse, not this reading's: a file damaged there is refused when the tracer reads its pixels
instead, with the same warning naming it and the texture's fallback, as a baseline JPEG whose
coded data is damaged always was.
"""

from __future__ import annotations

import logging
import os
from typing import BinaryIO, Callable

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
    frame = _jpeg_frame(path)
    if frame is not None:
        width, height, channels = frame
        _check_size(width, height, 1, channels)
        # What OIIO's JPEG reader says of every 8-bit JPEG: one level of uint8 values and no
        # wrap modes (its JPEG writer drops "wrapmodes": test_texture_files).
        return TextureHeader(width, height, channels, "uint8", 1, (None, None))
    image_input = open_image(path)
    try:
        return _header(image_input)
    finally:
        image_input.close()


def _check_size(width: int, height: int, depth: int, channels: int) -> None:
    """OSError when an image of this size cannot be a texture."""
    if depth > 1:
        raise OSError(f"a volume image ({width}×{height}×{depth}) is not a texture")
    if width * height > MAX_FILE_TEXELS:
        raise OSError(f"{width}×{height} texels: more than the {MAX_FILE_TEXELS:,} a texture file may have")
    if width <= 0 or height <= 0 or channels <= 0:
        raise OSError(f"an empty image ({width}×{height}, {channels} channels)")


def _header(image_input: oiio.ImageInput) -> TextureHeader:
    spec = image_input.spec()
    width, height = spec.width, spec.height
    _check_size(width, height, spec.depth, spec.nchannels)
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


# JPEG markers (ITU T.81 table B.1) read before the first scan.
_SOI, _SOS, _DQT, _DHT, _DRI, _COM = 0xD8, 0xDA, 0xDB, 0xC4, 0xDD, 0xFE
_APP = range(0xE0, 0xF0)
_HUFFMAN_FRAMES = {0xC0: False, 0xC1: False, 0xC2: True}  # SOF0–2, 8-bit Huffman-coded: progressive?
_JPEG_MAX_DIMENSION = 65500  # libjpeg's JPEG_MAX_DIMENSION: a larger side is an error
_JPEG_MAX_BLOCKS_IN_MCU = 10  # libjpeg's D_MAX_BLOCKS_IN_MCU


def _jpeg_frame(path: str) -> tuple[int, int, int] | None:
    """(width, height, channels) of the JPEG file `path` as OIIO reports them, read from its
    markers up to its first scan; None when it is not a JPEG (by its first bytes, whatever its
    name) or holds anything this reading does not vouch for (module docstring): OIIO reads it."""
    try:
        with open(path, "rb") as file:
            if file.read(2) != bytes((0xFF, _SOI)):
                return None
            return _jpeg_markers(file)
    except OSError:  # OIIO says why
        return None


def _jpeg_markers(file: BinaryIO) -> tuple[int, int, int] | None:
    """_jpeg_frame's reading of the markers after SOI, as libjpeg's jpeg_read_header and
    jpeg_start_decompress check them (jdmarker.c, jdinput.c, jdhuff.c, jdsample.c)."""
    quant_tables: set[int] = set()
    huffman_tables: set[int] = set()  # class << 4 | id
    frame = None
    while True:
        if file.read(1) != b"\xff":
            return None  # libjpeg skips stray bytes with a warning: not a file to vouch for
        code = file.read(1)
        while code == b"\xff":  # fill bytes
            code = file.read(1)
        length = file.read(2)
        if not code or len(length) != 2 or int.from_bytes(length) < 2:
            return None
        marker, size = code[0], int.from_bytes(length) - 2
        if marker in _APP or marker == _COM:
            file.seek(size, os.SEEK_CUR)  # past the end of a short file: the next read is empty
            continue
        body = file.read(size)
        if len(body) != size:
            return None
        if marker == _DQT:
            tables = _jpeg_tables(body, _quant_table_size)
            if tables is None:
                return None
            quant_tables.update(table & 15 for table in tables)
        elif marker == _DHT:
            tables = _jpeg_tables(body, _huffman_table_size)
            if tables is None:
                return None
            huffman_tables.update(tables)
        elif marker == _DRI:
            if size != 2:
                return None
        elif marker in _HUFFMAN_FRAMES and frame is None:
            frame = _jpeg_sof(body, _HUFFMAN_FRAMES[marker])
            if frame is None:
                return None
        elif marker == _SOS and frame is not None:
            return _jpeg_first_scan(body, frame, quant_tables, huffman_tables)
        else:  # another frame type (arithmetic, lossless, hierarchical), a second frame, EOI, ...
            return None


def _jpeg_tables(body: bytes, table_size: Callable[[bytes, int], int | None]) -> list[int] | None:
    """The first bytes (precision or class << 4 | id) of the tables a DQT or DHT segment `body`
    holds one after another, each `table_size(body, offset)` bytes long (None: malformed); None
    when one is malformed or they do not fill the segment exactly."""
    tables, offset = [], 0
    while offset < len(body):
        size = table_size(body, offset)
        if size is None or offset + size > len(body):
            return None
        tables.append(body[offset])
        offset += size
    return tables if tables else None


def _quant_table_size(body: bytes, offset: int) -> int | None:
    """Bytes of the DQT table at `offset` of `body`: 64 values of 8 or 16 bits; None for another
    precision or an id past 3."""
    precision, table = body[offset] >> 4, body[offset] & 15
    return 1 + 64 * (1 + precision) if precision <= 1 and table <= 3 else None


def _huffman_table_size(body: bytes, offset: int) -> int | None:
    """Bytes of the DHT table at `offset` of `body`; None when libjpeg would refuse it: a class
    or id out of range, more than 256 codes, lengths that overfill the code space (jdhuff.c
    keeps the all-ones code of each length free), a DC symbol past 15."""
    if offset + 17 > len(body) or body[offset] >> 4 > 1 or body[offset] & 15 > 3:
        return None
    counts = body[offset + 1:offset + 17]
    total = sum(counts)
    if total > 256 or offset + 17 + total > len(body):
        return None
    code = 0
    for bits, count in enumerate(counts, 1):
        code += count
        if code >= 1 << bits:
            return None
        code <<= 1
    if body[offset] >> 4 == 0 and max(body[offset + 17:offset + 17 + total], default=0) > 15:
        return None
    return 17 + total


def _jpeg_sof(body: bytes, progressive: bool) -> tuple | None:
    """(width, height, {component id: (h, v, quant table)}, progressive) of a SOF segment; None
    unless it has 1 (grey) or 3 (colour) components, which OIIO reports as as many channels (it
    makes 3 of CMYK's 4), and libjpeg would read it."""
    if len(body) < 6 or body[0] != 8:  # 12-bit and 16-bit samples: OIIO's own reading
        return None
    height, width, count = int.from_bytes(body[1:3]), int.from_bytes(body[3:5]), body[5]
    if count not in (1, 3) or len(body) != 6 + 3 * count:
        return None
    if not (0 < width <= _JPEG_MAX_DIMENSION and 0 < height <= _JPEG_MAX_DIMENSION):  # height 0: DNL
        return None
    components = {}
    for at in range(6, len(body), 3):
        identity, sampling, table = body[at:at + 3]
        h, v = sampling >> 4, sampling & 15
        if identity in components or not (1 <= h <= 4 and 1 <= v <= 4) or table > 3:
            return None
        components[identity] = (h, v, table)
    most_h = max(h for h, _, _ in components.values())
    most_v = max(v for _, v, _ in components.values())
    if any(most_h % h or most_v % v for h, v, _ in components.values()):  # fractional upsampling
        return None
    return width, height, components, progressive


def _jpeg_first_scan(body: bytes, frame: tuple, quant_tables: set[int],
                     huffman_tables: set[int]) -> tuple[int, int, int] | None:
    """_jpeg_markers' result from the first SOS segment and the frame; None when libjpeg would
    refuse or warn about that scan, or a table it needs is missing (libjpeg puts standard
    Huffman tables in some gaps, not all: any gap is left to OIIO)."""
    width, height, components, progressive = frame
    count = body[0] if body else 0
    if not 1 <= count <= 4 or len(body) != 4 + 2 * count:
        return None
    selected = [body[1 + 2 * index] for index in range(count)]
    if len(set(selected)) != count or any(identity not in components for identity in selected):
        return None
    start, end, approximation = body[-3:]
    # The Huffman tables the scan decodes with: a progressive file's first scan, of DC
    # coefficients, decodes none of AC.
    needed = {body[2 + 2 * index] >> 4 for index in range(count)}
    needed |= set() if progressive else {1 << 4 | body[2 + 2 * index] & 15 for index in range(count)}
    if not needed <= huffman_tables:
        return None
    if count > 1 and sum(components[i][0] * components[i][1] for i in selected) > _JPEG_MAX_BLOCKS_IN_MCU:
        return None
    if any(table not in quant_tables for _, _, table in components.values()):
        return None
    if progressive:  # libjpeg decodes DC coefficients first
        first_scan = start == 0 and end == 0 and approximation >> 4 == 0 and approximation & 15 <= 13
    else:
        first_scan = start == 0 and end == 63 and approximation == 0
    return (width, height, len(components)) if first_scan else None


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
