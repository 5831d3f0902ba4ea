"""Shot jobs on a real Dask LocalCluster: the example shot end to end, the same bytes
whatever the split and the worker count, resume, and a worker killed mid-job."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import dask
import numpy as np
import OpenEXR
import pytest
from distributed import Client
from test_cli import SCRIPT

from pxr_layers.jobs import load_job
from pxr_layers.jobs.executor import _scratch as scratch_folder
from pxr_layers.jobs.executor import (
    done_record,
    frame_plan,
    render_tile,
    run_job,
    tile_file,
    tiles,
)
from pxr_layers.jobs.workers import LOCAL_CLUSTER_CONFIG, local_cluster

REPO = Path(__file__).resolve().parents[1]
SHOT = REPO / "pipelines" / "shows" / "demo" / "shot010.toml"
PASSES = ("emission", "background", "diffuse_direct", "diffuse_indirect", "glossy_direct", "glossy_indirect",
          "transmission", "volume")
# 64 spp: the tracer's batches hold 1024 pixels, so a 64x48 frame is 3 batches (3 tiles at most)
SMALL = {"render.spp": 64, "render.resolution": [64, 48], "render.max_depth": 4}


def job_at(directory: Path, **overrides):
    return load_job(SHOT, {**SMALL, "frames": "1-2", "output.directory": str(directory), **overrides})


def deliverables(directory: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(directory.iterdir())
            if path.suffix in (".exr", ".pxlidx")}


@pytest.fixture(scope="module")
def client():
    with local_cluster(2, dashboard_address=":0") as cluster, \
            Client(cluster) as dask:
        yield dask


@pytest.fixture(scope="module")
def reference(tmp_path_factory, client):
    """Frames 1-2 of the example shot, one tile per frame, on two workers."""
    directory = tmp_path_factory.mktemp("reference")
    job = job_at(directory, **{"dask.batch_pixels": 1_000_000})
    report = run_job(job, client=client)
    return job, report, deliverables(directory)


def rgb(part: OpenEXR.Part, name: str) -> np.ndarray:
    channels = part.channels
    if name in channels:
        return np.asarray(channels[name].pixels, np.float64)
    return np.stack([channels[f"{name}.{c}"].pixels for c in "RGB"], axis=-1).astype(np.float64)


def test_the_example_shot_runs_end_to_end(reference):
    job, report, files = reference
    assert report.rendered == [1.0, 2.0] and report.skipped == []
    assert {"shot010.0001.pxlidx", "shot010.0002.pxlidx", "shot010.0001.light_passes.exr",
            "shot010.0002.showcase_selections.exr", "shot010.0002.sphere.exr"} <= set(files)
    beauties, layer_sets = [], []
    for frame in (1, 2):
        parts = {part.name(): part for part in OpenEXR.File(str(job.output_directory /
                                                                f"shot010.000{frame}.light_passes.exr")).parts}
        beauty = np.asarray(parts["rgba"].channels["RGBA"].pixels, np.float64)[..., :3]
        np.testing.assert_allclose(sum(rgb(parts[name], name) for name in PASSES), beauty, rtol=1e-5, atol=1e-6)
        beauties.append(beauty)
        layer_sets.append(list(parts))
        assert done_record(job, frame).exists() and not job.frame_directory(frame).exists()
    assert layer_sets[0] == layer_sets[1]  # the same recipe gives the same layers on every frame
    assert np.abs(beauties[0] - beauties[1]).max() > 0.01  # the shot is animated


@pytest.mark.parametrize(("wanted", "expected"), [(1, [1024] * 3), (1500, [1024] * 3), (2048, [2048, 1024]),
                                                  (2500, [2048, 1024]), (3072, [3072]), (10**6, [3072])])
def test_tiles_are_the_fewest_equal_runs_of_whole_batches(tmp_path, wanted, expected):
    plan = frame_plan(job_at(tmp_path), 1.0)  # 64x48 pixels, 1024 per batch
    ranges = tiles(plan, wanted)
    assert [stop - first for first, stop in ranges] == expected
    assert ranges[0][0] == 0 and ranges[-1][1] == plan.pixels
    assert all(stop == following for (_, stop), (following, _) in itertools.pairwise(ranges))
    assert all(first % 1024 == 0 for first, _ in ranges)


def test_same_bytes_whatever_the_split_and_the_worker_count(tmp_path, reference):
    _, _, expected = reference
    split = job_at(tmp_path / "split", **{"dask.batch_pixels": 1})
    assert len(tiles(frame_plan(split, 1.0), split.batch_pixels)) == 3
    with local_cluster(1, dashboard_address=":0") as cluster, \
            Client(cluster) as one_worker:
        report = run_job(split, client=one_worker)
    assert report.tiles_rendered == 6
    assert deliverables(tmp_path / "split") == expected


def test_a_frame_is_the_same_as_pxr_layers_render(tmp_path, reference):
    job, _, _ = reference
    command = [SCRIPT, "render", str(job.request.stage), "--frame", "1", "--spp", "64", "--resolution", "64", "48",
               "--max-depth", "4", "--per-light", "lights", "--seed",
               str(job.request.seed), "-o", str(tmp_path), "--quiet", "--no-previews"]
    if job.request.norm_bounces is not None:  # else both apply the request's norm-bounce rule
        command += ["--norm-bounces", str(job.request.norm_bounces)]
    for layer in job.request.recipe_layers:
        command += ["--recipe", str(layer)]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    rendered = OpenEXR.File(str(tmp_path / "light_passes.0001.exr"))
    from_job = OpenEXR.File(str(job.output_directory / "shot010.0001.light_passes.exr"))
    for ours, theirs in zip(from_job.parts, rendered.parts, strict=True):
        assert ours.name() == theirs.name()
        for name, channel in ours.channels.items():
            assert np.array_equal(channel.pixels, theirs.channels[name].pixels), (ours.name(), name)


def test_resume_skips_done_frames_and_reuses_committed_tiles(tmp_path, client, reference):
    _, _, expected = reference
    job = job_at(tmp_path, **{"dask.batch_pixels": 1})
    # An interrupted run: frame 1 has its first tile committed, frame 2 every tile but not
    # its data (the data then comes from a task of its own).
    for frame, committed in ((1.0, slice(0, 1)), (2.0, slice(None))):
        plan = frame_plan(job, frame)
        tile_list = tiles(plan, job.batch_pixels)
        folder = scratch_folder(job, plan, tile_list)
        for first, stop in tile_list[committed]:
            render_tile(plan, first, stop, str(tile_file(folder, first, stop)))
    report = run_job(job, client=client)
    assert report.rendered == [1.0, 2.0] and report.tiles_reused == 4 and report.tiles_rendered == 2
    assert deliverables(tmp_path) == expected
    # Done frames are skipped; a frame whose commit record is gone is rendered again.
    stamp = (tmp_path / "shot010.0001.light_passes.exr").stat().st_mtime_ns
    done_record(job, 2.0).unlink()
    report = run_job(job, client=client)
    assert report.skipped == [1.0] and report.rendered == [2.0]
    assert (tmp_path / "shot010.0001.light_passes.exr").stat().st_mtime_ns == stamp
    assert deliverables(tmp_path) == expected
    status = subprocess.run([SCRIPT, "job", "status", str(SHOT), "-o", str(tmp_path)], capture_output=True,
                            text=True, check=False)
    assert status.returncode == 0 and "shot010.0001  done" in status.stdout and "shot010.0003  pending" in status.stdout


@pytest.mark.slow
def test_a_worker_killed_mid_job_corrupts_nothing(tmp_path, reference):
    _, _, expected = reference
    job = job_at(tmp_path, **{"dask.batch_pixels": 1})
    with local_cluster(2, dashboard_address=":0") as cluster, \
            Client(cluster) as dask:
        outcome: dict = {}
        runner = threading.Thread(target=lambda: outcome.update(report=run_job(job, client=dask)))
        runner.start()
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("*/tile.*.pkl")) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not done_record(job, 2.0).exists(), "the job ended before a worker could be killed"
        victim = next(iter(dask.run(os.getpid).values()))
        os.kill(victim, signal.SIGKILL)
        runner.join(timeout=300)
        dask.wait_for_workers(2, timeout=60)
        assert worker_settings(dask) == [LOCAL_CLUSTER_CONFIG] * 2, "the restarted worker keeps the cluster's pace"
    assert sorted(outcome["report"].rendered) == [1.0, 2.0]
    assert deliverables(tmp_path) == expected
    assert not [path for path in tmp_path.rglob("*") if ".tmp" in path.name]


def worker_settings(client) -> list[dict]:
    """LOCAL_CLUSTER_CONFIG's keys as each worker process has them."""
    return list(client.run(lambda: {key: dask.config.get(key) for key in LOCAL_CLUSTER_CONFIG}).values())


def test_jobs_tune_their_workers(client, reference):
    """After a job, its workers run without Dask's statistical profiler, and the local
    cluster's workers keep house at the pace local_cluster sets (see jobs/workers.py)."""
    profiling = client.run(lambda dask_worker: sorted(set(dask_worker.periodic_callbacks) & {"profile", "profile-cycle"}))
    assert len(profiling) == 2 and all(names == [] for names in profiling.values())
    assert worker_settings(client) == [LOCAL_CLUSTER_CONFIG] * 2
    assert dask.config.get("distributed.admin.tick.interval") != LOCAL_CLUSTER_CONFIG["distributed.admin.tick.interval"], \
        "the cluster's settings stay out of the process that started it"


def test_job_run_from_the_command_line(tmp_path):
    """`pxr-layers job run` on its own LocalCluster: a summary on stdout, frame progress on
    stderr without Dask's chatter, then a second run that skips the done frame; a bad
    frame range is a user error (1) naming the key, a bad flag a usage error (2)."""
    command = [SCRIPT, "job", "run", str(SHOT), "--frames", "3", "--spp", "4", "--resolution", "32", "24",
               "--workers", "1", "-o", str(tmp_path)]
    first = subprocess.run(command, capture_output=True, text=True, check=False, timeout=300)
    assert first.returncode == 0, first.stderr
    assert "shot010: 1 frames rendered, 0 already done" in first.stdout
    assert "frame 3: done (1 of 1 frames)" in first.stderr
    assert "Nanny" not in first.stderr and "Scheduler" not in first.stderr  # Dask's INFO lines
    assert (tmp_path / "shot010.0003.light_passes.exr").exists() and done_record(job_at(tmp_path), 3.0).exists()
    again = subprocess.run(command, capture_output=True, text=True, check=False, timeout=300)
    assert again.returncode == 0 and "0 frames rendered, 1 already done" in again.stdout
    bad = subprocess.run([*command[:4], "--frames", "1-x"], capture_output=True, text=True, check=False)
    assert bad.returncode == 1 and "frames" in bad.stderr and bad.stderr.count("\n") == 1
    usage = subprocess.run([*command[:4], "--spp", "many"], capture_output=True, text=True, check=False)
    assert usage.returncode == 2


def test_a_user_error_in_a_task_is_raised_once_not_retried(tmp_path, client):
    from pxr_layers.errors import PxrLayersError
    from test_cli import ball_lit_by

    stage = tmp_path / "nan.usda"  # a light value refused when the task reads the frame
    stage.write_text(ball_lit_by('    def SphereLight "key"\n    {\n        float inputs:intensity = nan\n    }'))
    job_file = tmp_path / "nan.toml"
    job_file.write_text(f'stage = "{stage.name}"\nframes = "1"\n[render]\nspp = 4\nresolution = [16, 16]\n'
                        f'[output]\ndirectory = "out"\n[dask]\nretries = 2\n')
    job = load_job(job_file)
    started = time.perf_counter()
    with pytest.raises(PxrLayersError, match="/World/key: inputs:intensity is nan"):
        run_job(job, client=client)
    assert time.perf_counter() - started < 60
    assert not list((tmp_path / "out").glob("*.exr")) and not list((tmp_path / "out").glob("*.pxlidx"))


CRYPTO_RECIPE = """#usda 1.0
(
    renderSettingsPrimPath = "/Render/Crypto/Settings"
)

def Scope "Render"
{
    def Scope "Crypto"
    {
        def RenderSettings "Settings"
        {
            rel products = </Render/Crypto/ids>
        }

        def RenderProduct "ids"
        {
            rel orderedVars = </Render/Crypto/Vars/CryptoObject>
            token productName = "ids.exr"
        }

        def Scope "Vars"
        {
            def RenderVar "CryptoObject"
            {
                uniform token sourceType = "raw"
                uniform string sourceName = "CryptoObject"
                uniform token dataType = "float4"
            }
        }
    }
}
"""


def test_a_job_delivers_the_cryptomattes_its_recipe_asks_for(tmp_path, client):
    """A job renders a frame's Cryptomattes from its tiles' first hits: cut into 3 tiles, each
    pixel's coverages still sum to its alpha."""
    recipe = tmp_path / "crypto.usda"
    recipe.write_text(CRYPTO_RECIPE)
    out = tmp_path / "out"
    job = job_at(out, frames="1", **{"recipe.add_layers": [str(recipe)], "dask.batch_pixels": 1})
    assert len(tiles(frame_plan(job, 1.0), job.batch_pixels)) == 3
    run_job(job, client=client)
    parts = OpenEXR.File(str(out / "shot010.0001.ids.exr"), separate_channels=True).parts
    crypto = [part for part in parts if part.name().startswith("Crypto")]
    assert [part.name() for part in crypto] == ["CryptoObject00", "CryptoObject01", "CryptoObject02"]
    coverage = sum(part.channels[f"{part.name()}.{c}"].pixels.astype(np.float64)
                   for part in crypto for c in "GA")
    alpha = np.asarray(parts[0].channels["A"].pixels, np.float64)
    assert alpha.max() > 0 and np.allclose(coverage, alpha, atol=1e-6)


FRAME_NAMED_RECIPE = """#usda 1.0
(
    renderSettingsPrimPath = "/Render/Named/Settings"
)

def Scope "Render"
{
    def Scope "Named"
    {
        def RenderSettings "Settings"
        {
            rel products = </Render/Named/beauty>
            int2 resolution = (40, 30)
        }

        def RenderProduct "beauty"
        {
            token productName = "cornell.####.exr"
            rel orderedVars = </Render/Named/diffuse>
        }

        def RenderVar "diffuse"
        {
            uniform token sourceType = "lpe"
            uniform string sourceName = "C<RD>.*"
        }
    }
}
"""


def test_render_and_a_one_frame_job_write_the_same_bytes(tmp_path):
    """`pxr-layers render` and `pxr-layers job run` with the same options, Cryptomattes and a
    Nuke script included, write byte-identical files: one request, one frame entry."""
    recipe = tmp_path / "named.usda"
    recipe.write_text(FRAME_NAMED_RECIPE)
    stage = REPO / "render" / "cornell.usda"
    options = ["--recipe", str(recipe), "--spp", "4", "--max-depth", "3", "--seed", "7",
               "--cryptomatte", "object,material", "--cryptomatte-depth", "2", "--nuke-script", "--no-previews"]
    job_file = tmp_path / "one.toml"
    job_file.write_text(f'stage = "{stage}"\nframes = "1"\n[output]\ndirectory = "job"\nstem = "cornell.$F4"\n')
    rendered = subprocess.run([SCRIPT, "render", str(stage), "--frame", "1", "-o", str(tmp_path / "render"),
                               "--quiet", *options], capture_output=True, text=True, check=False, timeout=600)
    assert rendered.returncode == 0, rendered.stderr
    ran = subprocess.run([SCRIPT, "job", "run", str(job_file), "--workers", "1", "--quiet", *options],
                         capture_output=True, text=True, check=False, timeout=600)
    assert ran.returncode == 0, ran.stderr
    names = ("cornell.0001.exr", "cornell.0001.pxlidx", "cornell.0001.nk")
    for name in names:
        assert (tmp_path / "render" / name).read_bytes() == (tmp_path / "job" / name).read_bytes(), name
    parts = [part.name() for part in OpenEXR.File(str(tmp_path / "job" / names[0])).parts]
    assert parts == ["rgba", "diffuse", "CryptoObject00", "CryptoMaterial00"]


def test_a_job_denoises_its_frames_from_their_tiles_guides(tmp_path, client):
    """render.denoise in a job: each frame's denoised twin, its guides summed from 3 tiles,
    equal to the same frame rendered in one piece (the twin is a function of the frame)."""
    out = tmp_path / "out"
    job = job_at(out, frames="1", **{"render.denoise": True, "dask.batch_pixels": 1})
    assert len(tiles(frame_plan(job, 1.0), job.batch_pixels)) == 3
    run_job(job, client=client)
    whole = tmp_path / "whole"
    run_job(job_at(whole, frames="1", **{"render.denoise": True, "dask.batch_pixels": 1_000_000}), client=client)
    twins = sorted(path.name for path in out.glob("*.denoised.exr"))
    assert twins and twins == sorted(path.name for path in whole.glob("*.denoised.exr"))
    for name in twins:
        assert (out / name).read_bytes() == (whole / name).read_bytes()


def test_job_suggest_is_the_suggest_search_on_the_frames_done(tmp_path, reference, capsys):
    """`pxr-layers job suggest`: one layer set for the job's done frames, the very search of
    `pxr-layers suggest` (and of the inspector's /api/suggest); no frame done is one line."""
    import argparse

    from pxr_layers.cli import job as job_command
    from pxr_layers.paths.reader import PathIndex
    from pxr_layers.stage import load_recipe
    from pxr_layers.suggest import suggest

    job, _, _ = reference
    parser = argparse.ArgumentParser()
    job_command.add_arguments(parser)
    recipe = tmp_path / "shot.usda"
    arguments = ["suggest", str(SHOT), "--directory", str(job.output_directory), "-k", "3", "-o", str(recipe),
                 "--no-exr"]
    assert job_command.run(parser.parse_args(arguments)) == 0
    printed = capsys.readouterr().out
    expected = suggest([PathIndex(job.index_path(frame)) for frame in (1.0, 2.0)], 3)
    recipe_read = load_recipe(job.request.stage, recipe_layers=[recipe])
    layers = {layer.name: layer for product in recipe_read.products if product.name == "shot"
              for layer in product.layers}
    assert {name: layer.source_name for name, layer in layers.items()} == expected.layers
    assert {name: layer.description for name, layer in layers.items()} == expected.explanations
    assert all(text in printed for text in expected.explanations.values())
    with pytest.raises(Exception, match="no frame is done"):
        job_command.run(parser.parse_args(["suggest", str(SHOT), "--directory", str(tmp_path / "empty")]))
