"""Instanced sets (issue 35): a PointInstancer of many copies of one big prototype renders in
the memory of its unique triangles, not of its placed ones.

    python benchmarks/bench_instancing.py [--instances 20000] [--triangles 200000] [--quick]

The stage (written here with usd-core): a lumpy rock of about --triangles triangles (a quad
sphere, its poles' degenerate triangles dropped by the reader) as the one prototype of a
PointInstancer of --instances rocks on a grid, turned and scaled at random (unit
quaternions in half precision, as DCCs write them); the default rig lights it and the
automatic camera frames it. Rendered as a user does (``pxr-layers render``, the index on,
previews on) at 64x64, 1 spp, beside the same stage with a single instance, each in a fresh
process whose peak resident memory (ru_maxrss, from wait4) and wall time are reported.

Target: the full set's peak <= 1.5 GB (its flattened triangles would take hundreds of GB).
--quick: 2,000 instances of a 20,000-triangle rock. Exit 0 whether the target is met or
missed; 1 if a render fails.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, Vt

from bench_render import ROWS, cli_command, row

TARGET_BYTES = 1.5e9
RESOLUTION, SPP = (64, 64), 1


def write_rocks(path: Path, instances: int, triangles: int, seed: int = 1) -> int:
    """The stage (module docstring); returns the prototype's triangles as authored."""
    rings = max(2, int(round(np.sqrt(triangles / 4))))  # rings x 2 rings quads, two triangles each
    theta = np.linspace(0, np.pi, rings + 1)
    phi = np.linspace(0, 2 * np.pi, 2 * rings, endpoint=False)
    grid_theta, grid_phi = np.meshgrid(theta, phi, indexing="ij")
    points = np.stack([np.sin(grid_theta) * np.cos(grid_phi), np.cos(grid_theta),
                       np.sin(grid_theta) * np.sin(grid_phi)], axis=-1).reshape(-1, 3) * 0.5
    points *= 1 + 0.08 * np.sin(7 * points[:, :1]) * np.cos(5 * points[:, 2:])  # lumpy
    ring, column = np.meshgrid(np.arange(rings), np.arange(2 * rings), indexing="ij")
    corner = lambda i, j: (i * 2 * rings + j % (2 * rings)).reshape(-1)
    faces = np.stack([corner(ring, column), corner(ring + 1, column), corner(ring + 1, column + 1),
                      corner(ring, column + 1)], axis=1)

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.Xform.Define(stage, "/World")
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Rocks")
    rock = UsdGeom.Mesh.Define(stage, "/World/Rocks/Prototypes/Rock")
    rock.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    rock.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 4, np.int32)))
    rock.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1).astype(np.int32)))
    rock.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    instancer.CreatePrototypesRel().SetTargets([rock.GetPath()])
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(instances)))
    cells = np.stack(np.meshgrid(np.arange(side), np.arange(side)), axis=-1).reshape(-1, 2)[:instances]
    positions = np.zeros((instances, 3), np.float32)
    positions[:, 0], positions[:, 2] = cells[:, 0] * 1.2, -cells[:, 1] * 1.2
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(instances, np.int32)))
    turns = rng.normal(size=(instances, 4))
    turns /= np.linalg.norm(turns, axis=1, keepdims=True)
    instancer.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(*map(float, turn)) for turn in turns]))
    scales = np.repeat(rng.uniform(0.6, 1.0, instances)[:, None], 3, axis=1).astype(np.float32)
    instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(scales))
    stage.GetRootLayer().Save()
    return 2 * len(faces)


def render(cli: list[str], stage: Path, out: Path) -> tuple[float, int]:
    """(wall seconds, peak resident bytes) of one CLI render in a fresh process."""
    command = [*cli, "render", "-q", str(stage), "--resolution", *map(str, RESOLUTION), "--spp", str(SPP),
               "-o", str(out / f"{stage.stem}.exr")]
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {process.returncode}:\n{process.stderr.read().decode()[-4000:]}")
    return wall, usage.ru_maxrss * 1024


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--instances", type=int, help="rocks in the set (default 20000; 2000 with --quick)")
    parser.add_argument("--triangles", type=int, help="triangles of the rock (default 200000; 20000 with --quick)")
    parser.add_argument("--quick", action="store_true", help="a smaller set: a fast check")
    args = parser.parse_args()
    instances = args.instances or (2000 if args.quick else 20000)
    triangles = args.triangles or (20000 if args.quick else 200000)
    cli = cli_command()
    with tempfile.TemporaryDirectory(prefix="bench-instancing-") as folder:
        scratch = Path(folder)
        authored = write_rocks(scratch / "set.usdc", instances, triangles)
        write_rocks(scratch / "one.usdc", 1, triangles)
        print(f"a PointInstancer of {instances:,} rocks of {authored:,} triangles ({instances * authored:,} "
              f"flattened), {RESOLUTION[0]}x{RESOLUTION[1]}, {SPP} spp, index on")
        render(cli, scratch / "one.usdc", scratch)  # compiles the kernels if this version of the sources is new
        try:
            one_wall, one_peak = render(cli, scratch / "one.usdc", scratch)
            set_wall, set_peak = render(cli, scratch / "set.usdc", scratch)
        except RuntimeError as error:
            print(error, file=sys.stderr)
            return 1
    row("one rock: wall, peak memory", f"{one_wall:.1f} s, {one_peak / 1e6:,.0f} MB")
    row(f"{instances:,} rocks: wall, peak memory", f"{set_wall:.1f} s, {set_peak / 1e6:,.0f} MB",
        f"<= {TARGET_BYTES / 1e9:g} GB", set_peak <= TARGET_BYTES)
    row("peak of the set over one rock", f"{set_peak / one_peak:.2f}x")
    print(f"\n{'figure':<46s} {'value':>22s}  {'target':<10s} verdict")
    for figure, value, target, met in ROWS:
        print(f"  {figure:<44s} {value:>22s}  {target:<10s} {'' if met is None else ('met' if met else 'MISSED')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
