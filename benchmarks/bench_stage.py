"""Stage read: ``load_stage`` against a plain usd-core read loop on the same stage, in one run.

    python benchmarks/bench_stage.py [--stage PATH] [--repeats 5] [--subdiv-level N]

Both sides read the same USD file; each repeat runs the baseline, then ours, each in a
**fresh Python subprocess**, and the fastest of --repeats is kept for each. Fresh processes
rather than clearing USD's layer registry in one process, because more than the layer
registry is kept between reads in a process: ``pxr_layers.stage`` remembers the textures of
its last read (``textures.remember``), USD keeps its resolver and file-format caches, and the
OS page cache is warm for both sides alike either way. In a fresh process nothing of an
earlier repeat is reused. Imports (pxr, numpy, pxr_layers.stage and the reader module that
load_stage imports on first use) and USD's one-time plugin and schema-registry start-up
(``Usd.Stage.CreateInMemory()``) happen in both children before the clock starts; the clock
covers only the read.

* baseline: ``Usd.Stage.Open(path, Usd.Stage.LoadAll)``, then one ``Usd.PrimRange`` over
  the stage with instance proxies; for every ``UsdGeom.Mesh`` it reads points,
  faceVertexCounts, faceVertexIndices, normals (``primvars:normals`` flattened, else the
  ``normals`` attribute), the ``st`` primvar (``ComputeFlattened``), the world transform
  (one shared ``UsdGeom.XformCache``) and the bound material
  (``UsdShade.MaterialBindingAPI.ComputeBoundMaterial``); for every ``PointInstancer``
  positions, orientations, scales and protoIndices. Every array goes through
  ``np.asarray``, as any reader that hands numpy arrays on must. Tf warnings are trapped
  (as ``load_stage`` traps them), so neither side pays for printing them.
* ours: ``pxr_layers.stage.load_stage(path)``: the same open, plus triangulation
  (subdivision surfaces refined to ``--subdiv-level``, by default the render's level per
  mesh from its size on screen; 0 reads the cages), primvar expansion per corner, placement in world metres (instances
  included), degenerate triangles, materials and textures, lights, camera and render
  settings.

Prints both times (the baseline split into open and traversal), the ratio ours/baseline and
the triangle count of the SceneData. Target: ours ≤ 2× the baseline.

The default stage is the OpenChessSet (21 mesh prims placed 49 times, 1.7 M triangles at the
automatic subdivision levels at 640 px, payloads, PointInstancers, MaterialX looks); the script prints a
message and exits 0 when the asset is absent. Stages are read as shipped: one without a
camera gets load_stage's automatic camera (its framing is part of our read), and a load_stage
error is printed as such.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
from pathlib import Path


SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
DEFAULT_STAGE = SCENES / "usd-wg" / "full_assets" / "OpenChessSet" / "chess_set.usda"
TARGET_RATIO = 2.0

# Both children run this before the clock starts: imports and USD's one-time start-up
# (plugin registry, schema registry), so the clock sees the read alone.
_PRELUDE = """
import json, logging, sys, time
import numpy as np
from pxr import Tf, Usd, UsdGeom, UsdShade
Usd.Stage.CreateInMemory()
path = sys.argv[1]
"""

_BASELINE = _PRELUDE + """
def read(path):
    with Tf.DiagnosticTrap() as trap:
        start = time.perf_counter()
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
        opened = time.perf_counter()
        root = stage.GetRootLayer()
        t = Usd.TimeCode(stage.GetStartTimeCode()) if root.HasStartTimeCode() else Usd.TimeCode.EarliestTime()
        xforms = UsdGeom.XformCache(t)
        meshes = triangles = instancers = instances = 0
        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        for prim in Usd.PrimRange(stage.GetPseudoRoot(), predicate):
            if prim.IsA(UsdGeom.Mesh):
                mesh = UsdGeom.Mesh(prim)
                points = np.asarray(mesh.GetPointsAttr().Get(t))
                counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(t))
                indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(t))
                primvars = UsdGeom.PrimvarsAPI(prim)
                normals = primvars.GetPrimvar("normals")
                if normals and normals.HasAuthoredValue():
                    normals = np.asarray(normals.ComputeFlattened(t))
                else:
                    normals = mesh.GetNormalsAttr().Get(t)
                    normals = None if normals is None else np.asarray(normals)
                st = primvars.GetPrimvar("st")
                if st and st.HasAuthoredValue():
                    st = np.asarray(st.ComputeFlattened(t))
                world = np.asarray(xforms.GetLocalToWorldTransform(prim))
                material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
                meshes += 1
                triangles += int(np.maximum(counts - 2, 0).sum())
            elif prim.IsA(UsdGeom.PointInstancer):
                instancer = UsdGeom.PointInstancer(prim)
                arrays = [attribute.Get(t) for attribute in (
                    instancer.GetPositionsAttr(), instancer.GetOrientationsAttr(),
                    instancer.GetScalesAttr(), instancer.GetProtoIndicesAttr())]
                positions, orientations, scales, proto_indices = (
                    None if value is None else np.asarray(value) for value in arrays)
                world = np.asarray(xforms.GetLocalToWorldTransform(prim))
                instancers += 1
                instances += 0 if proto_indices is None else len(proto_indices)
        end = time.perf_counter()
        trap.Clear()
    return {"seconds": end - start, "open": opened - start, "traverse": end - opened,
            "meshes": meshes, "triangles": triangles, "instancers": instancers, "instances": instances}

print(json.dumps(read(path)))
"""

_OURS = _PRELUDE + """
import pxr_layers.stage
import pxr_layers.stage.reader  # load_stage imports it on first use: an import, not the read
from pxr_layers.errors import PxrLayersError
from pxr_layers.request import RenderRequest
logging.basicConfig(level=logging.CRITICAL)  # the reader's warnings are not what is timed
level = sys.argv[2]
request = RenderRequest(stage=path, subdiv_level=None if level == "auto" else int(level))

start = time.perf_counter()
try:
    scene, spec = pxr_layers.stage.load_stage(path, request=request)
except PxrLayersError as error:
    print(json.dumps({"error": str(error)}))
    sys.exit(0)
seconds = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "meshes": len(scene.meshes),
                  "triangles": sum(len(mesh.triangles) for mesh in scene.meshes),
                  "materials": len(scene.materials), "textures": len(scene.textures),
                  "lights": len(scene.lights), "camera": spec.camera.path}))
"""


def run_child(code: str, stage: Path, subdiv_level: int | None) -> dict:
    """Run one timed read in a fresh interpreter; its last stdout line is a JSON report."""
    completed = subprocess.run([sys.executable, "-P", "-c", code, str(stage), "auto" if subdiv_level is None else str(subdiv_level)],
                               capture_output=True, text=True)
    if completed.returncode != 0:
        raise SystemExit(f"bench_stage: a child failed (exit {completed.returncode}):\n"
                         f"{textwrap.indent(completed.stderr.strip()[-4000:], '  ')}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", type=Path, default=DEFAULT_STAGE, help=f"default: {DEFAULT_STAGE}")
    parser.add_argument("--repeats", type=int, default=5, help="fresh-process reads of each side; fastest kept")
    parser.add_argument("--subdiv-level", type=int, default=None,
                        help="our refinement level of every subdivision surface (default: the render's, "
                             "a level per mesh from its size on screen; 0 reads the cages)")
    args = parser.parse_args()
    if not args.stage.exists():
        print(f"bench_stage: {args.stage} is absent; skipped")
        return 0
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")

    stage = args.stage
    print(f"{stage} (our subdivision level: {'automatic' if args.subdiv_level is None else args.subdiv_level})")
    print(f"fastest of {args.repeats}, each read in a fresh process, baseline then ours per repeat")
    baselines, ours = [], []
    for repeat in range(args.repeats):
        baselines.append(run_child(_BASELINE, stage, args.subdiv_level))
        ours.append(run_child(_OURS, stage, args.subdiv_level))
        if "error" in ours[-1]:
            break
        print(f"  repeat {repeat + 1}: baseline {baselines[-1]['seconds']:6.3f} s, "
              f"ours {ours[-1]['seconds']:6.3f} s, ratio {ours[-1]['seconds'] / baselines[-1]['seconds']:.2f}",
              flush=True)

    base = min(baselines, key=lambda report: report["seconds"])
    print(f"  baseline (usd-core loop): {base['seconds']:6.3f} s  (open {base['open']:.3f} s, traversal "
          f"{base['traverse']:.3f} s; {base['meshes']} mesh prims, {base['triangles']:,} triangles as "
          f"authored, {base['instancers']} PointInstancers of {base['instances']} instances)")
    if "error" in ours[-1]:
        print(f"  ours (load_stage)       : FAILED: {ours[-1]['error']}")
        return 1
    best = min(ours, key=lambda report: report["seconds"])
    ratio = best["seconds"] / base["seconds"]
    print(f"  ours (load_stage)       : {best['seconds']:6.3f} s  ({best['meshes']} meshes, "
          f"{best['triangles']:,} triangles placed, {best['materials']} materials, "
          f"{best['textures']} textures, {best['lights']} lights)")
    print(f"  triangles {best['triangles']:,}; ratio ours/baseline {ratio:.2f} "
          f"(target ≤ {TARGET_RATIO:g}: {'met' if ratio <= TARGET_RATIO else 'MISSED'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
