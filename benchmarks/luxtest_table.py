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
so are pixels whose camera ray passes through the light's shape first ("behind light":
the stages ask for camera-invisible lights, so there the floor is expected), which get a
column of their own.

Per frame, over the surface pixels: the ratio of the means (render / reference, per RGB
channel when the light is coloured); the median |relative error| over the pixels where the
reference is above 5 % of its maximum, and the fraction of those within 2 %; the ratio of
the means behind the light. A frame is off when a channel's mean ratio is off by more than
--tolerance (default 3 %), or the pixels behind the light are. Every stage's first frame is
rendered a second time with another seed: the rms difference of the two over √2, relative
to the reference, is the render's per-pixel noise at this spp, and the fraction of pixels
within 2 % that this noise alone leaves (what a perfect renderer would score), per stage.

The defaults (64 × 64 at 1024 spp, order 12) run the default frames in about four minutes
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
    subLayers = [@{stage}@]
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
    too here); (H, W) bool: its centre and corners see one surface; (H, W) bool: some / all
    of their camera rays meet the light's shape before any surface."""
    light = reference.read_light(stage.GetPrimAtPath(light_path), time)
    quads = [quad for quad in (quad_of(stage, FLOOR, time), quad_of(stage, SQUARE, time)) if quad is not None]
    albedo = np.array(UsdShade.Shader(stage.GetPrimAtPath(MATERIAL + "/usdpreviewsurface1"))
                      .GetInput("diffuseColor").Get(time), float)
    origin, centres, corners = camera_rays(stage, time, resolution)
    values, surfaces, behind = [], [], []
    for directions in (centres, corners):
        rays = directions.reshape(1, -1, 3)
        hits = np.stack([quad.intersect(origin[None], rays)[0] for quad in quads])  # (quads, k)
        nearest = np.where(np.isfinite(hits.min(axis=0)), hits.argmin(axis=0), -1)
        t = hits.min(axis=0)
        value = np.zeros((rays.shape[1], 3))
        for index, quad in enumerate(quads):
            mine = nearest == index
            points = origin + t[mine, None] * rays[0, mine]
            facing = np.where((rays[0, mine] @ quad.normal)[:, None] < 0, quad.normal, -quad.normal)
            value[mine] = reference.irradiance(light, points, facing, quads, receiver=quad.path, order=order)
        values.append(albedo * value / np.pi)
        surfaces.append(nearest)
        if light.kind == "distant":
            behind.append(np.zeros(rays.shape[1], bool))
        else:
            through_light, _ = reference.hit(light, origin[None], rays, front_only=False)
            behind.append(through_light[0] < t)
    n = resolution
    centre, corner = values[0].reshape(n, n, 3), values[1].reshape(n + 1, n + 1, 3)
    corner_mean = (corner[:-1, :-1] + corner[1:, :-1] + corner[:-1, 1:] + corner[1:, 1:]) / 4
    kind, corner_kind = surfaces[0].reshape(n, n), surfaces[1].reshape(n + 1, n + 1)
    one_surface = (kind >= 0) & np.logical_and.reduce(
        [corner_kind[:-1, :-1] == kind, corner_kind[1:, :-1] == kind, corner_kind[:-1, 1:] == kind,
         corner_kind[1:, 1:] == kind])
    back, corner_back = behind[0].reshape(n, n), behind[1].reshape(n + 1, n + 1)
    backs = [back, corner_back[:-1, :-1], corner_back[1:, :-1], corner_back[:-1, 1:], corner_back[1:, 1:]]
    return (2 * centre + corner_mean) / 3, one_surface, np.logical_or.reduce(backs), np.logical_and.reduce(backs)


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


def figures(ours: np.ndarray, ref: np.ndarray, compared: np.ndarray, behind: np.ndarray, coloured: bool):
    """The row's figures: mean ratio, median |error|, fraction within 2 % (per channel when
    coloured), behind-light ratio."""
    channels = range(3) if coloured else [None]
    mean_ratio, median, within = [], [], []
    for channel in channels:
        o = ours[..., channel] if channel is not None else ours.mean(axis=-1)
        r = ref[..., channel] if channel is not None else ref.mean(axis=-1)
        o, r = o[compared], r[compared]
        mean_ratio.append(o.sum() / r.sum() if r.sum() > 0 else (np.inf if o.sum() > 0 else 1.0))
        bright = r > BRIGHT * r.max() if r.max() > 0 else np.zeros(len(r), bool)
        error = np.abs(o[bright] / r[bright] - 1)
        median.append(float(np.median(error)) if len(error) else float("nan"))
        within.append(float((error <= WITHIN).mean()) if len(error) else float("nan"))
    behind_ratio = None
    if behind.any():
        r = ref[behind].sum()
        behind_ratio = ours[behind].sum() / r if r > 0 else (np.inf if ours[behind].sum() > 0 else 1.0)
    return mean_ratio, median, within, behind_ratio


def fmt(values, pattern):
    return "/".join(pattern.format(value) for value in values)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES))
    parser.add_argument("--frames", nargs="+", type=int, help="these frames of every stage (default: see above)")
    parser.add_argument("--all-frames", action="store_true", help="every frame of every group")
    parser.add_argument("--resolution", type=int, default=64, help="square image side (default 64)")
    parser.add_argument("--spp", type=int, default=1024, help="(default 1024)")
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
          f"{args.tolerance:.0%}\n")
    print("| stage | frame | group | mean ratio | median abs err | within 2 % | behind light | |")
    print("|---|---:|---|---|---|---|---:|---|")
    off, noise, started = [], {}, time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="luxtest-") as folder:
        scratch = Path(folder)
        for name in args.stages:
            layer = scratch / f"{name}_white_floor.usda"
            layer.write_text(OVERRIDE.format(stage=(LUXTEST / "usd" / f"{name}.usda").as_posix(), material=MATERIAL))
            stage = Usd.Stage.Open(str(layer))
            frames = frames_of(descriptions[name], args.all_frames)
            if args.frames:
                labels = dict(frames_of(descriptions[name], True))
                frames = [(frame, labels.get(frame, "?")) for frame in args.frames]
            for index, (frame, label) in enumerate(frames):
                try:
                    ours = render(layer, frame, args.resolution, args.spp, 0, scratch)
                    ref, one_surface, partly_behind, behind = reference_image(stage, LIGHTS[name], frame,
                                                                              args.resolution, args.order)
                    compared, behind = one_surface & ~partly_behind, one_surface & behind
                    if index == 0:
                        again = render(layer, frame, args.resolution, args.spp, 1, scratch)
                        bright = compared & (ref.mean(-1) > BRIGHT * ref.mean(-1).max())
                        difference = (again - ours).mean(-1)[bright] / ref.mean(-1)[bright] / np.sqrt(2)
                        noise[name] = (float(np.sqrt(np.mean(difference**2))),
                                       float((np.abs(difference) <= WITHIN).mean()))
                except Exception as error:  # noqa: BLE001 — report the frame and go on
                    off.append((name, frame))
                    print(f"| {name} | {frame} | {label} | FAILED: {error} | | | | |", flush=True)
                    continue
                coloured = float(np.ptp(ref.sum(axis=(0, 1)))) > 1e-3 * float(ref.sum(axis=(0, 1)).max())
                mean_ratio, median, within, behind_ratio = figures(ours, ref, compared, behind, coloured)
                ratios = [*mean_ratio] + ([] if behind_ratio is None else [behind_ratio])
                bad = any(not abs(ratio - 1) <= args.tolerance for ratio in ratios)
                if bad:
                    off.append((name, frame))
                behind_text = "" if behind_ratio is None else f"{behind_ratio:.3f} ({int(behind.sum())} px)"
                print(f"| {name} | {frame} | {label} | {fmt(mean_ratio, '{:.3f}')} | {fmt(median, '{:.2%}')} | "
                      f"{fmt(within, '{:.0%}')} | {behind_text} | {'OFF' if bad else 'ok'} |", flush=True)

    print(f"\nrender noise at {args.spp} spp (per pixel, relative, where the reference is above {BRIGHT:.0%} "
          f"of its maximum, from two seeds of each stage's first frame; in brackets the fraction within "
          f"{WITHIN:.0%} it alone leaves): "
          + ", ".join(f"{name} {sigma:.2%} ({within:.0%})" for name, (sigma, within) in noise.items()))
    if collected.messages:
        print("warnings from the renders (once each):")
        for message in collected.messages:
            print(f"  {message}")
    print(f"{len(off)} of the frames off" + (": " + ", ".join(f"{n} {f}" for n, f in off) if off else "")
          + f" ({time.perf_counter() - started:.0f} s)")
    return 1 if off else 0


if __name__ == "__main__":
    sys.exit(main())
