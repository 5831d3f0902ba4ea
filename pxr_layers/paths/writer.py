"""Write a path index incrementally while rendering, and finalise it atomically."""

from __future__ import annotations

import itertools
import json
import logging
import os
import zlib
from pathlib import Path

import numpy as np
import zstandard

from ..errors import OutputError
from ..outputs import finish, temporary_beside
from . import format as fmt
from .events import EventVocabulary
from .trie import ClassTrie

log = logging.getLogger(__name__)

BUFFER_RECORDS = 1 << 21  # records held in memory before a flush (about 170 MB with N = 5)
CHUNK_RECORDS = 1 << 16  # records per chunk; small classes share chunks, large ones span several


class PathIndexWriter:
    """Receives the tracer's records batch by batch (in path order) and writes chunks.

    path : the final file; nothing appears under that name until ``close`` succeeds (the
    data goes to a temporary file beside it, removed by ``abort`` or on error).
    manifest : what was rendered (stage, frame, camera, resolution, spp, seed, ...), stored
    as given, plus the counts the writer knows. norm_slots : N.

    Class ids are given in order of first appearance, and each flush sorts its records by
    class keeping the tracer's order within a class, so the same render (same settings
    and batch size) gives a byte-identical file whatever the thread count.

    aggregate : merge, within each flush, the records of one pixel that share their class
    and their norms as stored (float16): one record with the summed rgb (float64 sum,
    stored float32) and, in the sample column, how many contributions it merges. Pixel
    sums stay exact to float32 rounding; what is lost is which sample each came from.
    """

    def __init__(self, path: str | os.PathLike, manifest: dict, norm_slots: int, *, aggregate: bool = False,
                 buffer_records: int = BUFFER_RECORDS, chunk_records: int = CHUNK_RECORDS):
        self.path = Path(path)
        self.manifest = dict(manifest)
        self.norm_slots = norm_slots
        self.aggregate = aggregate
        self._contributions = 0
        self.buffer_records = buffer_records
        self.chunk_records = chunk_records
        self._classes = ClassTrie()  # every class of the index, merged batch by batch
        self._node_class = np.zeros(0, np.int64)  # the class id of each trie node, −1 = none yet
        self._class_keys: list[tuple[int, ...]] = []  # per class, its event ids after the camera
        self._class_records = np.zeros(0, np.int64)  # (classes,) records so far
        self._class_rgb = np.zeros((0, 3))  # (classes, 3) float64 summed rgb
        self._buffer: list[tuple[np.ndarray, ...]] = []
        self._buffered = 0
        self._chunks: list[dict] = []
        self._records = 0
        self._compressor = zstandard.ZstdCompressor(level=fmt.ZSTD_LEVEL)
        handle, self._temporary = temporary_beside(self.path)
        self._file = os.fdopen(handle, "wb")
        self._file.write(fmt.HEADER.pack(fmt.HEADER_MAGIC, fmt.FORMAT_VERSION, 0))

    # -- writing

    def add(self, records) -> None:
        """Add one batch's ``Contributions`` (trace.integrator) in path order. Norms come as
        the tracer makes them (float32, saturated and cast here) or already as stored
        (float16, taken as they are); the arrays are kept, not copied, until the next flush."""
        if records is None or not len(records.pixel):
            return
        class_id = self._global_classes(records)
        if records.norms.shape[1:] != (self.norm_slots, 3):
            raise ValueError(f"records carry norms of shape {records.norms.shape[1:]}, the index expects "
                             f"({self.norm_slots}, 3)")
        self._buffer.append((class_id, records.pixel.astype(np.int64, copy=False),
                             records.sample.astype(np.uint32, copy=False), records.rgb.astype(np.float32, copy=False),
                             fmt.stored_norms(records.norms)))
        self._buffered += len(class_id)
        if self._buffered >= self.buffer_records:
            self._flush()

    def _global_classes(self, records) -> np.ndarray:
        """The batch's classes as global class ids (new classes numbered in the order of
        the batch's list, which the tracer makes deterministic). The batch's class trie is
        merged into the index's, so only new classes have their event sequence built."""
        nodes = self._classes.merge(records.trie_parent, records.trie_event)[records.class_nodes]
        if len(self._node_class) < len(self._classes):  # grown to twice the nodes: amortised
            self._node_class = np.concatenate([self._node_class,
                                               np.full(2 * len(self._classes) - len(self._node_class), -1, np.int64)])
        ids = self._node_class[nodes]
        new = np.flatnonzero(ids < 0)
        if len(new):
            ids[new] = np.arange(len(self._class_keys), len(self._class_keys) + len(new))
            self._node_class[nodes[new]] = ids[new]
            self._class_keys.extend(self._classes.sequences(nodes[new]))
        return ids[records.path_class]

    def _flush(self) -> None:
        if not self._buffer:
            return
        class_id, pixel, sample, rgb, norms = (np.concatenate(column) for column in zip(*self._buffer))
        self._buffer.clear()
        self._buffered = 0
        self._contributions += len(class_id)
        if self.aggregate:
            class_id, pixel, sample, rgb, norms = _merged(class_id, pixel, rgb, norms)
        classes = len(self._class_keys)
        order = _stable_order(class_id, classes)
        class_id, pixel, sample, rgb, norms = (np.take(column, order, axis=0)  # take: 3x faster than [order] on (r, N, 3)
                                               for column in (class_id, pixel, sample, rgb, norms))
        self._class_records = _grown(self._class_records, classes)
        self._class_rgb = _grown(self._class_rgb, classes)
        self._class_records += np.bincount(class_id, minlength=classes)
        for channel in range(3):
            self._class_rgb[:, channel] += np.bincount(class_id, weights=rgb[:, channel], minlength=classes)
        for start, stop in self._chunk_bounds(class_id):
            self._write_chunk(class_id[start:stop], pixel[start:stop], sample[start:stop], rgb[start:stop],
                              norms[start:stop])

    def _chunk_bounds(self, class_id: np.ndarray) -> list[tuple[int, int]]:
        """Cut sorted records into chunks: whole small classes together, large ones split."""
        starts = np.flatnonzero(np.r_[True, class_id[1:] != class_id[:-1]]).tolist() + [len(class_id)]
        bounds, chunk_start = [], 0
        for class_start, class_stop in itertools.pairwise(starts):
            if class_stop - chunk_start > self.chunk_records and class_start > chunk_start:
                bounds.append((chunk_start, class_start))
                chunk_start = class_start
            while class_stop - chunk_start > self.chunk_records:
                bounds.append((chunk_start, chunk_start + self.chunk_records))
                chunk_start += self.chunk_records
        if chunk_start < len(class_id):
            bounds.append((chunk_start, len(class_id)))
        return bounds

    def _write_chunk(self, class_id, pixel, sample, rgb, norms) -> None:
        pixel_delta = np.diff(pixel, prepend=0).astype(np.int32)
        payload = self._compressor.compress(b"".join(
            fmt.shuffle(column) for column in (class_id.astype(np.uint32), pixel_delta, sample, rgb, norms)
        ))
        crc = zlib.crc32(payload)
        try:
            offset = self._file.tell()
            self._file.write(fmt.CHUNK_HEADER.pack(fmt.CHUNK_MAGIC, len(payload), crc, len(class_id)))
            self._file.write(payload)
        except OSError as error:  # a full disk mid-render: the caller aborts, nothing is left behind
            raise OutputError(f"{self.path}: cannot write the path index ({error.strerror or error})") from error
        self._chunks.append({
            "offset": offset, "bytes": len(payload), "crc32": crc, "records": len(class_id),
            "classes": np.unique(class_id).tolist(),
        })
        self._records += len(class_id)

    # -- finishing

    def close(self, vocabulary: EventVocabulary) -> Path:
        """Flush, write the footer (event names from `vocabulary`) and trailer, and put the
        file in place (:func:`pxr_layers.outputs.finish`: after the products of an open
        OutputSet). Returns where the complete file is now."""
        try:
            self._flush()
            footer = self._compressor.compress(json.dumps(self._footer(vocabulary), separators=(",", ":")).encode())
            offset = self._file.tell()
            self._file.write(footer)
            self._file.write(fmt.TRAILER.pack(offset, len(footer), zlib.crc32(footer), fmt.FORMAT_VERSION,
                                              fmt.TRAILER_MAGIC))
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            where = finish(self._temporary, self.path, last=True)
        except OSError as error:
            self.abort()
            raise OutputError(f"{self.path}: cannot write the path index ({error.strerror or error})") from error
        except BaseException:
            self.abort()
            raise
        log.info("wrote %s: %d records, %d classes, %.1f bytes per record", self.path, self._records,
                 len(self._class_keys), where.stat().st_size / max(self._records, 1))
        return where

    def abort(self) -> None:
        """Drop everything written so far: no file is left behind."""
        if not self._file.closed:
            self._file.close()
        self._temporary.unlink(missing_ok=True)

    def _footer(self, vocabulary: EventVocabulary) -> dict:
        labels: dict[str, int] = {}
        event_ids: dict[int, int] = {}
        events = [["C", "", []]]  # every class starts with the camera, event 0
        classes = []
        for keys in self._class_keys:
            for key in keys:
                if key not in event_ids:
                    event = vocabulary.event(key)
                    event_ids[key] = len(events)
                    ids = sorted(labels.setdefault(label, len(labels)) for label in sorted(event.labels))
                    events.append([event.type, event.scatter, ids, event.name])
            classes.append([0] + [event_ids[key] for key in keys])
        manifest = {
            **self.manifest,
            "format_version": fmt.FORMAT_VERSION,
            "norm_slots": self.norm_slots,
            "norms": {name: fmt.NORM_UNITS[name] for name in fmt.NORM_NAMES},
            "norm_storage": "float16",
            "stores_sigma": False,
            "aggregated": self.aggregate,
            "contributions": self._contributions,
            "records": self._records,
            "classes": len(classes),
        }
        return {"manifest": manifest, "labels": list(labels), "events": events, "classes": classes,
                "class_records": self._class_records.tolist(), "class_rgb": self._class_rgb.tolist(),
                "chunks": self._chunks}


def _merged(class_id, pixel, rgb, norms) -> tuple[np.ndarray, ...]:
    """Records with equal (class, pixel, float16 norms) merged, in order of first
    appearance: (class, pixel, count, summed rgb float32, norms)."""
    columns = np.column_stack([class_id, pixel, norms.view(np.uint16).reshape(len(class_id), -1)]).astype(np.uint64)
    # a 64-bit hash of each row, then an exact check that every group's rows are equal
    multipliers = np.random.default_rng(0x5EED).integers(1, 2**63, columns.shape[1], dtype=np.uint64) | np.uint64(1)
    with np.errstate(over="ignore"):
        hashed = (columns * multipliers).sum(axis=1)
    _, first, group = np.unique(hashed, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    if not np.array_equal(columns, columns[first[group]]):  # a hash collision: fall back to exact rows
        _, first, group = np.unique(columns, axis=0, return_index=True, return_inverse=True)
        group = group.reshape(-1)
    # number the groups in order of first appearance
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    group = rank[group]
    first = np.sort(first)
    count = np.bincount(group, minlength=len(first)).astype(np.uint32)
    summed = np.stack([np.bincount(group, weights=rgb[:, c], minlength=len(first)) for c in range(3)], axis=1)
    return class_id[first], pixel[first], count, summed.astype(np.float32), norms[first]


def _stable_order(class_id: np.ndarray, classes: int) -> np.ndarray:
    """The permutation that sorts ``class_id`` (values < ``classes``) keeping equal ids in
    their order. Keys of 16 bits take numpy's radix sort, 5x faster than int64's."""
    if classes <= 1 << 16:
        class_id = class_id.astype(np.uint16)
    return np.argsort(class_id, kind="stable")


def _grown(array: np.ndarray, length: int) -> np.ndarray:
    """`array` padded with zeros along its first axis to `length` rows."""
    if len(array) >= length:
        return array
    return np.concatenate([array, np.zeros((length - len(array), *array.shape[1:]), array.dtype)])
