"""The path index: records reproduce the beauty, round trip, determinism, bad files."""

from __future__ import annotations

import struct
import subprocess
import threading

import numpy as np
import pytest
from test_cli import SCRIPT
from tracing import index_writer, trace_image

from pxr_layers.errors import PathIndexError
from pxr_layers.jobs.frame import render_frame
from pxr_layers.paths import format as fmt
from pxr_layers.paths.events import path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.paths.writer import PathIndexWriter
from pxr_layers.request import RenderRequest
from pxr_layers.trace import batch_pixels
from pxr_layers.trace.integrator import TraceSettings

RESOLUTION = (40, 32)
SETTINGS = TraceSettings(spp=4, max_depth=4, seed=11, norm_bounces=5, record_paths=True)
CHUNK_RECORDS, BUFFER_RECORDS = 512, 20000  # many chunks, written in several flushes
TWO_BATCHES = (160, 128)  # more paths at SETTINGS.spp than one batch holds: the threads share the frame


def render_with_index(stage, folder, *, threads=2, index_mode="records", resolution=RESOLUTION):
    """render_frame with SETTINGS (its index in chunks of CHUNK_RECORDS)."""
    request = RenderRequest(stage=stage, resolution=resolution, spp=SETTINGS.spp, max_depth=SETTINGS.max_depth,
                            seed=SETTINGS.seed, norm_bounces=SETTINGS.norm_bounces, index_mode=index_mode,
                            index_covariance="norms", previews=False)
    with index_writer(chunk_records=CHUNK_RECORDS, buffer_records=BUFFER_RECORDS):
        return render_frame(request, output=folder, threads=threads)


@pytest.fixture(scope="module", params=["cornell.usda", "showcase.usda"])
def stage(request, shipped_scene):
    return shipped_scene(request.param)


@pytest.fixture(scope="module")
def rendered(stage, tmp_path_factory):
    result = render_with_index(stage, tmp_path_factory.mktemp("index"))
    assert result.plan.trace == SETTINGS
    return result.index_path, result


def test_records_sum_to_the_beauty(rendered):
    path, result = rendered
    index = PathIndex(path)
    width, height = RESOLUTION
    image = np.zeros((width * height, 3))
    for chunk in index.records():
        for channel in range(3):
            image[:, channel] += np.bincount(chunk.pixel, weights=chunk.rgb[:, channel], minlength=width * height)
    beauty = result.rgba[..., :3].reshape(-1, 3).astype(np.float64)
    image /= SETTINGS.spp
    scale = np.maximum(np.abs(beauty), 1e-3 * beauty.max())
    assert np.max(np.abs(image - beauty) / scale) <= 1e-5


def test_everything_stored_round_trips(stage, rendered):
    """The index render_frame wrote holds every record the tracer's stages make (here in
    batches of 1024 paths), bit for bit but the norms' float16."""
    from pxr_layers.stage import load_stage

    path, _ = rendered
    index = PathIndex(path)
    traced = trace_image(*load_stage(stage), SETTINGS, resolution=RESOLUTION, threads=2, batch_paths=1024)
    batches = [batch.records for batch in traced.batches]
    written = {name: np.concatenate([getattr(b, name) for b in batches]) for name in ("pixel", "sample", "rgb", "norms")}
    written_text = np.concatenate([
        np.array([path_text(tuple(traced.vocabulary.event(e) for e in seq)) for seq in b.sequences])[b.path_class]
        for b in batches
    ])
    chunks = list(index.records())
    read = {name: np.concatenate([getattr(c, name) for c in chunks]) for name in ("pixel", "sample", "rgb", "norms")}
    class_text = np.array([path_text(c.events[1:]) for c in index.classes])
    read_text = class_text[np.concatenate([c.class_id for c in chunks])]
    assert index.record_count == len(written["pixel"]) == len(read["pixel"])
    assert all(c.events[0].type == "C" for c in index.classes)

    def order(columns, text):
        return np.lexsort((columns["rgb"][:, 0], columns["sample"], columns["pixel"], text))

    a, b = order(written, written_text), order(read, read_text)
    np.testing.assert_array_equal(written_text[a], read_text[b])
    for name in ("pixel", "sample", "rgb"):
        np.testing.assert_array_equal(written[name][a], read[name][b])
    # norms are stored as float16: 11 significant bits
    np.testing.assert_allclose(read["norms"][b], written["norms"][a], rtol=2**-11, atol=0)
    assert index.manifest["spp"] == SETTINGS.spp and index.manifest["norm_slots"] == 5
    assert index.manifest["norms"] == {"C": "1/m", "T": "cycles/m", "R": "cycles/rad"}
    counts = np.bincount(np.concatenate([c.class_id for c in chunks]), minlength=len(index.classes))
    assert counts.tolist() == [c.records for c in index.classes]


def test_reading_some_classes_reads_only_their_chunks(rendered):
    path, _ = rendered
    index = PathIndex(path)
    assert len(index.chunks) > 3
    wanted = {max(range(len(index.classes)), key=lambda i: index.classes[i].records)}
    chunks = list(index.records(wanted))
    assert 0 < len(chunks) < len(index.chunks)
    assert all(set(c.class_id.tolist()) <= wanted for c in chunks)
    assert sum(len(c.class_id) for c in chunks) == index.classes[next(iter(wanted))].records


def test_same_render_gives_the_same_bytes(stage, tmp_path):
    assert TWO_BATCHES[0] * TWO_BATCHES[1] > batch_pixels(SETTINGS.spp)
    one = render_with_index(stage, tmp_path / "a", threads=1, resolution=TWO_BATCHES)
    two = render_with_index(stage, tmp_path / "b", threads=2, resolution=TWO_BATCHES)
    assert one.index_path.read_bytes() == two.index_path.read_bytes()


@pytest.fixture
def index_bytes(rendered) -> bytes:
    return rendered[0].read_bytes()


def test_a_corrupted_chunk_is_named(index_bytes, tmp_path):
    good = tmp_path / "good.pxlidx"
    good.write_bytes(index_bytes)
    chunk = PathIndex(good).chunks[1]
    data = bytearray(index_bytes)
    data[chunk["offset"] + fmt.CHUNK_HEADER.size + 5] ^= 0xFF
    bad = tmp_path / "bad.pxlidx"
    bad.write_bytes(bytes(data))
    index = PathIndex(bad)  # the tables are intact
    with pytest.raises(PathIndexError, match=r"bad\.pxlidx.*chunk 1 .*checksum"):
        list(index.records())


def test_a_corrupted_footer_is_named(index_bytes, tmp_path):
    offset, *_ = fmt.TRAILER.unpack(index_bytes[-fmt.TRAILER.size:])
    data = bytearray(index_bytes)
    data[offset + 3] ^= 0x55
    bad = tmp_path / "bad.pxlidx"
    bad.write_bytes(bytes(data))
    with pytest.raises(PathIndexError, match="footer"):
        PathIndex(bad)


@pytest.mark.parametrize("keep", [0.999, 0.5, 0.01])
def test_a_truncated_file_is_named(index_bytes, tmp_path, keep):
    cut = tmp_path / "cut.pxlidx"
    cut.write_bytes(index_bytes[: int(len(index_bytes) * keep)])
    with pytest.raises(PathIndexError, match=r"cut\.pxlidx.*truncated"):
        PathIndex(cut)


def test_a_foreign_file_is_named(tmp_path):
    foreign = tmp_path / "picture.pxlidx"
    foreign.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    with pytest.raises(PathIndexError, match=r"picture\.pxlidx.*not a pxr-layers path index"):
        PathIndex(foreign)


def test_another_format_version_says_so(index_bytes, tmp_path):
    data = bytearray(index_bytes)
    data[8:12] = struct.pack("<I", fmt.FORMAT_VERSION + 1)
    newer = tmp_path / "newer.pxlidx"
    newer.write_bytes(bytes(data))
    with pytest.raises(PathIndexError, match=f"version {fmt.FORMAT_VERSION + 1}.*reads version {fmt.FORMAT_VERSION}"):
        PathIndex(newer)


OLD_TRAILER = struct.Struct("<QQII8s")  # format 3's: footer offset, bytes, CRC-32, version, magic


@pytest.mark.parametrize("command, flags", [(["index", "info"], []),
                                            (["extract"], ["--layer", "all=C.*", "--no-previews"])])
def test_an_index_of_an_older_format_is_one_line_and_exit_1(tmp_path, command, flags):
    """An index written by an earlier pxr-layers (format 3: its header and trailer, a chunk's
    worth of bytes between) is refused by the commands in one line saying what to do."""
    old = tmp_path / "shot.pxlidx"
    body = fmt.HEADER.pack(fmt.HEADER_MAGIC, 3, 0) + bytes(64)
    old.write_bytes(body + OLD_TRAILER.pack(len(body), 0, 0, 3, fmt.TRAILER_MAGIC))
    result = subprocess.run([SCRIPT, *command, str(old), *flags], capture_output=True,
                            text=True, check=False, cwd=tmp_path)
    assert result.returncode == 1 and not result.stdout, result
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.stderr == (f"pxr-layers: error: {old}: written in format version 3 of the path index; this "
                             f"pxr-layers reads version {fmt.FORMAT_VERSION} only: render the shot again to rebuild "
                             "its index\n")


def test_an_interrupted_render_leaves_no_index(stage, tmp_path):
    folder = tmp_path / "out"
    seen = []

    class Interrupted(PathIndexWriter):
        """Interrupts the render at its first batch (of two), once the index has a partial file."""

        def add(self, records):
            super().add(records)
            seen.append(1)
            if len(seen) == 1:
                partial = list(folder.iterdir())
                assert len(partial) == 1 and partial[0].name.startswith(f".{stage.stem}.")  # never the index
                assert partial[0].name.endswith(".tmp.pxlidx")
                with pytest.raises(PathIndexError, match="truncated"):
                    PathIndex(partial[0])
                raise KeyboardInterrupt

    request = RenderRequest(stage=stage, resolution=TWO_BATCHES, spp=SETTINGS.spp, max_depth=SETTINGS.max_depth,
                            norm_bounces=SETTINGS.norm_bounces, index_mode="records", previews=False)
    with index_writer(Interrupted, buffer_records=1000), pytest.raises(KeyboardInterrupt):
        render_frame(request, output=folder, threads=2)
    assert len(seen) == 1
    assert not list(folder.iterdir())  # neither the index, its temporary, nor a product
    assert not [thread for thread in threading.enumerate() if thread.name == "pxl-index-writer"]


def test_cli_render_writes_the_index_and_info_reads_it(tmp_path, shipped_scene):
    result = subprocess.run([SCRIPT, "render", str(shipped_scene("cornell.usda")), "-o", str(tmp_path), "--spp", "2",
                             "--resolution", "24", "24", "--quiet"], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cornell.exr", "cornell.pxlidx", "cornell.rgba.png"]
    info = subprocess.run([SCRIPT, "index", "info", str(tmp_path / "cornell.pxlidx")], capture_output=True, text=True, check=False)
    assert info.returncode == 0, info.stderr
    assert "records" in info.stdout and "bytes per record" in info.stdout and "C RD'" in info.stdout
    per_pixel = (tmp_path / "cornell.pxlidx").stat().st_size / (24 * 24)
    assert f"{per_pixel:,.0f} bytes per pixel" in info.stdout
    (tmp_path / "broken.pxlidx").write_bytes((tmp_path / "cornell.pxlidx").read_bytes()[:100])
    broken = subprocess.run([SCRIPT, "index", "info", str(tmp_path / "broken.pxlidx")], capture_output=True, text=True, check=False)
    assert broken.returncode == 1
    assert len(broken.stderr.strip().splitlines()) == 1 and "broken.pxlidx" in broken.stderr


def test_merged_index_keeps_the_beauty_with_fewer_records(stage, rendered, tmp_path):
    """The same render merged in the tracer: the same light per pixel (its records as read
    sum to the records index's, to float32 rounding: the carriers hold the rest), the same
    classes, every contribution counted, fewer records, and norms in their bins."""
    path, _ = rendered
    merged_path = render_with_index(stage, tmp_path, index_mode="merged").index_path
    full, merged = PathIndex(path), PathIndex(merged_path)
    assert merged.manifest["mode"] == "merged" and merged.manifest["contributions"] == full.record_count
    assert merged.record_count < full.record_count
    width, height = RESOLUTION
    images = []
    for index in (full, merged):
        image = np.zeros((width * height, 3))
        for chunk in index.records():
            for channel in range(3):
                image[:, channel] += np.bincount(chunk.pixel, weights=chunk.rgb[:, channel], minlength=width * height)
        images.append(image)
    np.testing.assert_allclose(images[1], images[0], rtol=1e-6, atol=1e-7 * images[0].max())
    assert [path_text(c.events) for c in merged.classes] == [path_text(c.events) for c in full.classes]
    centres = fmt.NormBins.centres()
    assert np.isin(np.concatenate([chunk.norms.reshape(-1) for chunk in merged.records()]), centres).all()


@pytest.mark.parametrize("dtype", ["u1", "<i2", "<f2", "<u4", "<i4", "<f4", "<f8", "<i8"])
def test_byte_planes_round_trip_bit_for_bit(dtype):
    """shuffle writes byte plane k as the k-th byte of every little-endian value; unshuffle
    rebuilds the very same bits (negative integers, NaN payloads, infinities included)."""
    rng = np.random.default_rng(3)
    itemsize = np.dtype(dtype).itemsize
    values = np.frombuffer(rng.integers(0, 256, size=3000 * itemsize, dtype=np.uint8).tobytes(), dtype).reshape(1000, 3)
    data = fmt.shuffle(values)
    planes = np.frombuffer(data, np.uint8).reshape(itemsize, -1)
    assert np.array_equal(planes[0], values.reshape(-1).view(np.uint8)[::itemsize])  # the low bytes first
    again = fmt.unshuffle(data, dtype, values.shape)
    assert again.dtype == np.dtype(dtype) and again.tobytes() == values.tobytes()


def test_the_tracers_float16_norms_equal_the_formats_conversion():
    """The recorder converts norms to float16 in its kernel; it must store exactly what
    paths.format.stored_norms stores (rounding, saturation, subnormals, NaN)."""
    from pxr_layers.paths.format import stored_norms
    from pxr_layers.trace.recorder import EventNorms

    rng = np.random.default_rng(7)
    values = np.concatenate([
        rng.uniform(0, 1, 4000), 10.0 ** rng.uniform(-12, 8, 4000),  # every float16 range and beyond
        [0.0, 5.96e-8, 2.98e-8, 6.1e-5, 6.0e-5, 65504.0, 65519.9, 65520.0, 1e30, np.inf, np.nan, 1.0009765625],
        np.nextafter(np.float32(2.0 ** -14), 0, dtype=np.float32) * np.ones(3),
    ]).astype(np.float32)
    values = np.concatenate([values, values * np.float32(1 + 2**-11), -values[:100]])
    count = len(values) - len(values) % 3
    norms = EventNorms()
    parent, table, _ = norms.reserve(count // 3)
    parent[:count // 3] = -1
    table[:count // 3] = values[:count].reshape(-1, 3)
    norms.size = count // 3
    ours = norms.first_events(np.arange(count // 3), 1)[:, 0]
    reference = stored_norms(table[:count // 3, None, :])[:, 0]
    same = (ours.view(np.uint16) == reference.view(np.uint16)) | (np.isnan(ours) & np.isnan(reference))
    assert same.all(), values[:count].reshape(-1, 3)[~same.all(axis=1)][:5]
