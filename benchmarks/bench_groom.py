"""What a groom costs: peak memory of a render with N hair strands against the same render
without them, beside the size of the strands' own data.

    python benchmarks/bench_groom.py [--strands 100000] [--resolution 256 256] [--spp 4]

Writes a stage (a .usdc crate) of one BasisCurves prim of N cubic B-spline strands (6 control points each,
widths per vertex) growing from a 20 cm disc on the floor of a centimetre stage under a dome,
and the same stage without it; renders each (and a groom of N/10 strands) in a child process (``python -m
pxr_layers.cli.main render``, no index) and reads its peak resident memory (``ru_maxrss``,
through bench_render's measuring child). Prints each peak, the curve data as USD holds it (points and widths, float32) and as the
tracer holds it (x, y, z, radius float32 and a segment index per segment), and the line
through the two grooms: a constant plus a multiple of the curve data. Target (issue 36): the
groom's memory is its curve data plus a constant.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_render import MEASURE_CHILD, cli_command

VERTICES = 6


def groom_stage(folder: Path, strands: int) -> Path:
    """The groom's stage as a binary crate (.usdc, as grooms are delivered; strands = 0: the
    same stage without the curves)."""
    rng = np.random.default_rng(7)
    body = ""
    if strands:
        radius, angle = 10 * np.sqrt(rng.random(strands)), 2 * np.pi * rng.random(strands)
        roots = np.stack([radius * np.cos(angle), np.zeros(strands), radius * np.sin(angle)], 1)
        lean = rng.normal(0, 0.3, (strands, 3)) * [1, 0, 1]
        steps = np.arange(VERTICES)[None, :, None]
        points = roots[:, None] + steps * (np.array([0, 2.0, 0]) + lean[:, None])  # 10 cm strands
        widths = np.tile(np.linspace(0.04, 0.01, VERTICES), strands)
        body = f"""
    def BasisCurves "groom"
    {{
        uniform token type = "cubic"
        uniform token basis = "bspline"
        int[] curveVertexCounts = [{", ".join([str(VERTICES)] * strands)}]
        point3f[] points = [{", ".join(f"({x:.3f}, {y:.3f}, {z:.3f})" for x, y, z in points.reshape(-1, 3))}]
        float[] widths = [{", ".join(f"{w:.4f}" for w in widths)}] (interpolation = "vertex")
        color3f[] primvars:displayColor = [(0.35, 0.2, 0.1)]
    }}"""
    text = folder / f"groom_{strands}.usda"
    text.write_text(f"""#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = 0.01
    defaultPrim = "World"
)
def Xform "World"
{{
    def Mesh "floor"
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-50, 0, 50), (50, 0, 50), (50, 0, -50), (-50, 0, -50)]
        uniform token subdivisionScheme = "none"
    }}{body}
    def DomeLight "sky"
    {{
    }}
    def Camera "Camera"
    {{
        float focalLength = 35
        float2 clippingRange = (0.1, 10000)
        double3 xformOp:translate = (0, 8, 45)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
}}
""")
    from pxr import Usd

    path = text.with_suffix(".usdc")
    stage = Usd.Stage.Open(str(text))
    stage.GetRootLayer().Export(str(path))
    return path


def peak_render(stage: Path, args) -> tuple[float, float]:
    """(peak resident MB, wall seconds) of a child render of `stage`."""
    command = [*cli_command(), "render", "-q", str(stage), "--resolution", *map(str, args.resolution), "--spp",
               str(args.spp), "--no-index", "--no-previews", "-o", str(stage.with_suffix(".exr"))]
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", MEASURE_CHILD, *command], capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        print(f"bench_groom: the render of {stage.name} failed:\n{done.stderr[-2000:]}")
        sys.exit(1)
    return int(done.stdout.split()[-1]) / 1024, seconds  # ru_maxrss: KiB on Linux


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strands", type=int, default=100_000)
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=4)
    args = parser.parse_args()
    sizes = (args.strands // 10, args.strands)
    with tempfile.TemporaryDirectory(prefix="bench_groom_") as folder:
        bare_peak, bare_seconds = peak_render(groom_stage(Path(folder), 0), args)
        grooms = [peak_render(groom_stage(Path(folder), strands), args) for strands in sizes]

    def data_mb(strands: int) -> float:  # as the tracer holds it: x, y, z, radius and a segment index
        return (strands * VERTICES * 16 + strands * (VERTICES - 3) * 4) / 2 ** 20

    print(f"groom     : cubic B-spline strands of {VERTICES} vertices, {args.resolution[0]}x{args.resolution[1]}, "
          f"{args.spp} spp")
    print(f"without   : peak {bare_peak:.0f} MB, {bare_seconds:.1f} s")
    for strands, (peak, seconds) in zip(sizes, grooms):
        print(f"{strands:>9,} : curve data {data_mb(strands):.1f} MB (USD: {strands * VERTICES * 16 / 2 ** 20:.1f} MB); "
              f"peak {peak:.0f} MB, {seconds:.1f} s: the groom adds {peak - bare_peak:.0f} MB")
    slope = (grooms[1][0] - grooms[0][0]) / (data_mb(sizes[1]) - data_mb(sizes[0]))
    constant = grooms[1][0] - bare_peak - slope * data_mb(sizes[1])
    print(f"fit       : a groom costs {constant:.0f} MB + {slope:.1f} x its curve data")
    return 0


if __name__ == "__main__":
    sys.exit(main())
