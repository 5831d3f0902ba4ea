"""What the path index costs: size per record, per pixel and per sample, and render-time
overhead, side by side.

    python benchmarks/bench_index.py [--resolution 256 256] [--spp 16 64 256] [--stages cornell showcase]
                                     [--modes merged records]

For each stage, spp and index mode, in one run, both through ``render_frame`` as `pxr-layers
render` does (the beauty's EXR, no previews): a plain render (no covariance, no index) and a
render that records every contribution with the norms of N = 5 events and writes the path
index (``merged``: one record per pixel, path class and
covariance bin, merged in the tracer, the default; ``records``: --index-mode records, one
per contribution). Prints records, classes, size on disk, bytes per record, per pixel and
per sample, and the overhead, then per stage and mode the growth of the size from 64 to
256 spp. Targets (issue 19, merged): ≤ 150 bytes per pixel at 256 spp, ≤ 1.5× growth from
64 to 256 spp, ≤ 15 % write overhead.
"""

from __future__ import annotations

import argparse
import tempfile
from importlib import resources
from pathlib import Path

from pxr_layers.jobs.frame import render_frame
from pxr_layers.paths import format as fmt
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

NORM_BOUNCES = 5
MODES = fmt.MODES


def timed_pair(stage: Path, resolution, spp: int, folder: Path, mode: str) -> tuple[float, float, PathIndex]:
    """Seconds of the plain render and of the indexed one, and the index."""
    common = dict(stage=stage, resolution=resolution, spp=spp, index_mode=mode, index_covariance="norms",
                  previews=False)
    plain = render_frame(RenderRequest(**common, norm_bounces=0, keep_index=False), output=folder).seconds
    indexed = render_frame(RenderRequest(**common, norm_bounces=NORM_BOUNCES), output=folder)
    return plain, indexed.seconds, PathIndex(indexed.index_path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, nargs="+", default=[16, 64, 256])
    parser.add_argument("--stages", nargs="+", default=["cornell", "showcase"])
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES),
                        help="index modes to measure (pxr-layers render --index-mode)")
    args = parser.parse_args()
    width, height = args.resolution
    print(f"{width}x{height}, N = {NORM_BOUNCES}; plain render vs render + path index, same run")
    print(f"{'stage':10} {'mode':10} {'spp':>4} {'records':>11} {'classes':>8} {'size MB':>8} {'B/record':>8} "
          f"{'B/pixel':>8} {'B/sample':>8} {'plain s':>8} {'index s':>8} {'overhead':>8}")
    sizes = {}
    with tempfile.TemporaryDirectory() as folder:
        for name in args.stages:
            stage = Path(str(resources.files("pxr_layers.render").joinpath(f"{name}.usda")))
            for mode in args.modes:  # compile and warm every kernel first: the timings are the render's
                timed_pair(stage, (16, 16), 4, Path(folder), mode)
            for mode in args.modes:
                for spp in args.spp:
                    plain, indexed, index = timed_pair(stage, (width, height), spp, Path(folder), mode)
                    sizes[name, mode, spp] = index.size
                    print(f"{name:10} {mode:10} {spp:>4} {index.record_count:>11,} {len(index.classes):>8,} "
                          f"{index.size / 1e6:>8.1f} {index.size / index.record_count:>8.2f} "
                          f"{index.size / (width * height):>8.0f} {index.size / (width * height * spp):>8.2f} "
                          f"{plain:>8.2f} {indexed:>8.2f} {indexed / plain - 1:>+8.1%}", flush=True)
    for (name, mode, spp), size in sizes.items():
        if spp == 256 and (name, mode, 64) in sizes:
            print(f"{name} {mode}: size grows {size / sizes[name, mode, 64]:.2f}x from 64 to 256 spp")


if __name__ == "__main__":
    main()
