"""Shading cost of MaterialX looks, measured side by side in one run.

    python benchmarks/bench_looks.py [--resolution 480 270] [--spp 16] [--repeats 5] [--stage PATH]

The OpenChessSet (../shared/scenes/usd-wg/full_assets/OpenChessSet/chess_set.usda: MaterialX
standard_surface looks with base colour, roughness, metallic and normal maps, and glass) is
read once; then the tracer's stages (``prepare``, then ``trace_pixels``, timed: the shading
cost, without the stage read and the EXR a ``render_frame`` adds) trace it with its looks,
and again with every material replaced in memory by one constant UsdPreviewSurface
(scene.Material's defaults: no texture, no normal map, no transmission), alternately, best
of --repeats each. Same camera, lights, geometry, settings
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
from pxr_layers.trace import TraceSettings, prepare, trace_pixels

CHESS_SET = Path(__file__).resolve().parents[2] / "shared/scenes/usd-wg/full_assets/OpenChessSet/chess_set.usda"
TARGET = 1.5


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stage", type=Path, default=CHESS_SET)
    parser.add_argument("--resolution", type=int, nargs=2, default=(480, 270), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=5)
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
    small = dataclasses.replace(spec, resolution=(32, 18))
    for variant in scenes.values():  # compile the kernels if the sources are new
        trace_pixels(prepare(variant, small, TraceSettings(spp=1)), 0, 32 * 18, lambda batch: None)
    pixels = args.resolution[0] * args.resolution[1]
    set_up = {}
    integrators = {}
    for name, variant in scenes.items():
        times = []
        for _ in range(2):  # the first prepare packs the atlas, the second reuses it
            started = time.perf_counter()
            integrators[name] = prepare(variant, spec, settings)
            times.append(time.perf_counter() - started)
        set_up[name] = times
    best = {name: float("inf") for name in scenes}
    for _ in range(args.repeats):
        for name, integrator in integrators.items():
            started = time.perf_counter()
            trace_pixels(integrator, 0, pixels, lambda batch: None)
            best[name] = min(best[name], time.perf_counter() - started)
    ratio = best["looks"] / best["constant"]
    textured = sum(1 for m in scene.materials if not isinstance(m.diffuse_color, tuple))
    texels = sum(t.pixels.nbytes for t in scene.textures)
    print(f"stage: {args.stage.name}, {sum(len(m.triangles) for m in scene.meshes):,} triangles, "
          f"{len(scene.materials)} materials ({textured} with a textured base colour), {len(scene.textures)} "
          f"textures ({texels / 2**30:.2f} GiB of texels); read in {read_seconds:.1f} s")
    print(f"trace {args.resolution[0]}x{args.resolution[1]}, {args.spp} spp, best of {args.repeats}:")
    print(f"  with looks      {best['looks']:7.2f} s")
    print(f"  constant look   {best['constant']:7.2f} s")
    verdict = "met" if ratio <= TARGET else "MISSED"
    print(f"shading cost of the looks: {ratio:.2f}x (target <= {TARGET}x: {verdict})")
    print("set-up (prepare), first / repeated in the process:")
    for name, (first, again) in set_up.items():
        print(f"  {name:<14} {first:7.2f} s / {again:5.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
