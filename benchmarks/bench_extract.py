"""Layer extraction: the automaton over path classes vs per-record regular expressions.

    python benchmarks/bench_extract.py [--resolution 256 256] [--spp 64] [--stages cornell showcase]

For each stage, in one run: render with the path index (timed), then extract the standard
light passes (docs/lpe.md) two ways on the same index:

* ours: ``layers.extract`` (one automaton over the index's distinct path classes, records
  read in chunks and accumulated per pixel with numpy);
* baseline, the seed prototype's method: every record's event sequence turned into a
  string and matched with Python's ``re`` against one regular expression per pass. It is
  timed on the first BASELINE_RECORDS records and its per-record cost scaled to the whole
  index (it is linear in records; running it on millions of records takes minutes).

Then one new layer (``C<RD>.*<L.'first light'>``) is extracted and compared with the
render time. Targets: ≥ 100× faster than the baseline; a new layer in ≤ 2 % of the render.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from pxr_layers import lpe
from pxr_layers.layers.extract import extract
from pxr_layers.paths.events import path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.paths.writer import PathIndexWriter
from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings
from pxr_layers.trace.render import render

BASELINE_RECORDS = 200_000
LABELS = r"(?:'[^']*')*"
# The standard passes written as regular expressions over ``C RD'floor' L'key'`` strings.
BASELINE_PASSES = {
    "emission": rf"^C [LO]{LABELS}$",
    "background": rf"^C B{LABELS}$",
    "diffuse_direct": rf"^C RD{LABELS} [LOB]{LABELS}$",
    "diffuse_indirect": rf"^C RD{LABELS}(?: \S+)+ [LOB]{LABELS}$",
    "glossy_direct": rf"^C R[GSs]{LABELS} [LOB]{LABELS}$",
    "glossy_indirect": rf"^C R[GSs]{LABELS}(?: \S+)+ [LOB]{LABELS}$",
    "transmission": r"^C T.*$",
    "volume": r"^C V.*$",
}


def baseline(index: PathIndex, width: int, height: int) -> tuple[float, int, dict[str, np.ndarray]]:
    """Seconds and records of the per-record regex extraction over the first records."""
    patterns = {name: re.compile(pattern) for name, pattern in BASELINE_PASSES.items()}
    sums = {name: np.zeros((width * height, 3)) for name in patterns}
    done = 0
    start = time.perf_counter()
    for chunk in index.records():
        for class_id, pixel, rgb in zip(chunk.class_id.tolist(), chunk.pixel.tolist(), chunk.rgb):
            text = path_text(index.classes[class_id].events, all_labels=True)  # the record's string
            for name, pattern in patterns.items():
                if pattern.match(text):
                    sums[name][pixel] += rgb
            done += 1
            if done == BASELINE_RECORDS:
                return time.perf_counter() - start, done, sums
    return time.perf_counter() - start, done, sums


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--stages", nargs="+", default=["cornell", "showcase"])
    args = parser.parse_args()
    width, height = args.resolution
    assert set(BASELINE_PASSES) == set(lpe.STANDARD_PASSES)
    with tempfile.TemporaryDirectory() as folder:
        for name in args.stages:
            scene, spec = load_stage(str(resources.files("pxr_layers.render").joinpath(f"{name}.usda")))
            spec = dataclasses.replace(spec, resolution=(width, height))
            settings = TraceSettings(spp=args.spp, norm_bounces=5, record_paths=True, merge_records=True)
            path = Path(folder) / f"{name}.pxlidx"
            start = time.perf_counter()
            writer = PathIndexWriter(path, {"spp": args.spp, "resolution": [width, height]}, 5)
            result = render(scene, spec, settings, show_progress=False, on_batch=lambda b, w=writer: w.add(b.records))
            writer.close(result.vocabulary)
            render_seconds = time.perf_counter() - start
            index = PathIndex(path)

            start = time.perf_counter()
            extract(index, lpe.STANDARD_PASSES)
            ours_seconds = time.perf_counter() - start
            base_seconds, base_records, _ = baseline(index, width, height)
            base_full = base_seconds * index.record_count / base_records
            light = scene.lights[0].name
            start = time.perf_counter()
            extract(index, {"new": f"C<RD>.*<L.'{light}'>"})
            new_seconds = time.perf_counter() - start
            print(f"{name} {width}x{height} {args.spp} spp: {index.record_count:,} records, "
                  f"{len(index.classes):,} classes; render + index {render_seconds:.1f} s")
            print(f"  standard passes, automaton : {ours_seconds:8.2f} s")
            print(f"  standard passes, re        : {base_full:8.1f} s (measured {base_seconds:.1f} s on "
                  f"{base_records:,} records, scaled)")
            print(f"  speed-up {base_full / ours_seconds:,.0f}x (target ≥ 100x)")
            print(f"  one new layer {new_seconds:.2f} s = {new_seconds / render_seconds:.1%} of the render "
                  f"(target ≤ 2 %)", flush=True)


if __name__ == "__main__":
    main()
