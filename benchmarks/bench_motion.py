"""What motion blur costs: the same Cornell frame with its shutter open and closed, side by side.

    python benchmarks/bench_motion.py [--resolution 256 256] [--spp 64] [--max-depth 8]
                                      [--threads N] [--repeat 3]

A stage over the embedded Cornell box (``pxr_layers.render/cornell.usda``) keys the tall box
sliding 60 mm and turning 20° between frames 1 and 2, and the camera dollying 40 mm; it is
rendered at frame 1 with ``shutter:open`` 0 and ``shutter:close`` 1 (everything blurred:
the box a moving mesh of 3 time steps, the camera posed per sample) and with the shutter
closed (``shutter:close`` 0: the same frame still), each as a child process timed whole
(``python -m pxr_layers.cli.main render``: start-up, stage read, render, EXR write), with and
without the path index, --repeat times each, interleaved, keeping the fastest.

Prints each time and what motion blur adds to the still frame (target: ≤ 20 %, issue 36).
Exits 0 whether or not the target is met (a measurement), 1 when a render fails.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from bench_render import cli_command, cli_render
from bench_vs_mitsuba import cornell_overlay

from pxr_layers.cores import available_cores

TARGET_OVERHEAD = 0.20


def moving_stage(folder: Path, shutter_close: float) -> str:
    """The Cornell box with its tall box and camera keyed over frames 1–2, the camera's shutter
    open from 0 to `shutter_close`."""
    return cornell_overlay(folder / f"cornell_moving_{shutter_close:g}.usda", f"""    over "Geometry"
    {{
        over "tallBox"
        {{
            double3 xformOp:translate:slide.timeSamples = {{1: (0, 0, 0), 2: (60, 0, 0)}}
            float xformOp:rotateY:turn.timeSamples = {{1: 0, 2: 20}}
            double3 xformOp:translate:pivot = (368, 0, 351)
            uniform token[] xformOpOrder = ["xformOp:translate:slide", "xformOp:translate:pivot",
                                            "xformOp:rotateY:turn", "!invert!xformOp:translate:pivot"]
        }}
    }}
    over "Camera"
    {{
        double shutter:open = 0
        double shutter:close = {shutter_close}
        double3 xformOp:translate.timeSamples = {{1: (278, 273, -800), 2: (278, 273, -760)}}
    }}""", end_time_code=2)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--threads", type=int, default=available_cores())
    parser.add_argument("--repeat", type=int, default=3, help="renders of each, keeping the fastest")
    args = parser.parse_args()
    cli = cli_command()
    with tempfile.TemporaryDirectory(prefix="bench_motion_") as folder:
        out = Path(folder)
        stages = {"moving": moving_stage(out, 1.0), "still": moving_stage(out, 0.0)}

        def render(stage: str, index: bool) -> float:
            extra = ["--frame", "1", "--max-depth", str(args.max_depth), "--threads", str(args.threads)]
            return cli_render(cli, stage, args.resolution, args.spp, out / "frame.exr", *extra,
                              *([] if index else ["--no-index"]))

        best: dict[tuple[str, bool], float] = {}
        try:
            render(stages["still"], index=False)  # warm the kernel cache
            for _ in range(args.repeat):
                for index in (False, True):
                    for name, stage in stages.items():
                        best[name, index] = min(best.get((name, index), float("inf")), render(stage, index))
        except RuntimeError as error:
            print(f"bench_motion: a render failed: {error}")
            return 1
    width, height = args.resolution
    print(f"scene     : Cornell box, tall box and camera moving over the shutter, {width}x{height}, {args.spp} spp, "
          f"max depth {args.max_depth}, {args.threads} threads, best of {args.repeat}")
    for index in (False, True):
        label = "index   " if index else "no index"
        moving, still = best["moving", index], best["still", index]
        overhead = moving / still - 1
        verdict = "met" if overhead <= TARGET_OVERHEAD else "MISSED"
        print(f"{label}  : moving {moving:.2f} s, still {still:.2f} s: motion blur costs {overhead:+.1%} "
              f"(target <= {TARGET_OVERHEAD:.0%}: {verdict})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
