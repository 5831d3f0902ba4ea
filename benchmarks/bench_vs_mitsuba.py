"""Whole-process render time against Mitsuba 3 on the same Cornell box, side by side in one run.

    python benchmarks/bench_vs_mitsuba.py [--resolution 256 256] [--spp 64] [--max-depth 8]
                                          [--threads N] [--repeat 1] [--keep DIR]
                                          [--lens F_STOP FOCUS_DISTANCE] [--curves]

Set-up (Mitsuba is a benchmark-only dependency, not one of pxr-layers'):

    pip install mitsuba            # measured with mitsuba 3.9.1, drjit 1.5.0
    apt-get install libllvm19      # the LLVM that drjit's CPU backend loads at run time

drjit finds libLLVM by itself (DRJIT_LIBLLVM_PATH chooses one). It must be recent: with
Debian 12's libllvm15 (/lib/x86_64-linux-gnu/libLLVM-15.so) drjit 1.5 loads, but its first
kernel that uses ``dr.minimum`` aborts the process with "LLVM ERROR: Cannot select: f32 =
fminimum"; libllvm19 (Debian 12 main; installed by default on Debian 13) works. The script
probes the backend first and, when it fails, tries the other libLLVM files it finds. Without
mitsuba, or without a usable LLVM, it prints one line saying what to install and exits 2.

1. Renders the embedded Cornell box (``pxr_layers.render/cornell.usda``) at equal
   resolution, spp and depth, each renderer in its own child process, timed from the
   parent as whole-process wall time (interpreter start, imports, stage read, render, EXR
   write), --repeat times each, interleaved, keeping the fastest:
   * pxr-layers (no index): ``python -m pxr_layers.cli.main render -q CORNELL --resolution
     W H --spp N --max-depth D --no-index --no-previews --threads T -o DIR``;
   * pxr-layers (index): the same without ``--no-index`` (the path index is written);
   * Mitsuba 3 (``llvm_ad_rgb``): this file run as a child (``--mitsuba-child``) that
     imports mitsuba, reads the same stage with ``pxr_layers.stage.load_stage`` (so both
     trace the very same triangles, in metres), builds the scene with ``mi.load_dict``,
     renders and writes an EXR. Its phases are printed too.
2. Compares the images: the RGB means (target: each channel within 1 %) and the means of
   8 × 8-pixel blocks (target: every block within 5 %; prints the worst block and the share
   within 5 %). Block differences are Monte Carlo noise as well as mismatch: the line also
   counts blocks beyond 4 standard errors (estimated from the pixels of the block, which
   overestimates the noise), which noise alone should almost never reach.
3. Prints the times and the speed ratio pxr-layers / Mitsuba = T_mitsuba / T_ours for the
   no-index render (target ≥ 0.8, moonshot ≥ 1), and what the index adds (target ≤ 25 %);
   with ``--lens``, also what depth of field adds to our no-index render of the same
   frame through a pinhole (target ≤ 20 %). ``--curves`` renders the box with a lawn of 400
   straight hairs on its floor instead (a linear BasisCurves: Embree's round linear curves
   for us, Mitsuba's ``linearcurve`` from the same control points and radii); ``--hair``
   binds a MaterialX chiang_hair_bsdf to that lawn, Mitsuba's ``hair`` BSDF for it.

Exits 0 whether or not targets are met (it is a measurement; each says met or MISSED), 1
when a render fails, 2 when Mitsuba is not available.

How the Mitsuba scene matches ours:
* geometry: every SceneData mesh, split per material (GeomSubsets), as an ``mi.Mesh`` of
  its world-space triangles in metres (meshes with shading normals are unwelded per
  corner: Mitsuba keeps one normal per vertex; the Cornell box has none, flat shading);
* materials: each must be a plain Lambertian UsdPreviewSurface (no texture, emission,
  metal, specular lobe, coat or transparency: all Cornell materials are); it becomes a
  ``twosided`` ``diffuse`` of reflectance diffuseColor (pxr-layers shades both sides, it
  turns the frame to the viewer; no Cornell path sees a back face anyway);
* the light: the RectLight as two triangles built as pxr-layers' ``light_shape`` does
  (wound so the emitting side, local −Z, is the front), with an ``area`` emitter of the
  same radiance (intensity × color, normalize off) and a black ``diffuse`` BSDF: a
  pxr-layers light absorbs what hits it. Only rect lights are mapped;
* camera: ``perspective`` at the camera's position, looking along its −Z with its +Y up,
  horizontal field of view 2·atan(aperture/2/focalLength) after the aspect-ratio conform
  policy, clipping range as authored; with ``--lens`` (depth of field: the camera's fStop
  and focusDistance, in millimetres, the stage's unit, overridden by a layer over the
  Cornell stage that both read) a ``thinlens`` of the same aperture radius
  (focalLength / 10 / (2·fStop) scene units: the schema's tenths) and focus distance; ``hdrfilm`` with a ``box`` filter (pxr-layers puts
  one uniformly jittered sample in the pixel) and the ``independent`` sampler, seed 0;
* integrator: ``path``, max_depth = ours + 1 (Mitsuba counts the camera segment:
  1 = emitters seen directly, 2 = direct light; ours counts scattering events,
  1 = direct light) and rr_depth = 3, the same point as ours: Mitsuba increments its
  depth after each scattering event and plays roulette when depth ≥ rr_depth; ours
  plays it when the number of scattering events so far ≥ roulette_depth = 3. The
  survival probabilities differ (Mitsuba min(max throughput, 0.95); ours clip(max
  throughput, 0.05, 1)): both unbiased, they shift work and noise a little.

Both renderers keep compiled kernels on disk across processes (drjit in ~/.drjit,
pxr-layers' numba kernels in its cache): a first-ever run pays compilation, later runs and
--repeat mostly do not. pxr-layers' no-index render still computes the first bounce's
covariance norms (the products' index bounces); Mitsuba's time includes the same
``load_stage`` read as ours (its phases show how long it took).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from pxr_layers.cores import available_cores  # the standard library only: the parent stays light

TARGET_RATIO = 0.8  # issue 35
MOONSHOT_RATIO = 1.0
TARGET_INDEX_OVERHEAD = 0.25  # issue 35: the index costs at most a quarter more than a render without it
TARGET_LENS_OVERHEAD = 0.20  # issue 36: depth of field costs at most a fifth more than the pinhole frame
TARGET_MEAN = 0.01
TARGET_BLOCK = 0.05
BLOCK = 8
NOISE_SIGMAS = 4.0
VARIANT = "llvm_ad_rgb"
ROULETTE_DEPTH = 3  # pxr_layers.trace.TraceSettings.roulette_depth (not imported: keep the parent light)

# drjit's backend check: a dr.minimum kernel is what an old libLLVM cannot compile.
_PROBE = f"""
import drjit as dr, mitsuba as mi
mi.set_variant({VARIANT!r})
x = dr.minimum(dr.llvm.Float([1.0, 2.0, 3.0]), 2.5)
dr.eval(x)
print(mi.__version__, dr.__version__)
"""

LLVM_DIRS = ("/usr/lib/x86_64-linux-gnu", "/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib",
             "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib")


def cornell_path() -> str:
    return str(resources.files("pxr_layers.render").joinpath("cornell.usda"))


def cornell_overlay(path: Path, body: str, end_time_code: int = 1) -> str:
    """Write at `path` a stage over the Cornell box: `body` (opinions over /World) on top of
    it, its metadata restated (a stage's units, up axis and render settings are its root
    layer's), time codes 1 to `end_time_code`. Returns the path."""
    path.write_text(f"""#usda 1.0
(
    subLayers = [@{cornell_path()}@]
    metersPerUnit = 0.001
    upAxis = "Y"
    renderSettingsPrimPath = "/Render/Settings"
    startTimeCode = 1
    endTimeCode = {end_time_code}
)
over "World"
{{
{body}
}}
""")
    return str(path)


def lens_stage(folder: Path, f_stop: float, focus_distance: float) -> str:
    """A stage over the Cornell box whose camera has a lens."""
    return cornell_overlay(folder / "cornell_lens.usda", f"""    over "Camera"
    {{
        float fStop = {f_stop}
        float focusDistance = {focus_distance}
    }}""")


HAIR_LOOK = """    def Material "hair"
    {
        token outputs:mtlx:surface.connect = </World/hair/Surface.outputs:out>
        def Shader "Surface"
        {
            uniform token info:id = "ND_surface"
            token inputs:bsdf.connect = </World/hair/Fibre.outputs:out>
            token outputs:out
        }
        def Shader "Fibre"
        {
            uniform token info:id = "ND_chiang_hair_bsdf"
            float2 inputs:roughness_R.connect = </World/hair/Roughness.outputs:roughness_R>
            float2 inputs:roughness_TT.connect = </World/hair/Roughness.outputs:roughness_TT>
            float2 inputs:roughness_TRT.connect = </World/hair/Roughness.outputs:roughness_TRT>
            vector3f inputs:absorption_coefficient = (0.2, 0.4, 0.8)
            token outputs:out
        }
        def Shader "Roughness"
        {
            uniform token info:id = "ND_chiang_hair_roughness"
            float inputs:longitudinal = 0.3
            float inputs:azimuthal = 0.3
            float2 outputs:roughness_R
            float2 outputs:roughness_TT
            float2 outputs:roughness_TRT
        }
    }
"""
"""/World/hair: a MaterialX chiang_hair_bsdf (longitudinal and azimuthal roughness 0.3, no
cuticle tilt, σa (0.2, 0.4, 0.8)): Mitsuba's ``hair`` with the same parameters."""


def curves_stage(folder: Path, hair: bool = False) -> str:
    """A stage over the Cornell box with a lawn of 20 × 20 straight hairs on its floor (a
    linear BasisCurves of the white material, or of HAIR_LOOK with `hair`, 4 mm wide, 120 mm
    tall, leaning)."""
    rng = np.random.default_rng(3)
    roots = np.stack(np.meshgrid(np.linspace(60, 500, 20), np.linspace(40, 500, 20)), -1).reshape(-1, 2)
    roots += rng.uniform(-8, 8, roots.shape)
    lean = rng.uniform(-30, 30, roots.shape)
    points = ", ".join(f"({x:.1f}, 0, {z:.1f}), ({x + dx:.1f}, 120, {z + dz:.1f})"
                       for (x, z), (dx, dz) in zip(roots, lean))
    look = "/World/hair" if hair else "/World/Materials/white"
    return cornell_overlay(folder / f"cornell_{'hair' if hair else 'curves'}.usda", f"""{HAIR_LOOK if hair else ""}
    over "Geometry"
    {{
        def BasisCurves "lawn" (prepend apiSchemas = ["MaterialBindingAPI"])
        {{
            uniform token type = "linear"
            int[] curveVertexCounts = [{", ".join(["2"] * len(roots))}]
            point3f[] points = [{points}]
            float[] widths = [4]
            rel material:binding = <{look}>
        }}
    }}""")


def _curve_file(strands, folder: Path) -> str:
    """Mitsuba's curve file of scene.Strands (one "x y z radius" line per control point, a
    blank line between curves): the curves are the runs of consecutive segments."""
    path = folder / f"{strands.name}.txt"
    segments = strands.segments.tolist()
    lines, start = [], segments[0]
    for previous, segment in zip(segments, segments[1:] + [None]):
        if segment != previous + 1:
            lines += [" ".join(f"{value:.7g}" for value in vertex)
                      for vertex in strands.vertices[start:previous + strands.span + 1]] + [""]
            start = segment
    path.write_text("\n".join(lines))
    return str(path)


def default_threads() -> int:
    return available_cores()


# -- Mitsuba availability ------------------------------------------------------------------


def _libllvm_candidates() -> list[str]:
    """libLLVM files on this machine, newest version first (by the number in the name)."""
    found = set()
    for directory in LLVM_DIRS:
        for pattern in ("libLLVM-*.so*", "libLLVM.so.*", "libLLVM.dylib"):
            found.update(os.path.realpath(path) for path in glob.glob(os.path.join(directory, pattern)))

    def version(path: str) -> tuple[int, ...]:
        digits = "".join(c if c.isdigit() else " " for c in os.path.basename(path)).split()
        return tuple(int(d) for d in digits) or (0,)

    return sorted(found, key=version, reverse=True)


def mitsuba_environment() -> tuple[dict[str, str], str] | None:
    """(environment for the Mitsuba child, "mitsuba X / drjit Y"), or None after printing
    why Mitsuba cannot be used here."""
    import importlib.util

    if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
        print("bench_vs_mitsuba: Mitsuba 3 is not installed (a benchmark-only dependency): "
              "pip install mitsuba, and a recent OS libLLVM (Debian: apt-get install libllvm19)")
        return None
    environment = dict(os.environ)
    tried = [environment.get("DRJIT_LIBLLVM_PATH")] + [path for path in _libllvm_candidates()
                                                       if path != environment.get("DRJIT_LIBLLVM_PATH")]
    for library in tried:
        if library is not None:
            environment["DRJIT_LIBLLVM_PATH"] = library
        probe = subprocess.run([sys.executable, "-c", _PROBE], env=environment, capture_output=True, text=True)
        if probe.returncode == 0:
            mitsuba_version, drjit_version = probe.stdout.split()[-2:]
            where = library or "libLLVM found by drjit"
            return environment, f"mitsuba {mitsuba_version} / drjit {drjit_version} ({VARIANT}, {where})"
    print(f"bench_vs_mitsuba: Mitsuba's {VARIANT} variant cannot run: drjit found no usable libLLVM (tried "
          f"{', '.join(t or 'its own search' for t in tried)}); install a recent one (15 fails, 19 works; Debian: "
          f"apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH")
    return None


# -- the Mitsuba child ---------------------------------------------------------------------


def _plain_lambertian(material) -> str | None:
    """Why a SceneData material is not a plain Lambertian, or None."""
    def constant(value):
        values = value if isinstance(value, tuple) else (value,)
        return all(isinstance(v, (int, float)) for v in values)

    for name in ("diffuse_color", "emissive_color", "metallic", "specular_color", "opacity", "clearcoat",
                 "transmission"):
        if not constant(getattr(material, name)):
            return f"{name} is textured"
    if material.normal is not None:
        return "it has a normal map"
    if material.transmission > 0:
        return "it transmits"
    if max(material.emissive_color) > 0:
        return "it emits"
    if material.metallic > 0:
        return "it is metallic"
    if not material.use_specular_workflow:
        return "the metallic workflow has a specular lobe (F0 from ior)"
    if max(material.specular_color) > 0:
        return "specularColor > 0 (a specular lobe)"
    if material.opacity < 1:
        return "it is not opaque"
    if material.clearcoat > 0:
        return "it has a clearcoat"
    return None


def _mitsuba_hair(material) -> dict:
    """Mitsuba's ``hair`` (Chiang et al. 2016, as pbrt-v3's) for a chiang_hair_bsdf made by
    chiang_hair_roughness: its β_m, β_n recovered from (v, s) by bisection of MaterialX's
    (and pbrt's) fits, which are increasing."""
    def inverse(fit, target: float) -> float:
        low, high = 0.0, 1.0
        for _ in range(60):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if fit(middle) < target else (low, middle)
        return 0.5 * (low + high)

    def near(pair, expected) -> bool:
        return all(abs(a - b) <= 1e-6 * abs(b) for a, b in zip(pair, expected))

    v, s = material.hair_roughness_r
    mapped = (near(material.hair_roughness_tt, (v * 0.25, s)) and near(material.hair_roughness_trt, (v * 4.0, s))
              and material.hair_cuticle_angle == 0.5
              and all(getattr(material, f"hair_tint_{lobe}") == (1.0, 1.0, 1.0) for lobe in ("r", "tt", "trt"))
              and isinstance(material.hair_absorption, tuple))
    if not mapped:
        raise SystemExit(f"bench_vs_mitsuba: hair {material.path} is not mapped to Mitsuba (tints, tilt or "
                         "roughness scales other than chiang_hair_roughness's defaults)")
    return {"type": "hair", "int_ior": float(material.ior), "scale_tilt": 0.0,
            "longitudinal_roughness": inverse(lambda b: (0.726 * b + 0.812 * b ** 2 + 3.7 * b ** 20) ** 2, v),
            "azimuthal_roughness": inverse(lambda b: 0.265 * b + 1.194 * b ** 2 + 5.372 * b ** 22, s),
            "sigma_a": {"type": "rgb", "value": [float(c) for c in material.hair_absorption]}}


def _mitsuba_mesh(mi, name: str, points: np.ndarray, faces: np.ndarray, bsdf, emitter=None, normals=None):
    props = mi.Properties()
    props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    mesh = mi.Mesh(name, len(points), len(faces), props=props, has_vertex_normals=normals is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(points, np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
    if normals is not None:
        params["vertex_normals"] = mi.Float(np.ascontiguousarray(normals, np.float32).ravel())
    params.update()
    return mesh


def _rect_light_corners(light) -> tuple[np.ndarray, np.ndarray]:
    """World corners and triangles of a rect light, wound so the front (the face normal,
    Mitsuba's emitting side) is the light's local −Z: pxr_layers.trace.world.light_shape."""
    w, h = light.width / 2, light.height / 2
    local = np.array([[-w, -h, 0, 1], [w, -h, 0, 1], [w, h, 0, 1], [-w, h, 0, 1]], np.float64)
    matrix = np.asarray(light.world_from_light, np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    if np.linalg.det(matrix[:3, :3]) < 0:
        faces = faces[:, ::-1]
    return (local @ matrix.T)[:, :3], faces


def _sensor(mi, spec, spp: int) -> dict:
    """A perspective sensor that sees what pxr_layers.trace.camera.ThinLensCamera sees."""
    camera = spec.camera
    if camera.projection != "perspective":
        raise SystemExit(f"bench_vs_mitsuba: {camera.projection} cameras are not mapped")
    if camera.horizontal_aperture_offset or camera.vertical_aperture_offset:
        raise SystemExit("bench_vs_mitsuba: aperture offsets are not mapped")
    from pxr_layers.trace.camera import ThinLensCamera

    width, height = spec.resolution
    traced = ThinLensCamera.from_spec(spec)  # the film window after the conform policy
    if abs((traced.half_width / traced.half_height) / (width / height) - 1) > 1e-6:
        raise SystemExit("bench_vs_mitsuba: non-square pixels (pixelAspectRatio, adjustPixelAspectRatio) "
                         "are not mapped")
    axes, origin = traced.world_from_camera, traced.position
    fov_x = np.degrees(2 * np.arctan(traced.half_width))
    lens = {"aperture_radius": traced.lens_radius, "focus_distance": traced.focus_distance}
    return {
        "type": "thinlens" if traced.lens_radius > 0 else "perspective",
        **(lens if traced.lens_radius > 0 else {}),
        "fov": float(fov_x),
        "fov_axis": "x",
        "near_clip": float(camera.clipping[0]),
        "far_clip": float(camera.clipping[1]),
        "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=(origin - axes[:, 2]).tolist(),
                                                   up=axes[:, 1].tolist()),
        "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb",
                 "component_format": "float32", "rfilter": {"type": "box"}},
        "sampler": {"type": "independent", "sample_count": spp},
    }


def mitsuba_child(args) -> int:
    """Runs in the timed child process: imports, stage read, scene, render, EXR."""
    start = time.perf_counter()
    import dataclasses

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(VARIANT)
    mi.set_log_level(mi.LogLevel.Warn)
    dr.set_thread_count(args.threads)  # the calling thread counts as one of them
    from pxr_layers.stage import load_stage

    imported = time.perf_counter()
    scene, spec = load_stage(args.stage or cornell_path())
    spec = dataclasses.replace(spec, resolution=tuple(args.resolution))
    read = time.perf_counter()

    bsdfs = []
    for material in scene.materials:
        if material.hair:
            bsdfs.append(mi.load_dict(_mitsuba_hair(material)))
            continue
        why = _plain_lambertian(material)
        if why is not None:
            raise SystemExit(f"bench_vs_mitsuba: material {material.path} is not mapped to Mitsuba: {why}")
        bsdfs.append(mi.load_dict({"type": "twosided", "bsdf": {
            "type": "diffuse", "reflectance": {"type": "rgb", "value": [float(c) for c in material.diffuse_color]}}}))
    black = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})

    objects = {}
    for number, mesh in enumerate(scene.meshes):
        for material in np.unique(mesh.triangle_material):
            triangles = mesh.triangles[mesh.triangle_material == material]
            if mesh.normal_values is None:
                points, faces, normals = mesh.points, triangles, None
            else:  # one normal per corner: unweld
                points = mesh.points[triangles].reshape(-1, 3)
                normals = mesh.normals[mesh.triangle_material == material].reshape(-1, 3)
                faces = np.arange(len(points)).reshape(-1, 3)
            name = f"mesh{number}_{material}"
            objects[name] = _mitsuba_mesh(mi, name, points, faces, bsdfs[material], normals=normals)
    for number, strands in enumerate(scene.strands):
        kinds = {"linear": "linearcurve", "bspline": "bsplinecurve"}
        if strands.shape not in kinds:
            raise SystemExit(f"bench_vs_mitsuba: {strands.shape} strands ({strands.path}) are not mapped")
        objects[f"strands{number}"] = mi.load_dict({"type": kinds[strands.shape],
                                                    "filename": _curve_file(strands, Path(args.mitsuba_child).parent),
                                                    "bsdf": bsdfs[strands.material]})
    for number, light in enumerate(scene.lights):
        if light.kind != "rect":
            raise SystemExit(f"bench_vs_mitsuba: light {light.path} ({light.kind}) is not mapped to Mitsuba")
        points, faces = _rect_light_corners(light)
        radiance = [float(c) for c in light.radiance]
        emitter = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": radiance}})
        objects[f"light{number}"] = _mitsuba_mesh(mi, f"light{number}", points, faces, black, emitter=emitter)

    mitsuba_scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": args.max_depth + 1, "rr_depth": ROULETTE_DEPTH,
                       "hide_emitters": False},
        "sensor": _sensor(mi, spec, args.spp),
        **objects,
    })
    built = time.perf_counter()
    image = mi.render(mitsuba_scene, spp=args.spp, seed=0)
    dr.eval(image)
    dr.sync_thread()  # the LLVM backend launches kernels asynchronously
    rendered = time.perf_counter()
    mi.util.write_bitmap(args.mitsuba_child, image)
    written = time.perf_counter()
    print(json.dumps({"imports": imported - start, "stage": read - imported, "scene": built - read,
                      "render": rendered - built, "write": written - rendered,
                      "triangles": sum(int(m.face_count()) for m in objects.values() if hasattr(m, "face_count"))}))
    return 0


# -- the parent ------------------------------------------------------------------------------


def run_timed(command: list[str], environment: dict[str, str], what: str) -> tuple[float, str]:
    """Wall seconds of a child process, and its stdout; exits 1 with its stderr if it fails."""
    start = time.perf_counter()
    done = subprocess.run(command, env=environment, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        tail = "\n".join((done.stderr or done.stdout).strip().splitlines()[-15:])
        print(f"bench_vs_mitsuba: the {what} render failed (exit {done.returncode}):\n{tail}")
        sys.exit(1)
    return seconds, done.stdout


def read_rgb(path: str) -> np.ndarray:
    """(h, w, 3) float64 RGB of an EXR's first part (pxr-layers' part 0 is the beauty)."""
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(path)
    if image is None:
        raise SystemExit(f"bench_vs_mitsuba: cannot read {path}: {oiio.geterror()}")
    spec = image.spec()
    pixels = np.asarray(image.read_image(0, 0, 0, spec.nchannels, "float"), np.float64)
    image.close()
    names = list(spec.channelnames)
    return pixels.reshape(spec.height, spec.width, spec.nchannels)[..., [names.index(c) for c in "RGB"]]


def block_means(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means of the RGB average over BLOCK × BLOCK blocks, and their standard errors (from
    the spread of the block's pixels: includes the image's own variation, so an upper bound
    on the noise). Partial blocks at the right and bottom edges are left out."""
    grey = rgb.mean(axis=2)
    rows, cols = grey.shape[0] // BLOCK, grey.shape[1] // BLOCK
    blocks = grey[:rows * BLOCK, :cols * BLOCK].reshape(rows, BLOCK, cols, BLOCK).transpose(0, 2, 1, 3)
    blocks = blocks.reshape(rows, cols, BLOCK * BLOCK)
    return blocks.mean(axis=2), blocks.std(axis=2, ddof=1) / np.sqrt(BLOCK * BLOCK)


def compare(ours: np.ndarray, theirs: np.ndarray) -> dict:
    if ours.shape != theirs.shape:
        raise SystemExit(f"bench_vs_mitsuba: image sizes differ: {ours.shape} and {theirs.shape}")
    our_mean, their_mean = ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1))
    mean_difference = our_mean / np.maximum(their_mean, 1e-30) - 1
    our_blocks, our_error = block_means(ours)
    their_blocks, their_error = block_means(theirs)
    floor = 1e-6 * float(their_mean.mean())  # blocks black in both (outside the box) are equal
    both_black = (our_blocks <= floor) & (their_blocks <= floor)
    difference = np.where(both_black, 0.0, our_blocks / np.maximum(their_blocks, floor) - 1)
    # Blocks that no noise reaches (inside the light) still differ by float rounding.
    noise = np.hypot(our_error, their_error) + 1e-4 * np.maximum(our_blocks, their_blocks) + floor
    sigmas = np.where(both_black, 0.0, np.abs(our_blocks - their_blocks) / noise)
    worst = np.unravel_index(np.argmax(np.abs(difference)), difference.shape)
    return {
        "our_mean": our_mean, "their_mean": their_mean, "mean_difference": mean_difference,
        "blocks": difference.size, "worst": float(difference[worst]), "worst_at": (int(worst[1]), int(worst[0])),
        "within": float((np.abs(difference) <= TARGET_BLOCK).mean()),
        "beyond_noise": int((sigmas > NOISE_SIGMAS).sum()),
    }


def verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def triple(values, form: str = ".4f") -> str:
    return "(" + ", ".join(format(v, form) for v in values) + ")"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8, help="scattering events, as pxr-layers counts them")
    parser.add_argument("--threads", type=int, default=default_threads())
    parser.add_argument("--repeat", type=int, default=1, help="renders of each, keeping the fastest")
    parser.add_argument("--keep", metavar="DIR", help="write the images to DIR (default: a temporary folder)")
    parser.add_argument("--lens", type=float, nargs=2, metavar=("F_STOP", "FOCUS_DISTANCE"),
                        help="depth of field: the camera's fStop and focusDistance (mm), e.g. 0.1 1000")
    parser.add_argument("--curves", action="store_true",
                        help="a lawn of 400 hairs (linear BasisCurves) on the Cornell floor: Mitsuba's linearcurve")
    parser.add_argument("--hair", action="store_true",
                        help="--curves with a MaterialX chiang_hair_bsdf on the lawn: Mitsuba's hair BSDF")
    parser.add_argument("--mitsuba-child", metavar="EXR", help=argparse.SUPPRESS)
    parser.add_argument("--stage", help=argparse.SUPPRESS)  # the child's stage
    args = parser.parse_args()
    if args.mitsuba_child:
        return mitsuba_child(args)

    found = mitsuba_environment()
    if found is None:
        return 2
    mitsuba_env, mitsuba_version = found

    width, height = args.resolution
    with tempfile.TemporaryDirectory(prefix="bench_vs_mitsuba-") as scratch:
        out = Path(args.keep or scratch)
        out.mkdir(parents=True, exist_ok=True)
        stage = (lens_stage(out, *args.lens) if args.lens else curves_stage(out, hair=args.hair)
                 if args.curves or args.hair else cornell_path())
        def ours(rendered: str) -> list[str]:
            return [sys.executable, "-m", "pxr_layers.cli.main", "render", "-q", rendered, "--resolution", str(width),
                    str(height), "--spp", str(args.spp), "--max-depth", str(args.max_depth), "--no-previews",
                    "--threads", str(args.threads)]

        common = ours(stage)
        runs = {
            "pxr-layers (no index)": (common + ["--no-index", "-o", str(out / "ours")], dict(os.environ)),
            "pxr-layers (index)": (common + ["-o", str(out / "ours-index")], dict(os.environ)),
            "Mitsuba": ([sys.executable, str(Path(__file__).resolve()), "--mitsuba-child", str(out / "mitsuba.exr"),
                         "--resolution", str(width), str(height), "--spp", str(args.spp), "--max-depth",
                         str(args.max_depth), "--threads", str(args.threads), "--stage", stage], mitsuba_env),
        }
        if args.lens:  # the same frame through a pinhole: what the lens costs
            runs["pxr-layers (no index, pinhole)"] = (
                ours(cornell_path()) + ["--no-index", "-o", str(out / "pinhole")], dict(os.environ))
        lens = f", lens f/{args.lens[0]:g} focused at {args.lens[1]:g} mm" if args.lens else ""
        print(f"scene     : {Path(stage).name} (metres){lens}, {width}x{height}, {args.spp} spp, max depth {args.max_depth} "
              f"(Mitsuba path: max_depth {args.max_depth + 1}, rr_depth {ROULETTE_DEPTH}), {args.threads} threads")
        print(f"mitsuba   : {mitsuba_version}")
        print(f"timing    : whole-process wall time of each child, fastest of {args.repeat}, interleaved")
        best: dict[str, float] = {}
        phases = None
        for repeat in range(args.repeat):
            times = {}
            for name, (command, environment) in runs.items():
                times[name], stdout = run_timed(command, environment, name)
                if name == "Mitsuba" and times[name] < best.get(name, float("inf")):
                    phases = json.loads(stdout.strip().splitlines()[-1])
                best[name] = min(best.get(name, float("inf")), times[name])
            if args.repeat > 1:
                print(f"  repeat {repeat + 1}: " + ", ".join(f"{name} {times[name]:.2f} s" for name in runs))

        print()
        column = max(map(len, runs)) + 2
        print(f"  {'renderer':<{column}}{'seconds':>9}")
        for name in runs:
            print(f"  {name:<{column}}{best[name]:>9.2f}")
        print(f"  (Mitsuba child: imports {phases['imports']:.2f} s, load_stage {phases['stage']:.2f} s, scene "
              f"{phases['scene']:.2f} s, render {phases['render']:.2f} s, EXR {phases['write']:.2f} s; "
              f"{phases['triangles']} triangles)")
        ratio = best["Mitsuba"] / best["pxr-layers (no index)"]
        print(f"speed     : pxr-layers / Mitsuba = T_mitsuba / T_ours (no index) = {ratio:.3f}  "
              f"(target >= {TARGET_RATIO}: {verdict(ratio >= TARGET_RATIO)}; moonshot >= {MOONSHOT_RATIO:g}: "
              f"{verdict(ratio >= MOONSHOT_RATIO)}); with the index {best['Mitsuba'] / best['pxr-layers (index)']:.3f}")
        overhead = best["pxr-layers (index)"] / best["pxr-layers (no index)"] - 1
        print(f"index     : the index costs {overhead:+.1%} of the render without it  "
              f"(target <= {TARGET_INDEX_OVERHEAD:.0%}: {verdict(overhead <= TARGET_INDEX_OVERHEAD)})")
        if args.lens:
            lens_cost = best["pxr-layers (no index)"] / best["pxr-layers (no index, pinhole)"] - 1
            print(f"lens      : depth of field costs {lens_cost:+.1%} of the same frame through a pinhole (no index)  "
                  f"(target <= {TARGET_LENS_OVERHEAD:.0%}: {verdict(lens_cost <= TARGET_LENS_OVERHEAD)})")

        ours_exr = out / "ours" / "cornell.exr"  # the Cornell recipe's product
        if not ours_exr.exists():
            written = sorted((out / "ours").glob("*.exr"))
            if not written:
                print(f"bench_vs_mitsuba: pxr-layers wrote no EXR in {out / 'ours'}")
                return 1
            ours_exr = written[0]
        figures = compare(read_rgb(str(ours_exr)), read_rgb(str(out / "mitsuba.exr")))
        worst_mean = float(np.abs(figures["mean_difference"]).max())
        print(f"image     : mean RGB ours {triple(figures['our_mean'])}, Mitsuba {triple(figures['their_mean'])}, "
              f"ours/Mitsuba - 1 = {triple(figures['mean_difference'], '+.2%')}  "
              f"(target within {TARGET_MEAN:.0%}: {verdict(worst_mean <= TARGET_MEAN)})")
        x, y = figures["worst_at"]
        print(f"blocks    : {figures['blocks']} blocks of {BLOCK}x{BLOCK} px: worst {figures['worst']:+.2%} at block "
              f"({x}, {y}) (pixels x {x * BLOCK}.., y {y * BLOCK}.. from the top left), {figures['within']:.1%} within "
              f"{TARGET_BLOCK:.0%}  (target every block within {TARGET_BLOCK:.0%}: "
              f"{verdict(figures['within'] == 1.0)}); {figures['beyond_noise']} beyond {NOISE_SIGMAS:g} standard "
              "errors of their noise")
        if args.keep:
            print(f"images    : {ours_exr} and {out / 'mitsuba.exr'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
