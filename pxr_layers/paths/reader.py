"""Read a path index: its manifest, label and class tables, and records class by class."""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zstandard

from ..errors import PathIndexError
from . import format as fmt
from .events import Event


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


@dataclass(frozen=True)
class RecordChunk:
    """Records of one chunk (or the part of it in the classes asked for).

    class_id : (r,) int64; pixel : (r,) int64 (y·width + x); sample : (r,) int64
    rgb : (r, 3) float32, as the film added it; norms : (r, N, 3) float32 C, T, R
    """

    class_id: np.ndarray
    pixel: np.ndarray
    sample: np.ndarray
    rgb: np.ndarray
    norms: np.ndarray


class PathIndex:
    """An open path index. Checks the header, trailer, version and footer checksum at
    open; every chunk's checksum when it is read. Memory: the tables, plus one chunk at
    a time while streaming records."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
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
                offset, length, crc, _, magic = fmt.TRAILER.unpack(file.read(fmt.TRAILER.size))
                if magic != fmt.TRAILER_MAGIC:
                    raise self._error("truncated or incomplete: no trailer at the end of the file "
                                      "(an interrupted write?)")
                if offset + length + fmt.TRAILER.size != self.size:
                    raise self._error("corrupted: the trailer points outside the file")
                file.seek(offset)
                footer = file.read(length)
        except OSError as error:
            raise PathIndexError(f"cannot read ({error.strerror or error})", file=str(self.path)) from error
        if zlib.crc32(footer) != crc:
            raise self._error("corrupted: the footer's checksum does not match")
        try:
            tables = json.loads(zstandard.ZstdDecompressor().decompress(footer))
        except (zstandard.ZstdError, ValueError) as error:
            raise self._error(f"corrupted footer ({error})") from error
        self.manifest: dict = tables["manifest"]
        self.labels: tuple[str, ...] = tuple(tables["labels"])
        self.events: tuple[Event, ...] = tuple(
            Event(kind, scatter, frozenset(self.labels[i] for i in ids), *name)
            for kind, scatter, ids, *name in tables["events"]
        )
        self.classes: tuple[PathClass, ...] = tuple(
            PathClass(index, tuple(events), records, tuple(rgb), self.events)
            for index, (events, records, rgb) in enumerate(
                zip(tables["classes"], tables["class_records"], tables["class_rgb"]))
        )
        self.chunks: tuple[dict, ...] = tuple(tables["chunks"])
        self.norm_slots: int = self.manifest["norm_slots"]

    @property
    def record_count(self) -> int:
        return self.manifest["records"]

    def records(self, classes: Iterable[int] | None = None, *, norms: bool = True) -> Iterator[RecordChunk]:
        """Stream the records of `classes` (ids; all if None), one chunk at a time.

        Only the chunks holding a wanted class are read and decompressed. norms=False
        skips decoding the norms and samples (RecordChunk.norms is then (r, 0, 3) and
        RecordChunk.sample empty).
        """
        wanted = None
        if classes is not None:  # a lookup table: wanted[class id]
            wanted = np.zeros(len(self.classes), bool)
            wanted[np.fromiter(classes, np.int64)] = True
        decompressor = zstandard.ZstdDecompressor()
        with open(self.path, "rb") as file:
            for number, chunk in enumerate(self.chunks):
                chunk_wanted = None if wanted is None else wanted[np.asarray(chunk["classes"], np.int64)]
                if chunk_wanted is not None and not chunk_wanted.any():
                    continue
                file.seek(chunk["offset"])
                head = file.read(fmt.CHUNK_HEADER.size)
                payload = file.read(chunk["bytes"])
                magic, length, crc, records = fmt.CHUNK_HEADER.unpack(head) if len(head) == fmt.CHUNK_HEADER.size \
                    else (b"", 0, 0, 0)
                if magic != fmt.CHUNK_MAGIC or length != chunk["bytes"] or len(payload) != length:
                    raise self._error(f"corrupted: chunk {number} at byte {chunk['offset']} has a bad header")
                if zlib.crc32(payload) != crc or crc != chunk["crc32"]:
                    raise self._error(f"corrupted: chunk {number} at byte {chunk['offset']} fails its checksum")
                decoded = self._decode(decompressor.decompress(payload), records, number, norms)
                if chunk_wanted is not None and not chunk_wanted.all():
                    keep = wanted[decoded.class_id]
                    decoded = RecordChunk(*(column[keep] if len(column) else column for column in vars(decoded).values()))
                yield decoded

    def _decode(self, data: bytes, records: int, number: int, all_columns: bool) -> RecordChunk:
        columns = {}
        position = 0
        layout = fmt.column_sizes(records, self.norm_slots)
        if position + sum(int(np.prod(shape)) * dtype.itemsize for _, dtype, shape in layout) != len(data):
            raise self._error(f"corrupted: chunk {number} does not hold its {records} records")
        for name, dtype, shape in layout:
            size = int(np.prod(shape)) * dtype.itemsize
            if all_columns or name in ("class", "pixel", "rgb"):
                columns[name] = fmt.unshuffle(data[position:position + size], dtype, shape)
            position += size
        return RecordChunk(
            class_id=columns["class"].astype(np.int64),
            pixel=np.cumsum(columns["pixel"], dtype=np.int64),
            sample=columns["sample"].astype(np.int64) if all_columns else np.zeros(0, np.int64),
            rgb=columns["rgb"],
            norms=columns["norms"].astype(np.float32) if all_columns else np.zeros((records, 0, 3), np.float32),
        )

    def _check_version(self, version: int) -> None:
        if version != fmt.FORMAT_VERSION:
            raise self._error(f"written in path index format version {version}; this pxr-layers reads version "
                              f"{fmt.FORMAT_VERSION} only: render the shot again to rebuild its index")

    def _error(self, message: str) -> PathIndexError:
        return PathIndexError(message, file=str(self.path))
