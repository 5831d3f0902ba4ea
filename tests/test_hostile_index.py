"""Hostile path indexes: truncated, flipped, forged and garbage files.

Every damaged file is one PathIndexError line naming it (and the chunk and its byte offset
where there is one), or, when the damage touched nothing the reader uses, the very pixels
of the intact index; never a traceback, never other pixels. `index info --verify` reads
every chunk. A forged chunk (its checksums made to agree, as a buggy or hostile writer
could) can still move light between pixels of the image or change its rgb, which no
reader can tell; what it cannot do is crash the reader, or bring NaN, pixels outside the
image or records of classes the footer does not list.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import io
import itertools
import json
import re
import zlib

import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st
from tracing import index_writer

from pxr_layers import lpe
from pxr_layers.cli.main import main
from pxr_layers.errors import PathIndexError
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.paths import format as fmt
from pxr_layers.paths.reader import MAX_CHUNK_BYTES, PathIndex
from pxr_layers.request import RenderRequest

RESOLUTION = (16, 12)
NORM_BOUNCES = 2
CHUNK_RECORDS = 48  # nine chunks: damage can land in any of them
LAYERS = {"beauty": lpe.BEAUTY, "diffuse": "C<RD>.*", "flat": "C<R.>@(|S_C| = 0).*"}  # the last reads the norms
PROPERTY = settings(deadline=None, derandomize=True, database=None)  # reproducible, leaves no .hypothesis/


@dataclasses.dataclass(frozen=True)
class Intact:
    """The undamaged index: its bytes, footer (JSON tables and class table columns), chunk
    columns and layers."""

    data: bytes
    tables: dict
    arrays: dict[str, np.ndarray]
    columns: list[bytes]  # per chunk, its decompressed columns (its three frames, one after the other)
    layers: dict[str, np.ndarray]

    def __repr__(self) -> str:  # pytest and hypothesis print the arguments of a failing example
        return f"Intact({len(self.data)} bytes, {len(self.columns)} chunks)"

    def _repr_pretty_(self, printer, cycle) -> None:
        printer.text(repr(self))


@pytest.fixture(scope="module")
def cornell_index(shipped_scene, tmp_path_factory) -> Intact:
    """A tiny Cornell render's index (16 × 12 pixels, 2 spp, chunks of 48 records)."""
    request = RenderRequest(stage=shipped_scene("cornell.usda"), resolution=RESOLUTION, spp=2, max_depth=3, seed=7,
                            norm_bounces=NORM_BOUNCES, index_mode="merged", index_covariance="norms", previews=False)
    with index_writer(chunk_records=CHUNK_RECORDS):
        path = render_frame(request, output=tmp_path_factory.mktemp("intact"), threads=2).index_path
    data = path.read_bytes()
    tables, arrays = footer_of(data)
    columns = []
    for chunk in tables["chunks"]:
        payload = data[chunk["offset"] + fmt.CHUNK_HEADER.size:][:chunk["bytes"]]
        ends = np.cumsum([0, chunk["where_bytes"], chunk["light_bytes"], len(payload)]).tolist()
        columns.append(b"".join(zstandard.ZstdDecompressor().decompress(payload[start:end])
                                for start, end in itertools.pairwise(ends)))
    assert len(columns) >= 6, len(columns)
    return Intact(data, tables, arrays, columns, extract(PathIndex(path), LAYERS).layers)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("damaged")


def footer_of(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """The footer of an index's bytes: its JSON tables and its class table's columns."""
    offset, length, json_bytes, *_ = fmt.TRAILER.unpack(data[-fmt.TRAILER.size:])
    tables = json.loads(zstandard.ZstdDecompressor().decompress(data[offset:offset + json_bytes]))
    entry = tables["class_table"]
    layout = fmt.class_table_layout(tables["manifest"]["mode"], tables["manifest"]["classes"], entry["events"],
                                    entry["length_dtype"], entry["event_dtype"])
    table = zstandard.ZstdDecompressor().decompress(data[offset + json_bytes:offset + length])
    return tables, {name: values.copy() for name, values in fmt.split_frame(table, layout).items()}


def with_footer(data: bytes, tables, arrays: dict[str, np.ndarray] | None = None) -> bytes:
    """`data` with its footer replaced by `tables` (any JSON value) and, given, class table
    `arrays` (else the file's own class table frame), its trailer made to agree."""
    offset, length, json_bytes, *_ = fmt.TRAILER.unpack(data[-fmt.TRAILER.size:])
    table = data[offset + json_bytes:offset + length]
    if arrays is not None:
        entry = tables["class_table"]
        layout = fmt.class_table_layout(tables["manifest"]["mode"], tables["manifest"]["classes"], entry["events"],
                                        entry["length_dtype"], entry["event_dtype"])
        table = zstandard.ZstdCompressor().compress(
            b"".join(fmt.shuffle(arrays[name].astype(dtype)) for name, dtype, _ in layout))
        entry["bytes"] = len(table)
    text = zstandard.ZstdCompressor().compress(json.dumps(tables).encode())
    footer = text + table
    return data[:offset] + footer + fmt.TRAILER.pack(offset, len(footer), len(text), zlib.crc32(footer),
                                                     fmt.FORMAT_VERSION, fmt.TRAILER_MAGIC)


def layout_of(chunk: dict):
    return fmt.column_layout("merged", chunk["records"], NORM_BOUNCES, False, runs=chunk["runs"],
                             exact=chunk["exact"])


def forged(tables: dict, arrays: dict[str, np.ndarray], columns: list[bytes], *, compress=None) -> bytes:
    """An index of these tables, class table columns and chunk columns with every offset,
    size and CRC-32 made to agree: damage no checksum can catch. compress: (chunk number,
    frame 0, 1 or 2, its columns' bytes) -> the frame as stored."""
    default = zstandard.ZstdCompressor(level=fmt.ZSTD_LEVEL).compress
    compress = compress or (lambda number, frame, data: default(data))
    tables = copy.deepcopy(tables)
    data = bytearray(fmt.HEADER.pack(fmt.HEADER_MAGIC, fmt.FORMAT_VERSION, 0))
    for number, (chunk, chunk_columns) in enumerate(zip(tables["chunks"], columns, strict=True)):
        ends = np.cumsum([0, *(fmt.frame_bytes(frame) for frame in layout_of(chunk)[:2]), len(chunk_columns)])
        frames = [compress(number, frame, chunk_columns[start:end])
                  for frame, (start, end) in enumerate(itertools.pairwise(ends.tolist()))]
        payload = b"".join(frames)
        chunk.update(offset=len(data), bytes=len(payload), where_bytes=len(frames[0]), light_bytes=len(frames[1]),
                     crc32=zlib.crc32(payload))
        data += fmt.CHUNK_HEADER.pack(fmt.CHUNK_MAGIC, len(payload), chunk["crc32"], chunk["records"], chunk["runs"],
                                      chunk["exact"], len(frames[0]), len(frames[1])) + payload
    data += fmt.TRAILER.pack(len(data), 0, 0, 0, fmt.FORMAT_VERSION, fmt.TRAILER_MAGIC)  # where the footer goes
    return with_footer(bytes(data), tables, arrays)


def with_column(columns: list[bytes], tables: dict, number: int, name: str, change) -> list[bytes]:
    """`columns` with chunk `number`'s column `name` replaced by change(values) (a copy)."""
    start = 0
    for column, dtype, shape in itertools.chain(*layout_of(tables["chunks"][number])):
        size = int(np.prod(shape)) * dtype.itemsize
        if column == name:
            values = change(fmt.unshuffle(columns[number][start:start + size], dtype, shape).copy())
            changed = list(columns)
            changed[number] = (columns[number][:start] + fmt.shuffle(values.astype(dtype))
                               + columns[number][start + size:])
            return changed
        start += size
    raise KeyError(name)


def cli(*argv: str) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of `pxr-layers ARGV`, in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def assert_one_line_naming(path, code: int, stderr: str) -> None:
    assert code == 1, stderr
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith(f"pxr-layers: error: {path}: "), stderr


def assert_refused_or_intact(data: bytes, intact: Intact, folder) -> None:
    """`index info`, `index info --verify` and extracting layers from `data` either refuse
    it in one line naming the file, or (verify passing, or nothing touched) give the
    intact index's pixels exactly."""
    path = folder / "damaged.pxlidx"
    path.write_bytes(data)
    for flags in ([], ["--verify"]):
        code, _, stderr = cli("index", "info", "-q", *flags, str(path))
        if code:
            assert_one_line_naming(path, code, stderr)
    verified = code == 0
    try:
        layers = extract(PathIndex(path), LAYERS).layers
    except PathIndexError as error:
        assert str(error).startswith(f"{path}: ") and "\n" not in str(error)
        assert not verified, "a file --verify passes must extract"
        return
    for name, image in intact.layers.items():
        assert np.array_equal(layers[name], image), f"{name}: other pixels from a damaged index"


# -- index info --verify


def test_info_says_chunks_are_not_verified_and_verify_reads_them(cornell_index, folder):
    path = folder / "intact.pxlidx"
    path.write_bytes(cornell_index.data)
    code, out, _ = cli("index", "info", str(path))
    assert code == 0 and "chunks       light read, not verified (--verify checks all of every chunk)" in out
    code, out, _ = cli("index", "info", "--verify", "-q", str(path))
    chunks = len(cornell_index.tables["chunks"])
    assert code == 0 and f"chunks       verified: {chunks} chunks, CRC-32 and contents ok" in out
    assert PathIndex(path).verify() == chunks


@pytest.mark.parametrize("number", [0, 3, -1])
def test_verify_names_the_chunk_of_a_flipped_payload_byte(cornell_index, folder, number):
    chunk = cornell_index.tables["chunks"][number]
    number %= len(cornell_index.tables["chunks"])
    data = bytearray(cornell_index.data)
    data[chunk["offset"] + fmt.CHUNK_HEADER.size + chunk["bytes"] // 2] ^= 0x10
    path = folder / "flipped.pxlidx"
    path.write_bytes(bytes(data))
    PathIndex(path)  # the tables are intact: only reading chunks finds it (info reads their light)
    for flags in ([], ["--verify"]):
        code, out, stderr = cli("index", "info", *flags, str(path))
        assert_one_line_naming(path, code, stderr)
        assert f"chunk {number} at byte {chunk['offset']} fails its checksum" in stderr and not out


@pytest.mark.parametrize("keep", [0.9, 0.5, 0.02])
def test_verify_refuses_a_truncated_file(cornell_index, folder, keep):
    path = folder / "cut.pxlidx"
    path.write_bytes(cornell_index.data[:int(len(cornell_index.data) * keep)])
    code, _, stderr = cli("index", "info", "--verify", str(path))
    assert_one_line_naming(path, code, stderr)
    assert "truncated" in stderr


# -- forged chunks: the checksums agree, the contents do not


def first_record_nan(stored: np.ndarray) -> np.ndarray:
    """A merged chunk's rgb column (3, r) with its first record's g a code that reads as NaN."""
    stored[0, 0] = fmt.RgbBins.EXACT + 1
    stored[1:, 0] = 0
    return stored


PIXELS = RESOLUTION[0] * RESOLUTION[1]
FORGED_CHUNKS = {  # damage: (column, change of its values, what the error says)
    "a class past the chunk's last": ("run_class", lambda deltas: np.r_[deltas[:-1], deltas[-1] + 1],
                                      "holds records of classes outside its footer entry's"),
    "a class past the table": ("run_class", lambda deltas: np.r_[deltas[:1] + 10**6, deltas[1:]],
                               "holds records of classes outside its footer entry's"),
    "runs of other lengths": ("run_length", lambda lengths: lengths + 1, "runs that do not add up to its records"),
    "a pixel past the image": ("pixel", lambda steps: np.r_[steps[:1] + 2 * PIXELS, steps[1:]],
                               f"outside the image's {PIXELS} pixels"),
    "a negative pixel": ("pixel", lambda steps: np.r_[np.uint32(1), steps[1:]], "holds pixel -"),
    "NaN rgb in a finite class": ("rgb", first_record_nan,
                                  "NaN or infinite rgb in a class the footer does not list as such"),
    "an exact record unmarked": ("rgb", lambda stored: np.where(stored == fmt.RgbBins.EXACT, 0, stored),
                                 "exact records, its header"),
}


@pytest.mark.parametrize("damage", list(FORGED_CHUNKS))
def test_forged_records_are_refused_naming_the_chunk(cornell_index, folder, damage):
    column, change, message = FORGED_CHUNKS[damage]
    path = folder / "forged.pxlidx"
    path.write_bytes(forged(cornell_index.tables, cornell_index.arrays,
                            with_column(cornell_index.columns, cornell_index.tables, 2, column, change)))
    offset = PathIndex(path).chunks[2]["offset"]
    for read in (lambda index: index.verify(), lambda index: extract(index, LAYERS),
                 lambda index: list(index.records(norms=False))):
        with pytest.raises(PathIndexError) as error:
            read(PathIndex(path))
        assert str(error.value).startswith(f"{path}: corrupted: chunk 2 at byte {offset} ")
        assert message in str(error.value)


@pytest.mark.parametrize("payload, message", [
    (lambda columns: zstandard.ZstdCompressor().compress(columns[:-1]), "does not hold its"),
    (lambda columns: zstandard.ZstdCompressor(write_content_size=False).compress(columns), "does not hold its"),
    (lambda columns: b"not zstd" + columns[:50], "is not three zstd frames of its records"),
    (lambda columns: zstandard.ZstdCompressor().compress(columns) + b"extra", "is not three zstd frames of its records"),
])
def test_a_payload_of_other_sizes_is_refused_naming_the_chunk(cornell_index, folder, payload, message):
    columns = cornell_index.columns
    path = folder / "sizes.pxlidx"
    path.write_bytes(forged(cornell_index.tables, cornell_index.arrays, columns,
                            compress=lambda number, frame, data: payload(data) if (number, frame) == (1, 0) else
                            zstandard.ZstdCompressor().compress(data)))
    index = PathIndex(path)
    with pytest.raises(PathIndexError, match=f"chunk 1 at byte {index.chunks[1]['offset']} {message}"):
        index.verify()


def test_a_chunk_header_of_other_record_count_is_refused(cornell_index, folder):
    data = bytearray(cornell_index.data)
    chunk = cornell_index.tables["chunks"][4]
    data[chunk["offset"] + 12:chunk["offset"] + 16] = (chunk["records"] - 1).to_bytes(4, "little")
    path = folder / "count.pxlidx"
    path.write_bytes(bytes(data))
    with pytest.raises(PathIndexError, match=f"chunk 4 at byte {chunk['offset']} has a bad header"):
        PathIndex(path).verify()


def test_verify_counts_each_classes_records(cornell_index, folder):
    arrays = copy.deepcopy(cornell_index.arrays)
    counts = arrays["records"].astype(np.int64)
    first, second = [c for c in range(len(counts)) if counts[c] > 1][:2]
    counts[first] += 1
    counts[second] -= 1  # the total still agrees
    arrays["records"] = counts
    path = folder / "counts.pxlidx"
    path.write_bytes(forged(cornell_index.tables, arrays, cornell_index.columns))
    extract(PathIndex(path), LAYERS)  # reading does not count per class...
    with pytest.raises(PathIndexError, match=f"class {first} has {counts[first] - 1} records in the chunks, "
                                             f"the footer says {counts[first]}"):
        PathIndex(path).verify()  # ...verify does


def test_a_render_with_nan_contributions_is_read_but_does_not_verify(cornell_index, folder):
    """NaN records of a class the footer lists as non-finite are what the render made (the
    jobs name the paths of a NaN beauty from them): read as they are, and --verify says so,
    not 'corrupted'."""
    tables = copy.deepcopy(cornell_index.tables)
    culprit = tables["chunks"][2]["first_class"]
    tables["nonfinite_classes"] = [culprit]
    columns = with_column(cornell_index.columns, tables, 2, "rgb", first_record_nan)
    path = folder / "nan.pxlidx"
    path.write_bytes(forged(tables, cornell_index.arrays, columns))
    index = PathIndex(path)
    rgb = np.concatenate([chunk.rgb for chunk in index.records(norms=False)])
    assert np.isnan(rgb).any(axis=1).sum() == 1
    code, _, stderr = cli("index", "info", "--verify", "-q", str(path))
    assert_one_line_naming(path, code, stderr)
    assert f"chunk 2 at byte {index.chunks[2]['offset']} holds 1 records of NaN or infinite rgb (class {culprit}" \
        in stderr and "corrupted" not in stderr
    code, _, stderr = cli("extract", str(path), "--layer", "all=C.*", "--no-previews", "-q")  # never NaN pixels
    assert_one_line_naming(path, code, stderr)
    assert "1 path classes carry NaN or infinite light" in stderr


# -- forged footers


def changed(tables: dict, change) -> dict:
    tables = copy.deepcopy(tables)
    change(tables)
    return tables


def set_key(table: dict, key: str, value):
    table[key] = value


def set_item(array: np.ndarray, at: int, value) -> None:
    array[at] = value


FORGED_FOOTERS = {  # damage: a change of (tables, class table arrays)
    "class event id past the table": lambda t, a: set_item(a["events"], 3, len(t["events"])),
    "class event id of the camera": lambda t, a: set_item(a["events"], 3, 0),
    "negative label id": lambda t, a: t["events"][1][2].append(-1),
    "unknown event type": lambda t, a: t["events"][1].__setitem__(0, "Q"),
    "class count mismatch": lambda t, a: set_key(t["manifest"], "classes", t["manifest"]["classes"] - 1),
    "class lengths past the events": lambda t, a: set_item(a["length"], 0, a["length"][0] + 1),
    "non-finite class past the table": lambda t, a: set_key(t, "nonfinite_classes", [t["manifest"]["classes"]]),
    "records disagree": lambda t, a: set_key(t["manifest"], "records", t["manifest"]["records"] + 1),
    "zero spp": lambda t, a: set_key(t["manifest"], "spp", 0),
    "resolution past MAX_PIXELS": lambda t, a: set_key(t["manifest"], "resolution", [1 << 20, 1 << 20]),
    "resolution of text": lambda t, a: set_key(t["manifest"], "resolution", ["16", 12]),
    "frame not a number": lambda t, a: set_key(t["manifest"], "frame", "tomorrow"),
    "norm slots of text": lambda t, a: set_key(t["manifest"], "norm_slots", "2"),
    "chunk classes past the table": lambda t, a: set_key(t["chunks"][1], "last_class", t["manifest"]["classes"]),
    "a huge chunk": lambda t, a: set_key(t["chunks"][1], "records", MAX_CHUNK_BYTES),
    "overlapping chunks": lambda t, a: set_key(t["chunks"][2], "offset", t["chunks"][1]["offset"] + 1),
    "chunk without offset": lambda t, a: t["chunks"][1].pop("offset"),
    "class table of another width": lambda t, a: set_key(t["class_table"], "event_dtype", "<u8"),
    "tables not an object": lambda t, a: [1, 2],
}


@pytest.mark.parametrize("damage", list(FORGED_FOOTERS))
def test_a_forged_footer_is_refused_at_open(cornell_index, folder, damage):
    tables, arrays = copy.deepcopy(cornell_index.tables), copy.deepcopy(cornell_index.arrays)
    replaced = FORGED_FOOTERS[damage](tables, arrays)
    path = folder / "footer.pxlidx"
    path.write_bytes(with_footer(cornell_index.data, tables, arrays) if replaced is None
                     else with_footer(cornell_index.data, replaced))
    code, _, stderr = cli("index", "info", str(path))
    assert_one_line_naming(path, code, stderr)
    assert "corrupted footer" in stderr


def test_an_index_without_a_resolution_is_refused_when_extracting(cornell_index, folder):
    """Other code than `pxr-layers render` may write an index without the render's keys:
    reading its records works, extracting layers (which needs the image size) is one error."""
    tables = changed(cornell_index.tables, lambda t: t["manifest"].pop("resolution"))
    path = folder / "bare.pxlidx"
    path.write_bytes(forged(tables, cornell_index.arrays, cornell_index.columns))
    index = PathIndex(path)
    assert index.verify() == len(index.chunks)
    with pytest.raises(PathIndexError, match=f"^{re.escape(str(path))}: its manifest has no 'resolution'"):
        extract(index, LAYERS)


# -- properties: random damage anywhere


@settings(PROPERTY, max_examples=40)
@given(data=st.data())
def test_a_file_truncated_anywhere_is_refused(cornell_index, folder, data):
    keep = data.draw(st.integers(0, len(cornell_index.data) - 1), label="bytes kept")
    assert_refused_or_intact(cornell_index.data[:keep], cornell_index, folder)


@settings(PROPERTY, max_examples=80)
@given(data=st.data())
def test_flipped_bytes_anywhere_are_refused_or_change_nothing(cornell_index, folder, data):
    size = len(cornell_index.data)
    footer, *_ = fmt.TRAILER.unpack(cornell_index.data[-fmt.TRAILER.size:])
    offsets = st.one_of(st.integers(0, size - 1),  # anywhere: most of this small file is its footer
                        st.integers(fmt.HEADER.size, footer - 1),  # in the chunks
                        st.integers(0, fmt.HEADER.size - 1), st.integers(size - fmt.TRAILER.size, size - 1))
    flips = data.draw(st.lists(st.tuples(offsets, st.integers(1, 255)), min_size=1, max_size=8),
                      label="(offset, xor) flips")
    damaged = bytearray(cornell_index.data)
    for offset, xor in flips:
        damaged[offset] ^= xor
    assert_refused_or_intact(bytes(damaged), cornell_index, folder)


@settings(PROPERTY, max_examples=40)
@given(garbage=st.one_of(
    st.binary(max_size=2048),
    st.binary(max_size=2048).map(lambda tail: fmt.HEADER.pack(fmt.HEADER_MAGIC, fmt.FORMAT_VERSION, 0) + tail),
    st.tuples(st.binary(max_size=2048), st.integers(0, 4096), st.integers(0, 4096)).map(
        lambda parts: fmt.HEADER.pack(fmt.HEADER_MAGIC, fmt.FORMAT_VERSION, 0) + parts[0] + fmt.TRAILER.pack(
            parts[1], parts[2], parts[2] // 2, 0, fmt.FORMAT_VERSION, fmt.TRAILER_MAGIC)),
))
def test_garbage_is_refused(cornell_index, folder, garbage):
    assert_refused_or_intact(garbage, cornell_index, folder)


@settings(PROPERTY, max_examples=60)
@given(data=st.data())
def test_forged_chunk_contents_never_crash_the_reader(cornell_index, folder, data):
    """Bytes flipped in a chunk's decoded columns, checksums made to agree: a PathIndexError
    naming the chunk, or layers that are finite images of the right size."""
    number = data.draw(st.integers(0, len(cornell_index.columns) - 1), label="chunk")
    size = len(cornell_index.columns[number])
    flips = data.draw(st.lists(st.tuples(st.integers(0, size - 1), st.integers(1, 255)), min_size=1, max_size=8),
                      label="(offset, xor) flips")
    columns = bytearray(cornell_index.columns[number])
    for offset, xor in flips:
        columns[offset] ^= xor
    path = folder / "forged.pxlidx"
    path.write_bytes(forged(cornell_index.tables, cornell_index.arrays,
                            [*cornell_index.columns[:number], bytes(columns), *cornell_index.columns[number + 1:]]))
    for flags in ([], ["--verify"]):
        code, _, stderr = cli("index", "info", "-q", *flags, str(path))
        if code:  # a class id moved to another class of the chunk shows only in the counts
            assert_one_line_naming(path, code, stderr)
            assert re.search(rf"chunk {number} at byte |held by chunks (\d+, )*{number}\b", stderr), stderr
    try:
        layers = extract(PathIndex(path), LAYERS).layers
    except PathIndexError as error:
        assert str(error).startswith(f"{path}: corrupted: chunk {number} at byte") and "\n" not in str(error)
        return
    for name, image in cornell_index.layers.items():
        assert layers[name].shape == image.shape and np.isfinite(layers[name]).all()
