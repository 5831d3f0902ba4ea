"""The luxtest conformance table: pxr-layers' renders of the UsdLux conformance stages
against the quadrature reference (tests/usdlux_reference.py), pixel by pixel.

    python benchmarks/luxtest_table.py [--stages rect disk ...] [--frames 1 5 ...] [--all-frames]
                                       [--resolution 64] [--spp 1024] [--order 12] [--tolerance 0.03]

The stages are ../shared/data/luxtest/usd/{rect,disk,sphere,cylinder,distant}.usda (see its
README and light_descriptions.json): one light animated through groups of 5 frames,
a 10 × 10 floor and a white square tilted 45°, the camera 30 units up looking down. Each
stage is rendered through a small layer that sublayers it and binds the floor to the
square's white UsdPreviewSurface (MaterialBindingAPI), by ``pxr-layers render`` (in this
process: the CLI's main) with --max-depth 1 (direct light only), --no-index; the beauty is
read back from the EXR with OpenImageIO.

Each pixel is compared with ρ·E/π, E from the reference at the points of the floor and the
square the camera sees (camera rays from the USD camera, a pinhole from its focal length
and apertures, as the stage says at the frame). The render's pixel filter is a box (one
uniformly jittered ray per sample), so the reference is its pixel's mean to O(h⁴):
(2 · value at the centre + mean of the 4 corners) / 3. Pixels whose centre and corners do
not all see the same surface (the outline of the square and of the floor) are left out;
so are pixels that straddle the plane of a rect or disk light (where it meets the floor,
the irradiance is singular), and pixels whose camera ray passes through the light's shape
first ("behind light": the stages ask for camera-invisible lights, so there the floor is
expected), which get a column of their own.

Per frame, over the surface pixels: the ratio of the means (render / reference, per RGB
channel when the light is coloured); the median |relative error| over the pixels where the
reference is above 5 % of its maximum, and the fraction of those within 2 %; the render's
noise there: each frame is rendered as two halves of --spp with different seeds, whose
half difference is a sample of the noise of their mean (its rms relative to the reference,
and the fraction of pixels within 2 % that this noise alone would leave: what a perfect
renderer would score); the ratio of the means behind the light. A frame is off when a
channel's mean ratio, or the one behind the light, is off by more than --tolerance (3 %)
plus three standard errors of the noise over the pixels counted.

The defaults (64 × 64 at 1024 spp, order 12) run the default frames in about six minutes
on two cores; the reference's error is ~1e-6 where its integrand is smooth and up to ~1 %
in penumbrae and at hard cone edges (see tests/usdlux_reference.py), below the noise.

Default frames: the first and last of every frame group (all 60 with --all-frames);
distant: frames 1–35. Exit 0 if every frame is within the tolerance, 1 if one is off (or
something fails), 2 without ../shared.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import usdlux_reference as reference  # noqa: E402  (imports pxr_layers.stage first: the schema)
import OpenImageIO as oiio  # noqa: E402
from pxr import Usd, UsdGeom, UsdShade  # noqa: E402

from pxr_layers.cli.main import main as pxr_layers  # noqa: E402

LUXTEST = Path(__file__).resolve().parents[2] / "shared/data/luxtest"
STAGES = ("rect", "disk", "sphere", "cylinder", "distant")
LIGHTS = {"rect": "/lights/rect_light", "disk": "/lights/disk_light", "sphere": "/lights/sphere_light",
          "cylinder": "/lights/cylinder_light", "distant": "/lights/distant_light"}
FLOOR, SQUARE = "/floorPlane/mesh_0", "/smallAngledRect/mesh_0"
MATERIAL = "/materials/usdpreviewsurface1"
BRIGHT = 0.05  # per-pixel errors where the reference is above this fraction of its maximum
WITHIN = 0.02

OVERRIDE = """#usda 1.0
(
    metersPerUnit = {meters}
    subLayers = [@{stage}@]
    upAxis = "{up}"
)

over "floorPlane"
{{
    over "mesh_0" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        rel material:binding = <{material}>
    }}
}}
"""


class Collect(logging.Handler):
    """Keeps the distinct warnings of the renders, to list once at the end."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: dict[str, None] = {}

    def emit(self, record):
        self.messages.setdefault(record.getMessage())


# -- the stage as the reference sees it -----------------------------------------------------


def quad_of(stage: Usd.Stage, path: str, time: float) -> reference.Quad | None:
    """A planar grid mesh in its local XZ plane → its world parallelogram (metres)."""
    prim = stage.GetPrimAtPath(path)
    if not prim:
        return None
    points = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(time), float)
    if np.abs(points[:, 1]).max() > 1e-6:
        raise ValueError(f"{path}: not a grid in its local XZ plane")
    low, high = points.min(axis=0), points.max(axis=0)
    matrix = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time), float).T
    matrix *= UsdGeom.GetStageMetersPerUnit(stage)
    centre = matrix[:3, :3] @ ((low + high) / 2) + matrix[:3, 3]
    return reference.Quad(centre, matrix[:3, 0] * (high[0] - low[0]), matrix[:3, 2] * (high[2] - low[2]), path)


def camera_rays(stage: Usd.Stage, time: float, resolution: int):
    """World origin (3,) and unit directions through the pixel centres (H, W, 3) and the
    pixel corners (H + 1, W + 1, 3) of a square image, row 0 at the top (metres)."""
    camera = UsdGeom.Camera(stage.GetPrimAtPath("/cameras/camera1")).GetCamera(time)
    if abs(camera.horizontalAperture - camera.verticalAperture) > 1e-6 * camera.horizontalAperture:
        raise ValueError("the table renders square images: the camera's aperture must be square")
    matrix = np.array(camera.transform, float).T
    half = camera.horizontalAperture / 2 / camera.focalLength
    offset = np.array([camera.horizontalApertureOffset, camera.verticalApertureOffset]) / camera.focalLength

    def through(film):  # film positions in [0, 1], x right, y down
        x = (2 * film[..., 0] - 1) * half + offset[0]
        y = (1 - 2 * film[..., 1]) * half + offset[1]
        local = np.stack([x, y, -np.ones_like(x)], axis=-1)
        world = local @ matrix[:3, :3].T
        return world / np.linalg.norm(world, axis=-1, keepdims=True)

    centres = (np.arange(resolution) + 0.5) / resolution
    corners = np.arange(resolution + 1) / resolution
    grid = lambda values: np.stack(np.meshgrid(values, values, indexing="xy"), axis=-1)  # noqa: E731
    return matrix[:3, 3] * UsdGeom.GetStageMetersPerUnit(stage), through(grid(centres)), through(grid(corners))


def reference_image(stage: Usd.Stage, light_path: str, time: float, resolution: int, order: int):
    """(H, W, 3) ρ·E/π per pixel (ρ the white material's diffuseColor, which the floor wears
    too here); (H, W) bool: its centre and corners see one surface, on one side of a planar
    light's plane (E is singular where a rect or disk meets a surface, as in rect frames
    21–30); (H, W) bool: some / all of their camera rays meet the light's shape first."""
    light = reference.read_light(stage.GetPrimAtPath(light_path), time)
    quads = [quad for quad in (quad_of(stage, FLOOR, time), quad_of(stage, SQUARE, time)) if quad is not None]
    albedo = np.array(UsdShade.Shader(stage.GetPrimAtPath(MATERIAL + "/usdpreviewsurface1"))
                      .GetInput("diffuseColor").Get(time), float)
    origin, centres, corners = camera_rays(stage, time, resolution)
    values, keys, behind = [], [], []
    for directions in (centres, corners):
        rays = directions.reshape(1, -1, 3)
        hits = np.stack([quad.intersect(origin[None], rays)[0] for quad in quads])  # (quads, k)
        t, nearest = hits.min(axis=0), np.where(np.isfinite(hits.min(axis=0)), hits.argmin(axis=0), -1)
        points = origin + np.where(np.isfinite(t), t, 0.0)[:, None] * rays[0]
        value = np.zeros((len(t), 3))
        for index, quad in enumerate(quads):
            mine = nearest == index
            facing = np.where((rays[0, mine] @ quad.normal)[:, None] < 0, quad.normal, -quad.normal)
            value[mine] = reference.irradiance(light, points[mine], facing, quads, receiver=quad.path, order=order)
        side = np.sign((points - light.origin) @ light.axis) if light.kind in ("rect", "disk") else 0
        values.append((albedo * value / np.pi).reshape(*directions.shape[:2], 3))
        keys.append(np.where(nearest >= 0, 3 * nearest + side + 1, -1).reshape(directions.shape[:2]))
        behind.append((reference.hit(light, origin[None], rays, front_only=False)[0] < t).reshape(directions.shape[:2]))

    def at_corners(grid):  # (n + 1, n + 1, ...) → the pixels' four corners, each (n, n, ...)
        return [grid[:-1, :-1], grid[1:, :-1], grid[:-1, 1:], grid[1:, 1:]]

    one_surface = (keys[0] >= 0) & np.logical_and.reduce([key == keys[0] for key in at_corners(keys[1])])
    backs = [behind[0], *at_corners(behind[1])]
    reference_value = (2 * values[0] + sum(at_corners(values[1])) / 4) / 3
    return reference_value, one_surface, np.logical_or.reduce(backs), np.logical_and.reduce(backs)


# -- rendering ------------------------------------------------------------------------------


def render(layer: Path, frame: int, resolution: int, spp: int, seed: int, out: Path) -> np.ndarray:
    """(H, W, 3) beauty of pxr-layers render at ``frame``, read from its EXR."""
    args = ["render", str(layer), "--frame", str(frame), "--spp", str(spp), "--resolution", str(resolution),
            str(resolution), "--max-depth", "1", "--seed", str(seed), "--no-index", "--no-previews", "-q",
            "-o", str(out)]
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        code = pxr_layers(args)
    if code != 0:
        raise RuntimeError(f"pxr-layers {' '.join(args)} exited {code}")
    (exr,) = [Path(line) for line in printed.getvalue().split()]
    image = oiio.ImageBuf(str(exr))
    pixels = image.get_pixels(oiio.FLOAT)
    exr.unlink()
    return np.asarray(pixels, float)[..., :3]


# -- the table ------------------------------------------------------------------------------


def frames_of(description: dict, all_frames: bool) -> list[tuple[int, str]]:
    """(frame, what its group varies) for the frames to render."""
    chosen = []
    for group in description["frame_groups"]:
        first, last = group["frames"]
        label = ", ".join(name.replace("inputs:", "").replace("shaping:", "") for name in group["varying"]) or "—"
        constants = group["non_default_constants"]
        extras = [name for name in ("inputs:normalize", "inputs:shaping:ies:normalize") if constants.get(name)]
        if any(name.startswith("inputs:shaping:ies:file") for name in constants):
            label += " (IES" + (", normalized)" if "inputs:shaping:ies:normalize" in extras else ")")
        elif "inputs:normalize" in extras:
            label += " (normalized)"
        for frame in range(first, last + 1) if all_frames else sorted({first, last}):
            chosen.append((frame, label))
    return chosen


def figures(ours, spread, ref, compared, behind, coloured: bool) -> dict:
    """The row's figures. ours: the render; spread: half the difference of its two halves (a
    sample of its noise); per channel when coloured, else on the channels' mean."""
    row = {"mean ratio": [], "median": [], "within": []}
    bright = compared & (ref.mean(-1) > BRIGHT * ref.mean(-1).max()) if ref.max() > 0 else compared & False
    for channel in range(3) if coloured else [slice(None)]:
        o, r = ours[..., channel], ref[..., channel]
        if not coloured:
            o, r = o.mean(-1), r.mean(-1)
        row["mean ratio"].append(_ratio(o[compared].sum(), r[compared].sum()))
        error = np.abs(o[bright] / r[bright] - 1)
        row["median"].append(float(np.median(error)) if error.size else float("nan"))
        row["within"].append(float((error <= WITHIN).mean()) if error.size else float("nan"))
    noise = np.abs(spread.mean(-1)[bright] / ref.mean(-1)[bright])
    row["noise"] = float(np.sqrt(np.mean(noise**2))) if noise.size else 0.0
    row["noise within"] = float((noise <= WITHIN).mean()) if noise.size else float("nan")
    row["behind"] = _ratio(ours[behind].sum(), ref[behind].sum()) if behind.any() else None
    return row


def _ratio(ours: float, ref: float) -> float:
    return ours / ref if ref > 0 else (math.inf if ours > 0 else 1.0)


def fmt(values, pattern):
    return "/".join(pattern.format(value) for value in values)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES))
    parser.add_argument("--frames", nargs="+", type=int, help="these frames of every stage (default: see above)")
    parser.add_argument("--all-frames", action="store_true", help="every frame of every group")
    parser.add_argument("--resolution", type=int, default=64, help="square image side (default 64)")
    parser.add_argument("--spp", type=int, default=1024, help="(default 1024, in two renders of half as many)")
    parser.add_argument("--order", type=int, default=12, help="the reference's quadrature order (default 12)")
    parser.add_argument("--tolerance", type=float, default=0.03, help="on the mean ratio (default 0.03)")
    args = parser.parse_args()
    collected = Collect()
    logging.basicConfig(level=logging.WARNING, handlers=[collected])  # before the CLI's own set-up
    if not (LUXTEST / "usd").is_dir():
        print(f"luxtest_table: {LUXTEST / 'usd'} not found (../shared is needed)", file=sys.stderr)
        return 2
    descriptions = json.loads((LUXTEST / "light_descriptions.json").read_text())

    print(f"luxtest conformance: {args.resolution}x{args.resolution}, {args.spp} spp, --max-depth 1; "
          f"reference order {args.order}; a frame is off when a mean ratio is off by more than "
          f"{args.tolerance:.0%} (+ 3 standard errors of the noise)\n")
    print("| stage | frame | group | mean ratio | median abs err | within 2 % | noise (within 2 %) | behind light | |")
    print("|---|---:|---|---|---|---|---|---:|---|")
    off, started = [], time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="luxtest-") as folder:
        scratch = Path(folder)
        for name in args.stages:
            source = LUXTEST / "usd" / f"{name}.usda"
            original = Usd.Stage.Open(str(source))
            layer = scratch / f"{name}_white_floor.usda"
            layer.write_text(OVERRIDE.format(stage=source.as_posix(), material=MATERIAL,
                                             meters=UsdGeom.GetStageMetersPerUnit(original),
                                             up=UsdGeom.GetStageUpAxis(original)))
            stage = Usd.Stage.Open(str(layer))
            labels = dict(frames_of(descriptions[name], True))
            frames = ([(frame, labels.get(frame, "?")) for frame in args.frames] if args.frames
                      else frames_of(descriptions[name], args.all_frames))
            for frame, label in frames:
                try:
                    halves = [render(layer, frame, args.resolution, args.spp // 2, seed, scratch) for seed in (0, 1)]
                    ref, one_surface, partly_behind, behind = reference_image(stage, LIGHTS[name], frame,
                                                                              args.resolution, args.order)
                except Exception as error:  # noqa: BLE001 — report the frame and go on
                    off.append((name, frame))
                    print(f"| {name} | {frame} | {label} | FAILED: {error} | | | | | |", flush=True)
                    continue
                compared, behind = one_surface & ~partly_behind, one_surface & behind
                coloured = float(np.ptp(ref.sum(axis=(0, 1)))) > 1e-3 * float(ref.sum(axis=(0, 1)).max())
                row = figures((halves[0] + halves[1]) / 2, (halves[0] - halves[1]) / 2, ref, compared, behind,
                              coloured)
                # the tolerance, widened by three standard errors of the noise over the pixels counted
                checks = [(ratio, compared.sum()) for ratio in row["mean ratio"]]
                checks += [] if row["behind"] is None else [(row["behind"], behind.sum())]
                bad = any(not abs(ratio - 1) <= args.tolerance + 3 * row["noise"] / math.sqrt(count)
                          for ratio, count in checks)
                if bad:
                    off.append((name, frame))
                behind_text = "" if row["behind"] is None else f"{row['behind']:.3f} ({int(behind.sum())} px)"
                print(f"| {name} | {frame} | {label} | {fmt(row['mean ratio'], '{:.3f}')} | "
                      f"{fmt(row['median'], '{:.2%}')} | {fmt(row['within'], '{:.0%}')} | "
                      f"{row['noise']:.2%} ({row['noise within']:.0%}) | {behind_text} | {'OFF' if bad else 'ok'} |",
                      flush=True)

    if collected.messages:
        print("\nwarnings from the renders (once each):")
        for message in collected.messages:
            print(f"  {message}")
    print(f"\n{len(off)} of the frames off" + (": " + ", ".join(f"{n} {f}" for n, f in off) if off else "")
          + f" ({time.perf_counter() - started:.0f} s)")
    return 1 if off else 0


if __name__ == "__main__":
    sys.exit(main())
