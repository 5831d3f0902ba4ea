"""Shot jobs on Dask: two workers against one, and the job against `pxr-layers render`, in one run.

    python benchmarks/bench_jobs.py [--frames 1-8] [--spp 32] [--resolution 160 120] [--repeats 3]

The example shot (pipelines/shows/demo/shot010.toml: the animated showcase, three products
with previews, per-light layers, the paper's selections) is rendered over the same frames
and settings, into fresh directories:

* the job on a LocalCluster of 1 single-threaded worker;
* the job on a LocalCluster of 2 single-threaded workers (target: >= 1.7x the throughput
  of 1 on this 2-core machine);
* the baseline for that ratio: the frames rendered by ``pxr-layers render --threads 1``
  in 1 process, then split between 2 independent processes (no Dask, no shared work: what
  2 cores give this render when nothing is coordinated, at the time of the run);
* each frame with ``pxr-layers render`` in this process with 2 render threads, the direct
  way a user would take.

The job's overhead is its time over the independent processes' on the same cores, and over
the direct render.

The machine's 2 cores are shared with other machines' work, so timings vary from run to
run by 10-30 %, and the hypervisor takes whole seconds at times (each run prints the CPU
time it stole): each repeat runs the job on 1 then 2 workers, then 1 then 2 processes, back
to back; the fastest run of each is kept, and each repeat's own ratios are printed too.
Cluster and process start-up are outside the timings (a farm's workers are up before a job
comes); everything a frame needs (stage read, Embree build, tracing, index, extraction,
EXRs, previews) is inside. The EXRs of the job runs and the direct render are checked equal
pixel for pixel.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR
import psutil
from distributed import Client

from pxr_layers.cli.main import main as cli
from pxr_layers.jobs import load_job
from pxr_layers.jobs.executor import run_job
from pxr_layers.jobs.workers import local_cluster

SHOT = Path(__file__).resolve().parents[1] / "pipelines" / "shows" / "demo" / "shot010.toml"
TARGET_SPEEDUP = 1.7
ENVIRONMENT = dict(os.environ)
"""This process's environment before any cluster: a Dask nanny writes its workers' settings
(MALLOC_TRIM_THRESHOLD_, OMP_NUM_THREADS) into os.environ before it spawns them."""


def stolen_seconds() -> float:
    """CPU seconds the hypervisor has given other machines (all CPUs, since boot)."""
    return getattr(psutil.cpu_times(), "steal", 0.0)


def job_seconds(job, workers: int) -> float:
    with local_cluster(workers, dashboard_address=None) as cluster, Client(cluster) as client:  # as `job run` starts it
        start = time.perf_counter()
        report = run_job(job, client=client)
        seconds = time.perf_counter() - start
    assert len(report.rendered) == len(job.frames)
    return seconds


def render_frames(job, frames, threads: int, directory: Path) -> None:
    """``pxr-layers render`` of each frame, as the job would render it."""
    for frame in frames:
        args = ["render", str(job.request.stage), "--frame", f"{frame:g}", "--spp", str(job.request.spp), "--resolution",
                *map(str, job.request.resolution), "--max-depth", str(job.request.max_depth),
                "--seed", str(job.request.seed), "--threads", str(threads), "-o", str(directory), "--quiet"]
        if job.request.norm_bounces is not None:
            args += ["--norm-bounces", str(job.request.norm_bounces)]
        if job.request.per_light:
            args += ["--per-light", job.request.per_light]
        for layer in job.request.recipe_layers:
            args += ["--recipe", str(layer)]
        with contextlib.redirect_stdout(io.StringIO()):  # the paths it wrote
            assert cli(args) == 0


def render_seconds(job, directory: Path) -> float:
    start = time.perf_counter()
    render_frames(job, job.frames, 2, directory)
    return time.perf_counter() - start


def _process(job, frames, directory: Path, started, finished) -> None:
    started.wait()  # imports done in every process: the parent starts the clock
    render_frames(job, frames, 1, directory)
    finished.put(True)


def processes_seconds(job, processes: int, directory: Path) -> float:
    """The frames split between ``processes`` independent single-threaded renders."""
    context = multiprocessing.get_context("spawn")
    started, finished = context.Barrier(processes + 1), context.Queue()
    shares = [job.frames[number::processes] for number in range(processes)]
    children = [context.Process(target=_process, args=(job, share, directory, started, finished)) for share in shares]
    polluted = dict(os.environ)
    os.environ.clear()
    os.environ.update(ENVIRONMENT)  # plain processes, as a user's shell starts them
    try:
        for child in children:
            child.start()
    finally:
        os.environ.clear()
        os.environ.update(polluted)
    started.wait()
    start = time.perf_counter()
    for _ in children:
        finished.get()
    seconds = time.perf_counter() - start
    for child in children:
        child.join()
        assert child.exitcode == 0
    return seconds


def same_pixels(job_directory: Path, render_directory: Path, frame: float) -> bool:
    ours = OpenEXR.File(str(job_directory / f"shot010.{frame:04.0f}.light_passes.exr"))
    theirs = OpenEXR.File(str(render_directory / f"light_passes.{frame:04.0f}.exr"))
    return all(np.array_equal(a.channels[name].pixels, b.channels[name].pixels)
               for a, b in zip(ours.parts, theirs.parts, strict=True) for name in a.channels)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", default="1-8")
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--resolution", type=int, nargs=2, default=(160, 120))
    parser.add_argument("--repeats", type=int, default=3, help="runs of each configuration; the fastest is kept")
    args = parser.parse_args()
    logging.getLogger("distributed").setLevel(logging.ERROR)
    times: dict[str, list[float]] = {"job 1": [], "job 2": [], "processes 1": [], "processes 2": []}
    stolen: dict[str, list[float]] = {name: [] for name in times}
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)

        def job_in(name: str):
            return load_job(SHOT, {"frames": args.frames, "render.spp": args.spp,
                                   "render.resolution": list(args.resolution), "output.directory": str(root / name)})

        def timed(name: str, run, *arguments) -> None:
            before = stolen_seconds()
            times[name].append(run(*arguments))
            stolen[name].append(stolen_seconds() - before)

        for repeat in range(args.repeats):  # each pair of runs back to back
            for workers in (1, 2):
                timed(f"job {workers}", job_seconds, job_in(f"job{workers}.{repeat}"), workers)
            for workers in (1, 2):
                job = job_in(f"processes{workers}.{repeat}")
                timed(f"processes {workers}", processes_seconds, job, workers, job.output_directory)
        job = job_in("render")
        direct = render_seconds(job, root / "render")
        for name in ("job1.0", "job2.0"):
            assert all(same_pixels(root / name, root / "render", frame) for frame in job.frames)
    best = {name: min(values) for name, values in times.items()}
    frames = len(job.frames)

    def line(label: str, name: str) -> str:
        runs = ", ".join(f"{value:.1f}" for value in times[name])
        steal = ", ".join(f"{value:.1f}" for value in stolen[name])
        return (f"  {label:<34}: {best[name]:6.1f} s  ({frames / best[name] * 60:5.1f} frames/min; runs {runs} s; "
                f"CPU stolen by the hypervisor {steal} s)")

    def paired_ratios(kind: str) -> str:
        ratios = [one / two for one, two in zip(times[f"{kind} 1"], times[f"{kind} 2"], strict=True)]
        return (f"    run by run (1 then 2, back to back): {', '.join(f'{value:.2f}' for value in ratios)}x, "
                f"median {float(np.median(ratios)):.2f}x")

    print(f"shot010 frames {args.frames} ({frames}), {args.resolution[0]}x{args.resolution[1]}, {args.spp} spp, "
          f"max depth {job.request.max_depth}, 3 products with previews; fastest of {args.repeats} interleaved runs")
    print(line("job, 1 worker", "job 1"))
    print(line("job, 2 workers", "job 2"))
    speedup = best["job 1"] / best["job 2"]
    print(f"  throughput 2 workers / 1 worker: {speedup:.2f}x (target >= {TARGET_SPEEDUP}x: "
          f"{'met' if speedup >= TARGET_SPEEDUP else 'MISSED'})")
    print(paired_ratios("job"))
    print(line("pxr-layers render, 1 process", "processes 1"))
    print(line("pxr-layers render, 2 processes", "processes 2"))
    ceiling = best["processes 1"] / best["processes 2"]
    print(f"  baseline, 2 independent processes / 1: {ceiling:.2f}x (the job's ratio is {speedup / ceiling:.0%} of it)")
    print(paired_ratios("processes"))
    for workers in (1, 2):
        overhead = best[f"job {workers}"] / best[f"processes {workers}"]
        print(f"  job overhead on {workers} core{'s' * (workers > 1)} (job / independent processes): {overhead:.2f}x "
              f"({(overhead - 1) * 100:+.0f} %)")
    print(f"  pxr-layers render, frame by frame, 2 threads: {direct:6.1f} s")
    print(f"  job on 2 workers vs that direct render: {best['job 2'] / direct:.2f}x "
          f"({(best['job 2'] / direct - 1) * 100:+.0f} %)")
    print("  outputs: the same pixels from the jobs and the direct render")


if __name__ == "__main__":
    main()
