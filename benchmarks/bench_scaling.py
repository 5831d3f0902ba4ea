"""How a render with the path index scales with threads (issue 35), and where its serial time goes.

    python benchmarks/bench_scaling.py [--quick] [--threads-list 1,2] [--resolution 256 256] [--spp 64]

The embedded Cornell box (``pxr_layers.render/cornell.usda``) at 256x256, max depth 8, 64 spp
(--quick: 128x128, 16 spp, one run each), rendered as ``pxr-layers render`` does by default: the
path index on, in its default merged mode, previews on.

1. CLI: the whole-process wall time of ``pxr-layers render --threads N`` (a fresh process), best
   of REPEATS, for N = 1 .. available_cores() (or --threads-list), and its speed-up over N = 1;
   the same with ``--no-index`` beside it. A warm-up CLI render first compiles the kernels if
   this version of the sources is new, so no timed run pays for it.
   Target: 2 threads over 1 with the index >= 1.8x.
2. In process: one ``render_frame`` per N (after a warm-up frame that loads the kernels), split
   by timing its stages: opening the stage and planning the frame, preparing it (scene, Embree,
   tables), ``trace_pixels`` (the parallel part), and each serial section around it (data AOVs,
   closing the index, opening it for delivery, the EXR, the previews, the rest). The frame
   goes through render_frame's own extension points (a FrameSource wrapping LocalTrace; the
   assembler's film and index writer wrapped on their instances); only the EXR and preview
   writers (in ``layers.deliver``'s namespace) are wrapped in a module, for the frame's
   duration. Inside trace_pixels the main thread takes in every batch (film sums; the index
   writer's class merge, handing full buffers to the writer's thread) while the workers trace:
   that intake overlaps the tracing but bounds it, since one thread does it all. The writer's
   own thread flushes those buffers (sort, zstd, write) meanwhile; what it has not done when
   tracing ends, the index's close waits for.
   s = the share of the frame outside trace_pixels at N = 1; printed beside the measured
   speed-ups: Amdahl's 1/(s + (1-s)/N) for N = 2, 4, ... 64, the same bounded by the intake
   (1/(s + max((1-s)/N, a)), a = the intake's share of the frame), and Amdahl for the whole
   process (its start-up — imports, kernel loading — is the CLI's time less the frame's).

The machine may be shared: before each figure the benchmark waits (--wait seconds at most) for
other processes to leave the CPU, and every measurement during which they used more than
BUSY_NOTE cores is listed at the end (bench_render's Load).

Exit 0 whether the target is met or missed; 1 if something fails.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from bench_render import NOTES, REPEATS, ROWS, Load, cli_command, embedded, measure_figure, note_load, row
from pxr_layers.cores import available_cores

FULL = {"resolution": (256, 256), "spp": 64}
QUICK = {"resolution": (128, 128), "spp": 16}
TARGET = 1.8  # 2 threads over 1, index on (issue 35)
AMDAHL_THREADS = (2, 4, 8, 16, 32, 64)

# the stages of a frame, in the order they run
OPEN = "open stage, plan frame"
PREPARE = "prepare: scene, Embree, tables"
TRACE = "trace_pixels (parallel)"
FILM_ADD = "film sums"
INDEX_ADD = "index add (class merge, hand-over)"
INDEX_FLUSH = "flushes: sort, zstd, write"
DATA = "data AOVs, Cryptomatte names"
INDEX_CLOSE = "index close: rest of the flushes, footer, fsync"
INDEX_OPEN = "index opened for delivery (writer's footer)"
EXR = "EXR"
PREVIEWS = "previews (PNG, contact sheet)"
REST = "rest: checks, render id, files into place"
SERIAL = (OPEN, PREPARE, DATA, INDEX_CLOSE, INDEX_OPEN, EXR, PREVIEWS)  # REST too, derived


# -- 1. the CLI ----------------------------------------------------------------------------


def cli_seconds(cli, out: Path, resolution, spp: int, max_depth: int, threads: int, *extra: str) -> Load:
    """One CLI render of the Cornell box, as a user runs it (previews on); raises with its stderr."""
    command = [*cli, "render", "-q", embedded("cornell.usda"), "--resolution", *map(str, resolution),
               "--spp", str(spp), "--max-depth", str(max_depth), "--threads", str(threads), "-o", str(out), *extra]
    with Load() as load:
        done = subprocess.run(command, capture_output=True, text=True)
    shutil.rmtree(out, ignore_errors=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr[-4000:]}")
    return load


def cli_scaling(cli, threads_list, resolution, spp: int, max_depth: int, repeats: int, scratch: Path) -> dict:
    """Best whole-process seconds per (index?, threads), runs interleaved across repeats."""
    best: dict[tuple[bool, int], float] = {}
    for repeat in range(repeats):
        for threads in threads_list:
            for index in (True, False):
                load = cli_seconds(cli, scratch / "cli", resolution, spp, max_depth, threads,
                                   *(() if index else ("--no-index",)))
                label = f"CLI {threads} thread(s){'' if index else ' --no-index'}, run {repeat + 1}"
                print(f"  {label:<36s} {load.wall:7.2f} s, {load.own:.2f} cores busy{note_load(label, load)}",
                      flush=True)
                best[index, threads] = min(best.get((index, threads), math.inf), load.wall)
    for index in (True, False):
        for threads in threads_list:
            speedup = best[index, 1] / best[index, threads]
            met = speedup >= TARGET if index and threads == 2 else None
            row(f"CLI {threads} thread(s), {'index' if index else '--no-index'}",
                f"{best[index, threads]:.2f} s {speedup:5.2f}x", f">= {TARGET}x" if met is not None else "", met)
    return best


# -- 2. one frame, stage by stage ----------------------------------------------------------


class Stopwatch:
    """Wall seconds per stage of one frame, summed over calls; a stage's calls may nest others
    (their time is in both). Every timed call runs on render_frame's thread but the index
    flushes, on the writer's thread (one stage per thread: the sums never race)."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def stage(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def timed(self, function, name: str):
        def timed(*args, **kwargs):
            with self.stage(name):
                return function(*args, **kwargs)

        return timed


@contextmanager
def timed_functions(watch: Stopwatch, module, stages: dict[str, str]):
    """Time ``module``'s functions (name → stage) while inside; put the originals back after."""
    originals = {name: getattr(module, name) for name in stages}
    try:
        for name, stage in stages.items():
            setattr(module, name, watch.timed(originals[name], stage))
        yield
    finally:
        for name, function in originals.items():
            setattr(module, name, function)


class TimedTrace:
    """render_frame's FrameSource: the CLI's LocalTrace, its stages timed into ``watch``."""

    def __init__(self, plan, shot, threads: int, watch: Stopwatch):
        from pxr_layers.jobs.frame import LocalTrace

        with watch.stage(PREPARE):
            self.local = LocalTrace(plan, shot, threads=threads)
        self.integrator = self.local.integrator  # render_frame's black-picture check reads it
        self.watch = watch
        self.load: Load | None = None
        self.flush_in_trace = 0.0

    def trace(self, add) -> None:
        # add is the frame's FrameAssembler.add: time its film and index writer on their instances
        assembler, watch = add.__self__, self.watch
        assembler.film.add = watch.timed(assembler.film.add, FILM_ADD)
        writer = assembler.writer
        if writer is not None:
            writer.add = watch.timed(writer.add, INDEX_ADD)
            writer._flush = watch.timed(writer._flush, INDEX_FLUSH)  # looked up by the writer's thread per flush
            writer.close = watch.timed(writer.close, INDEX_CLOSE)
            writer.opened = watch.timed(writer.opened, INDEX_OPEN)
        with Load() as self.load:
            self.local.trace(add)
        watch.seconds[TRACE] += self.load.wall
        self.flush_in_trace = watch.seconds[INDEX_FLUSH]

    def frame_data(self):
        with self.watch.stage(DATA):
            return self.local.frame_data()


@dataclass
class FrameTiming:
    """One render_frame, stage by stage: seconds (stage → s, REST included), wall (s), the
    cores busy during trace_pixels, the flushes' seconds inside it, and what it rendered."""

    seconds: dict[str, float]
    wall: float
    trace_cores: float
    flush_in_trace: float
    described: str

    @property
    def serial(self) -> float:
        """The frame's serial share s: all but trace_pixels."""
        return 1.0 - self.seconds[TRACE] / self.wall

    @property
    def intake(self) -> float:
        """The main thread's batch intake inside trace_pixels, as a share of the frame."""
        return (self.seconds[FILM_ADD] + self.seconds[INDEX_ADD]) / self.wall


def timed_frame(resolution, spp: int, max_depth: int, threads: int, out: Path, label: str) -> FrameTiming:
    import pxr_layers.layers.deliver as deliver_module
    from pxr_layers.jobs.frame import plan_frame, render_frame
    from pxr_layers.request import RenderRequest
    from pxr_layers.stage import open_request

    request = RenderRequest(stage=Path(embedded("cornell.usda")), resolution=tuple(resolution), spp=spp,
                            max_depth=max_depth)
    watch = Stopwatch()
    with Load() as load, timed_functions(watch, deliver_module, {"write_multipart": EXR, "write_previews": PREVIEWS}):
        # what render_frame does itself without a plan, split out to be timed
        with watch.stage(OPEN):
            shot = open_request(request)
            plan = plan_frame(request, None, shot=shot, directory=out)
        source = TimedTrace(plan, shot, threads, watch)
        render_frame(request, plan=plan, source=source)
    shutil.rmtree(out, ignore_errors=True)
    seconds = dict(watch.seconds)
    seconds[REST] = load.wall - sum(seconds.get(stage, 0.0) for stage in (*SERIAL, TRACE))
    settings = plan.trace
    described = (f"index {'merged' if settings.merge_records else 'records'} "
                 f"(on: {settings.record_paths}), {settings.norm_bounces} norm bounces")
    note_load(label, load)
    return FrameTiming(seconds, load.wall, source.load.own, source.flush_in_trace, described)


def frame_scaling(threads_list, resolution, spp: int, max_depth: int, repeats: int, scratch: Path) -> dict:
    """The best (shortest) timed frame per thread count; prints N = 1's split."""
    timed_frame((16, 16), 1, max_depth, 1, scratch / "warm", "in-process warm-up")  # load the kernels
    best: dict[int, FrameTiming] = {}
    for repeat in range(repeats):
        for threads in threads_list:
            label = f"render_frame {threads} thread(s), run {repeat + 1}"
            frame = timed_frame(resolution, spp, max_depth, threads, scratch / "frame", label)
            print(f"  {label:<36s} {frame.wall:7.2f} s, trace_pixels {frame.seconds[TRACE]:.2f} s "
                  f"({frame.trace_cores:.2f} cores busy)", flush=True)
            if threads not in best or frame.wall < best[threads].wall:
                best[threads] = frame
    one = best[1]
    print(f"\n  one frame at 1 thread, {one.described}: {one.wall:.2f} s")
    for stage, indent in ((OPEN, 0), (PREPARE, 0), (TRACE, 0), (FILM_ADD, 1), (INDEX_ADD, 1), (INDEX_FLUSH, 1),
                          (DATA, 0), (INDEX_CLOSE, 0), (INDEX_OPEN, 0), (EXR, 0), (PREVIEWS, 0), (REST, 0)):
        seconds = one.flush_in_trace if stage == INDEX_FLUSH else one.seconds.get(stage, 0.0)
        kind = ("parallel" if stage == TRACE else "writer thread, overlapped" if stage == INDEX_FLUSH
                else "main thread, overlapped" if indent else "serial")
        print(f"    {'  ' * indent}{stage:<{44 - 2 * indent}s} {seconds:7.3f} s {seconds / one.wall:6.1%}  {kind}")
    for threads, frame in best.items():
        row(f"render_frame {threads} thread(s), index",
            f"{frame.wall:.2f} s {one.wall / frame.wall:5.2f}x", f">= {TARGET}x" if threads == 2 else "",
            one.wall / frame.wall >= TARGET if threads == 2 else None)
        row(f"  trace_pixels alone, {frame.trace_cores:.2f} cores busy",
            f"{frame.seconds[TRACE]:.2f} s {one.seconds[TRACE] / frame.seconds[TRACE]:5.2f}x")
    row("serial share s of the frame (1 thread)", f"{one.serial:.1%}")
    row("  batch intake a (main thread, overlapped)", f"{one.intake:.1%}")
    return best


# -- Amdahl --------------------------------------------------------------------------------


def amdahl(serial: float, threads: int, floor: float = 0.0) -> float:
    """Speed-up over 1 thread of a run whose share ``serial`` is serial and whose parallel
    part cannot go below the share ``floor``."""
    return 1.0 / (serial + max((1.0 - serial) / threads, floor))


def amdahl_table(frames: dict[int, FrameTiming], cli: dict | None) -> list[str]:
    one = frames[1]
    lines = [f"Amdahl from 1 thread: frame s = {one.serial:.1%} (intake a = {one.intake:.1%})"]
    process_serial = None
    if cli is not None:
        process_serial = 1.0 - one.seconds[TRACE] / cli[True, 1]
        lines[0] += (f"; whole process s = {process_serial:.1%} (CLI {cli[True, 1]:.2f} s, of which start-up and "
                     f"exit {cli[True, 1] - one.wall:.2f} s, trace {one.seconds[TRACE]:.2f} s)")
    lines.append(f"  {'threads':>7s} {'frame: Amdahl':>14s} {'intake-bound':>13s} {'measured':>9s}"
                 f" {'process: Amdahl':>16s} {'measured CLI':>13s}")
    for threads in sorted({*frames, *AMDAHL_THREADS}):
        measured = f"{one.wall / frames[threads].wall:.2f}x" if threads in frames else "-"
        process = f"{amdahl(process_serial, threads):.2f}x" if process_serial is not None else "-"
        measured_cli = f"{cli[True, 1] / cli[True, threads]:.2f}x" if cli and (True, threads) in cli else "-"
        lines.append(f"  {threads:>7d} {amdahl(one.serial, threads):>13.2f}x "
                     f"{amdahl(one.serial, threads, one.intake):>12.2f}x {measured:>9s} {process:>16s} {measured_cli:>13s}")
    return lines


# ------------------------------------------------------------------------------------------


def threads_list_type(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated positive thread counts; 1 is always measured."""
    try:
        counts = {int(word) for word in text.split(",") if word.strip()}
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected thread counts like 1,2,4, got {text!r}") from None
    if not counts or min(counts) < 1:
        raise argparse.ArgumentTypeError(f"thread counts must be positive integers, got {text!r}")
    return tuple(sorted(counts | {1}))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, nargs=2, help=f"(default {FULL['resolution'][0]} "
                        f"{FULL['resolution'][1]}; {QUICK['resolution'][0]} {QUICK['resolution'][1]} with --quick)")
    parser.add_argument("--spp", type=int, help=f"(default {FULL['spp']}; {QUICK['spp']} with --quick)")
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--threads-list", type=threads_list_type, metavar="N,N,...",
                        default=tuple(range(1, available_cores() + 1)),
                        help="thread counts to measure, 1 always among them (default: 1 .. every core this "
                        f"process may use, here {available_cores()})")
    parser.add_argument("--repeats", type=int, help=f"best of this many runs of each (default {REPEATS}; 1 with --quick)")
    parser.add_argument("--wait", type=float, default=20.0,
                        help="before each figure, wait at most this many seconds for other processes to "
                        "leave the CPU (default 20)")
    parser.add_argument("--quick", action="store_true", help="a smaller render, one run each: a fast check")
    args = parser.parse_args()
    size = QUICK if args.quick else FULL
    resolution, spp = tuple(args.resolution or size["resolution"]), args.spp or size["spp"]
    repeats = args.repeats or (1 if args.quick else REPEATS)
    threads_list = args.threads_list
    print(f"Cornell box {resolution[0]}x{resolution[1]}, {spp} spp, max depth {args.max_depth}, threads "
          f"{', '.join(map(str, threads_list))}, best of {repeats}; {available_cores()} cores available, "
          f"load average {', '.join(f'{load:.2f}' for load in os.getloadavg())}")
    failures, results = [], {}

    def attempt(title, function, *arguments):
        results[title] = measure_figure(title, args.wait, failures, function, *arguments)

    with tempfile.TemporaryDirectory(prefix="bench-scaling-") as folder:
        scratch = Path(folder)
        cli = cli_command()
        # Kernels are cached per version of the tracer's sources: compile them now if this
        # version is new, so that no timed run below pays for it.
        warm = cli_seconds(cli, scratch / "warm-up", (16, 16), 1, args.max_depth, 1)
        print(f"warm-up CLI render (compiles the kernels if this version of the sources is new): {warm.wall:.1f} s")
        cli_title, frame_title = "1. CLI, whole process", "2. in process, one frame stage by stage"
        attempt(cli_title, cli_scaling, cli, threads_list, resolution, spp, args.max_depth, repeats, scratch)
        attempt(frame_title, frame_scaling, threads_list, resolution, spp, args.max_depth, repeats, scratch)

    print(f"\n{'figure':<46s} {'value':>22s}  {'target':<10s} verdict")
    for figure, value, target, met in ROWS:
        verdict = "" if met is None else ("met" if met else "MISSED")
        print(f"{figure:<46s} {value:>22s}  {target:<10s} {verdict}")
    if 2 not in threads_list:
        print(f"(the target, 2 threads over 1 >= {TARGET}x, needs 2 in --threads-list)")
    if results.get(frame_title) is not None:
        print()
        print("\n".join(amdahl_table(results[frame_title], results.get(cli_title))))
    for note in NOTES:
        print(f"disturbed: {note}")
    if failures:
        print(f"FAILED: {', '.join(failures)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
