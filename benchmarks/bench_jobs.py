"""Shot jobs on Dask: two workers against one, and the job against `pxr-layers render`, in one run.

    python benchmarks/bench_jobs.py [--frames 1-4] [--spp 32] [--resolution 160 120]

The example shot (pipelines/shows/demo/shot010.toml: the animated showcase, three products
with previews, per-light layers, the paper's selections) is rendered three times over the
same frames and settings, into fresh directories:

* the job on a LocalCluster of 1 single-threaded worker;
* the job on a LocalCluster of 2 single-threaded workers (target: >= 1.7x the throughput
  of 1 on this 2-core machine);
* each frame with ``pxr-layers render`` (in this process, 2 render threads), the direct
  way: the job's overhead is its time on 2 workers over this one.

Cluster start-up is outside the timings (a farm's workers are up before a job comes);
everything a frame needs (stage read, Embree build, tracing, index, extraction, EXRs,
previews) is inside. The three runs' EXRs are checked equal pixel for pixel.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR
from distributed import Client, LocalCluster

from pxr_layers.cli.main import main as cli
from pxr_layers.jobs import load_job
from pxr_layers.jobs.executor import run_job

SHOT = Path(__file__).resolve().parents[1] / "pipelines" / "shows" / "demo" / "shot010.toml"
TARGET_SPEEDUP = 1.7


def job_seconds(job, workers: int) -> float:
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        start = time.perf_counter()
        report = run_job(job, client=client)
        seconds = time.perf_counter() - start
    assert len(report.rendered) == len(job.frames)
    return seconds


def render_seconds(job, directory: Path) -> float:
    start = time.perf_counter()
    for frame in job.frames:
        args = ["render", str(job.stage), "--frame", f"{frame:g}", "--spp", str(job.spp), "--resolution",
                *map(str, job.resolution), "--max-depth", str(job.max_depth), "--norm-bounces", str(job.norm_bounces),
                "--seed", str(job.seed), "--threads", "2", "-o", str(directory), "--quiet"]
        if job.per_light:
            args += ["--per-light", job.per_light]
        for layer in job.recipe_layers:
            args += ["--recipe", str(layer)]
        with contextlib.redirect_stdout(io.StringIO()):  # the paths it wrote
            assert cli(args) == 0
    return time.perf_counter() - start


def same_pixels(job_directory: Path, render_directory: Path, frame: float) -> bool:
    ours = OpenEXR.File(str(job_directory / f"shot010.{frame:04.0f}.light_passes.exr"))
    theirs = OpenEXR.File(str(render_directory / f"light_passes.{frame:04.0f}.exr"))
    return all(np.array_equal(a.channels[name].pixels, b.channels[name].pixels)
               for a, b in zip(ours.parts, theirs.parts, strict=True) for name in a.channels)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", default="1-4")
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--resolution", type=int, nargs=2, default=(160, 120))
    args = parser.parse_args()
    logging.getLogger("distributed").setLevel(logging.ERROR)
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)

        def job_in(name: str):
            return load_job(SHOT, {"frames": args.frames, "render.spp": args.spp,
                                   "render.resolution": list(args.resolution), "output.directory": str(root / name)})

        one = job_seconds(job_in("one"), 1)
        two = job_seconds(job_in("two"), 2)
        job = job_in("render")
        direct = render_seconds(job, root / "render")
        assert all(same_pixels(root / "two", root / "render", frame) for frame in job.frames)
        assert all(same_pixels(root / "one", root / "render", frame) for frame in job.frames)
    frames = len(job.frames)
    print(f"shot010 frames {args.frames} ({frames}), {args.resolution[0]}x{args.resolution[1]}, {args.spp} spp, "
          f"max depth {job.max_depth}, 3 products with previews")
    print(f"  job, 1 worker   : {one:7.1f} s  ({frames / one * 60:5.1f} frames/min)")
    print(f"  job, 2 workers  : {two:7.1f} s  ({frames / two * 60:5.1f} frames/min)")
    speedup = one / two
    print(f"  throughput 2 workers / 1 worker: {speedup:.2f}x (target >= {TARGET_SPEEDUP}x: "
          f"{'met' if speedup >= TARGET_SPEEDUP else 'MISSED'})")
    print(f"  pxr-layers render, frame by frame, 2 threads: {direct:7.1f} s")
    print(f"  job overhead (2 workers vs direct render): {two / direct:.2f}x ({(two / direct - 1) * 100:+.0f} %)")
    print("  outputs: the same pixels in all three runs")


if __name__ == "__main__":
    main()
