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
    mode : "merged" (records arrive as ``trace.merge.MergedContributions``, merged on the
    tracer's threads) or "records" (``trace.recorder.Contributions``, one per
    contribution); see paths/format.py. sigma : keep each event's Σ too (the records
    carry it).

    Class ids are given in order of first appearance, and each flush sorts its records by
    class keeping the tracer's order within a class, so the same render (same settings
    and batch size) gives a byte-identical file whatever the thread count.
    """

    def __init__(self, path: str | os.PathLike, manifest: dict, norm_slots: int, *, mode: str = fmt.DEFAULT_MODE,
                 sigma: bool = False, buffer_records: int = BUFFER_RECORDS, chunk_records: int = CHUNK_RECORDS):
        if mode not in fmt.MODES:
            raise ValueError(f"unknown index mode {mode!r} (allowed: {', '.join(fmt.MODES)})")
        self.path = Path(path)
        self.manifest = dict(manifest)
        self.norm_slots = norm_slots
        self.mode = mode
        self.sigma = sigma
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
        """Add one batch's records in path order: ``MergedContributions`` for a merged
        index, ``Contributions`` for a records one. A records index takes norms as the
        tracer makes them (float16 as stored; float32 are saturated and cast here). The
        arrays are kept, not copied, until the next flush."""
        if records is None or not len(records.pixel):
            return
        merged = self.mode == "merged"
        if hasattr(records, "norm_codes") != merged:
            raise ValueError(f"a {self.mode} index takes {'merged' if merged else 'unmerged'} records "
                             "(TraceSettings.merge_records)")
        norms = records.norm_codes if merged else fmt.stored_norms(records.norms)
        if norms.shape[1:] != (self.norm_slots, 3):
            raise ValueError(f"records carry norms of shape {norms.shape[1:]}, the index expects ({self.norm_slots}, 3)")
        sigma = (records.sigma_codes if merged else records.sigma) if self.sigma else None
        if self.sigma and sigma is None:
            raise ValueError("the index keeps Σ but the records carry none (TraceSettings.record_sigma)")
        class_id = self._global_classes(records)
        count = records.count if merged else records.sample
        columns = (class_id, records.pixel.astype(np.int64, copy=False), count.astype(np.uint32, copy=False),
                   records.rgb.astype(np.float32, copy=False), norms)
        if sigma is not None:
            columns += (sigma if merged else sigma.astype(np.float32, copy=False),)
        self._buffer.append(columns)
        self._buffered += len(class_id)
        self._contributions += records.contributions if merged else len(class_id)
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
        columns = [np.concatenate(column) for column in zip(*self._buffer)]
        self._buffer.clear()
        self._buffered = 0
        classes = len(self._class_keys)
        order = _stable_order(columns[0], classes)
        columns = [np.take(column, order, axis=0) for column in columns]  # take: 3x faster than [order] on (r, N, 3)
        class_id, rgb = columns[0], columns[3]
        self._class_records = _grown(self._class_records, classes)
        self._class_rgb = _grown(self._class_rgb, classes)
        self._class_records += np.bincount(class_id, minlength=classes)
        for channel in range(3):
            self._class_rgb[:, channel] += np.bincount(class_id, weights=rgb[:, channel], minlength=classes)
        for start, stop in self._chunk_bounds(class_id):
            self._write_chunk(*(column[start:stop] for column in columns))

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

    def _write_chunk(self, class_id, pixel, count, rgb, *covariance) -> None:
        """One chunk: the sums frame (class, pixel deltas, count, rgb), then the covariance
        frame (norms, and Σ if kept), each column byte-shuffled (paths/format.py)."""
        pixel_delta = np.diff(pixel, prepend=0).astype(np.int32)
        sums = self._compressor.compress(b"".join(
            fmt.shuffle(column) for column in (class_id.astype(np.uint32), pixel_delta, count, rgb)))
        payload = sums + self._compressor.compress(b"".join(fmt.shuffle(column) for column in covariance))
        crc = zlib.crc32(payload)
        try:
            offset = self._file.tell()
            self._file.write(fmt.CHUNK_HEADER.pack(fmt.CHUNK_MAGIC, len(payload), crc, len(class_id), len(sums)))
            self._file.write(payload)
        except OSError as error:  # a full disk mid-render: the caller aborts, nothing is left behind
            raise OutputError(f"{self.path}: cannot write the path index ({error.strerror or error})") from error
        self._chunks.append({
            "offset": offset, "bytes": len(payload), "sums_bytes": len(sums), "crc32": crc, "records": len(class_id),
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
            "mode": self.mode,
            **({"bins": fmt.NormBins.manifest()} if self.mode == "merged" else {}),
            "covariance": "sigma" if self.sigma else "norms",
            "contributions": self._contributions,
            "records": self._records,
            "classes": len(classes),
        }
        return {"manifest": manifest, "labels": list(labels), "events": events, "classes": classes,
                "class_records": self._class_records.tolist(), "class_rgb": self._class_rgb.tolist(),
                "chunks": self._chunks}


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
