"""Tracer throughput against Embree's raw ray casting, side by side in one run.

    python benchmarks/bench_render.py [--resolution 256 256] [--spp 64] [--max-depth 8]

1. Renders the embedded Cornell box with the full tracer on every core, while a recording
   wrapper keeps a copy of the rays of every RECORD_EVERY-th batch (closest-hit and
   shadow queries, in the tracer's own batch sizes).
2. Replays exactly those rays through Embree alone, on the same number of threads.
3. Prints both throughputs and their ratio (target: the tracer reaches ≥ 50 % of raw).
4. Measures the peak resident memory of a 512×512, 64 spp render in a child process
   (target: < 2 GB).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from importlib import resources

import numpy as np

from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings
from pxr_layers.trace.embree import RayCaster
from pxr_layers.trace.render import DEFAULT_BATCH_PATHS, prepare

RECORD_EVERY = 4


class RecordingCaster:
    """Wraps a RayCaster; keeps copies of the queries of selected threads' batches."""

    def __init__(self, caster: RayCaster):
        self.caster = caster
        self.recorded: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
        self.recording = set()

    def intersect(self, origins, directions, t_max):
        self._keep("intersect", origins, directions, t_max)
        return self.caster.intersect(origins, directions, t_max)

    def occluded(self, origins, directions, t_max):
        self._keep("occluded", origins, directions, t_max)
        return self.caster.occluded(origins, directions, t_max)

    def _keep(self, kind, origins, directions, t_max):
        import threading

        if threading.get_ident() in self.recording:
            self.recorded.append((kind, origins.copy(), directions.copy(), t_max.copy()))


def cornell_path() -> str:
    return str(resources.files("pxr_layers.render").joinpath("cornell.usda"))


def trace_all(integrator, total_paths: int, spp: int, threads: int, recorder: RecordingCaster | None):
    """Render every batch on `threads` threads; returns (seconds, rays, paths)."""
    import threading

    batch = max(spp, DEFAULT_BATCH_PATHS // spp * spp)
    starts = list(range(0, total_paths, batch))

    def run(index_and_start):
        index, first = index_and_start
        if recorder is not None and index % RECORD_EVERY == 0:
            recorder.recording.add(threading.get_ident())
        try:
            return integrator.trace(first, min(first + batch, total_paths)).rays
        finally:
            if recorder is not None:
                recorder.recording.discard(threading.get_ident())

    start = time.perf_counter()
    with ThreadPoolExecutor(threads) as pool:
        rays = sum(pool.map(run, enumerate(starts)))
    return time.perf_counter() - start, rays


def replay(caster: RayCaster, queries, threads: int):
    """Cast the recorded queries again through Embree only; returns (seconds, rays)."""

    def run(query):
        kind, origins, directions, t_max = query
        if kind == "intersect":
            caster.intersect(origins, directions, t_max)
        else:
            caster.occluded(origins, directions, t_max)
        return origins.shape[1]  # (3, n)

    start = time.perf_counter()
    with ThreadPoolExecutor(threads) as pool:
        rays = sum(pool.map(run, queries))
    return time.perf_counter() - start, rays


def peak_memory_of_render(resolution, spp, max_depth) -> float:
    """Peak resident set (bytes) of a child process rendering the Cornell box."""
    code = (
        "import resource, sys, dataclasses\n"
        "from pxr_layers.stage import load_stage\n"
        "from pxr_layers.trace import TraceSettings, render\n"
        f"scene, spec = load_stage({cornell_path()!r})\n"
        f"spec = dataclasses.replace(spec, resolution=({resolution[0]}, {resolution[1]}))\n"
        f"render(scene, spec, TraceSettings(spp={spp}, max_depth={max_depth}), show_progress=False)\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    )
    start = time.perf_counter()
    output = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    seconds = time.perf_counter() - start
    return int(output.split()[-1]) * 1024, seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256))
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--skip-memory", action="store_true", help="skip the 512×512 peak-memory render")
    args = parser.parse_args()

    import dataclasses

    scene, spec = load_stage(cornell_path())
    spec = dataclasses.replace(spec, resolution=tuple(args.resolution))
    settings = TraceSettings(spp=args.spp, max_depth=args.max_depth)
    integrator = prepare(scene, spec, settings)
    recorder = RecordingCaster(integrator.caster)
    integrator.caster = recorder
    width, height = spec.resolution
    total_paths = width * height * settings.spp

    trace_seconds, trace_rays = trace_all(integrator, total_paths, settings.spp, args.threads, recorder)
    raw_seconds, raw_rays = replay(recorder.caster, recorder.recorded, args.threads)

    tracer_rate = trace_rays / trace_seconds
    raw_rate = raw_rays / raw_seconds
    print(f"scene            : cornell.usda, {integrator.world.triangle_count} triangles")
    print(f"settings         : {width}x{height}, {settings.spp} spp, max depth {settings.max_depth}, "
          f"{args.threads} threads")
    print(f"tracer           : {trace_seconds:8.2f} s  {trace_rays:>12,d} rays  {tracer_rate / 1e6:7.3f} M rays/s  "
          f"{total_paths / trace_seconds / 1e6:7.3f} M samples/s")
    print(f"embree raw replay: {raw_seconds:8.2f} s  {raw_rays:>12,d} rays  {raw_rate / 1e6:7.3f} M rays/s "
          f"(every {RECORD_EVERY}th batch's rays, same batch sizes)")
    print(f"ratio tracer/raw : {tracer_rate / raw_rate:.3f}   (target >= 0.50)")

    if not args.skip_memory:
        peak, seconds = peak_memory_of_render((512, 512), 64, args.max_depth)
        print(f"peak memory      : {peak / 2**30:.2f} GiB for 512x512, 64 spp ({seconds:.0f} s)   (target < 2 GiB)")
    print(f"this process     : {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GiB peak")
    return 0


if __name__ == "__main__":
    sys.exit(main())
