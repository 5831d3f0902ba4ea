"""The cost of shaped lights, measured side by side in one run.

    python benchmarks/bench_lights.py [--resolution 256 256] [--spp 32] [--repeats 5] [--write-ies]

The showcase (render/showcase.usda: a rect key, a sphere fill, a dome) gets two more lights,
through a small layer that sublayers it:

* shaped: a SphereLight spot (radius 0.1 m, ShapingAPI cone 30°, softness 0.3, aimed down at
  the set) and a DiskLight (radius 0.1 m) with the IES profile render/ies/spot_cos8.ies
  (normalized);
* plain: the same two lights, same place and intensity, without ShapingAPI.

Both are read once, prepared once, and traced alternately with ``trace_pixels`` (the
tracer's stage alone: the lights' cost, without the stage read and the EXR a
``render_frame`` adds; all cores, no path index), best of --repeats each, after a warm-up that compiles the kernels
if this version of the sources is new. Ratio: shaped over plain (target <= 1.2x). Timings
during which other processes used the CPU are flagged (the machine may be shared).

render/ies/spot_cos8.ies is made by this script (``--write-ies`` writes it again):
I(θ, φ) = 1000 cd · cos⁸θ · (1 + 0.25 cos φ), θ 0–90° in 5° steps, φ 0–360° in 90° steps.

Exit 0 whether the target is met or missed; 1 if something fails.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
from pathlib import Path

import pxr_layers.stage  # noqa: F401 — registers the pxr-layers schema before any stage is opened
from bench_render import NOTES, Load, note_load, wait_for_quiet
from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings, prepare, trace_pixels

ROOT = Path(__file__).resolve().parents[1]
SHOWCASE = ROOT / "render" / "showcase.usda"
IES = ROOT / "render" / "ies" / "spot_cos8.ies"
TARGET = 1.2

LIGHTS = """#usda 1.0
(
    subLayers = [@{showcase}@]
)

over "World"
{{
    over "Lights"
    {{
        def SphereLight "spot" ({spot_schemas})
        {{
            float inputs:intensity = 60
            float inputs:radius = 0.1
{spot_shaping}            float3 xformOp:rotateXYZ = (-90, 0, 0)
            double3 xformOp:translate = (-0.4, 2.6, 0.5)
            uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
        }}

        def DiskLight "profiled" ({ies_schemas})
        {{
            float inputs:intensity = 40
            float inputs:radius = 0.1
{ies_shaping}            float3 xformOp:rotateXYZ = (-90, 0, 0)
            double3 xformOp:translate = (1.0, 2.4, 0.2)
            uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
        }}
    }}
}}
"""
SHAPING = 'prepend apiSchemas = ["ShapingAPI"]'
SPOT_SHAPING = """            float inputs:shaping:cone:angle = 30
            float inputs:shaping:cone:softness = 0.3
"""
IES_SHAPING = """            asset inputs:shaping:ies:file = @{ies}@
            bool inputs:shaping:ies:normalize = 1
"""


def spot_profile(peak: float = 1000.0, power: int = 8) -> str:
    """An LM-63-2002 type C profile: peak · cos^power θ · (1 + 0.25 cos φ)."""
    vertical = list(range(0, 91, 5))
    horizontal = list(range(0, 361, 90))
    rows = [" ".join(f"{peak * math.cos(math.radians(v)) ** power * (1 + 0.25 * math.cos(math.radians(h))):.3f}"
                     for v in vertical) for h in horizontal]
    return "\n".join([
        "IESNA:LM-63-2002",
        "[TEST] synthetic spotlight for benchmarks/bench_lights.py",
        "[_GENERATOR] benchmarks/bench_lights.py --write-ies: I(theta, phi) = 1000 cd * cos^8(theta) * "
        "(1 + 0.25 cos(phi)), theta 0-90 deg in 5 deg steps, phi 0-360 deg in 90 deg steps",
        "TILT=NONE",
        f"1 -1 1 {len(vertical)} {len(horizontal)} 1 2 0 0 0",
        "1 1 0",
        " ".join(str(v) for v in vertical),
        " ".join(str(h) for h in horizontal),
        *rows,
    ]) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--wait", type=float, default=20.0,
                        help="wait at most this many seconds for other processes to leave the CPU (default 20)")
    parser.add_argument("--write-ies", action="store_true", help=f"write {IES.relative_to(ROOT)} again, then exit")
    args = parser.parse_args()
    if args.write_ies:
        IES.parent.mkdir(exist_ok=True)
        IES.write_text(spot_profile())
        print(f"wrote {IES}")
        return 0

    scenes = {}
    with tempfile.TemporaryDirectory(prefix="bench-lights-") as folder:
        for name, shaped in (("shaped", True), ("plain", False)):
            layer = Path(folder) / f"showcase_{name}.usda"
            layer.write_text(LIGHTS.format(
                showcase=SHOWCASE.as_posix(), spot_schemas=SHAPING if shaped else "",
                ies_schemas=SHAPING if shaped else "", spot_shaping=SPOT_SHAPING if shaped else "",
                ies_shaping=IES_SHAPING.format(ies=IES.as_posix()) if shaped else ""))
            scenes[name] = load_stage(layer)
    spec = dataclasses.replace(scenes["plain"][1], resolution=tuple(args.resolution))
    shaped_lights = [light.name for light in scenes["shaped"][0].lights if light.shaping is not None]
    settings = TraceSettings(spp=args.spp, record_paths=False)
    small = dataclasses.replace(spec, resolution=(32, 32))
    for scene, _ in scenes.values():  # compile the kernels if the sources are new
        trace_pixels(prepare(scene, small, TraceSettings(spp=1)), 0, 32 * 32, lambda batch: None)
    integrators = {name: prepare(scene, spec, settings) for name, (scene, _) in scenes.items()}
    pixels = args.resolution[0] * args.resolution[1]
    wait_for_quiet(args.wait)
    best, disturbed = {name: math.inf for name in scenes}, {name: "" for name in scenes}
    for repeat in range(args.repeats):
        for name, integrator in integrators.items():
            with Load() as load:
                trace_pixels(integrator, 0, pixels, lambda batch: None)
            note = note_load(f"{name}, repeat {repeat + 1}", load)
            if load.wall < best[name]:
                best[name], disturbed[name] = load.wall, note
    ratio = best["shaped"] / best["plain"]
    print(f"showcase + a 30° soft spot (SphereLight, cone 30°, softness 0.3) and an IES DiskLight "
          f"({IES.name}); lights with shaping as read: {', '.join(shaped_lights) or 'none'}")
    print(f"trace {args.resolution[0]}x{args.resolution[1]}, {args.spp} spp, max depth {settings.max_depth}, "
          f"best of {args.repeats}:")
    print(f"  shaped   {best['shaped']:7.2f} s{disturbed['shaped']}")
    print(f"  plain    {best['plain']:7.2f} s{disturbed['plain']}")
    verdict = "met" if ratio <= TARGET else "MISSED"
    print(f"cost of shaping and IES: {ratio:.2f}x (target <= {TARGET}x: {verdict})")
    for note in NOTES:
        print(f"disturbed: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
