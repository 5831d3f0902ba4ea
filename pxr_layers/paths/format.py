"""The path index file format (``.pxlidx``), version 1. The writer and the reader share it.

A path index holds one record per contribution to the image: the light a path brought
to a pixel, its path class (the camera-first sequence of events) and the covariance
norms C, T, R of its first N events. Layout, little-endian throughout:

    header   8 s  magic b"PXLIDX\\r\\n" (the \\r\\n catches text-mode copies)
             u32  format version           u32  reserved (0)
    chunk*   4 s  b"CHNK"  u32 payload bytes  u32 CRC-32 of the payload  u32 records
             payload: zstd frame of the record columns (below)
    footer   zstd frame of a UTF-8 JSON document: manifest, labels, classes, chunks
    trailer  u64 footer offset  u64 footer bytes  u32 CRC-32 of the footer  u32 version
             8 s  magic b"PXLEND\\r\\n"

Columns of a chunk, records grouped by class (in the tracer's order within a class; the
pixel deltas are mostly small), each column byte-shuffled
(byte planes one after the other, which lets zstd see the slowly varying high bytes):

    class   u32 (r,)     path class id (index into the footer's classes)
    pixel   i32 (r,)     delta from the previous record's pixel (first: from 0); y·width + x
    sample  u32 (r,)     sample index within the pixel; in an aggregated index (manifest
                         "aggregated": true) the number of contributions merged
    rgb     f32 (r, 3)   the contribution exactly as the film added it (linear, not / spp)
    norms   f16 (r, N, 3) C (1/m), T (cycles/m), R (cycles/rad) of events 1..N after the
                          camera; float16 keeps 11 significant bits (relative step 2⁻¹¹,
                          about 0.05 %), larger values saturate at 65504

The footer's JSON (see ``PathIndexWriter._footer``): ``manifest`` (what was rendered: stage
path and SHA-256, frame, camera, resolution, spp, seed, N, norm names and units, record
and class counts), ``labels`` (every name an event carries), ``events`` (every distinct
event as [type, scatter, [label ids], display name]), ``classes`` (per class, its event ids camera
first), ``class_records`` and ``class_rgb`` (per class, its record count and summed rgb),
``chunks`` (per chunk: offset, payload bytes, CRC, records, the classes it holds).

The file is written under a temporary name and renamed only when complete: a file with
the final name always has its trailer. Every chunk and the footer carry a CRC-32 the
reader checks before using them.
"""

from __future__ import annotations

import struct
import sys

import numpy as np

FORMAT_VERSION = 1
SUFFIX = ".pxlidx"
HEADER_MAGIC = b"PXLIDX\r\n"
TRAILER_MAGIC = b"PXLEND\r\n"
CHUNK_MAGIC = b"CHNK"
HEADER = struct.Struct("<8sII")
CHUNK_HEADER = struct.Struct("<4sIII")
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


def column_sizes(records: int, norm_slots: int) -> list[tuple[str, np.dtype, tuple[int, ...]]]:
    """(name, dtype, shape) of each column of a chunk of `records` records, in file order."""
    return [
        ("class", np.dtype(np.uint32), (records,)),
        ("pixel", np.dtype(np.int32), (records,)),
        ("sample", np.dtype(np.uint32), (records,)),
        ("rgb", np.dtype(np.float32), (records, 3)),
        ("norms", np.dtype(NORM_DTYPE), (records, norm_slots, 3)),
    ]
