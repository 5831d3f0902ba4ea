"""Shading cost of MaterialX looks, measured side by side in one run.

    python benchmarks/bench_looks.py [--resolution 480 270] [--spp 16] [--repeats 3] [--stage PATH]

The OpenChessSet (../shared/scenes/usd-wg/full_assets/OpenChessSet/chess_set.usda: MaterialX
standard_surface looks with base colour, roughness, metallic and normal maps, and glass) is
read once; then ``render()`` traces it with its looks, and again with every material replaced
by one constant UsdPreviewSurface (scene.Material's defaults: no texture, no normal map, no
transmission), alternately, best of --repeats each. Same camera, lights, geometry, settings
(no path index), threads = all cores. Ratio: looks over constant (target <= 1.5x).

A warm-up render of each compiles the kernels if this version of the sources is new. Exit 0
whether the target is met or missed; 1 if something fails; 2 without ../shared.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import pxr_layers.stage  # noqa: F401 — registers the pxr-layers schema before any stage is opened
from pxr_layers.scene import Material
from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings, render

CHESS_SET = Path(__file__).resolve().parents[2] / "shared/scenes/usd-wg/full_assets/OpenChessSet/chess_set.usda"
TARGET = 1.5


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stage", type=Path, default=CHESS_SET)
    parser.add_argument("--resolution", type=int, nargs=2, default=(480, 270), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if not args.stage.exists():
        print(f"bench_looks: {args.stage} not found (../shared is needed)", file=sys.stderr)
        return 2

    started = time.perf_counter()
    scene, spec = load_stage(args.stage)
    read_seconds = time.perf_counter() - started
    spec = dataclasses.replace(spec, resolution=tuple(args.resolution))
    constant = dataclasses.replace(scene, materials=tuple(Material(name=m.name, path=m.path) for m in scene.materials),
                                   textures=())
    settings = TraceSettings(spp=args.spp, record_paths=False)
    scenes = {"looks": scene, "constant": constant}
    for variant in scenes.values():  # compile the kernels, decode nothing twice
        render(variant, dataclasses.replace(spec, resolution=(32, 18)), TraceSettings(spp=1), show_progress=False)
    best = {name: float("inf") for name in scenes}
    means = {}
    for _ in range(args.repeats):
        for name, variant in scenes.items():
            started = time.perf_counter()
            result = render(variant, spec, settings, show_progress=False)
            best[name] = min(best[name], time.perf_counter() - started)
            means[name] = float(result.rgba[..., :3].mean())
    ratio = best["looks"] / best["constant"]
    textured = sum(1 for m in scene.materials if not isinstance(m.diffuse_color, tuple))
    print(f"stage: {args.stage.name}, {sum(len(m.triangles) for m in scene.meshes):,} triangles, "
          f"{len(scene.materials)} materials ({textured} with a textured base colour), {len(scene.textures)} "
          f"textures; read in {read_seconds:.1f} s")
    print(f"render {args.resolution[0]}x{args.resolution[1]}, {args.spp} spp, best of {args.repeats}:")
    print(f"  with looks      {best['looks']:7.2f} s  (image mean {means['looks']:.4f})")
    print(f"  constant look   {best['constant']:7.2f} s  (image mean {means['constant']:.4f})")
    verdict = "met" if ratio <= TARGET else "MISSED"
    print(f"shading cost of the looks: {ratio:.2f}x (target <= {TARGET}x: {verdict})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
