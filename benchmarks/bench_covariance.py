"""What covariance tracing costs: the showcase rendered with and without it, in one run.

    python benchmarks/bench_covariance.py [--resolution 256 256] [--spp 32] [--repeats 2]

Renders the embedded showcase (curvature, a two-frequency texture, glossy and near-mirror
lobes) with and without the per-event norms C, T, R of N = 5 events (texture spectra
included), alternating, best of --repeats each, in two settings:

* the beauty alone (norms feed only the first-bounce debug pictures), and
* recording every contribution, as the path index does: with the norms vs without.

Target: covariance adds at most 30 % to render time.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from importlib import resources

from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings
from pxr_layers.trace.render import render

NORM_BOUNCES = 5
TARGET_OVERHEAD = 0.30


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    scene, spec = load_stage(str(resources.files("pxr_layers.render").joinpath("showcase.usda")))
    spec = dataclasses.replace(spec, resolution=tuple(args.resolution))
    width, height = args.resolution
    print(f"showcase {width}x{height}, {args.spp} spp, best of {args.repeats}")
    for record in (False, True):
        times: dict[int, list[float]] = {0: [], NORM_BOUNCES: []}
        for _ in range(args.repeats):
            for bounces in list(times):
                settings = TraceSettings(spp=args.spp, norm_bounces=bounces, record_paths=record)
                start = time.perf_counter()
                render(scene, spec, settings, show_progress=False)
                times[bounces].append(time.perf_counter() - start)
        plain, traced = min(times[0]), min(times[NORM_BOUNCES])
        overhead = traced / plain - 1
        print(f"  {'recording contributions' if record else 'beauty only':24}: without {plain:6.2f} s, "
              f"with C, T, R {traced:6.2f} s, ratio {traced / plain:.3f}, overhead {overhead:+.1%} "
              f"(target ≤ {TARGET_OVERHEAD:.0%}: {'met' if overhead <= TARGET_OVERHEAD else 'MISSED'})")

if __name__ == "__main__":
    main()
