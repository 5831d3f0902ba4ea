"""The tracer's benchmark figures, each a ratio measured side by side in one run.

    python benchmarks/bench_render.py [--quick] [--resolution 256 256] [--spp 64] [--threads N]

1. Tracer vs raw Embree, on three stages (the embedded Cornell box, the showcase and a
   generated stage of >= 1 M triangles): the tracer renders every batch on the thread pool
   of ``trace_pixels`` while a wrapper around ``integrator.caster`` keeps a copy of the rays
   of every RECORD_EVERY-th batch (closest-hit and shadow queries, in the tracer's own batch
   sizes) and times every Embree call; those rays are then cast again through Embree alone
   on the same number of threads. Ratio: tracer rays/s over raw rays/s (target >= 0.5).
2. Index overhead: the CLI's whole-process wall time on the Cornell box with the path index
   over the same without (``--no-index``), best of REPEATS each (target <= +15 %); and in
   process, ``render_frame`` with the index over ``render_frame`` with the same norm bounces
   and no index; split into recording (the tracer's ``trace_pixels`` on a prepared scene with
   and without record_paths) and the rest (writing the index).
3. Threads: trace_pixels on a prepared, warmed-up integrator with 2 threads over 1 (start-up
   excluded), without and with the path index (target >= 1.8x).
4. Peak memory: the CLI rendering 1920x1080 at 16 spp with the index, in a child whose peak
   resident set is read by an intermediate process from RUSAGE_CHILDREN (target < 4 GiB).
   Skipped with --quick.
5. Cold start: the CLI rendering the Cornell box at 64x64, 4 spp with PXR_LAYERS_CACHE_DIR a
   fresh empty folder (every kernel compiled), then again with the same folder (cached).

The machine may be shared: before each figure the benchmark waits (--wait seconds at most)
for other processes to leave the CPU, and any measurement during which they used more than
BUSY_NOTE cores (from /proc/stat, minus this process and its children) is listed at the end.
A CLI warm-up render first compiles the kernels if this version of the sources is new.

Exit 0 whether targets are met or missed; 1 if something fails.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path

import numpy as np

from pxr_layers.cores import available_cores
import pxr_layers.stage  # noqa: F401 — registers the pxr-layers schema before any stage is opened

RECORD_EVERY = 4
REPEATS = 2
BIG_GRID = 708  # 708 x 708 quads = 1,002,528 triangles
GIB = 2**30

ROWS: list[tuple[str, str, str, bool | None]] = []  # (figure, value, target, met)


def row(figure: str, value: str, target: str = "", met: bool | None = None) -> None:
    ROWS.append((figure, value, target, met))
    verdict = "" if met is None else ("met" if met else "MISSED")
    print(f"  {figure:<44s} {value:>22s}  {target:<10s} {verdict}", flush=True)


# -- the machine is shared: how much CPU did other processes take during a measurement? -------

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
BUSY_NOTE = 0.25  # cores taken by other processes above which a figure is marked as disturbed
NOTES: list[str] = []


def _busy_seconds() -> float:
    """CPU seconds the whole machine has been busy (all cores), from /proc/stat."""
    try:
        with open("/proc/stat") as stat:
            fields = [int(x) for x in stat.readline().split()[1:]]
    except OSError:
        return float("nan")
    user, nice, system, idle, iowait, irq, softirq, steal = (fields + [0] * 8)[:8]
    return (user + nice + system + irq + softirq + steal) / CLOCK_TICKS


def _own_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class Load:
    """``with Load() as load:`` → load.wall, load.own (cores this process and its waited-for
    children used), load.others (cores every other process used)."""

    def __enter__(self):
        self._start = (time.perf_counter(), _busy_seconds(), _own_seconds())
        return self

    def __exit__(self, *exc):
        wall, busy, own = time.perf_counter(), _busy_seconds(), _own_seconds()
        self.wall = wall - self._start[0]
        self.own = (own - self._start[2]) / self.wall
        self.others = max(0.0, (busy - self._start[1]) / self.wall - self.own)
        return False


def note_load(figure: str, load: Load) -> str:
    """' (others: x cores)' when other processes competed for the CPU; remembered for the table."""
    if load.others > BUSY_NOTE:
        NOTES.append(f"{figure}: other processes used {load.others:.1f} of {os.cpu_count()} cores meanwhile")
        return f"  [others used {load.others:.1f} cores]"
    return ""


def wait_for_quiet(limit: float) -> None:
    """Wait (at most ``limit`` s) until other processes use less than BUSY_NOTE cores for 2 s."""
    deadline, quiet = time.perf_counter() + limit, 0
    while time.perf_counter() < deadline and quiet < 4:
        with Load() as load:
            time.sleep(0.5)
        quiet = quiet + 1 if load.others < BUSY_NOTE else 0
    if quiet < 4 and limit > 0:
        print(f"   (the machine stayed busy: other processes use {load.others:.1f} cores; measuring anyway)")


def embedded(name: str) -> str:
    return str(resources.files("pxr_layers.render").joinpath(name))


# -- a stage of >= 1 M triangles ------------------------------------------------------------


def write_big_stage(path: Path, n: int = BIG_GRID) -> int:
    """A bumpy n x n quad terrain (2 n^2 triangles, 10 x 10 m) under a sun and a sky, seen
    from above at an angle. Returns the triangle count."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

    stage = Usd.Stage.CreateNew(str(path))
    stage.SetMetadata("metersPerUnit", 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(1)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())

    x = np.linspace(-5.0, 5.0, n + 1)
    gx, gz = np.meshgrid(x, x, indexing="xy")
    height = (0.25 * np.sin(3.1 * gx) * np.cos(2.3 * gz) + 0.08 * np.sin(17.0 * gx + 11.0 * gz)
              + 0.03 * np.cos(41.0 * gx - 37.0 * gz))
    points = np.stack([gx, height, gz], axis=-1).reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="xy")
    v00 = (j * (n + 1) + i).reshape(-1)
    v10, v01, v11 = v00 + 1, v00 + n + 1, v00 + n + 2
    # two triangles per quad, counter-clockwise seen from +Y (normals up)
    faces = np.stack([v00, v01, v10, v10, v01, v11], axis=-1).reshape(-1).astype(np.int32)
    triangles = len(faces) // 3

    mesh = UsdGeom.Mesh.Define(stage, "/World/Geometry/terrain")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(triangles, 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*points.min(0).tolist()), Gf.Vec3f(*points.max(0).tolist())]))

    material = UsdShade.Material.Define(stage, "/World/Materials/ground")
    shader = UsdShade.Shader.Define(stage, "/World/Materials/ground/previewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.55, 0.5, 0.42))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    shader.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.04, 0.04, 0.04))
    shader.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)

    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateAngleAttr(1.0)
    sun.CreateNormalizeAttr(False)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(-50.0, -30.0, 0.0))
    sky = UsdLux.DomeLight.Define(stage, "/World/Lights/sky")
    sky.CreateIntensityAttr(0.4)
    sky.CreateColorAttr(Gf.Vec3f(0.75, 0.85, 1.0))
    sky.CreateNormalizeAttr(False)

    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.CreateFocalLengthAttr(35.0)
    camera.CreateHorizontalApertureAttr(36.0)
    camera.CreateVerticalApertureAttr(36.0)
    camera.CreateClippingRangeAttr(Gf.Vec2f(0.1, 100.0))
    camera.AddTranslateOp().Set(Gf.Vec3d(0.0, 3.5, 6.0))
    camera.AddRotateXOp().Set(-32.0)
    stage.GetRootLayer().Save()
    return triangles


# -- 1. tracer vs raw Embree ---------------------------------------------------------------


class RecordingCaster:
    """Wraps a RayCaster: times every query, and keeps copies of those of the batches that
    the current thread has been told to record."""

    def __init__(self, caster):
        self.caster = caster
        self.recorded: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
        self.local = threading.local()
        self.lock = threading.Lock()
        self.seconds = 0.0  # summed over threads
        self.rays = 0

    def intersect(self, origins, directions, t_max):
        return self._cast("intersect", origins, directions, t_max)

    def occluded(self, origins, directions, t_max):
        return self._cast("occluded", origins, directions, t_max)

    def _cast(self, kind, origins, directions, t_max):
        if getattr(self.local, "record", False):
            kept = (kind, np.array(origins, np.float32), np.array(directions, np.float32),
                    np.array(t_max, np.float32))
        else:
            kept = None
        start = time.perf_counter()
        result = getattr(self.caster, kind)(origins, directions, t_max)
        seconds = time.perf_counter() - start
        with self.lock:
            self.seconds += seconds
            self.rays += len(t_max)
            if kept is not None:
                self.recorded.append(kept)
        return result

    def __getattr__(self, name):  # anything else the integrator may ask of the caster
        return getattr(self.caster, name)


def warm_up(integrator) -> None:
    """Load (or compile) every kernel before timing: one small batch."""
    spp = integrator.settings.spp
    integrator.trace(0, spp * min(64, integrator.width * integrator.height))


def tracer_vs_raw(label: str, stage: str, resolution, spp: int, max_depth: int, threads: int) -> None:
    from pxr_layers.stage import load_stage
    from pxr_layers.trace import TraceSettings
    from pxr_layers.trace.render import DEFAULT_BATCH_PATHS, batch_pixels, prepare, trace_pixels

    start = time.perf_counter()
    scene, spec = load_stage(stage)
    spec = dataclasses.replace(spec, resolution=tuple(resolution))
    settings = TraceSettings(spp=spp, max_depth=max_depth)
    integrator = prepare(scene, spec, settings)
    setup = time.perf_counter() - start
    warm_up(integrator)

    recorder = RecordingCaster(integrator.caster)
    integrator.caster = recorder
    batch_paths = batch_pixels(spp, DEFAULT_BATCH_PATHS) * spp
    trace = integrator.trace  # the bound method; an instance attribute wraps it for trace_pixels

    def traced(first_path, stop_path):
        recorder.local.record = (first_path // batch_paths) % RECORD_EVERY == 0
        try:
            return trace(first_path, stop_path)
        finally:
            recorder.local.record = False

    integrator.trace = traced
    width, height = spec.resolution
    totals = {"rays": 0}

    def add(batch):
        totals["rays"] += batch.rays

    with Load() as traced_load:
        trace_pixels(integrator, 0, width * height, add, threads=threads)
    trace_seconds = traced_load.wall
    del integrator.trace
    integrator.caster = recorder.caster

    with Load() as raw_load:
        raw_seconds, raw_rays = replay(recorder.caster, recorder.recorded, threads)
    tracer_rate, raw_rate = totals["rays"] / trace_seconds, raw_rays / raw_seconds
    paths = width * height * spp
    print(f"{label}: {integrator.world.triangle_count:,d} triangles, {width}x{height}, {spp} spp, "
          f"max depth {max_depth}, {threads} threads (set-up {setup:.1f} s)")
    print(f"    tracer    {trace_seconds:7.2f} s {totals['rays']:>12,d} rays {tracer_rate / 1e6:7.2f} M rays/s "
          f"{paths / trace_seconds / 1e6:6.2f} M paths/s, {totals['rays'] / paths:.2f} rays/path; "
          f"Embree calls {recorder.seconds / (threads * trace_seconds):.0%} of its thread time; "
          f"{traced_load.own:.2f} cores busy{note_load(f'tracer, {label}', traced_load)}")
    print(f"    raw       {raw_seconds:7.2f} s {raw_rays:>12,d} rays {raw_rate / 1e6:7.2f} M rays/s "
          f"(every {RECORD_EVERY}th batch's {len(recorder.recorded)} queries){note_load(f'raw, {label}', raw_load)}")
    if recorder.rays != totals["rays"]:
        print(f"    note: the caster saw {recorder.rays:,d} rays, the batches report {totals['rays']:,d}")
    row(f"tracer / raw Embree, {label}", f"{tracer_rate / raw_rate:.3f}", ">= 0.50", tracer_rate / raw_rate >= 0.5)


def replay(caster, queries, threads: int) -> tuple[float, int]:
    """Cast the recorded queries again through Embree only; returns (seconds, rays)."""

    def run(query):
        kind, origins, directions, t_max = query
        getattr(caster, kind)(origins, directions, t_max)
        return len(t_max)

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(run, queries[: threads * 2]))  # warm: first touches of the BVH, pool start
        start = time.perf_counter()
        rays = sum(pool.map(run, queries))
    return time.perf_counter() - start, rays


# -- 2. index overhead ---------------------------------------------------------------------


def cli_command() -> list[str]:
    probe = subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", "--help"], capture_output=True)
    if probe.returncode == 0:
        return [sys.executable, "-m", "pxr_layers.cli.main"]
    script = Path(sys.executable).with_name("pxr-layers")
    if script.exists():
        return [str(script)]
    raise RuntimeError(f"neither `{sys.executable} -m pxr_layers.cli.main` nor {script} runs:\n"
                       f"{probe.stderr.decode(errors='replace')}")


def cli_render(cli, stage, resolution, spp, out: Path, *extra, env=None) -> float:
    """Whole-process wall time of one CLI render (raises with its stderr if it fails)."""
    command = [*cli, "render", "-q", stage, "--resolution", str(resolution[0]), str(resolution[1]),
               "--spp", str(spp), "--no-previews", "-o", str(out), *extra]
    with Load() as load:
        done = subprocess.run(command, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr[-4000:]}")
    note_load(f"CLI {stage.rsplit('/', 1)[-1]} {resolution[0]}x{resolution[1]} {spp} spp {' '.join(extra)}", load)
    return load.wall


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def index_overhead(cli, resolution, spp: int, threads: int, scratch: Path) -> None:
    stage = embedded("cornell.usda")
    times = {"index": [], "no index": []}
    size = 0
    for repeat in range(REPEATS):
        for key, extra in (("index", ()), ("no index", ("--no-index",))):
            out = scratch / f"cli-{key.replace(' ', '-')}-{repeat}"
            times[key].append(cli_render(cli, stage, resolution, spp, out, "--threads", str(threads), *extra))
            if key == "index":
                size = sum(p.stat().st_size for p in out.glob("*.pxlidx"))
            shutil.rmtree(out, ignore_errors=True)
    with_index, without = min(times["index"]), min(times["no index"])
    print(f"CLI, Cornell {resolution[0]}x{resolution[1]}, {spp} spp, best of {REPEATS}: "
          f"with index {with_index:.2f} s ({size / 2**20:.1f} MiB index), --no-index {without:.2f} s "
          f"(all runs: {', '.join(f'{t:.2f}' for t in times['index'])} / "
          f"{', '.join(f'{t:.2f}' for t in times['no index'])})")
    overhead = with_index / without - 1
    row("index overhead, CLI whole process", f"{overhead:+.1%}", "<= 15 %", overhead <= 0.15)

    # in process
    from pxr_layers.jobs.frame import render_frame
    from pxr_layers.request import RenderRequest
    from pxr_layers.stage import load_stage
    from pxr_layers.trace import TraceSettings, prepare, trace_pixels

    def framed(frame_size, norm_bounces: int, keep_index: bool) -> tuple[float, int]:
        """render_frame's wall time (stage read, trace, index, EXR) and its index's bytes."""
        out = scratch / "in-process"
        request = RenderRequest(stage=Path(stage), resolution=frame_size, spp=spp, norm_bounces=norm_bounces,
                                keep_index=keep_index, index_mode="merged", index_covariance="norms", previews=False)
        with Load() as load:
            result = render_frame(request, output=out, threads=threads)
        note_load(f"in-process render_frame, norm_bounces {norm_bounces}, index {keep_index}", load)
        index_bytes = result.index_path.stat().st_size if result.index_path else 0
        shutil.rmtree(out)
        return load.wall, index_bytes

    framed((16, 16), 5, True)  # warm every kernel
    with_index, size = framed(tuple(resolution), 5, True)
    norms_only, _ = framed(tuple(resolution), 5, False)
    bare, _ = framed(tuple(resolution), 0, False)

    scene, spec = load_stage(stage)
    spec = dataclasses.replace(spec, resolution=tuple(resolution))

    def traced(record_paths: bool) -> float:
        """trace_pixels alone on a prepared scene, norm bounces 5, recording (merged) or not."""
        integrator = prepare(scene, spec, TraceSettings(spp=spp, norm_bounces=5, record_paths=record_paths,
                                                        merge_records=record_paths))
        with Load() as load:
            trace_pixels(integrator, 0, spec.resolution[0] * spec.resolution[1], lambda batch: None, threads=threads)
        note_load(f"in-process trace_pixels, record_paths {record_paths}", load)
        return load.wall

    recording = traced(True) - traced(False)
    print(f"in process, same render: render_frame with the index {with_index:.2f} s ({size / 2**20:.1f} MiB), "
          f"norm_bounces 5 without it (= --no-index) {norms_only:.2f} s, norm_bounces 0 {bare:.2f} s; "
          f"recording costs the tracer {recording:+.2f} s")
    overhead = with_index / norms_only - 1
    row("index overhead, in process (vs --no-index)", f"{overhead:+.1%}", "<= 15 %", overhead <= 0.15)
    row("  of which recording in the tracer", f"{recording / norms_only:+.1%}")
    row("  of which the writer (the rest)", f"{(with_index - norms_only - recording) / norms_only:+.1%}")
    row("  covariance norms alone (5 vs 0 bounces)", f"{norms_only / bare - 1:+.1%}")
    row("  index + norms vs bare render", f"{with_index / bare - 1:+.1%}")


# -- 3. threads ----------------------------------------------------------------------------


def thread_scaling(resolution, spp: int, max_depth: int, scratch: Path) -> None:
    from pxr_layers.paths.writer import PathIndexWriter
    from pxr_layers.stage import load_stage
    from pxr_layers.trace import TraceSettings
    from pxr_layers.trace.render import prepare, trace_pixels

    scene, spec = load_stage(embedded("cornell.usda"))
    spec = dataclasses.replace(spec, resolution=tuple(resolution))
    width, height = spec.resolution
    for label, settings in (("plain", TraceSettings(spp=spp, max_depth=max_depth)),
                            ("with index", TraceSettings(spp=spp, max_depth=max_depth, norm_bounces=5,
                                                         record_paths=True, merge_records=True))):
        integrator = prepare(scene, spec, settings)
        warm_up(integrator)
        seconds, cores, notes = {}, {}, {}
        for threads in (1, 2):
            writer = (PathIndexWriter(scratch / "threads.pxlidx", {}, settings.norm_bounces)
                      if settings.record_paths else None)
            with Load() as load:
                trace_pixels(integrator, 0, width * height,
                             (lambda batch: writer.add(batch.records)) if writer else (lambda batch: None),
                             threads=threads)
                if writer:
                    writer.close(integrator.vocabulary)
            seconds[threads], cores[threads] = load.wall, load.own
            notes[threads] = note_load(f"threads {label}, {threads} thread(s)", load)
        (scratch / "threads.pxlidx").unlink(missing_ok=True)
        speedup = seconds[1] / seconds[2]
        print(f"threads, Cornell {width}x{height}, {spp} spp, {label}: 1 thread {seconds[1]:.2f} s "
              f"({cores[1]:.2f} cores busy){notes[1]}, 2 threads {seconds[2]:.2f} s ({cores[2]:.2f} cores busy){notes[2]}")
        row(f"2 threads / 1, {label}", f"{speedup:.2f}x", ">= 1.8x", speedup >= 1.8)


# -- 4. peak memory ------------------------------------------------------------------------

MEASURE_CHILD = (
    "import resource, subprocess, sys\n"
    "done = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)\n"
    "sys.stderr.write(done.stderr[-4000:])\n"
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
    "sys.exit(done.returncode)\n"
)


def peak_memory(cli, scratch: Path) -> None:
    out = scratch / "memory"
    command = [*cli, "render", "-q", embedded("cornell.usda"), "--resolution", "1920", "1080", "--spp", "16",
               "--no-previews", "-o", str(out)]
    with Load() as load:
        done = subprocess.run([sys.executable, "-c", MEASURE_CHILD, *command], capture_output=True, text=True)
    seconds = load.wall
    note_load("peak-memory render", load)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    peak = int(done.stdout.split()[-1]) * 1024  # ru_maxrss is in KiB on Linux
    size = sum(p.stat().st_size for p in out.glob("*.pxlidx"))
    shutil.rmtree(out, ignore_errors=True)
    print(f"peak memory, CLI Cornell 1920x1080, 16 spp with the index: {peak / GIB:.2f} GiB "
          f"({seconds:.1f} s whole process, index {size / 2**20:.0f} MiB)")
    row("peak RSS, 1920x1080 16 spp + index", f"{peak / GIB:.2f} GiB", "< 4 GiB", peak < 4 * GIB)


# -- 5. cold start -------------------------------------------------------------------------


def cold_start(cli, scratch: Path) -> None:
    cache = Path(tempfile.mkdtemp(prefix="kernel-cache-", dir=scratch))
    env = dict(os.environ, PXR_LAYERS_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    stage = embedded("cornell.usda")
    cold = cli_render(cli, stage, (64, 64), 4, scratch / "cold", env=env)
    before = {p: p.stat().st_mtime_ns for p in cache.rglob("*") if p.is_file()}
    warm = cli_render(cli, stage, (64, 64), 4, scratch / "warm", env=env)
    after = {p: p.stat().st_mtime_ns for p in cache.rglob("*") if p.is_file()}
    print(f"cold start, CLI Cornell 64x64, 4 spp: empty kernel cache {cold:.2f} s "
          f"({len(before)} files, {folder_bytes(cache) / 2**20:.1f} MiB cached), same cache again {warm:.2f} s")
    rewritten = sorted(p.name for p in after if before.get(p) != after[p])
    if rewritten:  # a kernel's source changed between the runs (or its cache entry was unusable)
        print(f"    note: the warm run wrote {len(rewritten)} cache files, so it compiled again: {', '.join(rewritten)}")
    row("cold start (empty kernel cache)", f"{cold:.2f} s")
    row("warm start (cached kernels)", f"{warm:.2f} s")
    row("  cold / warm", f"{cold / warm:.1f}x")


# ------------------------------------------------------------------------------------------



def measure_figure(title: str, wait: float, failures: list[str], function, *arguments):
    """Measure one figure once the machine is quiet: its result, or None with its title added
    to ``failures`` (the traceback printed, the other figures still measured)."""
    print(f"\n== {title}", flush=True)
    wait_for_quiet(wait)
    start = time.perf_counter()
    try:
        return function(*arguments)
    except Exception:  # noqa: BLE001 — report and go on with the other figures
        failures.append(title)
        traceback.print_exc()
        row(title, "FAILED")
        return None
    finally:
        print(f"   ({time.perf_counter() - start:.0f} s)", flush=True)

def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), help="of 1.-3. (default 256 256)")
    parser.add_argument("--spp", type=int, default=64, help="of 1.-3. (default 64; 16 with --quick)")
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--threads", type=int, default=available_cores(), help="of 1. and 2. (default: every core this process may use)")
    parser.add_argument("--wait", type=float, default=20.0,
                        help="before each figure, wait at most this many seconds for other processes to "
                        "leave the CPU (default 20)")
    parser.add_argument("--quick", action="store_true", help="16 spp unless --spp is given; no peak-memory render")
    args = parser.parse_args()
    spp = 16 if args.quick and "--spp" not in sys.argv else args.spp
    resolution = tuple(args.resolution)
    failures: list[str] = []

    def attempt(title, function, *arguments):
        measure_figure(title, args.wait, failures, function, *arguments)

    with tempfile.TemporaryDirectory(prefix="bench-render-") as folder:
        scratch = Path(folder)
        big = scratch / "big_terrain.usdc"
        start = time.perf_counter()
        triangles = write_big_stage(big)
        print(f"generated {big.name}: {triangles:,d} triangles in {time.perf_counter() - start:.1f} s")
        cli = cli_command()
        # Kernels are cached per version of the tracer's sources: compile them now if this
        # version is new, so that no timed run below pays for it (5. measures that cost).
        warm = cli_render(cli, embedded("cornell.usda"), (16, 16), 1, scratch / "warm-up")
        print(f"warm-up CLI render (compiles the kernels if this version of the sources is new): {warm:.1f} s")

        for label, stage, stage_spp in (("cornell", embedded("cornell.usda"), spp),
                                        ("showcase", embedded("showcase.usda"), spp),
                                        (f"{triangles / 1e6:.1f}M-triangle terrain", str(big), spp)):
            attempt(f"1. tracer vs raw Embree: {label}", tracer_vs_raw, label, stage, resolution, stage_spp,
                    args.max_depth, args.threads)
        attempt("2. index overhead", index_overhead, cli, resolution, spp, args.threads, scratch)
        attempt("3. threads", thread_scaling, resolution, spp, args.max_depth, scratch)
        if not args.quick:
            attempt("4. peak memory", peak_memory, cli, scratch)
        attempt("5. cold start", cold_start, cli, scratch)

    print(f"\n{'figure':<46s} {'value':>22s}  {'target':<10s} verdict")
    for figure, value, target, met in ROWS:
        verdict = "" if met is None else ("met" if met else "MISSED")
        print(f"{figure:<46s} {value:>22s}  {target:<10s} {verdict}")
    for note in NOTES:
        print(f"disturbed: {note}")
    print(f"(this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GiB peak; "
          f"{os.cpu_count()} cores)")
    if failures:
        print(f"FAILED: {', '.join(failures)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
