"""Extraction on threads: the same layers, byte for byte, whatever the thread count; chunks
streamed in file order, a bounded number in flight, the first bad chunk named."""

from __future__ import annotations

import numpy as np
import pytest
from tracing import index_writer

from pxr_layers import lpe
from pxr_layers.errors import PathIndexError
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers import extract as extract_module
from pxr_layers.layers.extract import extract, extract_reference, extraction_threads
from pxr_layers.paths import format as fmt
from pxr_layers.paths import reader as reader_module
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

RESOLUTION = (40, 30)
CHUNK_RECORDS = 150  # small chunks: a small render still makes tens of them, for the threads to share
THREAD_COUNTS = (2, 3, 8)
CONDITIONAL_LAYERS = {
    "sharp": "C<R.>@(|S_R| > 100).*",
    "flat": "C<R.>@(|S_C| = 0).*",
    "textured": "C<R.>@(|S_T| > 1).*",
    "second_rough": "C<R.><R.>@(|S_R| < 10).*",
}


@pytest.fixture(scope="module", params=["cornell", "showcase"])
def indexed(request, shipped_scene, tmp_path_factory):
    """(the stage's light names, render_frame's merged index in chunks of CHUNK_RECORDS)."""
    asked = RenderRequest(stage=shipped_scene(f"{request.param}.usda"), resolution=RESOLUTION, spp=4, max_depth=4,
                          seed=3, norm_bounces=4, index_mode="merged", index_covariance="norms", previews=False)
    with index_writer(chunk_records=CHUNK_RECORDS):
        result = render_frame(asked, output=tmp_path_factory.mktemp("threads"), threads=2)
    index = PathIndex(result.index_path)
    assert len(index.chunks) >= 8
    return result.vocabulary.light_names, index


def layers_of(lights) -> dict[str, str]:
    expressions = dict(lpe.STANDARD_PASSES)
    expressions.update(lpe.per_light_passes(list(lights)))
    expressions.update(CONDITIONAL_LAYERS)
    expressions["new"] = f"C<RD>.*<L.'{lights[0]}'>"
    return expressions


def test_layers_are_byte_identical_whatever_the_thread_count(indexed):
    lights, index = indexed
    expressions = layers_of(lights)
    one = extract(index, expressions, threads=1)
    assert sum(one.layers[name].sum() > 0 for name in CONDITIONAL_LAYERS) >= 2
    for threads in THREAD_COUNTS:
        many = extract(index, expressions, threads=threads)
        assert many.records_read == one.records_read
        for name in expressions:
            assert many.layers[name].tobytes() == one.layers[name].tobytes(), f"{name} on {threads} threads"
    slow = extract_reference(index, expressions)
    for name, expression in expressions.items():
        np.testing.assert_allclose(one.layers[name], slow[name], rtol=1e-6, atol=1e-9, err_msg=f"{name}: {expression}")


def test_a_layer_without_conditions_is_byte_identical_on_threads(indexed):
    """The path a new layer takes: the where and light frames only, no covariance."""
    lights, index = indexed
    expressions = {"new": f"C<RD>.*<L.'{lights[0]}'>"}
    one = extract(index, expressions, threads=1).layers["new"]
    assert one.sum() > 0
    assert extract(index, expressions, threads=2).layers["new"].tobytes() == one.tobytes()


def test_records_stream_in_chunk_order_on_threads(indexed):
    _, index = indexed
    wanted = list(range(0, len(index.classes), 3))
    for classes, norms in ((None, True), (wanted, False)):
        serial = list(index.records(classes, norms=norms))
        threaded = list(index.records(classes, norms=norms, threads=3))
        assert len(serial) == len(threaded) > 1
        for first, second in zip(serial, threaded):
            for name, column in vars(first).items():
                other = getattr(second, name)
                assert (column is None) == (other is None)
                if column is not None:
                    assert column.dtype == other.dtype and column.tobytes() == other.tobytes(), name


def test_records_of_chosen_chunks_are_those_chunks(indexed):
    _, index = indexed
    every = list(index.records(whole_chunks=True))
    chosen = [1, 4, len(every) - 1]
    for threads in (1, 2):
        picked = list(index.records(chunks=chosen, whole_chunks=True, threads=threads))
        assert len(picked) == len(chosen)
        for number, chunk in zip(chosen, picked):
            assert chunk.pixel.tobytes() == every[number].pixel.tobytes()
            assert chunk.rgb.tobytes() == every[number].rgb.tobytes()


def test_a_bounded_number_of_chunks_is_in_flight(indexed, monkeypatch):
    """However slowly the records are consumed, the reading threads stay at most
    CHUNKS_IN_FLIGHT_PER_THREAD chunks per thread ahead."""
    _, index = indexed
    started = []
    read_chunk = PathIndex._read_chunk

    def counted(self, read, number, *rest):
        started.append(number)
        return read_chunk(self, read, number, *rest)

    monkeypatch.setattr(PathIndex, "_read_chunk", counted)
    threads = 2
    window = threads * reader_module.CHUNKS_IN_FLIGHT_PER_THREAD
    consumed = 0
    for _ in index.records(norms=False, threads=threads):
        consumed += 1
        assert len(started) <= consumed + window
    assert consumed == len(index.chunks) == len(started)


def test_stopping_early_reads_no_further(indexed, monkeypatch):
    _, index = indexed
    started = []
    read_chunk = PathIndex._read_chunk
    monkeypatch.setattr(PathIndex, "_read_chunk",
                        lambda self, read, number, *rest: started.append(number) or read_chunk(self, read, number, *rest))
    stream = index.records(threads=2)
    next(stream)
    stream.close()
    assert len(started) <= 1 + 2 * reader_module.CHUNKS_IN_FLIGHT_PER_THREAD < len(index.chunks)


def test_the_first_bad_chunk_is_named_on_threads(indexed, tmp_path):
    _, index = indexed
    data = bytearray(index.path.read_bytes())
    for number in (3, 5):  # two damaged chunks: the first in file order is the one named
        data[index.chunks[number]["offset"] + fmt.CHUNK_HEADER.size + 7] ^= 0xFF
    bad = tmp_path / "bad.pxlidx"
    bad.write_bytes(bytes(data))
    offset = PathIndex(bad).chunks[3]["offset"]
    for threads in (1, 2, 4):
        with pytest.raises(PathIndexError, match=f"chunk 3 at byte {offset} fails its checksum"):
            extract(PathIndex(bad), {"all": lpe.BEAUTY}, threads=threads)


def test_extraction_threads_reach_extract(indexed, monkeypatch):
    """``pxr-layers extract --threads`` sets extraction_threads around deliver, whose
    extract calls do not name a thread count."""
    _, index = indexed
    seen = []
    records = PathIndex.records

    def spy(self, *args, threads=1, **kwargs):
        seen.append(threads)
        return records(self, *args, threads=threads, **kwargs)

    monkeypatch.setattr(PathIndex, "records", spy)
    with extraction_threads(3):
        extract(index, {"all": lpe.BEAUTY})
    extract(index, {"all": lpe.BEAUTY}, threads=5)
    extract(index, {"all": lpe.BEAUTY})
    assert seen == [3, 5, extract_module.default_threads()]


def test_the_cli_documents_threads(capsys):
    from pxr_layers.cli.main import main

    assert main(["extract", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--threads N" in text and "default: every core" in text and "bit for bit" in text
