"""The path index file format (``.pxlidx``), version 3. The writer and the reader share it.

A path index holds the light every path brought to every pixel, with its path class (the
camera-first sequence of events) and the covariance of its first N events, in one of two
modes (the manifest's ``"mode"``):

``merged`` (the default) — one record per distinct (pixel, path class, covariance bins):
    the contributions of a pixel whose class is the same and whose norms (and Σ) fall in
    the same logarithmic bins (``NormBins``) are summed into one record, in the tracer's
    own kernels (``trace/merge.py``), before they reach the writer. The size grows with
    the distinct (pixel, class, bins), not with the samples. Conditions read each bin's
    centre: a condition's outcome can differ from full precision only for contributions
    whose value lies in the bin holding the threshold (within one bin width, a factor
    ``NormBins.WIDTH`` = 2^(1/4) ≈ 1.19); ``= 0`` is exact (zero has its own code).
``records`` — one record per contribution (pixel, sample, rgb, norms as float16): for
    whoever needs per-sample records. Size grows with spp.

Layout, little-endian throughout:

    header   8 s  magic b"PXLIDX\\r\\n" (the \\r\\n catches text-mode copies)
             u32  format version           u32  reserved (0)
    chunk*   4 s  b"CHNK"  u32 payload bytes  u32 CRC-32 of the payload  u32 records
             u32  bytes of the payload's first frame
             payload: two zstd frames, the sums (class, pixel, count, rgb: what a layer
             without conditions reads) then the covariance (norms, Σ: what conditions read)
    footer   zstd frame of a UTF-8 JSON document: manifest, labels, classes, chunks
    trailer  u64 footer offset  u64 footer bytes  u32 CRC-32 of the footer  u32 version
             8 s  magic b"PXLEND\\r\\n"

Columns of a chunk (``column_layout``), records sorted by class, then by pixel (merged) or
in the tracer's order (records), each column byte-shuffled (byte planes one after the
other, which lets zstd see the slowly varying high bytes):

    sums frame
    class   u32 (r,)     path class id (index into the footer's classes)
    pixel   i32 (r,)     delta from the previous record's pixel (first: from 0); y·width + x
    count   u32 (r,)     merged: the contributions summed; records: the sample index
    rgb     f32 (r, 3)   the light exactly as the film added it (linear, not / spp; merged:
                         the float64 sum of the contributions, rounded once)
    covariance frame
    norms   merged: u8 (r, N, 3) bin codes (``NormBins``); records: f16 (r, N, 3) values
                         (11 significant bits, saturated at 65504)
                         of C (1/m), T (cycles/m), R (cycles/rad) of events 1..N after the camera
    sigma   only with covariance "sigma": the upper triangle (xx xy xu xv yy yu yv uu uv vv)
            of each event's 4×4 Σ (trace/sigma.py states the frame and units); merged:
            i16 (r, N, 10) signed bin codes (sign · ``NormBins`` code of |value|);
            records: f32 (r, N, 10)

The footer's JSON (see ``PathIndexWriter._footer``): ``manifest`` (what was rendered: stage
path and SHA-256, frame, camera, resolution, spp, seed, ``clamp_indirect`` when the render
clamped indirect light, N, the mode, norm names, units and bins, record, contribution and
class counts), ``labels`` (every name an event carries),
``events`` (every distinct event as [type, scatter, [label ids], display name]),
``classes`` (per class, its event ids camera first), ``class_records`` and ``class_rgb``
(per class, its record count and summed rgb), ``chunks`` (per chunk: offset, payload
bytes, the sums frame's bytes, CRC, records, the classes it holds).

The file is written under a temporary name and renamed only when complete: a file with
the final name always has its trailer. Every chunk and the footer carry a CRC-32 the
reader checks before using them.
"""

from __future__ import annotations

import math
import struct
import sys

import numpy as np

from ..lpe.conditions import SIGMA_ENTRY_COUNT  # Σ's upper triangle, in the order conditions read

FORMAT_VERSION = 3
MODES = ("merged", "records")
"""Index modes (module docstring); the first is the default."""
DEFAULT_MODE = MODES[0]
SUFFIX = ".pxlidx"
HEADER_MAGIC = b"PXLIDX\r\n"
TRAILER_MAGIC = b"PXLEND\r\n"
CHUNK_MAGIC = b"CHNK"
HEADER = struct.Struct("<8sII")
CHUNK_HEADER = struct.Struct("<4sIIII")
TRAILER = struct.Struct("<QQII8s")
ZSTD_LEVEL = 3
NORM_NAMES = ("C", "T", "R")
NORM_UNITS = {"C": "1/m", "T": "cycles/m", "R": "cycles/rad"}
NORM_DTYPE = np.float16
FLOAT16_MAX = float(np.finfo(np.float16).max)


def stored_norms(norms: np.ndarray) -> np.ndarray:
    """Norms (r, N, 3) as the index stores them: float16, saturated at FLOAT16_MAX (norms
    are >= 0). Norms already stored so are returned as they are (the conversion is a
    tenth of a tile's time: a job's tiles store them so, and the writer does not redo it)."""
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
    (little-endian), which is 4-17x faster than copying the transposed byte matrix.
    """
    dtype = np.dtype(dtype)
    planes = np.frombuffer(data, np.uint8).reshape(dtype.itemsize, -1)
    if sys.byteorder != "little":  # the shifts below build little-endian bytes only on such a host
        return planes.T.copy().view(dtype).reshape(shape)
    wide = UNSIGNED_OF_SIZE[dtype.itemsize]
    values = planes[0].astype(wide)
    for plane in range(1, dtype.itemsize):
        values |= planes[plane].astype(wide) << wide(8 * plane)
    return values.view(dtype).reshape(shape)


Column = tuple[str, np.dtype, tuple[int, ...]]


def column_layout(mode: str, records: int, norm_slots: int, sigma: bool) -> tuple[list[Column], list[Column]]:
    """(name, dtype, shape) of each column of a chunk of `records` records, in file order:
    the sums frame's columns, then the covariance frame's (module docstring)."""
    merged = mode == "merged"
    sums = [
        ("class", np.dtype(np.uint32), (records,)),
        ("pixel", np.dtype(np.int32), (records,)),
        ("count", np.dtype(np.uint32), (records,)),
        ("rgb", np.dtype(np.float32), (records, 3)),
    ]
    covariance = [("norms", np.dtype(np.uint8 if merged else NORM_DTYPE), (records, norm_slots, 3))]
    if sigma:
        covariance.append(("sigma", np.dtype(np.int16 if merged else np.float32),
                           (records, norm_slots, SIGMA_ENTRY_COUNT)))
    return sums, covariance


def frame_bytes(columns: list[Column]) -> int:
    """Decoded bytes of a frame of these columns."""
    return sum(dtype.itemsize * int(np.prod(shape)) for _, dtype, shape in columns)


class NormBins:
    """The logarithmic bins of a merged index's norms and Σ entries.

    Code 0 is exactly 0. Codes 1..255 split the positive values into bins of constant
    ratio ``WIDTH`` = 2^(1/BINS_PER_OCTAVE): code k ≥ 1 holds [LOWEST·WIDTH^(k−1),
    LOWEST·WIDTH^k), with the first and the last bins open to 0 and to infinity (and NaN
    in the last). A code reads as its bin's geometric centre (the first bin's: its upper
    edge / √WIDTH), so a value read back is within a factor √WIDTH ≈ 1.09 of the true one
    and a threshold test on it differs from the test on the true value only when both lie
    in one bin. Σ entries, of either sign, are stored as sign · code of |value| (int16).
    """

    BINS_PER_OCTAVE = 4
    WIDTH = 2.0 ** (1.0 / BINS_PER_OCTAVE)
    LOWEST = 2.0 ** -32
    """Lower edge of code 1 (2.3e-10); codes reach LOWEST · WIDTH^254 ≈ 2^31.5 (3.0e9)."""
    CODES = 256

    @classmethod
    def code(cls, values: np.ndarray) -> np.ndarray:
        """(...) uint8 codes of values >= 0 (float32 or float64)."""
        values = np.asarray(values, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            scaled = np.floor(cls.BINS_PER_OCTAVE * np.log2(values / cls.LOWEST)) + 1
        codes = np.clip(np.nan_to_num(scaled, nan=cls.CODES - 1, posinf=cls.CODES - 1, neginf=1), 1, cls.CODES - 1)
        return np.where(values == 0, 0, codes).astype(np.uint8)

    @classmethod
    def signed_code(cls, values: np.ndarray) -> np.ndarray:
        """(...) int16 codes of values of either sign: sign · code(|value|)."""
        values = np.asarray(values, np.float64)
        return (np.sign(values).astype(np.int16) * cls.code(np.abs(values)).astype(np.int16)).astype(np.int16)

    @classmethod
    def centres(cls) -> np.ndarray:
        """(CODES,) float32: the value each code reads as (0 for code 0)."""
        codes = np.arange(cls.CODES, dtype=np.float64)
        centres = cls.LOWEST * cls.WIDTH ** (codes - 0.5)
        centres[0] = 0.0
        return centres.astype(np.float32)

    @classmethod
    def edges(cls, code: int) -> tuple[float, float]:
        """[low, high) of the values code `code` (>= 1) holds."""
        low = 0.0 if code == 1 else cls.LOWEST * cls.WIDTH ** (code - 1)
        return low, (math.inf if code == cls.CODES - 1 else cls.LOWEST * cls.WIDTH ** code)

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
        return {"kind": "log2", "bins_per_octave": cls.BINS_PER_OCTAVE, "lowest": cls.LOWEST, "codes": cls.CODES,
                "reads_as": "geometric centre"}
