"""Read a path index: its manifest, label and class tables, and records class by class.

Nothing the file says is taken on trust, so that a damaged file is one PathIndexError
naming it (and the chunk), never a traceback, unbounded memory or other pixels; even a
forged one (its checksums made to agree) cannot crash the reader or bring NaN, pixels
outside the image or records of classes the footer does not list. At open: the header,
trailer and footer checksum, then the tables (types, ids in range, counts that agree,
chunks inside the file and apart). When a chunk is read: its CRC-32, zstd frames of
exactly its columns' size, class runs inside the chunk's class range, pixels inside the
image, rgb finite unless the footer lists the class as holding NaN or infinite light.
``PathIndex.verify`` reads every chunk and checks the rest: every rgb finite, and the
records of each class what the footer says.

Reading costs only numpy and zstd (no compiled kernels: ``pxr-layers extract`` starts
without importing numba), and only the records of the classes asked for are decoded:
a chunk's records come in runs of one class, and a run is decoded only when wanted.
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
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zstandard

from ..errors import PathIndexError
from ..inputs import regular_input
from ..progress import Progress
from ..request import MAX_PIXELS
from . import format as fmt
from .events import ALL_SCATTERINGS, EVENT_TYPES, Event

MAX_CHUNK_BYTES = 1 << 28
"""The most one chunk may decode to (256 MiB): bounds the memory of reading it. The
writer's chunks hold at most writer.CHUNK_RECORDS (2^16) records, 1.6 MB with N = 5."""
MAX_FOOTER_BYTES = 1 << 28
"""The most the footer's JSON, or its class table, may take decoded (256 MiB): bounds the
memory of opening a file. The class table takes some 15 bytes per path class."""

CHUNKS_IN_FLIGHT_PER_THREAD = 2
"""Chunks read ahead per reading thread when records are streamed on threads: enough that a
thread never waits for the consumer to take a chunk, few enough that memory stays a handful
of chunks (each at most MAX_CHUNK_BYTES, in practice under 1 MB of sums) whatever the file's size."""

CHUNKS_NAMED = 8
"""How many of the chunks holding a class whose records disagree with the footer verify names."""

AUTOMATIC_SUBDIV_LEVEL = -1
"""The manifest's ``subdiv_level`` of a render whose subdivision levels were automatic (a level
per mesh from its size on the image: RenderRequest.subdiv_level None); else it is the one
level asked. Either way the levels may have been lowered to the scene's budget."""
RENDER_KEYS = {"stage": str, "stage_sha256": str, "camera": str, "frame": str, "variants": str,
               "defaultLights": str, "beauty": str, "version": str, "maxDepth": str, "spp": int,
               "seed": int, "max_depth": int, "subdiv_level": int, "clampIndirect": str, "clamp_indirect": float,
               "model_paths": list, "light_groups": dict}
"""Manifest keys that whoever wrote the index may give (PathIndexWriter stores its manifest
as given) and that pxr-layers reads, with their types; checked when present. model_paths:
the stage's models (prim paths), light_groups: {light prim path: pxrLayers:lightGroup}
(jobs.frame.stage_names; absent from older indexes and stages without any)."""
CHUNK_KEYS = ("offset", "bytes", "where_bytes", "light_bytes", "crc32", "records", "runs", "exact", "first_class",
              "last_class")
"""A chunk's entry in the footer (paths/format.py): whole numbers >= 0."""


class PathClass:
    """One distinct event sequence: its event ids camera first (into ``PathIndex.events``)
    and records; ``events`` are the Events themselves.

    An index can hold tens of thousands of classes and is opened for every extraction:
    the Event tuple is built when asked for, not at open (a third of the open time).
    """

    __slots__ = ("_table", "event_ids", "id", "records")

    def __init__(self, id: int, event_ids: tuple[int, ...], records: int, table: tuple[Event, ...]):
        self.id, self.event_ids, self.records, self._table = id, event_ids, records, table

    @property
    def events(self) -> tuple[Event, ...]:
        return tuple(self._table[event] for event in self.event_ids)

    def __repr__(self) -> str:
        return f"PathClass({self.id}, {self.event_ids}, records={self.records})"


def _padded(lengths: np.ndarray, flat: np.ndarray, pad: int) -> np.ndarray:
    """(n, longest) int64 rows of `flat` (n sequences of `lengths`, one after the other), padded with `pad`."""
    events = np.full((len(lengths), max(1, int(lengths.max(initial=0)))), pad, np.int64)
    # Each flat event goes to its class's row, at its position within the class (its flat
    # index minus where the class starts).
    rows = np.repeat(np.arange(len(lengths)), lengths)
    events[rows, np.arange(len(flat)) - np.repeat(np.cumsum(lengths) - lengths, lengths)] = flat
    return events


@dataclass(frozen=True)
class RecordChunk:
    """Records of one chunk (or the part of it in the classes asked for).

    class_id : (r,) int64; pixel : (r,) int64 (y·width + x)
    sample : (r,) int64 sample index (records index), None (merged index, or the light not read)
    rgb : (r, 3) float32 as read (merged: paths/format.py's rule; records: as the film added it)
    norms : (r, N, 3) float32 C, T, R (merged: what each bin reads as, paths/format.py)
    sigma : (r, N, 10) float32 upper triangles of Σ, or None (an index without Σ)
    """

    class_id: np.ndarray
    pixel: np.ndarray
    sample: np.ndarray | None
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
        footer, json_bytes = self._footer_bytes()
        try:
            self._load(*self._footer_tables(footer, json_bytes))
        except _Malformed as error:
            raise self._error(f"corrupted footer: {error}") from None

    @classmethod
    def from_footer(cls, path: str | os.PathLike, tables: dict, arrays: dict[str, np.ndarray], footer_offset: int,
                    size: int, *, shown_as: str | os.PathLike | None = None) -> PathIndex:
        """The index at `path` whose footer is already in memory: `tables`, its JSON object
        as parsed, and `arrays`, its class table's columns, at byte `footer_offset` of the
        file of `size` bytes (its writer's own, ``PathIndexWriter.opened``). Its tables are
        built and checked as for a file read from disk; only reading, checking and parsing
        the header, trailer and footer is skipped."""
        index = cls.__new__(cls)
        index._named(path, shown_as)
        index.size, index._footer_offset = size, footer_offset
        try:
            index._load(tables, arrays)
        except _Malformed as error:  # a bug of the writer's
            raise index._error(f"corrupted footer: {error}") from None
        return index

    def _named(self, path: str | os.PathLike, shown_as: str | os.PathLike | None) -> None:
        self.path = Path(path)
        self.shown_as = Path(shown_as) if shown_as is not None else self.path

    def _footer_bytes(self) -> tuple[bytes, int]:
        """The footer and the bytes of its JSON frame, after checking the header, trailer
        and footer checksum; sets size and the footer's offset."""
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
                offset, length, json_bytes, crc, trailer_version, magic = fmt.TRAILER.unpack(
                    file.read(fmt.TRAILER.size))
                if magic != fmt.TRAILER_MAGIC:
                    raise self._error("truncated or incomplete: no trailer at the end of the file "
                                      "(an interrupted write?)")
                if offset < fmt.HEADER.size or offset + length + fmt.TRAILER.size != self.size \
                        or json_bytes > length:
                    raise self._error("corrupted: the trailer points outside the file")
                if trailer_version != version:
                    raise self._error(f"corrupted: the trailer says format version {trailer_version}, "
                                      f"the header {version}")
                if length > 2 * MAX_FOOTER_BYTES:  # before reading it: a forged trailer must not cost memory
                    raise self._error(f"corrupted: the footer would be {length:,} bytes, more than the "
                                      f"{2 * MAX_FOOTER_BYTES:,} an index holds")
                file.seek(offset)
                footer = file.read(length)
        except OSError as error:
            raise PathIndexError(f"cannot read ({error.strerror or error})", file=str(self.shown_as)) from error
        if zlib.crc32(footer) != crc:
            raise self._error("corrupted: the footer's checksum does not match")
        self._footer_offset = offset
        return footer, json_bytes

    def _footer_tables(self, footer: bytes, json_bytes: int) -> tuple[dict, dict[str, np.ndarray]]:
        """The footer's JSON object and its class table's columns: raises _Malformed."""
        tables = json.loads(_decompressed(footer[:json_bytes], None, "its JSON"))
        if type(tables) is not dict:
            raise _Malformed("not a JSON object")
        manifest = _typed(tables, "manifest", dict)
        entry = _typed(tables, "class_table", dict)
        for key in ("bytes", "events"):
            if type(entry.get(key)) is not int or entry[key] < 0:
                raise _Malformed(f"the class table's {key!r} is not a whole number >= 0")
        dtypes = {key: entry.get(key) for key in ("length_dtype", "event_dtype")}
        if not all(dtype in fmt.TABLE_DTYPES for dtype in dtypes.values()) or manifest.get("mode") not in fmt.MODES \
                or type(manifest.get("classes")) is not int or not 0 <= manifest["classes"] <= MAX_FOOTER_BYTES:
            raise _Malformed(f"the class table's widths {dtypes}, mode or class count make no sense")
        if entry["bytes"] != len(footer) - json_bytes:
            raise _Malformed(f"the class table takes {len(footer) - json_bytes} bytes, not the {entry['bytes']} said")
        layout = fmt.class_table_layout(manifest["mode"], manifest["classes"], entry["events"], **dtypes)
        data = _decompressed(footer[json_bytes:], fmt.frame_bytes(layout), "its class table")
        return tables, fmt.split_frame(data, layout)

    def _load(self, tables: dict, arrays: dict[str, np.ndarray]) -> None:
        """The tables, checked: raises _Malformed."""
        manifest = _typed(tables, "manifest", dict)
        self.labels: tuple[str, ...] = tuple(_typed(tables, "labels", list))
        if not all(type(label) is str for label in self.labels):
            raise _Malformed("a label is not a string")
        self.events: tuple[Event, ...] = tuple(self._event(entry) for entry in _typed(tables, "events", list))
        lengths = arrays["length"].astype(np.int64)
        flat = arrays["events"].astype(np.int64)
        if int(lengths.sum()) != len(flat):
            raise _Malformed(f"the class table's lengths add up to {int(lengths.sum())} events, it holds {len(flat)}")
        if len(flat) and (flat.min() < 1 or flat.max() >= len(self.events)):
            raise _Malformed(f"a class's event ids go outside 1 to {len(self.events) - 1}")
        self.class_count: int = len(lengths)
        self._class_lengths, self._class_flat = lengths, flat
        self._event_matrices: dict[int, np.ndarray] = {}  # pad → event_matrix(pad)
        self._class_records = arrays["records"].astype(np.int64)
        self._chroma = arrays.get("chroma")  # (classes, 2) uint16, merged
        nonfinite = _ids(_typed(tables, "nonfinite_classes", list), self.class_count, "the non-finite classes")
        # (classes,) bool, the class has finite records only: a record that is not is damage
        # (a render with NaN contributions lists their classes, and is read as it is).
        self.finite_class: np.ndarray = np.ones(self.class_count, bool)
        self.finite_class[nonfinite] = False
        self.chunks: tuple[dict, ...] = tuple(_typed(tables, "chunks", list))
        self._check_manifest(manifest)
        self.manifest: Manifest = Manifest(manifest, self.shown_as)
        if manifest["classes"] != self.class_count:
            raise _Malformed(f"the manifest says {manifest['classes']} classes, its table holds {self.class_count}")
        self._check_chunks()
        total = int(self._class_records.sum())
        if not manifest["records"] == total == sum(chunk["records"] for chunk in self.chunks):
            raise _Malformed(f"the manifest says {manifest['records']} records, its classes {total}, its chunks "
                             f"{sum(chunk['records'] for chunk in self.chunks)}")

    @functools.cached_property
    def classes(self) -> tuple[PathClass, ...]:
        """Every path class, by id. Built when first asked for: a render that extracts no
        layer never needs them."""
        flat = self._class_flat.tolist()
        ends = np.cumsum(self._class_lengths).tolist()
        starts = [0, *ends[:-1]]
        return tuple(PathClass(index, (0, *flat[start:end]), records, self.events)
                     for index, (start, end, records) in enumerate(zip(starts, ends, self._class_records.tolist())))

    def event_matrix(self, pad: int) -> np.ndarray:
        """(classes, longest) int64, read-only: every class's event ids camera first, padded
        with `pad` (built from the class table's arrays at once, not from ``classes``; once
        per pad: every layer's automaton of an extraction asks for it)."""
        if pad not in self._event_matrices:
            lengths = self._class_lengths + 1
            flat = np.zeros(int(lengths.sum()), np.int64)
            starts = np.cumsum(lengths) - lengths
            inside = np.ones(len(flat), bool)
            inside[starts] = False
            flat[inside] = self._class_flat  # the camera (event 0) first in each class
            matrix = _padded(lengths, flat, pad)
            matrix.setflags(write=False)
            self._event_matrices[pad] = matrix
        return self._event_matrices[pad]

    def class_records(self) -> np.ndarray:
        """(classes,) int64: the records of each class."""
        return self._class_records.copy()

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
        if manifest["mode"] == "merged" and self._chroma is None:
            raise _Malformed("a merged index's class table has no chroma")
        if manifest["norm_slots"] < 0:
            raise _Malformed(f"the manifest's norm_slots is {manifest['norm_slots']}")
        if not all(type(name) is str and type(unit) is str for name, unit in manifest["norms"].items()):
            raise _Malformed("the manifest's norms are not names and units")
        for key, kind in RENDER_KEYS.items():
            if key in manifest:
                _typed(manifest, key, kind, "the manifest's ")
        if not all(type(path) is str and path.startswith("/") for path in manifest.get("model_paths", ())):
            raise _Malformed("the manifest's model_paths are not all prim paths")
        if not all(type(path) is str and path.startswith("/") and type(group) is str and group
                   for path, group in manifest.get("light_groups", {}).items()):
            raise _Malformed("the manifest's light_groups do not map light prim paths to group names")
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
        """Each chunk: its fields, its class range, its decoded size, and its bytes inside the
        file between the header and the footer, apart from the others."""
        self.norm_slots: int = self.manifest["norm_slots"]
        self.mode: str = self.manifest["mode"]
        self.has_sigma: bool = self.manifest["covariance"] == "sigma"
        end = fmt.HEADER.size
        for number, chunk in enumerate(self.chunks):
            if type(chunk) is not dict:
                raise _Malformed(f"chunk {number} is not a JSON object")
            for key in CHUNK_KEYS:
                if type(chunk.get(key)) is not int or chunk[key] < 0:
                    raise _Malformed(f"chunk {number}'s {key!r} is not a whole number >= 0")
            if chunk["where_bytes"] + chunk["light_bytes"] > chunk["bytes"]:
                raise _Malformed(f"chunk {number}'s first frames are longer than the chunk")
            if not (1 <= chunk["runs"] <= chunk["records"] and chunk["first_class"] <= chunk["last_class"]
                    < self.class_count and chunk["last_class"] - chunk["first_class"] + 1 >= chunk["runs"]
                    and chunk["exact"] <= (chunk["records"] if self.mode == "merged" else 0)):
                raise _Malformed(f"chunk {number}'s records, runs, exact records and classes "
                                 f"({chunk['first_class']} to {chunk['last_class']}) do not agree")
            if sum(fmt.frame_bytes(frame) for frame in self._layout(chunk)) > MAX_CHUNK_BYTES:
                raise _Malformed(f"chunk {number} holds {chunk['records']} records, more than MAX_CHUNK_BYTES "
                                 f"({MAX_CHUNK_BYTES}) bytes")
            if chunk["offset"] < end or chunk["offset"] + fmt.CHUNK_HEADER.size + chunk["bytes"] > self._footer_offset:
                raise _Malformed(f"chunk {number} at byte {chunk['offset']} overlaps the one before, "
                                 "the header or the footer")
            end = chunk["offset"] + fmt.CHUNK_HEADER.size + chunk["bytes"]

    @property
    def record_count(self) -> int:
        return self.manifest["records"]

    def records(self, classes: Iterable[int] | None = None, *, norms: bool = True, light: bool = True,
                threads: int = 1, whole_chunks: bool = False,
                chunks: Iterable[int] | None = None) -> Iterator[RecordChunk]:
        """Stream the records of `classes` (ids; all if None), one chunk at a time, in the
        file's chunk order whatever `threads` is.

        Only the chunks whose classes may hold a wanted class are read and decompressed
        (``chunks_holding``), and in them only the runs of wanted classes are decoded.
        norms=False skips the covariance frame (RecordChunk.norms is then (r, 0, 3) and sigma
        None); light=False skips the light frame (RecordChunk.rgb is then (r, 0) and sample
        None: a pass that looks for pixels only, a third of the work). whole_chunks: those
        chunks are decoded and yielded whole, with the records of the other classes they
        hold. chunks: only these chunk numbers (of those holding a wanted class), e.g. the
        ones an earlier pass found a pixel in.

        threads > 1: chunks read with their covariance (norms) are read, checked and decoded on
        that many threads (file reads, CRC-32, zstd and numpy's loops release the GIL; without
        the covariance, on this thread: faster), at most CHUNKS_IN_FLIGHT_PER_THREAD per thread
        ahead of the consumer, and yielded in chunk order: the same chunks, and the same first
        error (the first bad chunk in file order), as with one thread. Closing the iterator
        early waits for the chunks being read.
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
            # Without the covariance a chunk's decoding is many small numpy steps that hold the
            # GIL: a pool only adds contention (0.85-0.91x the one thread's speed on 2 cores, a
            # 1080p, 64 spp index); the covariance's larger frames gain from it (1.32x).
            if threads <= 1 or len(numbers) <= 1 or not norms:
                for number, mixed in numbers:
                    yield self._read_chunk(read, number, norms, wanted if mixed else None, light)
                return
            window = threads * CHUNKS_IN_FLIGHT_PER_THREAD
            with ThreadPoolExecutor(threads, thread_name_prefix="pxl-read") as pool:
                queued = iter(numbers)
                pending = collections.deque(
                    pool.submit(self._read_chunk, read, number, norms, wanted if mixed else None, light)
                    for number, mixed in itertools.islice(queued, window))
                try:
                    while pending:
                        decoded = pending.popleft().result()
                        for number, mixed in itertools.islice(queued, 1):
                            pending.append(pool.submit(self._read_chunk, read, number, norms,
                                                       wanted if mixed else None, light))
                        yield decoded
                finally:  # an error, or the consumer stopped: read nothing more (the pool waits for the rest)
                    for future in pending:
                        future.cancel()

    def chunks_holding(self, classes: Iterable[int] | None = None) -> list[int]:
        """Numbers of the chunks whose class range holds one of `classes` (ids; all if None):
        the chunks ``records`` reads."""
        return [number for number, _ in self._chunks_holding(self._wanted(classes))]

    def _wanted(self, classes: Iterable[int] | None) -> np.ndarray | None:
        """(classes,) bool lookup table of `classes` (ids), or None for all."""
        if classes is None:
            return None
        wanted = np.zeros(self.class_count, bool)
        wanted[np.fromiter(classes, np.int64)] = True
        return wanted

    def _chunks_holding(self, wanted: np.ndarray | None) -> list[tuple[int, bool]]:
        """(number, whether its class range also holds classes not wanted) of each chunk
        whose class range holds a class `wanted` ((classes,) bool; None: all) marks."""
        if wanted is None:
            return [(number, False) for number in range(len(self.chunks))]
        counted = np.r_[0, np.cumsum(wanted)]  # wanted classes below each id
        numbers = []
        for number, chunk in enumerate(self.chunks):
            inside = int(counted[chunk["last_class"] + 1] - counted[chunk["first_class"]])
            if inside:
                numbers.append((number, inside < chunk["last_class"] - chunk["first_class"] + 1))
        return numbers

    def verify(self, *, show_progress: bool = False) -> int:
        """Read every chunk and check all of it (module docstring), also that every rgb is
        finite and that each class has the records the footer says; returns the number of
        chunks. Raises PathIndexError naming the file and the first bad chunk's number and
        byte offset (for a class whose count is wrong, the chunks that may hold it).
        Progress (records) on stderr when `show_progress`."""
        classes = self.class_count
        counts = np.zeros(classes, np.int64)
        progress = Progress(self.record_count, "verify", enabled=show_progress)
        with self._open() as file:
            read = _ChunkReader(file)
            for number in range(len(self.chunks)):
                decoded = self._read_chunk(read, number, True, None)
                wrong = None if np.isfinite(decoded.rgb).all() else ~np.isfinite(decoded.rgb).all(axis=1)
                if wrong is not None:
                    raise self._chunk_error(number, f"holds {int(wrong.sum())} records of NaN or infinite rgb "
                                            f"(class {int(decoded.class_id[wrong][0])} first): the render went wrong",
                                            damaged=False)
                counts += np.bincount(decoded.class_id, minlength=classes)
                progress.advance(len(decoded.class_id))
        miscounted = np.flatnonzero(counts != self._class_records)
        if len(miscounted):
            class_id = int(miscounted[0])
            raise self._error(f"corrupted: class {class_id} has {counts[class_id]} records in the chunks, the footer "
                              f"says {self._class_records[class_id]} ({self._holders(class_id)})")
        return len(self.chunks)

    def _holders(self, class_id: int) -> str:
        """'held by chunks 3, 4': the chunks whose class range holds the class."""
        holders = [str(number) for number, chunk in enumerate(self.chunks)
                   if chunk["first_class"] <= class_id <= chunk["last_class"]]
        return f"held by chunks {', '.join(holders[:CHUNKS_NAMED])}{', ...' if len(holders) > CHUNKS_NAMED else ''}"

    def _open(self):
        try:
            return open(self.path, "rb")
        except OSError as error:
            raise PathIndexError(f"cannot read ({error.strerror or error})", file=str(self.shown_as)) from error

    def _read_chunk(self, read: _ChunkReader, number: int, all_columns: bool, wanted: np.ndarray | None,
                    light: bool = True) -> RecordChunk:
        """Chunk `number`, read and checked (all_columns: with its covariance frame; light:
        with its rgb), its runs of the classes `wanted` marks decoded (None: all). Safe to
        call from several threads at once with one `read`."""
        chunk = self.chunks[number]
        try:
            head, payload = read(chunk["offset"], fmt.CHUNK_HEADER.size, chunk["bytes"])
        except OSError as error:
            raise self._chunk_error(number, f"cannot be read ({error.strerror or error})") from error
        stated = fmt.CHUNK_HEADER.unpack(head) if len(head) == fmt.CHUNK_HEADER.size else (b"",) + (0,) * 7
        magic, length, crc, records, runs, exact, where_bytes, light_bytes = stated
        if magic != fmt.CHUNK_MAGIC or length != chunk["bytes"] or len(payload) != length \
                or (records, runs, exact, where_bytes, light_bytes) != tuple(chunk[key] for key in (
                    "records", "runs", "exact", "where_bytes", "light_bytes")):
            raise self._chunk_error(number, "has a bad header")
        if zlib.crc32(payload) != crc or crc != chunk["crc32"]:
            raise self._chunk_error(number, "fails its checksum")
        where_layout, light_layout, covariance_layout = self._layout(chunk)
        columns = self._frame(payload[:where_bytes], where_layout, number)
        if light:
            columns.update(self._frame(payload[where_bytes:where_bytes + light_bytes], light_layout, number))
        run_class = np.cumsum(columns["run_class"], dtype=np.int64)
        run_length = columns["run_length"].astype(np.int64)
        if run_class[0] != chunk["first_class"] or run_class[-1] != chunk["last_class"] \
                or (np.diff(run_class) <= 0).any() or (run_length == 0).any() or run_length.sum() != records:
            raise self._chunk_error(number, "holds records of classes outside its footer entry's, or runs that "
                                    "do not add up to its records")
        run_start = np.cumsum(run_length) - run_length
        # Each run's first pixel: the zigzag steps between runs' firsts, summed.
        first_pixel = np.cumsum(fmt.unzigzag(columns["pixel"][run_start]))
        kept = None if wanted is None else wanted[run_class]
        rows = None  # the records decoded (None: all)
        if kept is not None and not kept.all():
            rows = fmt.run_rows(run_start[kept], run_length[kept])
            run_class, run_length, first_pixel = run_class[kept], run_length[kept], first_pixel[kept]
        class_id = np.repeat(run_class, run_length)
        # The others: their steps within the run, summed from its first. In uint32, which wraps
        # (the running sum over many runs may pass 2^32) but is exact for the differences within
        # a run (pixels < MAX_PIXELS): half the memory traffic of int64, a third of the time.
        within = columns["pixel"].copy() if rows is None else columns["pixel"][rows]
        starts = np.cumsum(run_length) - run_length
        within[starts] = 0
        running = np.cumsum(within, dtype=np.uint32)
        pixel = running + np.repeat((first_pixel - running[starts]).astype(np.uint32), run_length)
        pixel = pixel.astype(np.int64) if len(first_pixel) and 0 <= first_pixel.min() \
            and first_pixel.max() < 1 << 31 else np.full(len(pixel), -1, np.int64)
        if not light:
            rgb, sample = np.zeros((len(class_id), 0), np.float32), None
        elif self.mode == "merged":
            rgb = self._rgb_of(columns["rgb"], columns["exact"], class_id, rows, number)
            sample = None
        else:
            rgb = columns["rgb"] if rows is None else columns["rgb"][rows]
            sample = (columns["sample"] if rows is None else columns["sample"][rows]).astype(np.int64)
        norms = sigma = None
        if all_columns:
            covariance = self._frame(payload[where_bytes + light_bytes:], covariance_layout, number)
            norms, sigma = (None if name not in covariance else covariance[name] if rows is None
                            else covariance[name][rows] for name in ("norms", "sigma"))
            if self.mode == "merged":
                if sigma is not None and len(sigma) and np.abs(sigma.astype(np.int32)).max() >= fmt.NormBins.CODES:
                    raise self._chunk_error(number, "holds Σ codes past the bins'")
                norms = fmt.NormBins.decoded(norms)
                sigma = None if sigma is None else fmt.NormBins.decoded(sigma)
        decoded = RecordChunk(
            class_id=class_id, pixel=pixel, sample=sample, rgb=rgb,
            norms=np.zeros((len(class_id), 0, 3), np.float32) if norms is None else norms.astype(np.float32, copy=False),
            sigma=sigma)
        self._check_records(decoded, number)
        return decoded

    def _frame(self, frame: bytes, layout: list[fmt.Column], number: int) -> dict[str, np.ndarray]:
        """The columns of one zstd frame of chunk `number`, which must decode to exactly `layout`."""
        size = fmt.frame_bytes(layout)
        try:
            if zstandard.frame_content_size(frame) != size:
                raise self._chunk_error(number, "does not hold its records")
            data = zstandard.ZstdDecompressor().decompress(frame, allow_extra_data=False)
        except zstandard.ZstdError as error:
            raise self._chunk_error(number, f"is not three zstd frames of its records ({error})") from None
        return fmt.split_frame(data, layout)

    def _rgb_of(self, stored: np.ndarray, exact: np.ndarray, class_id: np.ndarray, rows: np.ndarray | None,
                number: int) -> np.ndarray:
        """(r, 3) float32 rgb of the decoded records (`rows` of the chunk; None: all) from a
        merged chunk's light frame: rgb (3, R) and exact (e, 3) (format.py)."""
        exact_at = np.flatnonzero(stored[0] == fmt.RgbBins.EXACT)  # the chunk's exact records
        if len(exact_at) != len(exact):
            raise self._chunk_error(number, f"marks {len(exact_at)} exact records, its header {len(exact)}")
        if rows is not None:
            stored = np.take(stored, rows, axis=1)
        # np.take: 2-15x faster than the same fancy indexing, on rows as on values
        rgb = np.take(fmt.RgbBins.table(), fmt.codes_of_residuals(stored, np.take(self._chroma, class_id, axis=0)))
        if len(exact):
            at = exact_at if rows is None else np.flatnonzero(stored[0] == fmt.RgbBins.EXACT)
            values = exact if rows is None else np.take(exact, np.searchsorted(exact_at, rows[at]), axis=0)
            _as_rows(rgb)[at] = _as_rows(np.ascontiguousarray(values))  # whole rows: 3x faster than rgb[at] = values
        return rgb

    def _layout(self, chunk: dict):
        return fmt.column_layout(self.mode, chunk["records"], self.norm_slots, self.has_sigma, runs=chunk["runs"],
                                 exact=chunk["exact"])

    def _check_records(self, decoded: RecordChunk, number: int) -> None:
        """Pixels inside the image, rgb finite unless the footer lists the class as holding
        NaN or infinite light (the class ids were checked against the chunk's range)."""
        pixel = decoded.pixel
        if len(pixel) and (pixel.min() < 0 or self._pixels is not None and pixel.max() >= self._pixels):
            outside = int(pixel.min()) if pixel.min() < 0 else int(pixel.max())
            raise self._chunk_error(number, f"holds pixel {outside}, outside the image's {self._pixels or '?'} pixels")
        if np.isfinite(decoded.rgb).all():  # the common case, 40x cheaper than finding the rows
            return
        not_finite = ~np.isfinite(decoded.rgb).all(axis=1)
        if self.finite_class[decoded.class_id[not_finite]].any():
            raise self._chunk_error(number, "holds NaN or infinite rgb in a class the footer does not list as such")

    def _check_version(self, version: int) -> None:
        if version != fmt.FORMAT_VERSION:
            raise self._error(f"written in format version {version} of the path index; this pxr-layers reads "
                              f"version {fmt.FORMAT_VERSION} only: render the shot again to rebuild its index")

    def _chunk_error(self, number: int, message: str, *, damaged: bool = True) -> PathIndexError:
        return self._error(f"{'corrupted: ' if damaged else ''}chunk {number} at byte "
                           f"{self.chunks[number]['offset']} {message}")

    def _error(self, message: str) -> PathIndexError:
        return PathIndexError(message, file=str(self.shown_as))


def _as_rows(values: np.ndarray) -> np.ndarray:
    """A C-contiguous (r, k) array as (r,) opaque items of its rows' bytes (a view)."""
    return values.view(np.dtype((np.void, values.shape[1] * values.itemsize))).reshape(-1)


def _decompressed(frame: bytes, size: int | None, what: str) -> bytes:
    """A footer's zstd `frame`, decoded: of `size` bytes (None: at most MAX_FOOTER_BYTES), else _Malformed."""
    try:
        stated = zstandard.frame_content_size(frame)
        if not 0 <= stated <= MAX_FOOTER_BYTES or size is not None and stated != size:
            raise _Malformed(f"{what} states a size of {stated} bytes, not "
                             f"{size if size is not None else f'0 to MAX_FOOTER_BYTES ({MAX_FOOTER_BYTES})'}")
        return zstandard.ZstdDecompressor().decompress(frame, allow_extra_data=False)
    except zstandard.ZstdError as error:
        raise _Malformed(f"{what}: {error}") from None


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


def _array(values: list, what: str) -> np.ndarray:
    """np.array(values), else _Malformed (lists of unequal lengths)."""
    try:
        return np.array(values)
    except (ValueError, TypeError):
        raise _Malformed(f"{what} are not numbers") from None


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan
