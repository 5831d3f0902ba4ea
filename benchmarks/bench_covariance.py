"""What covariance tracing costs: the showcase rendered with and without it, in one run.

    python benchmarks/bench_covariance.py [--resolution 256 256] [--spp 32] [--repeats 2]

Renders the embedded showcase (curvature, a two-frequency texture, glossy and near-mirror
lobes) with ``render_frame``, as `pxr-layers render` does (no previews), with and without
the per-event norms C, T, R of N = 5 events (texture spectra included), alternating, best
of --repeats each, in two settings:

* the beauty alone, no path index (norms feed only the first-bounce debug pictures), and
* with the path index recording every contribution (--index-mode records): with the norms
  vs without.

Target: covariance adds at most 30 % to render time.
"""

from __future__ import annotations

import argparse
import tempfile
from importlib import resources
from pathlib import Path

from pxr_layers.jobs.frame import render_frame
from pxr_layers.request import RenderRequest

NORM_BOUNCES = 5
TARGET_OVERHEAD = 0.30


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    stage = Path(str(resources.files("pxr_layers.render").joinpath("showcase.usda")))
    width, height = args.resolution
    print(f"showcase {width}x{height}, {args.spp} spp, best of {args.repeats}")
    with tempfile.TemporaryDirectory(prefix="bench-covariance-") as folder:
        for record in (False, True):
            times: dict[int, list[float]] = {0: [], NORM_BOUNCES: []}
            for _ in range(args.repeats):
                for bounces in list(times):
                    request = RenderRequest(stage=stage, resolution=tuple(args.resolution), spp=args.spp,
                                            norm_bounces=bounces, keep_index=record, index_mode="records",
                                            index_covariance="norms", previews=False)
                    times[bounces].append(render_frame(request, output=folder).seconds)
            plain, traced = min(times[0]), min(times[NORM_BOUNCES])
            overhead = traced / plain - 1
            print(f"  {'recording contributions' if record else 'beauty only':24}: without {plain:6.2f} s, "
                  f"with C, T, R {traced:6.2f} s, ratio {traced / plain:.3f}, overhead {overhead:+.1%} "
                  f"(target ≤ {TARGET_OVERHEAD:.0%}: {'met' if overhead <= TARGET_OVERHEAD else 'MISSED'})")


if __name__ == "__main__":
    main()
