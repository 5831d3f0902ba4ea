"""Stage read: ``load_stage`` against a plain usd-core read loop on the same stage, in one run.

    python benchmarks/bench_stage.py [--stage PATH] [--repeats 5] [--subdiv-level N]
    python benchmarks/bench_stage.py --synthetic [--repeats 1] [--render]

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

Prints both times (the baseline split into open and traversal; ours with the seconds spent in
``TextureLibrary.load``, the texture reads, timed by wrapping it, and the ratio without them),
the ratio ours/baseline, the triangle count of the SceneData and each side's peak resident memory (``ru_maxrss`` of its
child, start-up included; the start-up's own peak, taken before the clock, is printed beside
it). Target: ours ≤ 2× the baseline.

``--synthetic`` reads a production-sized set written by :func:`write_synthetic_set` instead:
SYNTHETIC_MATERIALS UsdPreviewSurface materials, each with a UsdUVTexture of one of
SYNTHETIC_TEXTURES distinct 4096×4096 8-bit PNGs (two-colour checkers, a colour pair per
image: small files, true 4K images), each bound to a quad of its own, of which only
SYNTHETIC_VISIBLE are rendered (in front of the camera); the others are invisible (under an
invisible Xform), of purpose ``guide`` (outside the default purposes), or bound to nothing
(a third each). Target: load_stage < SYNTHETIC_LOAD_SECONDS. The set is written once to
SYNTHETIC_CACHE/<its parameters> and reused by later runs (the PNGs take minutes).
``--render`` also renders it as a user does (``pxr-layers render``, 1920×1080, 64 spp, the
index on) in a fresh process and prints its wall time and peak memory (ru_maxrss, from
wait4). Target: peak ≤ SYNTHETIC_RENDER_BYTES.

The default stage is the OpenChessSet (21 mesh prims placed 49 times, 2.8 M triangles at the
automatic subdivision levels at 640 px, payloads, PointInstancers, MaterialX looks); the script prints a
message and exits 0 when the asset is absent. Stages are read as shipped: one without a
camera gets load_stage's automatic camera (its framing is part of our read), and a load_stage
error is printed as such.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np


SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
DEFAULT_STAGE = SCENES / "usd-wg" / "full_assets" / "OpenChessSet" / "chess_set.usda"
TARGET_RATIO = 2.0

SYNTHETIC_MATERIALS = 2000
SYNTHETIC_TEXTURES = 500
SYNTHETIC_VISIBLE = 20
SYNTHETIC_TEXTURE_SIZE = 4096  # texels a side
SYNTHETIC_CACHE = Path(tempfile.gettempdir()) / "pxr-layers-synthetic"
SYNTHETIC_LOAD_SECONDS = 10.0
SYNTHETIC_RENDER_BYTES = 2 * 2**30
SYNTHETIC_RENDER = ((1920, 1080), 64)  # resolution, spp

# Both children run this before the clock starts: imports and USD's one-time start-up
# (plugin registry, schema registry), so the clock sees the read alone.
_PRELUDE = """
import json, logging, resource, sys, time
import numpy as np
from pxr import Tf, Usd, UsdGeom, UsdShade
Usd.Stage.CreateInMemory()
path = sys.argv[1]
def peak_kb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
"""

_BASELINE = _PRELUDE + """
def read(path):
    start_up_kb = peak_kb()
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
            "meshes": meshes, "triangles": triangles, "instancers": instancers, "instances": instances,
            "peak_kb": peak_kb(), "start_up_kb": start_up_kb}

print(json.dumps(read(path)))
"""

_OURS = _PRELUDE + """
import pxr_layers.stage
import pxr_layers.stage.reader  # load_stage imports it on first use: an import, not the read
from pxr_layers.errors import PxrLayersError
from pxr_layers.request import RenderRequest
from pxr_layers.stage.textures import TextureLibrary
logging.basicConfig(level=logging.CRITICAL)  # the reader's warnings are not what is timed
level = sys.argv[2]
texture_seconds = 0.0
_load = TextureLibrary.load
def timed_load(*args, **kwargs):  # the texture reads' share of the read, as they are
    global texture_seconds
    start = time.perf_counter()
    try:
        return _load(*args, **kwargs)
    finally:
        texture_seconds += time.perf_counter() - start
TextureLibrary.load = timed_load
request = RenderRequest(stage=path, subdiv_level=None if level == "auto" else int(level))

start_up_kb = peak_kb()
start = time.perf_counter()
try:
    scene, spec = pxr_layers.stage.load_stage(path, request=request)
except PxrLayersError as error:
    print(json.dumps({"error": str(error)}))
    sys.exit(0)
seconds = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "texture_seconds": texture_seconds, "meshes": len(scene.meshes),
                  "triangles": sum(len(mesh.triangles) for mesh in scene.meshes),
                  "materials": len(scene.materials), "textures": len(scene.textures),
                  "lights": len(scene.lights), "camera": spec.camera.path,
                  "peak_kb": peak_kb(), "start_up_kb": start_up_kb}))
"""


def run_child(code: str, stage: Path, subdiv_level: int | None) -> dict:
    """Run one timed read in a fresh interpreter; its last stdout line is a JSON report."""
    completed = subprocess.run([sys.executable, "-P", "-c", code, str(stage), "auto" if subdiv_level is None else str(subdiv_level)],
                               capture_output=True, text=True)
    if completed.returncode != 0:
        raise SystemExit(f"bench_stage: a child failed (exit {completed.returncode}):\n"
                         f"{textwrap.indent(completed.stderr.strip()[-4000:], '  ')}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


# --- the synthetic production set --------------------------------------------------------------

# What the rendered and unrendered quads are: the first SYNTHETIC_VISIBLE materials are bound to
# quads the camera sees; the rest, in turn, to an invisible quad, a guide quad, or nothing.
_UNRENDERED_KINDS = ("invisible", "guide", "unbound")


def synthetic_folder() -> Path:
    """The cache folder of the set of the current parameters (a new one when they change)."""
    key = (f"m{SYNTHETIC_MATERIALS}-t{SYNTHETIC_TEXTURES}-v{SYNTHETIC_VISIBLE}-"
           f"s{SYNTHETIC_TEXTURE_SIZE}-k{len(_UNRENDERED_KINDS)}")
    return SYNTHETIC_CACHE / key


_STAGE_REVISION = 2  # of _write_synthetic_stage: a new one is written beside the same textures


def write_synthetic_set() -> Path:
    """The synthetic set's stage (see the module docstring), written on first use and reused
    after: its stage file is written last, so a folder holding it is complete."""
    folder = synthetic_folder()
    stage_path = folder / f"set.{_STAGE_REVISION}.usda"
    if stage_path.exists():
        return stage_path
    folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    texture_paths = [folder / f"checker_{index:04d}.png" for index in range(SYNTHETIC_TEXTURES)]
    # OpenImageIO releases the GIL while it compresses: two writers use both cores.
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        written = sum(pool.map(_write_checker, range(SYNTHETIC_TEXTURES), texture_paths))
    print(f"wrote {written} {SYNTHETIC_TEXTURE_SIZE}² textures in {time.perf_counter() - started:.0f} s "
          f"to {folder}", flush=True)
    partial = folder / "set.partial.usda"
    _write_synthetic_stage(partial, texture_paths)
    partial.rename(stage_path)
    return stage_path


def _write_checker(index: int, path: Path) -> bool:
    """A SYNTHETIC_TEXTURE_SIZE² 8-bit RGB PNG: an 8×8 checker of two colours of its own.
    False when an interrupted earlier run wrote it already (under a temporary name first)."""
    import OpenImageIO as oiio

    if path.exists():
        return False
    size = SYNTHETIC_TEXTURE_SIZE
    rng = np.random.default_rng(index)
    colours = rng.integers(0, 256, size=(2, 3), dtype=np.uint8)
    cell = (np.arange(size) // (size // 8)) % 2
    pixels = colours[cell[:, None] ^ cell[None, :]]  # (size, size, 3) uint8
    spec = oiio.ImageSpec(size, size, 3, "uint8")
    spec.attribute("png:compressionLevel", 1)  # fast: flat checkers compress well at any level
    partial = path.with_suffix(".partial.png")
    output = oiio.ImageOutput.create(str(partial))
    if output is None or not output.open(str(partial), spec) or not output.write_image(pixels):
        raise RuntimeError(f"cannot write {partial}: {oiio.geterror()}")
    output.close()
    partial.rename(path)
    return True


def _write_synthetic_stage(path: Path, texture_paths: list[Path]) -> None:
    """The stage: a camera, a distant light, /World/Looks/M_<i> (UsdPreviewSurface, its
    diffuseColor a UsdUVTexture of texture i mod SYNTHETIC_TEXTURES read at the quad's st), and
    a unit quad per bound material: rendered ones in a grid in front of the camera (metres)."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    columns = 5
    rows = -(-SYNTHETIC_VISIBLE // columns)
    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 2.2 * max(columns, rows)))
    camera.CreateFocalLengthAttr(35.0)
    light = UsdLux.DistantLight.Define(stage, "/World/Sun")
    light.CreateIntensityAttr(3.0)
    light.CreateNormalizeAttr(True)  # 3 lux-like on the quads, not 3 nits from a 0.53° disc (near black)
    UsdGeom.Xform.Define(stage, "/World/Hidden").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    UsdGeom.Xform.Define(stage, "/World/Guides").CreatePurposeAttr(UsdGeom.Tokens.guide)
    UsdGeom.Scope.Define(stage, "/World/Looks")
    UsdGeom.Scope.Define(stage, "/World/Rendered")
    for index in range(SYNTHETIC_MATERIALS):
        material = _preview_material(stage, f"/World/Looks/M_{index:04d}",
                                     texture_paths[index % len(texture_paths)])
        if index < SYNTHETIC_VISIBLE:
            parent = "/World/Rendered"
            offset = Gf.Vec3d(1.2 * (index % columns - (columns - 1) / 2),
                              1.2 * (index // columns - (rows - 1) / 2), 0.0)
        else:
            kind = _UNRENDERED_KINDS[index % len(_UNRENDERED_KINDS)]
            if kind == "unbound":
                continue
            parent = "/World/Hidden" if kind == "invisible" else "/World/Guides"
            offset = Gf.Vec3d(0.0, 0.0, -1.0 - 0.001 * index)
        quad = UsdGeom.Mesh.Define(stage, f"{parent}/Quad_{index:04d}")
        quad.CreatePointsAttr([(-0.5, -0.5, 0.0), (0.5, -0.5, 0.0), (0.5, 0.5, 0.0), (-0.5, 0.5, 0.0)])
        quad.CreateFaceVertexCountsAttr([4])
        quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        quad.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        st = UsdGeom.PrimvarsAPI(quad).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.vertex)
        st.Set([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)])
        quad.AddTranslateOp().Set(offset)
        UsdShade.MaterialBindingAPI.Apply(quad.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()


def _preview_material(stage, path: str, texture: Path):
    from pxr import Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    reader = UsdShade.Shader.Define(stage, f"{path}/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    image = UsdShade.Shader.Define(stage, f"{path}/Diffuse")
    image.CreateIdAttr("UsdUVTexture")
    image.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(str(texture)))
    image.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    image.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.ConnectableAPI(), "result")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        image.ConnectableAPI(), "rgb")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return material


def render_peak(stage: Path) -> tuple[float, int]:
    """(wall seconds, peak resident bytes) of one ``pxr-layers render`` of ``stage`` at
    SYNTHETIC_RENDER, the index on, in a fresh process (ru_maxrss from wait4)."""
    (width, height), spp = SYNTHETIC_RENDER
    with tempfile.TemporaryDirectory(prefix="bench-stage-render-") as out:
        command = [sys.executable, "-m", "pxr_layers.cli.main", "render", "-q", str(stage), "--resolution",
                   str(width), str(height), "--spp", str(spp), "-o", out]
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
        if os.waitstatus_to_exitcode(status) != 0:
            raise SystemExit(f"bench_stage: {' '.join(command)} failed:\n{process.stderr.read().decode()[-4000:]}")
    return wall, usage.ru_maxrss * 1024


def _megabytes(report: dict) -> str:
    return f"peak {report['peak_kb'] / 1024:,.0f} MB (start-up {report['start_up_kb'] / 1024:,.0f} MB)"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", type=Path, default=DEFAULT_STAGE, help=f"default: {DEFAULT_STAGE}")
    parser.add_argument("--synthetic", action="store_true",
                        help="read the synthetic production set instead (written once to "
                             f"{SYNTHETIC_CACHE})")
    parser.add_argument("--render", action="store_true",
                        help="with --synthetic: also render it (1920x1080, 64 spp, the index on) and "
                             "report its peak memory")
    parser.add_argument("--repeats", type=int, default=None,
                        help="fresh-process reads of each side; fastest kept (default 5; 1 with --synthetic)")
    parser.add_argument("--subdiv-level", type=int, default=None,
                        help="our refinement level of every subdivision surface (default: the render's, "
                             "a level per mesh from its size on screen; 0 reads the cages)")
    args = parser.parse_args()
    repeats = args.repeats if args.repeats is not None else (1 if args.synthetic else 5)
    if repeats < 1:
        parser.error("--repeats must be at least 1")
    if args.render and not args.synthetic:
        parser.error("--render renders the synthetic set: give --synthetic too")
    if args.synthetic:
        stage = write_synthetic_set()
        print(f"synthetic set: {SYNTHETIC_MATERIALS} materials, {SYNTHETIC_TEXTURES} distinct "
              f"{SYNTHETIC_TEXTURE_SIZE}² textures, {SYNTHETIC_VISIBLE} quads rendered; the others "
              f"{', '.join(_UNRENDERED_KINDS)} in turn")
    elif not args.stage.exists():
        print(f"bench_stage: {args.stage} is absent; skipped")
        return 0
    else:
        stage = args.stage

    print(f"{stage} (our subdivision level: {'automatic' if args.subdiv_level is None else args.subdiv_level})")
    print(f"fastest of {repeats}, each read in a fresh process, baseline then ours per repeat")
    baselines, ours = [], []
    for repeat in range(repeats):
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
    print(f"                            {_megabytes(max(baselines, key=lambda report: report['peak_kb']))}")
    if "error" in ours[-1]:
        print(f"  ours (load_stage)       : FAILED: {ours[-1]['error']}")
        return 1
    best = min(ours, key=lambda report: report["seconds"])
    ratio = best["seconds"] / base["seconds"]
    print(f"  ours (load_stage)       : {best['seconds']:6.3f} s  ({best['meshes']} meshes, "
          f"{best['triangles']:,} triangles placed, {best['materials']} materials, "
          f"{best['textures']} textures, {best['lights']} lights)")
    print(f"                            {_megabytes(max(ours, key=lambda report: report['peak_kb']))}")
    print(f"  triangles {best['triangles']:,}; ratio ours/baseline {ratio:.2f} "
          f"(target ≤ {TARGET_RATIO:g}: {'met' if ratio <= TARGET_RATIO else 'MISSED'})")
    untextured = min(report["seconds"] - report["texture_seconds"] for report in ours)
    print(f"  ours without texture reads: {untextured:6.3f} s (fastest of {len(ours)}; those reads took "
          f"{best['texture_seconds']:.3f} s of the fastest read), ratio {untextured / base['seconds']:.2f}")
    if args.synthetic:
        print(f"  synthetic load_stage {best['seconds']:.1f} s (target < {SYNTHETIC_LOAD_SECONDS:g} s: "
              f"{'met' if best['seconds'] < SYNTHETIC_LOAD_SECONDS else 'MISSED'})", flush=True)
    if args.render:
        (width, height), spp = SYNTHETIC_RENDER
        wall, peak = render_peak(stage)
        print(f"  pxr-layers render {width}x{height} {spp} spp, index on: {wall:.0f} s, peak "
              f"{peak / 2**20:,.0f} MB (target ≤ {SYNTHETIC_RENDER_BYTES / 2**30:g} GB: "
              f"{'met' if peak <= SYNTHETIC_RENDER_BYTES else 'MISSED'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
