"""The cost of Cryptomatte, measured side by side in one run.

    python benchmarks/bench_cryptomatte.py [--resolution 512 512] [--spp 64] [--threads N]

The showcase (render/showcase.usda), prepared once (stage read, Embree scene): its beauty
(trace_pixels into the film, as `pxr-layers render` does, without the path index), then the
three Cryptomatte types at depth 6 (jobs.frame.frame_data: the first-visible-hit pass over
the beauty's camera samples, the coverage counts, the ranking and the manifests), then the
three layers written into the product's multipart EXR beside the beauty, against the beauty
written alone. Ratio: (beauty + Cryptomatte pass + its write) / (beauty + its write),
target <= 1.10. A first small render compiles the kernels if the sources are new.

Exit 0 whether the target is met or missed; 1 if something fails.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

TARGET = 1.10


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(512, 512), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()

    from pxr_layers.cli.demo import embedded_scene
    from pxr_layers.jobs.frame import FrameAssembler, frame_data, plan_frame, prepare_frame
    from pxr_layers.layers.multipart import write_multipart
    from pxr_layers.recipe.model import CRYPTOMATTE_SOURCES
    from pxr_layers.request import RenderRequest
    from pxr_layers.trace import trace_pixels

    stage = Path(embedded_scene("showcase.usda"))
    with tempfile.TemporaryDirectory() as folder:
        def plan_for(resolution, spp):
            request = RenderRequest(stage=stage, resolution=tuple(resolution), spp=spp)
            return plan_frame(request, None, directory=Path(folder), keep_index=False, previews=False,
                              cryptomattes=CRYPTOMATTE_SOURCES, cryptomatte_depth=6)

        warm = plan_for((32, 32), 4)  # compiles the kernels when the sources are new
        _beauty(warm, prepare_frame(warm), args.threads, FrameAssembler, trace_pixels)

        plan = plan_for(args.resolution, args.spp)
        integrator = prepare_frame(plan)
        start = time.perf_counter()
        rgba = _beauty(plan, integrator, args.threads, FrameAssembler, trace_pixels)
        beauty_seconds = time.perf_counter() - start

        start = time.perf_counter()
        data = frame_data(plan, integrator, threads=args.threads)
        crypto_seconds = time.perf_counter() - start

        product = plan.recipe.products[0]
        alone = dataclasses.replace(product, layers=tuple(l for l in product.layers if not l.is_cryptomatte))
        start = time.perf_counter()
        write_multipart(Path(folder) / "beauty.exr", rgba, {}, alone)
        write_alone = time.perf_counter() - start
        start = time.perf_counter()
        write_multipart(Path(folder) / "crypto.exr", rgba, {layer.name: data[layer.source_name]
                                                           for layer in product.layers if layer.is_cryptomatte}, product)
        write_with = time.perf_counter() - start

    without = beauty_seconds + write_alone
    with_crypto = beauty_seconds + crypto_seconds + write_with
    ratio = with_crypto / without
    width, height = args.resolution
    print(f"showcase {width}x{height} at {args.spp} spp, Cryptomatte {', '.join(CRYPTOMATTE_SOURCES)} depth 6")
    print(f"  beauty render            {beauty_seconds:8.2f} s")
    print(f"  Cryptomatte pass         {crypto_seconds:8.2f} s (first-visible hits, coverage, ranking, manifests)")
    print(f"  EXR write without / with {write_alone:8.2f} s / {write_with:.2f} s")
    verdict = "met" if ratio <= TARGET else "MISSED"
    print(f"  with / without           {ratio:8.3f}  (target <= {TARGET:.2f}: {verdict})")
    return 0


def _beauty(plan, integrator, threads, assembler, trace_pixels):
    with assembler(plan) as frame:
        trace_pixels(integrator, 0, plan.pixels, frame.add, threads=threads)
        rgba, _ = frame.images()
    return rgba


if __name__ == "__main__":
    sys.exit(main())
