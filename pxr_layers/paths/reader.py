"""Read a path index: its manifest, label and class tables, and records class by class.

Nothing the file says is taken on trust, so that a damaged file is one PathIndexError
naming it (and the chunk), never a traceback, unbounded memory or other pixels; even a
forged one (its checksums made to agree) cannot crash the reader or bring NaN, pixels
outside the image or records of classes the footer does not list. At open: the header, trailer and footer checksum, then the tables (types, ids in
range, counts that agree, chunks inside the file and apart). When a chunk is read: its
CRC-32, a zstd frame of exactly its columns' size, class ids among those the footer lists
for it, pixels inside the image, rgb finite wherever the footer's class sums are.
``PathIndex.verify`` reads every chunk and checks the rest: every rgb finite, and the
records and summed rgb of each class what the footer says.
"""

from __future__ import annotations

import collections
import functools
import itertools
import json
import math
import os
import threading
import zlib
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zstandard

from ..compiled import inline, kernel
from ..errors import PathIndexError
from ..inputs import regular_input
from ..progress import Progress
from ..request import MAX_PIXELS
from . import format as fmt
from .events import ALL_SCATTERINGS, EVENT_TYPES, Event

MAX_CHUNK_BYTES = 1 << 28
"""The most one chunk may decode to (256 MiB): bounds the memory of reading it. The
writer's chunks hold at most writer.CHUNK_RECORDS (2^16) records, 3.5 MB with N = 5."""
MAX_FOOTER_BYTES = 1 << 28
"""The most the footer's JSON may take (256 MiB): bounds the memory of opening a file.
A footer takes some 100 bytes per path class: 10 MB for a hundred thousand classes."""

CHUNKS_IN_FLIGHT_PER_THREAD = 2
"""Chunks read ahead per reading thread when records are streamed on threads: enough that a
thread never waits for the consumer to take a chunk, few enough that memory stays a handful
of chunks (each at most MAX_CHUNK_BYTES, in practice 1.5 MB of sums) whatever the file's size."""

CHUNKS_NAMED = 8
"""How many of the chunks holding a class whose records disagree with the footer verify names."""
RGB_SUM_TOLERANCE = 1e-6
"""How far (relative to the summed |rgb|) verify lets a class's summed rgb stray from the
footer's: both are float64 sums of the same float32 values, in another order (the footer's
per flush of the writer), which differ by some 1e-16 × the number of records at most."""

AUTOMATIC_SUBDIV_LEVEL = -1
"""The manifest's ``subdiv_level`` of a render whose subdivision levels were automatic (a level
per mesh from its size on the image: RenderRequest.subdiv_level None); else it is the one
level asked. Either way the levels may have been lowered to the scene's budget."""
RENDER_KEYS = {"stage": str, "stage_sha256": str, "camera": str, "frame": str, "variants": str,
               "defaultLights": str, "beauty": str, "version": str, "maxDepth": str, "spp": int,
               "seed": int, "max_depth": int, "subdiv_level": int, "clampIndirect": str, "clamp_indirect": float}
"""Manifest keys that whoever wrote the index may give (PathIndexWriter stores its manifest
as given) and that pxr-layers reads, with their types; checked when present."""


class PathClass:
    """One distinct event sequence: its event ids camera first (into ``PathIndex.events``),
    records and summed rgb; ``events`` are the Events themselves.

    An index can hold tens of thousands of classes and is opened for every extraction:
    the Event tuple is built when asked for, not at open (a third of the open time).
    """

    __slots__ = ("_table", "event_ids", "id", "records", "rgb")

    def __init__(self, id: int, event_ids: tuple[int, ...], records: int, rgb: tuple[float, float, float],
                 table: tuple[Event, ...]):
        self.id, self.event_ids, self.records, self.rgb, self._table = id, event_ids, records, rgb, table

    @property
    def events(self) -> tuple[Event, ...]:
        return tuple(self._table[event] for event in self.event_ids)

    def __repr__(self) -> str:
        return f"PathClass({self.id}, {self.event_ids}, records={self.records})"


def padded_event_ids(classes: Sequence[PathClass], pad: int) -> np.ndarray:
    """(classes, longest) int64: each class's event ids camera first, padded with `pad`
    (at least one column), built without a Python loop over the events."""
    lengths = np.fromiter((len(path_class.event_ids) for path_class in classes), np.int64, len(classes))
    events = np.full((len(classes), max(1, int(lengths.max(initial=0)))), pad, np.int64)
    flat = np.fromiter(itertools.chain.from_iterable(path_class.event_ids for path_class in classes), np.int64,
                       int(lengths.sum()))
    # Each flat event goes to its class's row, at its position within the class (its flat
    # index minus where the class starts).
    rows = np.repeat(np.arange(len(classes)), lengths)
    events[rows, np.arange(len(flat)) - np.repeat(np.cumsum(lengths) - lengths, lengths)] = flat
    return events


@dataclass(frozen=True)
class RecordChunk:
    """Records of one chunk (or the part of it in the classes asked for).

    class_id : (r,) int64; pixel : (r,) int64 (y·width + x)
    count : (r,) int64: contributions merged (merged index), sample index (records index)
    rgb : (r, 3) float32, as the film added it
    norms : (r, N, 3) float32 C, T, R (merged: each bin's centre, paths/format.py)
    sigma : (r, N, 10) float32 upper triangles of Σ, or None (an index without Σ)
    """

    class_id: np.ndarray
    pixel: np.ndarray
    count: np.ndarray
    rgb: np.ndarray
    norms: np.ndarray
    sigma: np.ndarray | None = None


class Manifest(dict):
    """The footer's manifest. A key it lacks is a PathIndexError naming the file, not a
    KeyError in whatever reads it: the render's keys (resolution, spp, ...) are given by
    whoever wrote the index, and an index written by other code may lack them."""

    def __init__(self, values: dict, path: Path):
        super().__init__(values)
        self.path = path

    def __missing__(self, key):
        raise PathIndexError(f"its manifest has no {key!r} (not written by `pxr-layers render`?)",
                             file=str(self.path))


class _Malformed(ValueError):
    """A footer whose checksum matches but whose tables make no sense (a foreign or buggy
    writer, or a forged file): PathIndex turns it into a PathIndexError naming the file."""


class PathIndex:
    """An open path index. Checks the header, trailer, version, footer checksum and tables
    at open; every chunk when it is read (module docstring). Memory: the tables, plus one
    chunk at a time while streaming records (with threads: CHUNKS_IN_FLIGHT_PER_THREAD per
    thread)."""

    def __init__(self, path: str | os.PathLike, *, shown_as: str | os.PathLike | None = None):
        """shown_as: the file's name in messages, when it is read under another (a render
        reads its index under its temporary name, before the frame's files are put in place)."""
        self._named(path, shown_as)
        regular_input(self.path, "path index", PathIndexError, name=self.shown_as)  # a FIFO would block the open
        footer = self._footer_bytes()
        try:
            self._load(self._footer_tables(footer))
        except _Malformed as error:
            raise self._error(f"corrupted footer: {error}") from None

    @classmethod
    def from_footer(cls, path: str | os.PathLike, tables: dict, footer_offset: int, size: int, *,
                    shown_as: str | os.PathLike | None = None) -> PathIndex:
        """The index at `path` whose footer is already in memory: `tables`, its JSON object
        as parsed, at byte `footer_offset` of the file of `size` bytes (its writer's own,
        ``PathIndexWriter.opened``). Its tables are built and checked as for a file read
        from disk; only reading, checking and parsing the header, trailer and footer is
        skipped."""
        index = cls.__new__(cls)
        index._named(path, shown_as)
        index.size, index._footer_offset = size, footer_offset
        try:
            index._load(tables)
        except _Malformed as error:  # a bug of the writer's
            raise index._error(f"corrupted footer: {error}") from None
        return index

    def _named(self, path: str | os.PathLike, shown_as: str | os.PathLike | None) -> None:
        self.path = Path(path)
        self.shown_as = Path(shown_as) if shown_as is not None else self.path

    def _footer_bytes(self) -> bytes:
        """The footer, after checking the header, trailer and footer checksum; sets size
        and the footer's offset."""
        try:
            self.size = self.path.stat().st_size
            with open(self.path, "rb") as file:
                head = file.read(fmt.HEADER.size)
                if len(head) < fmt.HEADER.size or head[:8] != fmt.HEADER_MAGIC:
                    raise self._error("not a pxr-layers path index (no PXLIDX header)")
                _, version, _ = fmt.HEADER.unpack(head)
                self._check_version(version)
                if self.size < fmt.HEADER.size + fmt.TRAILER.size:
                    raise self._error("truncated: the file ends before its trailer (an interrupted write?)")
                file.seek(self.size - fmt.TRAILER.size)
                offset, length, crc, trailer_version, magic = fmt.TRAILER.unpack(file.read(fmt.TRAILER.size))
                if magic != fmt.TRAILER_MAGIC:
                    raise self._error("truncated or incomplete: no trailer at the end of the file "
                                      "(an interrupted write?)")
                if offset < fmt.HEADER.size or offset + length + fmt.TRAILER.size != self.size:
                    raise self._error("corrupted: the trailer points outside the file")
                if trailer_version != version:
                    raise self._error(f"corrupted: the trailer says format version {trailer_version}, "
                                      f"the header {version}")
                if length > MAX_FOOTER_BYTES:  # before reading it: a forged trailer must not cost memory
                    raise self._error(f"corrupted: the footer would be {length:,} bytes, more than the "
                                      f"{MAX_FOOTER_BYTES:,} an index holds")
                file.seek(offset)
                footer = file.read(length)
        except OSError as error:
            raise PathIndexError(f"cannot read ({error.strerror or error})", file=str(self.shown_as)) from error
        if zlib.crc32(footer) != crc:
            raise self._error("corrupted: the footer's checksum does not match")
        self._footer_offset = offset
        return footer

    def _footer_tables(self, footer: bytes) -> dict:
        try:
            size = zstandard.frame_content_size(footer)
            if not 0 <= size <= MAX_FOOTER_BYTES:
                raise _Malformed(f"it states a size of {size} bytes, not 0 to MAX_FOOTER_BYTES ({MAX_FOOTER_BYTES})")
            tables = json.loads(zstandard.ZstdDecompressor().decompress(footer, allow_extra_data=False))
        except (zstandard.ZstdError, ValueError, RecursionError) as error:
            raise _Malformed(str(error) or type(error).__name__) from None
        if type(tables) is not dict:
            raise _Malformed("not a JSON object")
        return tables

    def _load(self, tables: dict) -> None:
        """The tables, checked: raises _Malformed."""
        manifest = _typed(tables, "manifest", dict)
        self.labels: tuple[str, ...] = tuple(_typed(tables, "labels", list))
        if not all(type(label) is str for label in self.labels):
            raise _Malformed("a label is not a string")
        self.events: tuple[Event, ...] = tuple(self._event(entry) for entry in _typed(tables, "events", list))
        class_events = _id_lists(_typed(tables, "classes", list), len(self.events), "a class's event ids")
        records_listed, rgb_listed = _typed(tables, "class_records", list), _typed(tables, "class_rgb", list)
        class_records = _counts(records_listed, "class_records")
        class_rgb = _array(rgb_listed or np.zeros((0, 3)), "class_rgb")
        if len(class_records) != len(class_events) or class_rgb.shape != (len(class_events), 3) \
                or class_rgb.dtype.kind not in "iuf":
            raise _Malformed(f"class_records and class_rgb do not give counts and rgb for its "
                             f"{len(class_events)} classes")
        self.class_count: int = len(class_events)
        self._class_lists = (class_events, records_listed, rgb_listed)  # checked above; PathClasses when asked
        # (classes,) bool, the class's summed rgb is finite. Such a class has finite records
        # only: a record that is not is damage (a render with NaN contributions has NaN sums,
        # and is read as it is).
        self.finite_class: np.ndarray = np.isfinite(class_rgb).all(axis=1)
        self._class_records = class_records
        self._class_rgb = class_rgb.astype(np.float64)
        self.chunks: tuple[dict, ...] = tuple(_typed(tables, "chunks", list))
        self._check_manifest(manifest)
        self.manifest: Manifest = Manifest(manifest, self.shown_as)
        self._check_chunks()
        total = sum(records_listed)  # Python ints: a forged count cannot wrap around
        if not manifest["records"] == total == sum(chunk["records"] for chunk in self.chunks):
            raise _Malformed(f"the manifest says {manifest['records']} records, its classes {total}, its chunks "
                             f"{sum(chunk['records'] for chunk in self.chunks)}")
        if manifest["classes"] != self.class_count:
            raise _Malformed(f"the manifest says {manifest['classes']} classes, its table holds {self.class_count}")

    @functools.cached_property
    def classes(self) -> tuple[PathClass, ...]:
        """Every path class, by id. Built when first asked for, from the footer's lists
        (3x faster than from arrays): a render that extracts no layer never needs them."""
        return tuple(PathClass(index, tuple(events), records, tuple(rgb), self.events)
                     for index, (events, records, rgb) in enumerate(zip(*self._class_lists)))

    def _event(self, entry) -> Event:
        if type(entry) is not list or len(entry) not in (3, 4):
            raise _Malformed("an event is not [type, scatter, label ids, name]")
        kind, scatter, label_ids, *name = entry
        if type(kind) is not str or len(kind) != 1 or kind not in EVENT_TYPES or scatter not in ALL_SCATTERINGS \
                or not all(type(text) is str for text in name):
            raise _Malformed(f"an event has type {kind!r}, scattering {scatter!r}")
        ids = _ids(label_ids if type(label_ids) is list else [None], len(self.labels), "an event's label ids")
        return Event(kind, scatter, frozenset(self.labels[i] for i in ids.tolist()), *name)

    def _check_manifest(self, manifest: dict) -> None:
        """The writer's own keys must be there; the render's (RENDER_KEYS, resolution) are
        checked when present. Sets _pixels, the image's pixel count (None: not given)."""
        for key, kind in (("norm_slots", int), ("records", int), ("classes", int), ("contributions", int),
                          ("format_version", int), ("norms", dict), ("mode", str),
                          ("covariance", str)):
            _typed(manifest, key, kind, "the manifest's ")
        if manifest["mode"] not in fmt.MODES or manifest["covariance"] not in ("norms", "sigma"):
            raise _Malformed(f"the manifest's mode is {manifest['mode']!r} and covariance {manifest['covariance']!r}")
        if manifest["norm_slots"] < 0:
            raise _Malformed(f"the manifest's norm_slots is {manifest['norm_slots']}")
        if not all(type(name) is str and type(unit) is str for name, unit in manifest["norms"].items()):
            raise _Malformed("the manifest's norms are not names and units")
        for key, kind in RENDER_KEYS.items():
            if key in manifest:
                _typed(manifest, key, kind, "the manifest's ")
        if manifest.get("spp", 1) < 1:
            raise _Malformed(f"the manifest's spp is {manifest['spp']}")
        clamp = manifest.get("clamp_indirect", 0.0)  # present when the render clamped indirect light
        if not (math.isfinite(clamp) and clamp >= 0):
            raise _Malformed(f"the manifest's clamp_indirect is {clamp!r}, not a finite number of at least 0")
        frame = manifest.get("frame", "default")
        if frame != "default" and not math.isfinite(_number(frame)):
            raise _Malformed(f"the manifest's frame is {frame!r}, not a finite number or 'default'")
        self._pixels = None  # pixels in the image, when the manifest says
        if "resolution" in manifest:
            resolution = manifest["resolution"]
            if type(resolution) is not list or len(resolution) != 2 \
                    or not all(type(n) is int and n > 0 for n in resolution) \
                    or resolution[0] * resolution[1] > MAX_PIXELS:
                raise _Malformed(f"the manifest's resolution is {resolution!r}, not two sizes of at most "
                                 f"MAX_PIXELS ({MAX_PIXELS}) pixels in all")
            self._pixels = resolution[0] * resolution[1]

    def _check_chunks(self) -> None:
        """Each chunk: its fields, its classes, its decoded size, and its bytes inside the
        file between the header and the footer, apart from the others."""
        self.norm_slots: int = self.manifest["norm_slots"]
        self.mode: str = self.manifest["mode"]
        self.has_sigma: bool = self.manifest["covariance"] == "sigma"
        self._record_bytes = sum(fmt.frame_bytes(frame) for frame in self._layout(1))  # decoded bytes of one record
        end = fmt.HEADER.size
        for number, chunk in enumerate(self.chunks):
            if type(chunk) is not dict:
                raise _Malformed(f"chunk {number} is not a JSON object")
            for key in ("offset", "bytes", "sums_bytes", "crc32", "records"):
                if type(chunk.get(key)) is not int or chunk[key] < 0:
                    raise _Malformed(f"chunk {number}'s {key!r} is not a whole number >= 0")
            if chunk["sums_bytes"] > chunk["bytes"]:
                raise _Malformed(f"chunk {number}'s first frame is longer than the chunk")
            _id_lists([_typed(chunk, "classes", list, f"chunk {number}'s ")], self.class_count,
                      f"chunk {number}'s classes")
            if chunk["records"] * self._record_bytes > MAX_CHUNK_BYTES:
                raise _Malformed(f"chunk {number} holds {chunk['records']} records, more than MAX_CHUNK_BYTES "
                                 f"({MAX_CHUNK_BYTES}) bytes")
            if chunk["offset"] < end or chunk["offset"] + fmt.CHUNK_HEADER.size + chunk["bytes"] > self._footer_offset:
                raise _Malformed(f"chunk {number} at byte {chunk['offset']} overlaps the one before, "
                                 "the header or the footer")
            end = chunk["offset"] + fmt.CHUNK_HEADER.size + chunk["bytes"]

    @property
    def record_count(self) -> int:
        return self.manifest["records"]

    def records(self, classes: Iterable[int] | None = None, *, norms: bool = True, threads: int = 1,
                whole_chunks: bool = False, chunks: Iterable[int] | None = None) -> Iterator[RecordChunk]:
        """Stream the records of `classes` (ids; all if None), one chunk at a time, in the
        file's chunk order whatever `threads` is.

        Only the chunks holding a wanted class are read and decompressed (``chunks_holding``).
        norms=False skips the covariance frame (RecordChunk.norms is then (r, 0, 3) and sigma
        None). whole_chunks: those chunks are yielded whole, with the records of the other
        classes they hold, for a caller that ignores those itself (cutting them out costs a
        fifth of decoding a chunk). chunks: only these chunk numbers (of those holding a wanted
        class), e.g. the ones an earlier pass found a pixel in.

        threads > 1: chunks are read, checked and decoded on that many threads (file reads,
        CRC-32, zstd and numpy's loops release the GIL), at most
        CHUNKS_IN_FLIGHT_PER_THREAD per thread ahead of the consumer, and yielded in chunk
        order: the same chunks, and the same first error (the first bad chunk in file order),
        as with one thread. Closing the iterator early waits for the chunks being read.
        """
        wanted = self._wanted(classes)
        numbers = self._chunks_holding(wanted)
        if chunks is not None:
            allowed = set(chunks)
            numbers = [(number, mixed) for number, mixed in numbers if number in allowed]
        if whole_chunks:
            numbers = [(number, False) for number, _ in numbers]
        with self._open() as file:
            read = _ChunkReader(file)
            if threads <= 1 or len(numbers) <= 1:
                for number, mixed in numbers:
                    yield self._wanted_records(read, number, norms, wanted if mixed else None)
                return
            window = threads * CHUNKS_IN_FLIGHT_PER_THREAD
            with ThreadPoolExecutor(threads, thread_name_prefix="pxl-read") as pool:
                queued = iter(numbers)
                pending = collections.deque(
                    pool.submit(self._wanted_records, read, number, norms, wanted if mixed else None)
                    for number, mixed in itertools.islice(queued, window))
                try:
                    while pending:
                        decoded = pending.popleft().result()
                        for number, mixed in itertools.islice(queued, 1):
                            pending.append(pool.submit(self._wanted_records, read, number, norms,
                                                       wanted if mixed else None))
                        yield decoded
                finally:  # an error, or the consumer stopped: read nothing more (the pool waits for the rest)
                    for future in pending:
                        future.cancel()

    def chunks_holding(self, classes: Iterable[int] | None = None) -> list[int]:
        """Numbers of the chunks holding a record of `classes` (ids; all if None): the
        chunks ``records`` reads."""
        return [number for number, _ in self._chunks_holding(self._wanted(classes))]

    def _wanted(self, classes: Iterable[int] | None) -> np.ndarray | None:
        """(classes,) bool lookup table of `classes` (ids), or None for all."""
        if classes is None:
            return None
        wanted = np.zeros(self.class_count, bool)
        wanted[np.fromiter(classes, np.int64)] = True
        return wanted

    def _chunks_holding(self, wanted: np.ndarray | None) -> list[tuple[int, bool]]:
        """(number, whether it also holds classes not wanted) of each chunk holding a class
        `wanted` ((classes,) bool; None: all) marks."""
        numbers = []
        for number, chunk in enumerate(self.chunks):
            chunk_wanted = None if wanted is None else wanted[np.asarray(chunk["classes"], np.int64)]
            if chunk_wanted is None or chunk_wanted.any():
                numbers.append((number, chunk_wanted is not None and not chunk_wanted.all()))
        return numbers

    def _wanted_records(self, read: "_ChunkReader", number: int, all_columns: bool,
                        wanted: np.ndarray | None) -> RecordChunk:
        """Chunk `number`, read and checked, keeping only the records of the classes
        ``wanted`` marks (None: all of them)."""
        decoded = self._read_chunk(read, number, all_columns)
        if wanted is None:
            return decoded
        keep = wanted[decoded.class_id]
        return RecordChunk(*(column[keep] if column is not None and len(column) else column
                             for column in vars(decoded).values()))

    def verify(self, *, show_progress: bool = False) -> int:
        """Read every chunk and check all of it (module docstring), also that every rgb is
        finite and that each class has the records and the summed rgb (to RGB_SUM_TOLERANCE)
        the footer says; returns the number of chunks. Raises PathIndexError naming the file
        and the first bad chunk's number and byte offset (for a class whose counts or sums
        are wrong, the chunks holding it). Progress (records) on stderr when `show_progress`."""
        classes = self.class_count
        counts = np.zeros(classes, np.int64)
        sums, magnitudes = np.zeros((classes, 3)), np.zeros((classes, 3))  # float64 sums of rgb and |rgb|
        progress = Progress(self.record_count, "verify", enabled=show_progress)
        with self._open() as file:
            read = _ChunkReader(file)
            for number in range(len(self.chunks)):
                decoded = self._read_chunk(read, number, True)
                wrong = None if np.isfinite(decoded.rgb).all() else ~np.isfinite(decoded.rgb).all(axis=1)
                if wrong is not None:
                    raise self._chunk_error(number, f"holds {int(wrong.sum())} records of NaN or infinite rgb "
                                            f"(class {int(decoded.class_id[wrong][0])} first): the render went wrong",
                                            damaged=False)
                counts += np.bincount(decoded.class_id, minlength=classes)
                for channel in range(3):
                    sums[:, channel] += np.bincount(decoded.class_id, decoded.rgb[:, channel], classes)
                    magnitudes[:, channel] += np.bincount(decoded.class_id, np.abs(decoded.rgb[:, channel]), classes)
                progress.advance(len(decoded.class_id))
        miscounted = np.flatnonzero(counts != self._class_records)
        if len(miscounted):
            class_id = int(miscounted[0])
            raise self._error(f"corrupted: class {class_id} has {counts[class_id]} records in the chunks, the footer "
                              f"says {self._class_records[class_id]} ({self._holders(class_id)})")
        # not (difference <= tolerance): a NaN sum in the footer (its records are finite) disagrees too
        off = ~(np.abs(sums - self._class_rgb) <= RGB_SUM_TOLERANCE * magnitudes)
        mismatched = np.flatnonzero(off.any(axis=1))
        if len(mismatched):
            class_id = int(mismatched[0])
            raise self._error(f"corrupted: class {class_id}'s records sum to rgb "
                              f"({', '.join(f'{value:.7g}' for value in sums[class_id])}), the footer says "
                              f"({', '.join(f'{value:.7g}' for value in self._class_rgb[class_id])}) "
                              f"({self._holders(class_id)})")
        return len(self.chunks)

    def _holders(self, class_id: int) -> str:
        """'held by chunks 3, 4': the chunks whose footer entries list the class."""
        holders = [str(number) for number, chunk in enumerate(self.chunks) if class_id in chunk["classes"]]
        return f"held by chunks {', '.join(holders[:CHUNKS_NAMED])}{', ...' if len(holders) > CHUNKS_NAMED else ''}"

    def _open(self):
        try:
            return open(self.path, "rb")
        except OSError as error:
            raise PathIndexError(f"cannot read ({error.strerror or error})", file=str(self.shown_as)) from error

    def _read_chunk(self, read: "_ChunkReader", number: int, all_columns: bool) -> RecordChunk:
        """Chunk `number`, read and checked (all_columns: with its covariance frame). Safe to
        call from several threads at once with one `read`."""
        chunk = self.chunks[number]
        try:
            head, payload = read(chunk["offset"], fmt.CHUNK_HEADER.size, chunk["bytes"])
        except OSError as error:
            raise self._chunk_error(number, f"cannot be read ({error.strerror or error})") from error
        magic, length, crc, records, sums_bytes = fmt.CHUNK_HEADER.unpack(head) \
            if len(head) == fmt.CHUNK_HEADER.size else (b"", 0, 0, 0, 0)
        if magic != fmt.CHUNK_MAGIC or length != chunk["bytes"] or len(payload) != length \
                or records != chunk["records"] or sums_bytes != chunk["sums_bytes"]:
            raise self._chunk_error(number, "has a bad header")
        if zlib.crc32(payload) != crc or crc != chunk["crc32"]:
            raise self._chunk_error(number, "fails its checksum")
        layout = self._layout(records)
        frames = (payload[:sums_bytes], payload[sums_bytes:])
        columns = {}
        for frame, frame_layout in zip(frames if all_columns else frames[:1], layout):
            size = fmt.frame_bytes(frame_layout)
            try:
                if zstandard.frame_content_size(frame) != size:
                    raise self._chunk_error(number, f"does not hold its {records} records")
                data = zstandard.ZstdDecompressor().decompress(frame, allow_extra_data=False)
            except zstandard.ZstdError as error:
                raise self._chunk_error(number, f"is not two zstd frames of its records ({error})") from None
            if frame_layout is layout[0]:  # the sums: one compiled pass instead of numpy's dozen
                columns.update(_sums_columns(data, records))
                continue
            position = 0
            for name, dtype, shape in frame_layout:
                end = position + int(np.prod(shape)) * dtype.itemsize
                columns[name] = fmt.unshuffle(data[position:end], dtype, shape)
                position = end
        decoded = self._decoded(columns, records)
        self._check_records(decoded, number)
        return decoded

    def _layout(self, records: int):
        return fmt.column_layout(self.mode, records, self.norm_slots, self.has_sigma)

    def _decoded(self, columns: dict, records: int) -> RecordChunk:
        """A RecordChunk of the columns (the sums as RecordChunk holds them already; norms
        and sigma, when read, as stored: turned into values here)."""
        norms, sigma = columns.get("norms"), columns.get("sigma")
        if self.mode == "merged":
            norms = None if norms is None else fmt.NormBins.decoded(norms)
            sigma = None if sigma is None else fmt.NormBins.decoded(sigma)
        return RecordChunk(
            class_id=columns["class"], pixel=columns["pixel"], count=columns["count"], rgb=columns["rgb"],
            norms=np.zeros((records, 0, 3), np.float32) if norms is None else norms.astype(np.float32, copy=False),
            sigma=sigma,
        )

    def _check_records(self, decoded: RecordChunk, number: int) -> None:
        """Class ids among the chunk's (the footer's list is what decides which chunks are
        read), pixels inside the image, rgb finite where the class's sum is."""
        class_id = decoded.class_id
        run_heads = class_id[np.r_[True, class_id[1:] != class_id[:-1]]] if len(class_id) else class_id
        if not np.isin(run_heads, self.chunks[number]["classes"]).all():  # records come in runs of a class
            raise self._chunk_error(number, "holds records of classes its footer entry does not list")
        pixel = decoded.pixel
        if len(pixel) and (pixel.min() < 0 or self._pixels is not None and pixel.max() >= self._pixels):
            outside = int(pixel.min()) if pixel.min() < 0 else int(pixel.max())
            raise self._chunk_error(number, f"holds pixel {outside}, outside the image's {self._pixels or '?'} pixels")
        if np.isfinite(decoded.rgb).all():  # the common case, 40x cheaper than finding the rows
            return
        not_finite = ~np.isfinite(decoded.rgb).all(axis=1)
        if self.finite_class[decoded.class_id[not_finite]].any():
            raise self._chunk_error(number, "holds NaN or infinite rgb in a class whose footer sum is finite")

    def _check_version(self, version: int) -> None:
        if version != fmt.FORMAT_VERSION:
            raise self._error(f"written in format version {version} of the path index; this pxr-layers reads "
                              f"version {fmt.FORMAT_VERSION} only: render the shot again to rebuild its index")

    def _chunk_error(self, number: int, message: str, *, damaged: bool = True) -> PathIndexError:
        return self._error(f"{'corrupted: ' if damaged else ''}chunk {number} at byte "
                           f"{self.chunks[number]['offset']} {message}")

    def _error(self, message: str) -> PathIndexError:
        return PathIndexError(message, file=str(self.shown_as))


SUMS_LAYOUT = [("class", "<u4", 1), ("pixel", "<i4", 1), ("count", "<u4", 1), ("rgb", "<f4", 3)]
"""The sums frame's columns as ``_unshuffle_sums`` reads them: (name, dtype, values per
record). Checked against format.column_layout at import: a change of the format must
change the kernel too, not decode garbage."""
assert [(name, dtype.str, int(np.prod(shape))) for name, dtype, shape in fmt.column_layout("merged", 1, 0, False)[0]] \
    == SUMS_LAYOUT, "paths/format.py's sums columns are not what reader._unshuffle_sums decodes"
SUMS_RECORD_BYTES = fmt.frame_bytes(fmt.column_layout("merged", 1, 0, False)[0])


def _sums_columns(data: bytes, records: int) -> dict[str, np.ndarray]:
    """The sums frame's columns (format.column_layout), as RecordChunk holds them: class,
    pixel (absolute: the deltas summed) and count (r,) int64, rgb (r, 3) float32.

    One compiled pass over the byte planes (``_unshuffle_sums``): unshuffling each column
    with numpy (format.unshuffle), widening and summing the deltas took 8 ns a record, a
    third of a chunk's decoding; this takes about 1.
    """
    planes = np.frombuffer(data, np.uint8)
    if len(planes) != SUMS_RECORD_BYTES * records:  # the caller checked the frame's size: a bug
        raise AssertionError(f"a sums frame of {len(planes)} bytes for {records} records")
    class_id, pixel, count = (np.empty(records, np.int64) for _ in range(3))
    rgb_bits = np.empty((records, 3), np.uint32)
    _unshuffle_sums(planes, records, class_id, pixel, count, rgb_bits.reshape(-1))
    return {"class": class_id, "pixel": pixel, "count": count, "rgb": rgb_bits.view(np.float32)}


@kernel
def _unshuffle_sums(planes, records, class_id, pixel, count, rgb_bits):
    """Decode a sums frame: planes (24 r,) uint8, each column's byte planes one after the
    other (least significant first), class u32 | pixel delta i32 | count u32 | rgb f32 (3 r).
    Writes class_id, pixel (the running sum of the deltas, from 0), count (r,) int64 and
    rgb_bits (3 r,) uint32 (the floats' bits)."""
    r = records
    running = np.int64(0)
    for record in range(r):
        class_id[record] = _word(planes, record, r, 0)
        delta = _word(planes, record, r, 4 * r)
        if delta >= 2 ** 31:  # two's complement of a negative int32
            delta -= 2 ** 32
        running += delta
        pixel[record] = running
        count[record] = _word(planes, record, r, 8 * r)
    values = 3 * r
    for value in range(values):
        rgb_bits[value] = _word(planes, value, values, 12 * r)


@inline
def _word(planes, item, stride, start):
    """The little-endian 32-bit unsigned word of `item` from 4 byte planes of `stride` bytes at `start`."""
    return (np.int64(planes[start + item]) | np.int64(planes[start + stride + item]) << 8
            | np.int64(planes[start + 2 * stride + item]) << 16 | np.int64(planes[start + 3 * stride + item]) << 24)


class _ChunkReader:
    """Reads a chunk's header and payload from an open file, from any number of threads:
    with ``os.pread`` (no shared file position) where the system has it, else seek and read
    under a lock."""

    def __init__(self, file):
        self._file = file
        self._descriptor = file.fileno() if hasattr(os, "pread") else None
        self._lock = threading.Lock()

    def __call__(self, offset: int, head_bytes: int, payload_bytes: int) -> tuple[bytes, bytes]:
        """(the head_bytes at `offset`, the payload_bytes after them): shorter at the end of the file."""
        if self._descriptor is not None:
            data = os.pread(self._descriptor, head_bytes + payload_bytes, offset)
            return data[:head_bytes], data[head_bytes:]
        with self._lock:
            self._file.seek(offset)
            return self._file.read(head_bytes), self._file.read(payload_bytes)


def _typed(table: dict, key: str, kind: type, owner: str = ""):
    """table[key], which must be of type `kind` (exactly: a bool is no int here)."""
    value = table.get(key)
    if type(value) is not kind:
        raise _Malformed(f"{owner}{key!r} is {'missing' if value is None else type(value).__name__}, "
                         f"not {kind.__name__}")
    return value


def _ids(values: list, bound: int, what: str) -> np.ndarray:
    """`values` as (n,) int64: integers in [0, bound), else _Malformed."""
    array = _array(values, what) if values else np.zeros(0, np.int64)
    if array.ndim != 1 or array.dtype.kind not in "iu":
        raise _Malformed(f"{what} are not integers")
    if len(array) and (array.min() < 0 or array.max() >= bound):
        raise _Malformed(f"{what} go outside 0 to {bound - 1}")
    return array.astype(np.int64)


def _id_lists(lists: list, bound: int, what: str) -> list[list[int]]:
    """`lists`, a list of lists of integers in [0, bound), else _Malformed."""
    if not all(type(values) is list for values in lists):
        raise _Malformed(f"{what} are not lists")
    _ids(list(itertools.chain.from_iterable(lists)), bound, what)
    return lists


def _array(values: list, what: str) -> np.ndarray:
    """np.array(values), else _Malformed (lists of unequal lengths)."""
    try:
        return np.array(values)
    except (ValueError, TypeError):
        raise _Malformed(f"{what} are not numbers") from None


def _counts(values: list, what: str) -> np.ndarray:
    """`values` as (n,) int64 counts (integers >= 0), else _Malformed."""
    return _ids(values, np.iinfo(np.int64).max, what)


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan
