"""The path index written while rendering: its buffers flushed on the writer's own thread,
its bytes the same whatever the thread count, every record read back, a write error told
once, nothing left behind by an abort, and the index opened for delivery from the footer
in memory equal to the file read back."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from tracing import index_writer

from pxr_layers.jobs.frame import render_frame
from pxr_layers.paths import format as fmt
from pxr_layers.paths.events import path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.paths.trie import class_sequences
from pxr_layers.paths.writer import PathIndexWriter
from pxr_layers.request import RenderRequest
from pxr_layers.trace.merge import MergedContributions

RESOLUTION, SPP = (96, 96), 64  # 9 batches of 1024 pixels (trace.batch_pixels), some 20,000 records each
BUFFER_RECORDS = 50_000  # several flushes of two or three batches each
WRITER_THREAD = "pxl-index-writer"


def writer_threads() -> list[threading.Thread]:
    return [thread for thread in threading.enumerate() if thread.name == WRITER_THREAD]


class KeepingWriter(PathIndexWriter):
    """A PathIndexWriter that keeps what it was given and the index it opened for delivery."""

    kept: list = []  # of the last render: the records of every batch, then the index opened

    def add(self, records) -> None:
        KeepingWriter.kept.append(records)
        super().add(records)

    def opened(self) -> PathIndex:
        index = super().opened()
        KeepingWriter.kept.append(index)
        return index


def render(stage: Path, folder: Path, threads: int, writer=PathIndexWriter):
    request = RenderRequest(stage=stage, resolution=RESOLUTION, spp=SPP, max_depth=4, seed=5, previews=False)
    with index_writer(writer, buffer_records=BUFFER_RECORDS):
        return render_frame(request, output=folder, threads=threads)


@pytest.fixture(scope="module")
def kept(shipped_scene, tmp_path_factory):
    """A render whose writer kept every batch's records: (FrameResult, records, opened index)."""
    KeepingWriter.kept = []
    result = render(shipped_scene("cornell.usda"), tmp_path_factory.mktemp("kept"), 2, KeepingWriter)
    *records, opened = KeepingWriter.kept
    assert not writer_threads()  # close ended the writer's thread
    return result, [batch for batch in records if batch is not None], opened


def test_same_index_on_one_thread_two_and_again(shipped_scene, tmp_path, kept):
    result, records, _ = kept
    assert len(records) > 4 and sum(len(batch.pixel) for batch in records) > 3 * BUFFER_RECORDS  # several flushes
    stage = shipped_scene("cornell.usda")
    again = [render(stage, tmp_path / str(threads), threads).index_path.read_bytes() for threads in (1, 2)]
    assert again[0] == again[1] == result.index_path.read_bytes()


def test_every_record_added_is_read_back(kept):
    """The index holds exactly the records added (their class, pixel and norm bins; their
    rgb within the format's rule: one bin, but for the carriers of each pixel's rest), and
    they sum per pixel to the film's beauty."""
    result, records, _ = kept
    index = PathIndex(result.index_path)
    vocabulary = result.vocabulary

    def texts(batch) -> np.ndarray:
        sequences = class_sequences(batch.trie_parent, batch.trie_event, batch.class_nodes)
        return np.array([path_text(tuple(vocabulary.event(e) for e in keys)) for keys in sequences])[batch.path_class]

    added = {"text": np.concatenate([texts(batch) for batch in records])}
    for name in ("pixel", "rgb", "norm_codes"):
        added[name] = np.concatenate([getattr(batch, name) for batch in records])
    added["norms"] = fmt.NormBins.decoded(added.pop("norm_codes")).astype(np.float32)
    chunks = list(index.records())
    read = {name: np.concatenate([getattr(chunk, name) for chunk in chunks]) for name in ("pixel", "rgb", "norms")}
    read["text"] = np.array([path_text(c.events[1:]) for c in index.classes])[
        np.concatenate([chunk.class_id for chunk in chunks])]
    assert len(read["pixel"]) == len(added["pixel"]) == index.record_count

    def order(columns):  # records of one (pixel, class, norms) are one merged record
        return np.lexsort((*columns["norms"].reshape(len(columns["pixel"]), -1).T, columns["pixel"], columns["text"]))

    a, b = order(added), order(read)
    for name in ("text", "pixel", "norms"):
        np.testing.assert_array_equal(added[name][a], read[name][b], err_msg=name)
    with np.errstate(divide="ignore", invalid="ignore"):
        bins = np.abs(np.log2(read["rgb"][b] / added["rgb"][a])) * fmt.RgbBins.BINS_PER_OCTAVE
    outside = (np.nan_to_num(bins, nan=0.0) > 1 + 1e-6).any(axis=1)
    pixels = RESOLUTION[0] * RESOLUTION[1]
    assert outside.sum() <= 3 * pixels  # at most a carrier per pixel and channel
    image = np.stack([np.bincount(read["pixel"], read["rgb"][:, channel].astype(np.float64), pixels)
                      for channel in range(3)], axis=1) / SPP
    beauty = result.rgba[..., :3].reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(image, beauty, rtol=1e-5, atol=1e-6 * beauty.max())
    index.verify()  # and the footer's per-class records are those of the records


def test_index_opened_for_delivery_is_the_file_read_back(kept):
    """The index delivery got from the writer's footer in memory has the very tables of the
    file it wrote, read back and parsed."""
    result, _, opened = kept
    read = PathIndex(result.index_path)
    assert opened.shown_as == read.path == result.index_path
    assert opened.size == read.size == result.index_path.stat().st_size
    assert opened.manifest == read.manifest and opened.labels == read.labels and opened.events == read.events
    assert opened.chunks == read.chunks
    assert [(c.event_ids, c.records) for c in opened.classes] == [(c.event_ids, c.records) for c in read.classes]


def synthetic_batches(count: int, records: int, classes: int = 50, seed: int = 3):
    """`count` batches of `records` merged records each (incompressible rgb and norm codes,
    N = 2), over `classes` classes of one event after the camera each."""
    rng = np.random.default_rng(seed)
    for number in range(count):
        yield MergedContributions(
            pixel=np.sort(rng.integers(number * records, (number + 1) * records, records)),
            count=np.ones(records, np.uint32), rgb=rng.random((records, 3), np.float32),
            path_class=rng.integers(0, classes, records), norm_codes=rng.integers(0, 256, (records, 2, 3), np.uint8),
            sigma_codes=None, class_nodes=np.arange(1, classes + 1), trie_parent=np.r_[-1, np.zeros(classes, np.int64)],
            trie_event=np.arange(classes + 1), contributions=records)


def test_abort_mid_stream_leaves_no_file_and_no_thread(tmp_path):
    writer = PathIndexWriter(tmp_path / "aborted.pxlidx", {}, 2, buffer_records=1000)
    for batch in synthetic_batches(40, 500):  # 20 buffers: the queue is full, the thread writing
        writer.add(batch)
    assert writer_threads() and list(tmp_path.iterdir())
    writer.abort()
    assert not list(tmp_path.iterdir())
    assert not writer_threads()


FILE_SIZE_LIMIT = 150_000  # bytes; each buffer of 2000 synthetic records takes some 35 kB

WRITE_UNTIL_THE_LIMIT = """
import json, resource, signal, sys, threading
from pathlib import Path
from pxr_layers.errors import OutputError
from pxr_layers.paths.writer import PathIndexWriter
from test_index_streaming import synthetic_batches

folder, buffer_records, limit = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
warm = PathIndexWriter(folder / "warm-up.pxlidx", {}, 2, buffer_records=1)  # the kernels loaded before the limit
warm.add(next(synthetic_batches(1, 10)))
warm.abort()
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write beyond the limit fails with EFBIG, as on a full disk
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
errors, where = [], None
writer = PathIndexWriter(folder / "big.pxlidx", {}, 2, buffer_records=buffer_records)
try:  # as FrameAssembler does: add every batch, close; abort on any error
    where = "add"
    for batch in synthetic_batches(20, 1000):
        writer.add(batch)
    where = "close"
    writer.close(None)  # never reaches the footer, whose events the vocabulary would name
    where = None
except OutputError as error:
    errors.append(str(error))
finally:
    writer.abort()
print(json.dumps({"errors": errors, "where": where, "files": sorted(p.name for p in folder.iterdir()),
                  "threads": [thread.name for thread in threading.enumerate()]}))
"""


@pytest.mark.parametrize("buffer_records, raised_by", [(2000, ("add", "close")), (10**6, ("close",))])
def test_a_write_error_is_told_once_and_leaves_no_file(tmp_path, buffer_records, raised_by):
    """A file size limit (RLIMIT_FSIZE: writes fail as on a full disk) reached by the writer's
    thread: one OutputError naming the file, raised by a later add or by close (a single
    buffer: by close), then no file and no thread."""
    done = subprocess.run([sys.executable, "-c", WRITE_UNTIL_THE_LIMIT, str(tmp_path), str(buffer_records),
                           str(FILE_SIZE_LIMIT)], capture_output=True, text=True, cwd=Path(__file__).parent)
    assert done.returncode == 0, done.stderr
    outcome = json.loads(done.stdout)
    assert len(outcome["errors"]) == 1, outcome
    assert outcome["errors"][0] == f"{tmp_path / 'big.pxlidx'}: cannot write the path index (File too large)"
    assert outcome["where"] in raised_by
    assert outcome["files"] == [] and WRITER_THREAD not in outcome["threads"]


def test_a_closed_writer_leaves_no_thread(tmp_path):
    writer = PathIndexWriter(tmp_path / "empty.pxlidx", {}, 2)
    where = writer.close(None)  # no records: no event for the vocabulary to name
    assert not writer_threads()
    assert PathIndex(where).record_count == 0 == writer.opened().record_count
