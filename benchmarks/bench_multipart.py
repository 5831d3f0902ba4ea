"""What the deliverable writer costs over a plain OpenEXR write of the same arrays, in one run.

    python benchmarks/bench_multipart.py [--resolution 1920 1080] [--layers 10] [--repeats 3]

The same arrays are written twice per repeat, alternating, best of --repeats each:

* ``write_multipart``: the recipe-driven writer (validation, part 0 rgba, one part per
  layer, chromaticities and pxrLayers/ metadata on every part, the recipe's JSON on part 0,
  contiguous channel planes, temporary file then rename);
* a plain ``OpenEXR.File([OpenEXR.Part(...), ...]).write`` of the same beauty and layers,
  same parts, channels and compression, no metadata, no rename. It too must split each
  (h, w, 3) layer into contiguous planes (the binding ignores numpy strides), so that is
  inside its timing; the time of the bare write of planes split beforehand is printed too.

The images are smooth gradients with a little noise (a rendered frame compresses about so),
float32, ZIP. Target: write_multipart takes at most 1.2 times the plain write.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR

from pxr_layers.layers.exr import REC709_CHROMATICITIES
from pxr_layers.layers.multipart import write_multipart
from pxr_layers.recipe import Layer, Product, Recipe

TARGET_RATIO = 1.2


def images(width: int, height: int, layers: int, seed: int = 7) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A beauty (h, w, 4) and ``layers`` colour layers (h, w, 3) that add up to its RGB."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    parts = {}
    for index in range(layers):
        phase = index * 0.7
        base = np.stack([np.sin(x / (40 + 7 * index) + phase), np.cos(y / (30 + 5 * index) - phase),
                         np.sin((x + y) / (90 + 3 * index))], axis=-1)
        noise = rng.random((height, width, 3), dtype=np.float32) * 0.02
        parts[f"layer{index:02d}"] = ((base + 1.0) * 0.5 / layers + noise).astype(np.float32)
    rgb = np.sum(list(parts.values()), axis=0, dtype=np.float32)
    beauty = np.concatenate([rgb, np.ones((height, width, 1), np.float32)], axis=-1)
    return beauty, parts


def plain_parts(beauty: np.ndarray, layers: dict[str, np.ndarray], planes: dict | None = None) -> list:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "chromaticities": REC709_CHROMATICITIES}
    parts = [OpenEXR.Part(dict(header), {"RGBA": beauty}, "rgba")]
    for name, image in layers.items():
        channels = planes[name] if planes else {
            f"{name}.{c}": np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}
        parts.append(OpenEXR.Part(dict(header), channels, name))  # Part keeps (and names) its dict
    return parts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(1920, 1080), metavar=("W", "H"))
    parser.add_argument("--layers", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    width, height = args.resolution
    beauty, layers = images(width, height, args.layers)
    product = Product("bench", "bench.exr", "/camera", (width, height),
                      tuple(Layer(name, "lpe", f"C.*<L.'{name}'>", group="bench") for name in layers))
    recipe = Recipe((product,))
    metadata = {"stage": "/shots/bench.usda", "camera": "/camera"}
    planes = {name: {f"{name}.{c}": np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}
              for name, image in layers.items()}
    print(f"{width}x{height}, beauty + {args.layers} RGB layers, float32 ZIP "
          f"({(beauty.nbytes + sum(a.nbytes for a in layers.values())) / 2**20:.0f} MiB), best of {args.repeats}")
    times: dict[str, list[float]] = {"multipart": [], "plain": [], "presplit": []}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        for _ in range(args.repeats):
            start = time.perf_counter()
            write_multipart(folder / "multipart.exr", beauty, layers, product, recipe=recipe,
                            spp=64, seed=0, frame=1001, metadata=metadata)
            times["multipart"].append(time.perf_counter() - start)
            start = time.perf_counter()
            OpenEXR.File(plain_parts(beauty, layers)).write(str(folder / "plain.exr"))
            times["plain"].append(time.perf_counter() - start)
            start = time.perf_counter()
            OpenEXR.File(plain_parts(beauty, layers, planes)).write(str(folder / "presplit.exr"))
            times["presplit"].append(time.perf_counter() - start)
        sizes = {name: (folder / f"{name}.exr").stat().st_size / 2**20 for name in times}
    best = {name: min(values) for name, values in times.items()}
    ratio = best["multipart"] / best["plain"]
    print(f"  write_multipart              : {best['multipart']:6.3f} s  ({sizes['multipart']:.1f} MiB)")
    print(f"  plain OpenEXR.File write     : {best['plain']:6.3f} s  ({sizes['plain']:.1f} MiB)")
    print(f"  plain, planes split before   : {best['presplit']:6.3f} s")
    print(f"  ratio {ratio:.3f} (target ≤ {TARGET_RATIO}: {'met' if ratio <= TARGET_RATIO else 'MISSED'}); "
          f"against the pre-split write {best['multipart'] / best['presplit']:.3f}")


if __name__ == "__main__":
    main()
