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
"""Records taken in before a buffer goes to the writer's thread (some 10 MB merged, with N = 5).
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
    class, then pixel (stable), so the same render (same settings and batch size) gives a
    byte-identical file whatever the thread count.

    ``add`` numbers a batch's classes on the caller's thread (that order is the file's);
    every ``buffer_records`` records, the buffer goes (FIFO, at most QUEUED_BUFFERS waiting)
    to the writer's own thread, which codes (merged: ``_coded_rgb``; a buffer holds whole
    batches, so every record of each of its pixels), sorts, compresses and writes it. An error
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
        self._chroma = np.zeros((0, 2), np.uint16)  # (classes, 2) merged: each class's chroma (format.py)
        self._chroma_known = np.zeros(0, bool)  # (classes,) its chroma is set: by its first flush
        self._nonfinite: set[int] = set()  # classes with a NaN or infinite record
        self._chunks: list[dict] = []
        self._records = 0
        # The footer's tables as the flushes meet new classes, so that closing costs only
        # concatenating them: the footer's events after the camera (the tracer's event ids, in
        # order of first appearance: footer id = position + 1), and per flush the events after
        # the camera of each class it met first (their count, and their footer ids one class
        # after the other).
        self._footer_events = np.zeros(0, np.int64)
        self._class_lengths: list[np.ndarray] = []
        self._class_events: list[np.ndarray] = []
        self._compressor = zstandard.ZstdCompressor(level=fmt.ZSTD_LEVEL)
        self._closed: tuple | None = None  # after close: (where, footer tables, class table, its offset, size)
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
        # merged: the count of contributions is not stored (the manifest has their total)
        sample = None if merged else records.sample.astype(np.uint32, copy=False)
        columns = (class_id, records.pixel.astype(np.int64, copy=False), sample,
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
        """Code a buffer's rgb (merged), sort its records by class, then pixel, add them to
        the class table and write them as chunks. Runs on the writer's thread."""
        names = ("class", "pixel", "sample", "rgb", "norms", "sigma")
        columns = {name: np.concatenate(column) for name, column in zip(names, zip(*buffer.columns))
                   if column[0] is not None}
        buffer.columns.clear()
        classes = buffer.classes
        # Per pixel: a buffer holds whole batches, so every record of each of its pixels (were a
        # pixel's records split between buffers, each part would carry its own rest: exact still).
        if self.mode == "merged":
            columns["codes"], columns["exact"], columns["rgb"] = _coded_rgb(columns["pixel"], columns["rgb"])
        order = _class_pixel_order(columns["class"], columns["pixel"], classes)
        columns = {name: np.take(column, order, axis=0) for name, column in columns.items()}  # take: 3x faster on (r, N, 3)
        class_id = columns["class"]
        self._class_records = _grown(self._class_records, classes)
        self._class_records += np.bincount(class_id, minlength=classes)
        finite = np.isfinite(columns["rgb"]).all(axis=1)
        if not finite.all():
            self._nonfinite.update(np.unique(class_id[~finite]).tolist())
        if self.mode == "merged":
            self._chroma = _grown(self._chroma, classes)
            self._chroma_known = _grown(self._chroma_known, classes)
            _learn_chroma(class_id, columns["codes"], columns["exact"], self._chroma, self._chroma_known)
        for start, stop in self._chunk_bounds(class_id):
            self._write_chunk({name: column[start:stop] for name, column in columns.items()})
        self._footer_grown(buffer.new_class_nodes)

    def _footer_grown(self, new_class_nodes: list[np.ndarray]) -> None:
        """The footer's class table extended by the classes of `new_class_nodes` (trie nodes,
        in id order). Vectorised: Python loops here would hold the GIL the tracer's threads need."""
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
        # listed is a prefix of each row: its True entries, row-major, are the classes' events in order
        self._class_events.append(by_event[np.searchsorted(self._footer_events, flat, sorter=by_event)] + 1)
        self._class_lengths.append(listed.sum(axis=1))

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

    def _write_chunk(self, columns: dict[str, np.ndarray]) -> None:
        """One chunk of records sorted by class, then pixel: the where frame (class runs,
        pixels), the light frame (rgb) and the covariance frame (norms, and Σ if kept), each
        column byte-shuffled (paths/format.py)."""
        class_id, pixel = columns["class"], columns["pixel"]
        run_starts = np.flatnonzero(np.r_[True, class_id[1:] != class_id[:-1]])
        run_class = class_id[run_starts]
        run_length = np.diff(np.r_[run_starts, len(class_id)])
        # Pixels: within a run, the step from the record before (>= 0: sorted); a run's first,
        # the zigzag-coded step from the run before's first (classes numbered together first
        # appeared near each other: the steps are small).
        steps = np.diff(pixel, prepend=0)
        steps[run_starts] = fmt.zigzag(np.diff(pixel[run_starts], prepend=0))
        where = [np.diff(run_class, prepend=0), run_length, steps]
        exact = 0
        if self.mode == "merged":
            exact_rows = columns["exact"]
            codes = columns["codes"]
            codes[exact_rows] = [0, fmt.RgbBins.EXACT, 0]  # an exact record: its g says so, r and b are 0
            light = [fmt.chroma_residuals(codes, self._chroma[class_id]), columns["rgb"][exact_rows]]
            exact = int(exact_rows.sum())
        else:
            light = [columns["sample"], columns["rgb"]]
        covariance = [columns[name] for name in ("norms", "sigma") if name in columns]
        layout = fmt.column_layout(self.mode, len(class_id), self.norm_slots, self.sigma, runs=len(run_class),
                                   exact=exact)
        frames = [self._compressor.compress(b"".join(
            fmt.shuffle(np.asarray(value).astype(dtype, copy=False))
            for (_, dtype, _), value in zip(frame_layout, values, strict=True)))
            for frame_layout, values in zip(layout, (where, light, covariance))]
        payload = b"".join(frames)
        crc = zlib.crc32(payload)
        try:
            offset = self._file.tell()
            self._file.write(fmt.CHUNK_HEADER.pack(fmt.CHUNK_MAGIC, len(payload), crc, len(class_id), len(run_class),
                                                   exact, len(frames[0]), len(frames[1])))
            self._file.write(payload)
        except OSError as error:  # a full disk mid-render: the caller aborts, nothing is left behind
            raise OutputError(f"{self.path}: cannot write the path index ({error.strerror or error})") from error
        self._chunks.append({
            "offset": offset, "bytes": len(payload), "where_bytes": len(frames[0]), "light_bytes": len(frames[1]),
            "crc32": crc, "records": len(class_id), "runs": len(run_class), "exact": exact,
            "first_class": int(class_id[0]), "last_class": int(class_id[-1]),
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
            tables, arrays = self._footer(vocabulary)
            footer = fmt.footer(tables, arrays, self._compressor)
            offset = self._file.tell()
            self._file.write(footer.data)
            self._file.write(fmt.TRAILER.pack(offset, len(footer.data), footer.json_bytes, zlib.crc32(footer.data),
                                              fmt.FORMAT_VERSION, fmt.TRAILER_MAGIC))
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            where = finish(self._temporary, self.path, last=True)
            size = offset + len(footer.data) + fmt.TRAILER.size
            self._closed = (where, footer.tables, arrays, offset, size)
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

    def _footer(self, vocabulary: EventVocabulary) -> tuple[dict, dict[str, np.ndarray]]:
        """The footer's JSON tables and its class table's columns, as a reader parses them
        (paths/format.py)."""
        labels: dict[str, int] = {}
        events = [["C", "", []]]
        for key in self._footer_events.tolist():
            event = vocabulary.event(key)
            ids = sorted(labels.setdefault(label, len(labels)) for label in sorted(event.labels))
            events.append([event.type, event.scatter, ids, event.name])
        lengths = np.concatenate([np.zeros(0, np.int64), *self._class_lengths])
        arrays = {"length": lengths, "events": np.concatenate([np.zeros(0, np.int64), *self._class_events]),
                  "records": _grown(self._class_records, len(lengths))}
        if self.mode == "merged":
            arrays["chroma"] = _grown(self._chroma, len(lengths))
        manifest = {
            **json.loads(json.dumps(self.manifest)),  # as a reader parses it (a tuple becomes a list)
            "format_version": fmt.FORMAT_VERSION,
            "norm_slots": self.norm_slots,
            "norms": {name: fmt.NORM_UNITS[name] for name in fmt.NORM_NAMES},
            "mode": self.mode,
            **({"bins": fmt.NormBins.manifest(), "rgb": fmt.RgbBins.manifest()} if self.mode == "merged" else {}),
            "covariance": "sigma" if self.sigma else "norms",
            "contributions": self._contributions,
            "records": self._records,
            "classes": len(lengths),
        }
        tables = {"manifest": manifest, "labels": list(labels), "events": events,
                  "nonfinite_classes": sorted(self._nonfinite), "chunks": self._chunks}
        return tables, arrays


class _FullBuffer(NamedTuple):
    """A buffer handed to the writer's thread: its records' columns batch by batch (class id,
    pixel, sample (records mode; merged: None), rgb, norms[, Σ]), the number of classes numbered by then, and the trie
    nodes of the classes first met in it, in id order."""

    columns: list[tuple[np.ndarray, ...]]
    classes: int
    new_class_nodes: list[np.ndarray]


def _coded_rgb(pixel: np.ndarray, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rgb of a merged buffer's records as stored (paths/format.py, ``RgbBins``).

    pixel (r,) int64; rgb (r, 3) float32, every record of each pixel present. Returns codes
    (r, 3) int64, exact (r,) bool (kept as float32: the carriers, and records a code cannot
    hold) and the rgb as a reader reads it (r, 3) float32: the codes' values, and for each
    pixel and channel the record with the most light (its carrier) holding the pixel's sum
    minus the others as read, so that a pixel's records, as read, sum to what they summed to.
    """
    codes = fmt.RgbBins.code(rgb)
    exact = (codes == fmt.RgbBins.EXACT).any(axis=1)
    values = rgb.astype(np.float64)
    order = np.argsort(pixel, kind="stable")
    in_order = values[order]
    starts = np.flatnonzero(np.r_[True, pixel[order][1:] != pixel[order][:-1]])
    sizes = np.diff(np.r_[starts, len(order)])
    group = np.repeat(np.arange(len(starts)), sizes)  # of each record in pixel order
    finite = np.isfinite(in_order)
    sums = np.add.reduceat(in_order, starts, axis=0) if len(order) else np.zeros((0, 3))
    carried = np.isfinite(sums)  # (pixels, 3): a NaN or infinite sum has no rest to carry
    carrier = np.full((len(starts), 3), -1, np.int64)  # its place in pixel order
    for channel in range(3):
        light = np.where(finite[:, channel], in_order[:, channel], -np.inf)
        peak = np.maximum.reduceat(light, starts) if len(order) else light
        at_peak = np.flatnonzero(light == peak[group])
        first = at_peak[np.r_[True, group[at_peak][1:] != group[at_peak][:-1]]]  # the first at each pixel's peak
        chosen = carried[group[first], channel] & (light[first] > 0)  # all 0: nothing to carry
        carrier[group[first[chosen]], channel] = first[chosen]
        exact[order[first[chosen]]] = True
    read = np.where(exact[:, None], values, fmt.RgbBins.table()[codes & 0xFFFF].astype(np.float64))
    with np.errstate(invalid="ignore"):  # pixels of NaN or infinite light: no carrier reads their rest
        rest = sums - (np.add.reduceat(read[order], starts, axis=0) if len(order) else sums)
    for channel in range(3):
        has = carrier[:, channel] >= 0
        at = order[carrier[has, channel]]
        read[at, channel] += rest[has, channel]
    return codes, exact, read.astype(np.float32)


def _learn_chroma(class_id: np.ndarray, codes: np.ndarray, exact: np.ndarray, chroma: np.ndarray,
                  known: np.ndarray) -> None:
    """Set the chroma (format.py) of the classes of `class_id` not `known` yet: r − g and
    b − g codes of the first of their records (sorted) whose three channels are bin codes
    (0, 0 if none), modulo 2^16. chroma (classes, 2) uint16 and known (classes,) bool are
    updated in place; codes (r, 3) int64, exact (r,) bool."""
    new = ~known[class_id]
    binned = new & ~exact & ((codes >= 1) & (codes <= fmt.RgbBins.LARGEST_CODE)).all(axis=1)
    rows = np.flatnonzero(binned)
    classes, first = np.unique(class_id[rows], return_index=True)
    rows = rows[first]
    chroma[classes] = (codes[rows][:, [0, 2]] - codes[rows][:, 1:2]) & 0xFFFF
    known[class_id[new]] = True


def _class_pixel_order(class_id: np.ndarray, pixel: np.ndarray, classes: int) -> np.ndarray:
    """The permutation that sorts records by class, then pixel (stable): a stable sort by
    class, which is enough when each class's records come in pixel order (merged batches
    do), else a sort by both."""
    order = _stable_order(class_id, classes)
    sorted_class, sorted_pixel = class_id[order], pixel[order]
    if ((np.diff(sorted_pixel) >= 0) | (np.diff(sorted_class) != 0)).all():
        return order
    return np.lexsort((pixel, class_id))


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
