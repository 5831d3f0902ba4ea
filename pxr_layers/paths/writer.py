"""Write a path index incrementally while rendering, and finalise it atomically.

The caller's thread does only the cheap, order-dependent part of each batch (numbering its
classes); full buffers are sorted, summed, cut into chunks, compressed and written on one
thread of the writer's own, overlapping the render, so that closing the index costs only
the last, small buffer and the footer."""

from __future__ import annotations

import itertools
import json
import logging
import os
import queue
import threading
import zlib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import zstandard

from ..errors import OutputError
from ..outputs import finish, temporary_beside
from . import format as fmt
from .events import EventVocabulary
from .reader import PathIndex
from .trie import ClassTrie, class_events

log = logging.getLogger(__name__)

BUFFER_RECORDS = 1 << 18
"""Records taken in before a buffer goes to the writer's thread (some 12 MB merged, with N = 5).
Small, so that the last flush, in ``close``, is short; each flush cuts its own chunks, so a
class appears in up to one chunk per flush (smaller buffers: more, smaller chunks)."""
QUEUED_BUFFERS = 2
"""Full buffers waiting for the writer's thread; ``add`` blocks beyond, so memory stays at
most QUEUED_BUFFERS + 2 buffers (the one filling, the one being written, and the copies sorting
it takes) whatever the render."""
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

    ``add`` numbers a batch's classes on the caller's thread (that order is the file's);
    every ``buffer_records`` records, the buffer goes (FIFO, at most QUEUED_BUFFERS waiting)
    to the writer's own thread, which sorts, sums, compresses and writes it. An error
    there (a full disk: OutputError naming the file) is raised by the next ``add`` or by
    ``close``, which then remove the temporary file. ``close`` and ``abort`` end the thread.
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
        self._class_count = 0
        self._new_class_nodes: list[np.ndarray] = []  # trie nodes of the classes first met in the buffer
        self._buffer: list[tuple[np.ndarray, ...]] = []
        self._buffered = 0
        # written by the writer's thread only, read once it has ended:
        self._class_records = np.zeros(0, np.int64)  # (classes,) records so far
        self._class_rgb = np.zeros((0, 3))  # (classes, 3) float64 summed rgb
        self._chunks: list[dict] = []
        self._records = 0
        # The footer's tables as the flushes meet new classes, so that closing costs only the
        # class sums: the footer's events after the camera (the tracer's event ids, in order of
        # first appearance: footer id = position + 1), each class's footer event ids camera
        # first, and the JSON text of the classes and chunks listed so far (each flush's items,
        # comma-separated).
        self._footer_events = np.zeros(0, np.int64)
        self._footer_classes: list[list[int]] = []
        self._footer_json: dict[str, list[str]] = {"classes": [], "chunks": []}
        self._compressor = zstandard.ZstdCompressor(level=fmt.ZSTD_LEVEL)
        self._closed: tuple[Path, dict, int, int] | None = None  # after close: (where, footer tables, its offset, size)
        handle, self._temporary = temporary_beside(self.path)
        self._file = os.fdopen(handle, "wb")
        self._file.write(fmt.HEADER.pack(fmt.HEADER_MAGIC, fmt.FORMAT_VERSION, 0))
        self._file.flush()  # from now on, whenever the writer's thread is, the file reads as a truncated index
        self._buffers: queue.Queue[_FullBuffer | None] = queue.Queue(QUEUED_BUFFERS)  # None ends the thread
        self._failure: BaseException | None = None  # the writer thread's error, raised by add or close
        self._aborting = False
        self._thread = threading.Thread(target=self._write_buffers, name="pxl-index-writer", daemon=True)
        self._thread.start()

    # -- writing

    def add(self, records) -> None:
        """Add one batch's records in path order: ``MergedContributions`` for a merged
        index, ``Contributions`` for a records one. A records index takes norms as the
        tracer makes them (float16 as stored; float32 are saturated and cast here). The
        arrays are kept, not copied, until their buffer is written: the caller must not
        change them. Blocks while QUEUED_BUFFERS full buffers wait; raises the writer
        thread's error (the temporary file then removed)."""
        self._raise_failure()
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
            self._hand_over()

    def _global_classes(self, records) -> np.ndarray:
        """The batch's classes as global class ids (new classes numbered in the order of
        the batch's list, which the tracer makes deterministic). The batch's class trie is
        merged into the index's; the writer's thread builds the event sequences of new classes."""
        nodes = self._classes.merge(records.trie_parent, records.trie_event)[records.class_nodes]
        if len(self._node_class) < len(self._classes):  # grown to twice the nodes: amortised
            self._node_class = np.concatenate([self._node_class,
                                               np.full(2 * len(self._classes) - len(self._node_class), -1, np.int64)])
        ids = self._node_class[nodes]
        new = np.flatnonzero(ids < 0)
        if len(new):
            ids[new] = np.arange(self._class_count, self._class_count + len(new))
            self._node_class[nodes[new]] = ids[new]
            self._new_class_nodes.append(nodes[new])
            self._class_count += len(new)
        return ids[records.path_class]

    def _hand_over(self) -> None:
        """Queue the buffer for the writer's thread."""
        if self._buffer:
            self._buffers.put(_FullBuffer(self._buffer, self._class_count, self._new_class_nodes))
            self._buffer, self._buffered, self._new_class_nodes = [], 0, []

    def _raise_failure(self) -> None:
        if self._failure is not None:
            self.abort()
            raise self._failure

    def _write_buffers(self) -> None:
        """The writer's thread: flush every buffer queued, in order, until None. After an
        error or an abort it only empties the queue, so that ``add`` never waits for it."""
        while (queued := self._buffers.get()) is not None:
            if self._failure is None and not self._aborting:
                try:
                    self._flush(queued)
                except BaseException as error:  # raised on the caller's thread, by add or close
                    self._failure = error

    def _end_thread(self) -> None:
        if self._thread.is_alive():
            self._buffers.put(None)
            self._thread.join()

    def _flush(self, buffer: _FullBuffer) -> None:
        """Sort a buffer's records by class, add them to the class sums and write them as
        chunks. Runs on the writer's thread."""
        columns = [np.concatenate(column) for column in zip(*buffer.columns)]
        buffer.columns.clear()
        classes = buffer.classes
        order = _stable_order(columns[0], classes)
        columns = [np.take(column, order, axis=0) for column in columns]  # take: 3x faster than [order] on (r, N, 3)
        class_id, rgb = columns[0], columns[3]
        self._class_records = _grown(self._class_records, classes)
        self._class_rgb = _grown(self._class_rgb, classes)
        self._class_records += np.bincount(class_id, minlength=classes)
        for channel in range(3):
            self._class_rgb[:, channel] += np.bincount(class_id, weights=rgb[:, channel], minlength=classes)
        chunks_before = len(self._chunks)
        for start, stop in self._chunk_bounds(class_id):
            self._write_chunk(*(column[start:stop] for column in columns))
        self._footer_grown(buffer.new_class_nodes, self._chunks[chunks_before:])

    def _footer_grown(self, new_class_nodes: list[np.ndarray], chunks: list[dict]) -> None:
        """The footer's class table extended by the classes of `new_class_nodes` (trie nodes,
        in id order), and the JSON text of those classes and of a flush's `chunks` added.
        Vectorised: Python loops here would hold the GIL the tracer's threads need."""
        nodes = np.concatenate(new_class_nodes) if new_class_nodes else np.zeros(0, np.int64)
        # The caller's thread may be merging a batch into the trie meanwhile: it only adds
        # nodes (beyond these) and replaces its arrays by larger copies, so these read the same.
        events = class_events(self._classes.parent, self._classes.event, nodes)
        listed = events >= 0
        flat = events[listed]  # class by class: in order of first appearance
        unique, first = np.unique(flat, return_index=True)
        unseen = ~np.isin(unique, self._footer_events)
        self._footer_events = np.concatenate([self._footer_events, unique[unseen][np.argsort(first[unseen])]])
        by_event = np.argsort(self._footer_events)
        ids = np.zeros((len(nodes), events.shape[1] + 1), np.int64)  # column 0: the camera, event 0
        ids[:, 1:][listed] = by_event[np.searchsorted(self._footer_events, flat, sorter=by_event)] + 1
        new = [row[:length] for row, length in zip(ids.tolist(), (listed.sum(axis=1) + 1).tolist())]
        self._footer_classes.extend(new)
        for name, items in (("classes", new), ("chunks", chunks)):
            if items:
                self._footer_json[name].append(_json(items)[1:-1])

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
            "classes": class_id[np.r_[True, class_id[1:] != class_id[:-1]]].tolist(),  # sorted: its runs' heads
        })
        self._records += len(class_id)

    # -- finishing

    def close(self, vocabulary: EventVocabulary) -> Path:
        """Flush the last buffer, wait for the writer's thread, write the footer (event names
        from `vocabulary`) and trailer, and put the file in place
        (:func:`pxr_layers.outputs.finish`: after the products of an open OutputSet). Returns
        where the complete file is now; :meth:`opened` gives it open for reading."""
        try:
            self._hand_over()
            self._end_thread()
            if self._failure is not None:
                raise self._failure
            tables = self._footer(vocabulary)
            footer = self._compressor.compress(self._footer_text(tables).encode())
            offset = self._file.tell()
            self._file.write(footer)
            self._file.write(fmt.TRAILER.pack(offset, len(footer), zlib.crc32(footer), fmt.FORMAT_VERSION,
                                              fmt.TRAILER_MAGIC))
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            where = finish(self._temporary, self.path, last=True)
            size = offset + len(footer) + fmt.TRAILER.size
            self._closed = (where, tables, offset, size)
        except OSError as error:
            self.abort()
            raise OutputError(f"{self.path}: cannot write the path index ({error.strerror or error})") from error
        except BaseException:
            self.abort()
            raise
        log.info("wrote %s: %d records, %d classes, %.1f bytes per record", self.path, self._records,
                 self._class_count, size / max(self._records, 1))
        return where

    def opened(self) -> PathIndex:
        """The index just closed, open for reading: its tables built from the footer this
        writer holds (:meth:`PathIndex.from_footer`), not read back and parsed again."""
        if self._closed is None:
            raise RuntimeError("PathIndexWriter.opened before close")
        return PathIndex.from_footer(*self._closed, shown_as=self.path)

    def abort(self) -> None:
        """Drop everything written so far: ends the writer's thread (after the buffer it
        is writing, if any), and no file is left behind."""
        self._aborting = True
        self._end_thread()
        if not self._file.closed:
            self._file.close()
        self._temporary.unlink(missing_ok=True)

    def _footer(self, vocabulary: EventVocabulary) -> dict:
        """The footer's tables, as a reader parses them (paths/format.py)."""
        labels: dict[str, int] = {}
        events = [["C", "", []]]
        for key in self._footer_events.tolist():
            event = vocabulary.event(key)
            ids = sorted(labels.setdefault(label, len(labels)) for label in sorted(event.labels))
            events.append([event.type, event.scatter, ids, event.name])
        manifest = {
            **json.loads(json.dumps(self.manifest)),  # as a reader parses it (a tuple becomes a list)
            "format_version": fmt.FORMAT_VERSION,
            "norm_slots": self.norm_slots,
            "norms": {name: fmt.NORM_UNITS[name] for name in fmt.NORM_NAMES},
            "mode": self.mode,
            **({"bins": fmt.NormBins.manifest()} if self.mode == "merged" else {}),
            "covariance": "sigma" if self.sigma else "norms",
            "contributions": self._contributions,
            "records": self._records,
            "classes": len(self._footer_classes),
        }
        return {"manifest": manifest, "labels": list(labels), "events": events, "classes": self._footer_classes,
                "class_records": self._class_records.tolist(), "class_rgb": self._class_rgb.tolist(),
                "chunks": self._chunks}

    def _footer_text(self, tables: dict) -> str:
        """The very text of ``json.dumps(tables)`` (compact), with the classes and chunks from
        the JSON the flushes made of them."""
        return "{" + ",".join(
            f'"{name}":' + (f"[{','.join(self._footer_json[name])}]" if name in self._footer_json else _json(value))
            for name, value in tables.items()) + "}"


class _FullBuffer(NamedTuple):
    """A buffer handed to the writer's thread: its records' columns batch by batch (class id,
    pixel, count, rgb, norms[, Σ]), the number of classes numbered by then, and the trie
    nodes of the classes first met in it, in id order."""

    columns: list[tuple[np.ndarray, ...]]
    classes: int
    new_class_nodes: list[np.ndarray]


def _json(value) -> str:
    """The footer's JSON text of `value` (compact)."""
    return json.dumps(value, separators=(",", ":"))


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
