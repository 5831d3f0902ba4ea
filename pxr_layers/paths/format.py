"""The path index file format (``.pxlidx``), version 4. The writer and the reader share it.

A path index holds the light every path brought to every pixel, with its path class (the
camera-first sequence of events) and the covariance of its first N events, in one of two
modes (the manifest's ``"mode"``):

``merged`` (the default) — one record per distinct (pixel, path class, covariance bins):
    the contributions of a pixel whose class is the same and whose norms (and Σ) fall in
    the same bins (``NormBins``) are summed into one record, in the tracer's own kernels
    (``trace/merge.py``), before they reach the writer. The size grows with the distinct
    (pixel, class, bins), not with the samples. The rgb of a record is kept as log codes
    (``RgbBins``), except one record per pixel and channel that carries the rest exactly.
``records`` — one record per contribution (pixel, sample, rgb as float32, norms as
    float16): for whoever needs per-sample records. Size grows with spp.

What a merged index answers, exactly and within how much (the quantisation rule):

- **Covariance conditions.** Norms and Σ entries are kept as 0, as an exact power of two,
  or as the open octave between two powers of two (``NormBins``). A threshold that is 0
  or a power of two (…, 0.25, 0.5, 1, 2, 4, …) is exact for every comparison
  (``= != < <= > >=``). Any other threshold t is exact except for values in t's own
  octave (2^k < value < 2^(k+1) with 2^k < t < 2^(k+1)): a value is read as its octave's
  geometric centre, within a factor √2 of the true one, and a comparison between two
  quantities (``|S_T| > |S_R|``, ``>>``) is decided on those read values.
- **Light.** A record's r, g and b are each read within a factor ``RgbBins.WIDTH`` =
  2^(1/256) (0.27 %) of what the tracer summed (its brightest channel within half that),
  except that, per pixel and channel, the record with the most light carries the
  pixel's rest exactly: it is stored as the pixel's sum minus the others as read (a
  float32). So every pixel's records, as read, sum to what the tracer's records summed
  to (to the float32 rounding of that one value): the layers of any partition (the
  standard passes, the per-light layers, a layer and its complement) sum to the beauty
  exactly. A layer that holds no carrier is within a factor 2^(1/256) of its
  full-precision value; one that holds a carrier is within 2^(1/256) − 1 (0.27 %) of the
  rest of that pixel's light; every layer is within 0.27 % of the beauty, per pixel and
  channel (of the sum of the records' magnitudes, should some light be negative). Records
  of non-finite, negative or out-of-range light are stored exactly.

Layout, little-endian throughout:

    header   8 s  magic b"PXLIDX\\r\\n" (the \\r\\n catches text-mode copies)
             u32  format version           u32  reserved (0)
    chunk*   4 s  b"CHNK"  u32 payload bytes  u32 CRC-32 of the payload  u32 records
             u32  class runs  u32 exact records  u32 bytes of the where frame  u32 bytes
             of the light frame
             payload: three zstd frames: where (classes, pixels: what a click on a pixel
             reads), light (rgb: what a layer without conditions reads too), covariance
             (norms, Σ: what conditions read)
    footer   a zstd frame of a UTF-8 JSON document (manifest, labels, events, chunks), then
             a zstd frame of the class table (binary columns, ``class_table_layout``)
    trailer  u64 footer offset  u64 footer bytes  u64 bytes of the footer's JSON frame
             u32 CRC-32 of the footer  u32 version  8 s  magic b"PXLEND\\r\\n"

Columns of a chunk (``column_layout``), records sorted by class, then by pixel, each column
byte-shuffled (byte planes one after the other, which lets zstd see the slowly varying
high bytes):

    where frame
    run_class  u32 (runs,)   the class of each run of records of one class: its id minus
                             the previous run's (the first: minus 0)
    run_length u32 (runs,)   the records of each run
    pixel      u32 (r,)      y·width + x: the first record of a run as the zigzag-coded
                             difference from the previous run's first pixel (the first:
                             from 0), the others as the difference from the record before
    light frame, merged:
    rgb        u16 (3, r)    channel-major: g, then r, then b (``RgbBins``: g is a code; r
                             and b, where g is a bin code, are code − g code − the class's
                             chroma (class table), modulo 2^16, else codes; EXACT in g
                             marks an exact record, whose r and b are 0)
    exact      f32 (e, 3)    the rgb of the exact records, in record order (e: the chunk
                             header's exact records)
    light frame, records:
    sample     u32 (r,)      the sample index
    rgb        f32 (r, 3)    the light exactly as the film added it
    (rgb is linear and not divided by spp; merged, what is coded is the float64 sum of the
    contributions, rounded once to float32.)
    covariance frame
    norms   merged: u8 (r, N, 3) ``NormBins`` codes; records: f16 (r, N, 3) values (11
            significant bits, saturated at 65504) of C (1/m), T (cycles/m), R (cycles/rad)
            of events 1..N after the camera
    sigma   only with covariance "sigma": the upper triangle (xx xy xu xv yy yu yv uu uv vv)
            of each event's 4×4 Σ (trace/sigma.py states the frame and units); merged:
            i16 (r, N, 10) signed codes (sign · ``NormBins`` code of |value|);
            records: f32 (r, N, 10)

The class table (``class_table_layout``), shuffled columns in one zstd frame: ``length``
(classes,) events after the camera; ``events`` (total,) their footer event ids, class after
class (both u8, u16 or u32: the footer's ``class_table`` says); ``records`` u32 (classes,)
records of each class; merged also ``chroma`` u16 (classes, 2) the class's reference r − g
and b − g codes (those of its first record written with three bin codes, else 0).

The footer's JSON (see ``PathIndexWriter._footer``): ``manifest`` (what was rendered: stage
path and SHA-256, frame, camera, resolution, spp, seed, ``clamp_indirect`` when the render
clamped indirect light, ``model_paths`` (the stage's models) and ``light_groups`` ({light
prim path: pxrLayers:lightGroup}) when the stage has any (jobs.frame.stage_names; what
``suggest`` names assets and light groups from), N, the mode, norm names, units and bins, rgb bins, record,
contribution and class counts), ``labels`` (every name an event carries), ``events`` (every
distinct event as [type, scatter, [label ids], display name]), ``nonfinite_classes`` (ids
of the classes with a NaN or infinite record), ``class_table`` (its frame's bytes and
events), ``chunks`` (per chunk: offset, payload bytes, the where and light frames' bytes,
CRC, records, runs, exact records, its first and last class).

The file is written under a temporary name and renamed only when complete: a file with
the final name always has its trailer. Every chunk and the footer carry a CRC-32 the
reader checks before using them.
"""

from __future__ import annotations

import functools
import json
import struct
import sys
from typing import NamedTuple

import numpy as np
import zstandard

from ..lpe.conditions import SIGMA_ENTRY_COUNT  # Σ's upper triangle, in the order conditions read

FORMAT_VERSION = 4
MODES = ("merged", "records")
"""Index modes (module docstring); the first is the default."""
DEFAULT_MODE = MODES[0]
SUFFIX = ".pxlidx"
HEADER_MAGIC = b"PXLIDX\r\n"
TRAILER_MAGIC = b"PXLEND\r\n"
CHUNK_MAGIC = b"CHNK"
HEADER = struct.Struct("<8sII")
CHUNK_HEADER = struct.Struct("<4sIIIIIII")
"""magic, payload bytes, CRC-32, records, class runs, exact records, where and light frame bytes."""
TRAILER = struct.Struct("<QQQII8s")
"""footer offset, footer bytes, its JSON frame's bytes, CRC-32 of the footer, version, magic."""
ZSTD_LEVEL = 3
"""zstd level of the chunks: written on the writer's thread while the frame renders."""
FOOTER_ZSTD_LEVEL = 19
"""zstd level of the footer's class table, written once at close (some 10 bytes a class
raw): it takes a tenth of the file at 128², and level 19 makes it a third smaller than 3."""
NORM_NAMES = ("C", "T", "R")
NORM_UNITS = {"C": "1/m", "T": "cycles/m", "R": "cycles/rad"}
NORM_DTYPE = np.float16
FLOAT16_MAX = float(np.finfo(np.float16).max)


def stored_norms(norms: np.ndarray) -> np.ndarray:
    """Norms (r, N, 3) as a records index stores them: float16, saturated at FLOAT16_MAX
    (norms are >= 0). Norms already stored so are returned as they are (the conversion is
    a tenth of a tile's time: a job's tiles store them so, and the writer does not redo it)."""
    if norms.dtype == NORM_DTYPE:
        return norms
    return np.minimum(norms, FLOAT16_MAX).astype(NORM_DTYPE)


def shuffle(values: np.ndarray) -> bytes:
    """Bytes of `values` as byte planes: all first bytes, then all second bytes, ..."""
    flat = np.ascontiguousarray(values).reshape(-1)
    return flat.view(np.uint8).reshape(-1, flat.itemsize).T.tobytes()


UNSIGNED_OF_SIZE = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


def unshuffle(data: bytes, dtype, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of ``shuffle`` for an array of `dtype` and `shape`.

    The byte planes are combined with shifts in an unsigned integer as wide as `dtype`
    (little-endian), which is 3-15x faster than copying the transposed byte matrix, and
    1.5-3x faster than copying each plane into its byte of the values.
    """
    dtype = np.dtype(dtype)
    planes = np.frombuffer(data, np.uint8).reshape(dtype.itemsize, -1)
    if dtype.itemsize == 1:
        return planes[0].view(dtype).reshape(shape)
    if sys.byteorder != "little":  # the shifts below build little-endian bytes only on such a host
        return planes.T.copy().view(dtype).reshape(shape)
    wide = UNSIGNED_OF_SIZE[dtype.itemsize]
    values = planes[0].astype(wide)
    for plane in range(1, dtype.itemsize):
        values |= planes[plane].astype(wide) << wide(8 * plane)
    return values.view(dtype).reshape(shape)


def zigzag(values: np.ndarray) -> np.ndarray:
    """Signed int64 values as unsigned ones, small magnitudes first: 0, −1, 1, −2 → 0, 1, 2, 3."""
    values = np.asarray(values, np.int64)
    return ((values << 1) ^ (values >> 63)).astype(np.uint64)


def unzigzag(values: np.ndarray) -> np.ndarray:
    """Inverse of ``zigzag``: int64."""
    values = np.asarray(values).astype(np.int64)
    return (values >> 1) ^ -(values & 1)


Column = tuple[str, np.dtype, tuple[int, ...]]


def column_layout(mode: str, records: int, norm_slots: int, sigma: bool, *, runs: int = 0,
                  exact: int = 0) -> tuple[list[Column], list[Column], list[Column]]:
    """(name, dtype, shape) of each column of a chunk of `records` records in `runs` class
    runs (`exact` of them exact: merged), in file order: the where frame's columns, the
    light frame's, then the covariance frame's (module docstring)."""
    merged = mode == "merged"
    where = [
        ("run_class", np.dtype(np.uint32), (runs,)),
        ("run_length", np.dtype(np.uint32), (runs,)),
        ("pixel", np.dtype(np.uint32), (records,)),
    ]
    if merged:
        light = [("rgb", np.dtype(np.uint16), (3, records)), ("exact", np.dtype(np.float32), (exact, 3))]
    else:
        light = [("sample", np.dtype(np.uint32), (records,)), ("rgb", np.dtype(np.float32), (records, 3))]
    covariance = [("norms", np.dtype(np.uint8 if merged else NORM_DTYPE), (records, norm_slots, 3))]
    if sigma:
        covariance.append(("sigma", np.dtype(np.int16 if merged else np.float32),
                           (records, norm_slots, SIGMA_ENTRY_COUNT)))
    return where, light, covariance


TABLE_DTYPES = ("<u1", "<u2", "<u4")
"""The widths the class table's lengths and event ids may take (the footer's ``class_table``
says which): the narrowest that holds them, a third of the bytes to compress at close."""


def narrowest(values: np.ndarray) -> str:
    """The first of TABLE_DTYPES that holds `values` (integers >= 0, < 2^32)."""
    top = int(values.max(initial=0))
    return next(dtype for dtype in TABLE_DTYPES if top < 1 << 8 * np.dtype(dtype).itemsize)


def class_table_layout(mode: str, classes: int, events: int, length_dtype: str = "<u4",
                       event_dtype: str = "<u4") -> list[Column]:
    """(name, dtype, shape) of the class table's columns, for `classes` classes of `events`
    events after the camera in all (module docstring)."""
    layout = [("length", np.dtype(length_dtype), (classes,)), ("events", np.dtype(event_dtype), (events,)),
              ("records", np.dtype(np.uint32), (classes,))]
    if mode == "merged":
        layout.append(("chroma", np.dtype(np.uint16), (classes, 2)))
    return layout


class Footer(NamedTuple):
    """A footer as written: its bytes, the bytes of its JSON frame (the trailer says), and
    its JSON tables (with the class table's entry)."""

    data: bytes
    json_bytes: int
    tables: dict


def footer(tables: dict, arrays: dict[str, np.ndarray], compressor) -> Footer:
    """The footer of JSON `tables` (without ``class_table``) and the class table's `arrays`
    (``class_table_layout``'s columns): a zstd frame of the JSON (`compressor`), then one of
    the class table (FOOTER_ZSTD_LEVEL)."""
    dtypes = {"length_dtype": narrowest(arrays["length"]), "event_dtype": narrowest(arrays["events"])}
    layout = class_table_layout(tables["manifest"]["mode"], len(arrays["length"]), len(arrays["events"]), **dtypes)
    table = zstandard.ZstdCompressor(level=FOOTER_ZSTD_LEVEL).compress(
        b"".join(shuffle(arrays[name].astype(dtype)) for name, dtype, _ in layout))
    tables = {**tables, "class_table": {"bytes": len(table), "events": len(arrays["events"]), **dtypes}}
    frame = compressor.compress(json.dumps(tables, separators=(",", ":")).encode())
    return Footer(frame + table, len(frame), tables)


def frame_bytes(columns: list[Column]) -> int:
    """Decoded bytes of a frame of these columns."""
    return sum(dtype.itemsize * int(np.prod(shape)) for _, dtype, shape in columns)


def split_frame(data: bytes, columns: list[Column]) -> dict[str, np.ndarray]:
    """The columns of a decoded frame (its length checked by the caller), unshuffled."""
    arrays, position = {}, 0
    for name, dtype, shape in columns:
        end = position + int(np.prod(shape)) * dtype.itemsize
        arrays[name] = unshuffle(data[position:end], dtype, shape)
        position = end
    return arrays


class NormBins:
    """The bins of a merged index's norms and Σ entries: 0, every power of two, and the
    open octaves between, so that a condition whose threshold is 0 or a power of two is
    exact (module docstring).

    Code 0 is exactly 0. With E = LOWEST_EXPONENT: code 1 holds (0, 2^E); code 2 + 2i is
    exactly 2^(E + i) and code 3 + 2i the open octave (2^(E+i), 2^(E+i+1)), for i = 0 ..
    EDGES − 1; the last code (255) holds everything above 2^(E + EDGES − 1), infinity and
    NaN. Powers of two read as themselves, octaves as their geometric centre 2^(E+i+½)
    (within a factor √2 of any value they hold), code 1 as 2^(E−½) and code 255 as +inf.
    Σ entries, of either sign, are stored as sign · code of |value| (int16).
    """

    LOWEST_EXPONENT = -63
    EDGES = 127
    """Powers of two 2^-63 (1.1e-19) … 2^63 (9.2e18), each with its own code."""
    CODES = 256
    WIDTH = 2.0
    """The ratio of an octave's edges: a value read back is within √WIDTH of the true one."""

    @classmethod
    def code(cls, values: np.ndarray) -> np.ndarray:
        """(...) uint8 codes of values >= 0 (float16, float32 or float64). Exact: a power
        of two is found from the float's exponent and mantissa, not from a logarithm."""
        values = np.asarray(values, np.float64)
        mantissa, exponent = np.frexp(values)  # values = mantissa · 2^exponent, 0.5 <= mantissa < 1
        octave = exponent.astype(np.int64) - 1 - cls.LOWEST_EXPONENT  # value in [2^(E+octave), 2^(E+octave+1))
        codes = 2 + 2 * octave + (mantissa != 0.5)
        codes = np.where(octave < 0, 1, np.minimum(codes, cls.CODES - 1))
        codes = np.where(np.isfinite(values), codes, cls.CODES - 1)
        return np.where(values == 0, 0, codes).astype(np.uint8)

    @classmethod
    def signed_code(cls, values: np.ndarray) -> np.ndarray:
        """(...) int16 codes of values of either sign: sign · code(|value|)."""
        values = np.asarray(values, np.float64)
        return (np.sign(values).astype(np.int16) * cls.code(np.abs(values)).astype(np.int16)).astype(np.int16)

    @classmethod
    def centres(cls) -> np.ndarray:
        """(CODES,) float32: the value each code reads as."""
        codes = np.arange(cls.CODES)
        exponent = cls.LOWEST_EXPONENT + (codes - 2) / 2.0  # integers for powers, +½ for octaves
        values = 2.0 ** exponent
        values[0], values[1], values[-1] = 0.0, 2.0 ** (cls.LOWEST_EXPONENT - 0.5), np.inf
        return values.astype(np.float32)

    @classmethod
    def edges(cls, code: int) -> tuple[float, float]:
        """(low, high) of the values code `code` (>= 1) holds: equal for a power of two,
        else the open interval between them (the last code's high is inf)."""
        if code == 1:
            return 0.0, 2.0 ** cls.LOWEST_EXPONENT
        if code == cls.CODES - 1:
            return 2.0 ** (cls.LOWEST_EXPONENT + cls.EDGES - 1), np.inf
        low = 2.0 ** (cls.LOWEST_EXPONENT + (code - 2) // 2)
        return (low, low) if code % 2 == 0 else (low, 2 * low)

    @classmethod
    def decoded(cls, codes: np.ndarray) -> np.ndarray:
        """Values (float32) of uint8 codes, or of signed int16 codes."""
        centres = cls.centres()
        if codes.dtype == np.uint8:
            return centres[codes]
        return np.sign(codes).astype(np.float32) * centres[np.abs(codes.astype(np.int32))]

    @classmethod
    def manifest(cls) -> dict:
        """How the bins are described in a merged index's manifest."""
        return {"kind": "octaves", "exact": "0 and powers of two", "lowest": 2.0 ** cls.LOWEST_EXPONENT,
                "highest": 2.0 ** (cls.LOWEST_EXPONENT + cls.EDGES - 1), "codes": cls.CODES,
                "reads_as": "the power of two, else the octave's geometric centre"}


class RgbBins:
    """The light of a merged index's records: a log code per channel, or exact.

    A uint16 code k in 1 .. 0x7FFF reads as 2^((k − OFFSET) / BINS_PER_OCTAVE); 0 is exactly
    0; EXACT marks a record kept as float32 (the chunk's exact column). A record's codes
    share its brightest channel's: that channel is rounded to the nearest code (within a
    factor √WIDTH) and each other channel c to its code plus the rounded log ratio
    c / brightest (within WIDTH, one bin), so that records of the same colour have the
    same code differences (which the class's chroma then predicts, module docstring).
    Values that are negative, not finite or outside 2^-64 .. 2^64 are exact.
    """

    BINS_PER_OCTAVE = 256
    WIDTH = 2.0 ** (1.0 / BINS_PER_OCTAVE)
    """A channel read back is within a factor WIDTH (0.27 %) of the true value."""
    OFFSET = 64 * BINS_PER_OCTAVE
    """Code of 1.0; codes 1 .. 0x7FFF span 2^-64 .. 2^64."""
    ZERO = 0
    EXACT = 0x8000
    LARGEST_CODE = 0x7FFF

    @classmethod
    def code(cls, rgb: np.ndarray) -> np.ndarray:
        """(r, 3) int64 codes of (r, 3) values (float32 or float64): ZERO, bin codes, or
        EXACT for values a code cannot hold."""
        values = np.asarray(rgb, np.float64)
        coded = np.isfinite(values) & (values > 0)
        brightest = np.where(coded, values, 0.0).max(axis=1, initial=0.0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # records without coded values
            anchor = np.rint(cls.BINS_PER_OCTAVE * np.log2(brightest))
            ratio = np.rint(cls.BINS_PER_OCTAVE * np.log2(values / brightest[:, None]))
            codes = np.where(coded, anchor[:, None] + ratio + cls.OFFSET, 0)
        coded &= (codes >= 1) & (codes <= cls.LARGEST_CODE)
        return np.where(coded, codes, np.where(values == 0, cls.ZERO, cls.EXACT)).astype(np.int64)

    @classmethod
    @functools.cache
    def table(cls) -> np.ndarray:
        """(65536,) float32, read-only, built once: the value of each uint16 code; NaN for
        EXACT and the codes above it, which no writer stores (a reader finds them by their NaN)."""
        codes = np.arange(1 << 16, dtype=np.float64)
        values = 2.0 ** ((codes - cls.OFFSET) / cls.BINS_PER_OCTAVE)
        values[0] = 0.0
        values[cls.EXACT:] = np.nan
        table = values.astype(np.float32)
        table.flags.writeable = False
        return table

    @classmethod
    def manifest(cls) -> dict:
        """How the rgb codes are described in a merged index's manifest."""
        return {"kind": "log2", "bins_per_octave": cls.BINS_PER_OCTAVE,
                "within": "a factor 2^(1/bins_per_octave) per channel",
                "exact": "one record per pixel and channel, carrying the pixel's rest"}


def chroma_residuals(codes: np.ndarray, chroma: np.ndarray) -> np.ndarray:
    """(3, r) uint16 stored rgb of (r, 3) int64 codes and their classes' (r, 2) chroma
    references: g; r and b as residuals where g is a bin code (module docstring)."""
    green = codes[:, 1]
    binned = (green >= 1) & (green <= RgbBins.LARGEST_CODE)
    stored = np.empty((3, len(codes)), np.int64)
    stored[0] = green
    stored[1] = np.where(binned, codes[:, 0] - green - chroma[:, 0], codes[:, 0])
    stored[2] = np.where(binned, codes[:, 2] - green - chroma[:, 1], codes[:, 2])
    return (stored & 0xFFFF).astype(np.uint16)


def codes_of_residuals(stored: np.ndarray, chroma: np.ndarray) -> np.ndarray:
    """Inverse of ``chroma_residuals``: (r, 3) uint16 codes of (3, r) stored columns and
    their records' (r, 2) chroma references."""
    green = stored[0]
    binned = (green >= 1) & (green <= RgbBins.LARGEST_CODE)
    codes = np.empty((len(green), 3), np.uint16)
    codes[:, 1] = green
    for channel, row in ((0, 1), (2, 2)):
        shifted = stored[row] + green + chroma[:, row - 1]  # uint16 arithmetic: modulo 2^16
        codes[:, channel] = np.where(binned, shifted, stored[row])
    return codes


def run_rows(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(Σ lengths,) int64: the numbers of the rows of runs of `lengths` rows from `starts`
    (the reader's class runs, the accumulator's layer lists), in order."""
    before = np.cumsum(lengths) - lengths
    return np.arange(int(lengths.sum())) + np.repeat(starts - before, lengths)
