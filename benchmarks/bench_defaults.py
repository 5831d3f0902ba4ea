"""Real assets as shipped, beside their published screenshots: what a studio user sees first.

    python benchmarks/bench_defaults.py [--width 640] [--spp 16] [--only NAME ...] [--out DIR]

1. Renders each asset of ASSETS (../shared/scenes: the usd-wg assets and the
   StandardShaderBall) through the CLI exactly as shipped, ``--no-index``, at --width pixels
   wide and the aspect ratio of its reference screenshot, and writes contact sheets
   (``contact_sheet_N.png``, three assets a sheet: our OCIO preview left, the asset's own
   screenshot right, each labelled) into --out.
2. Framing: for every stage framed by the automatic camera, how much of the frame's width and
   height the subject covers (the bounding box of the pixels whose alpha is above 0.5).
   Target: 50-90 % of the width or the height, whichever is larger.
3. ``--no-index`` cost: for the assets of SPEED_ASSETS, the CLI's wall time rendering
   ``--no-index --norm-bounces 5`` (the covariance norms ``--no-index`` computed before, for
   nothing) over ``--no-index`` (none), side by side in one run, after a small warm-up render
   of each kind (the kernels' compile is not timed). Target: >= 2x.

Prints a table and exits 0 whether targets are met or missed; 1 if a render fails; 0 with a
message when ../shared is absent. Look at the sheets: the figures do not say whether a
picture is right.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
CLI = Path(sys.executable).with_name("pxr-layers")
COVERAGE_TARGET = (0.50, 0.90)
SPEED_TARGET = 2.0
SHEET_ROWS = 3
SHEET_HEIGHT = 240  # pixels of each picture on a sheet
LABEL_HEIGHT = 28

log = logging.getLogger("bench_defaults")


@dataclass(frozen=True)
class Asset:
    """A stage and its published picture, both relative to SCENES."""

    name: str
    stage: str
    reference: str


WG = "usd-wg"
ASSETS = (
    Asset("OpenChessSet", f"{WG}/full_assets/OpenChessSet/chess_set.usda",
          f"{WG}/full_assets/OpenChessSet/thumbnails/chess_set.png"),
    Asset("McUsd", f"{WG}/full_assets/McUsd/McUsd.usda", f"{WG}/full_assets/McUsd/screenshots/usdview.png"),
    Asset("Teapot", f"{WG}/full_assets/Teapot/Teapot.usd", f"{WG}/full_assets/Teapot/screenshots/UtahTeapot.png"),
    Asset("SpinningPyramids", f"{WG}/full_assets/SubdivisionSurfaces/Creases_SpinningPyramids.usda",
          f"{WG}/full_assets/SubdivisionSurfaces/media/Creases_SpinningPyramids_Storm.jpg"),
    Asset("Pyramid", f"{WG}/full_assets/SubdivisionSurfaces/Pyramid/Pyramid.usd",
          f"{WG}/full_assets/SubdivisionSurfaces/Pyramid/thumbnail.png"),
    Asset("Elephant", f"{WG}/full_assets/ElephantWithMonochord/SoC-ElephantWithMonochord.usdc",
          f"{WG}/full_assets/ElephantWithMonochord/screenshots/20220604-screenshot.png"),  # its thumbnail is empty
    Asset("RoughnessTest", f"{WG}/test_assets/RoughnessTest/RoughnessTest.usdz",
          f"{WG}/test_assets/RoughnessTest/screenshots/usdview-20.08.png"),
    Asset("NormalsBiasScale", f"{WG}/test_assets/NormalsTextureBiasAndScale/NormalsTextureBiasAndScale.usda",
          f"{WG}/test_assets/NormalsTextureBiasAndScale/screenshots/crn_usdview.png"),
    Asset("TextureCoordinate", f"{WG}/test_assets/TextureCoordinateTest/TextureCoordinateTest.usda",
          f"{WG}/test_assets/TextureCoordinateTest/screenshot/TextureCoordinateTest_usdview.png"),
    Asset("TextureTransform", f"{WG}/test_assets/TextureTransformTest/TextureTransformTest.usd",
          f"{WG}/test_assets/TextureTransformTest/screenshots/20220603-usdview.png"),
    Asset("TextureFormats", f"{WG}/test_assets/TextureFileFormatTests/all_files.usda",
          f"{WG}/test_assets/TextureFileFormatTests/screenshots/all_files.png"),
    Asset("AlphaBlendMode", f"{WG}/test_assets/AlphaBlendModeTest/AlphaBlendModeTest.usd",
          f"{WG}/test_assets/AlphaBlendModeTest/screenshots/20220603-usdview.png"),
    Asset("AlphaBlendSort", f"{WG}/test_assets/AlphaBlendSortTest/AlphaBlendSortTest.usda",
          f"{WG}/test_assets/AlphaBlendSortTest/screenshots/usdview.png"),
    Asset("NormalsTypes", f"{WG}/test_assets/schemaTests/usdGeom/meshes/normals_types/normalsTypes.usda",
          f"{WG}/test_assets/schemaTests/usdGeom/meshes/normals_types/screenshots/normalsTypes_usdrecord_22.08.png"),
    Asset("CatmullClarkCube",
          f"{WG}/test_assets/schemaTests/usdGeom/meshes/subdiv_catmullClark/subdiv_catmullClark.usda",
          f"{WG}/test_assets/schemaTests/usdGeom/meshes/subdiv_catmullClark/screenshots/"
          "subdiv_catmullClark_usdrecord_22.08.png"),
    Asset("AnimatedCube", f"{WG}/test_assets/USDZ/AnimatedCube/AnimatedCube.usdz",
          f"{WG}/test_assets/USDZ/AnimatedCube/thumbnails/AnimatedCube.png"),
    Asset("MaterialXBasic", f"{WG}/test_assets/MaterialXTest/basic.usda",
          f"{WG}/test_assets/MaterialXTest/screenshots/basic.png"),
    Asset("StandardShaderBall", "StandardShaderBall/standard_shader_ball_scene.usda",
          "StandardShaderBall/media/cover.jpg"),
)
SPEED_ASSETS = ("OpenChessSet", "McUsd", "StandardShaderBall")
OLD_NO_INDEX = ("--no-index", "--norm-bounces", "5")  # the products' default index bounces


@dataclass
class Rendered:
    asset: Asset
    exr: Path
    preview: Path
    seconds: float
    auto_camera: bool
    coverage: tuple[float, float] | None  # (width, height) fractions the subject spans


def render(stage: Path, exr: Path, resolution: tuple[int, int], spp: int, *extra: str) -> float:
    """Render through the CLI, as a user would; returns the wall time in seconds."""
    command = [str(CLI), "render", str(stage), "-q", "--spp", str(spp),
               "--resolution", *map(str, resolution), "-o", str(exr), *extra]
    start = time.perf_counter()
    completed = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if completed.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed (exit {completed.returncode}): "
                           f"{completed.stderr.strip()[-2000:]}")
    return seconds


def reference_size(path: Path) -> tuple[int, int]:
    spec = oiio.ImageInput.open(str(path)).spec()
    return spec.width, spec.height


def resolution_like(reference: Path, width: int) -> tuple[int, int]:
    """--width pixels wide at the reference's aspect ratio (kept between 1:2 and 2:1), even."""
    ref_width, ref_height = reference_size(reference)
    aspect = min(max(ref_width / ref_height, 0.5), 2.0)
    return width, 2 * round(width / aspect / 2)


def subject_coverage(exr: Path) -> tuple[float, float] | None:
    """Fractions of the frame's width and height spanned by pixels of alpha above 0.5."""
    pixels = oiio.ImageBuf(str(exr)).get_pixels(oiio.FLOAT)  # (H, W, C)
    covered = pixels[..., 3] > 0.5
    if not covered.any():
        return None
    rows, columns = np.flatnonzero(covered.any(axis=1)), np.flatnonzero(covered.any(axis=0))
    height, width = covered.shape
    return (columns[-1] - columns[0] + 1) / width, (rows[-1] - rows[0] + 1) / height


def fitted(path: Path, height: int) -> oiio.ImageBuf:
    """An image as 8-bit-looking RGB of the given height (alpha over black), for a sheet."""
    image = oiio.ImageBuf(str(path))
    if image.spec().nchannels >= 4:
        image = oiio.ImageBufAlgo.channels(oiio.ImageBufAlgo.premult(image), (0, 1, 2))
    elif image.spec().nchannels < 3:
        image = oiio.ImageBufAlgo.channels(image, (0, 0, 0))
    width = max(1, round(image.spec().width * height / image.spec().height))
    return oiio.ImageBufAlgo.resize(image, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, 3))


def write_sheets(rendered: list[Rendered], out: Path) -> list[Path]:
    """Contact sheets of SHEET_ROWS assets each: ours left, the reference right."""
    sheets = []
    for first in range(0, len(rendered), SHEET_ROWS):
        rows = []
        for item in rendered[first:first + SHEET_ROWS]:
            ours = fitted(item.preview, SHEET_HEIGHT)
            theirs = fitted(SCENES / item.asset.reference, SHEET_HEIGHT)
            coverage = "" if item.coverage is None else f", subject {max(item.coverage):.0%}"
            rows.append((f"{item.asset.name}: ours ({item.seconds:.0f} s{coverage}) | "
                         f"{Path(item.asset.reference).name}", ours, theirs))
        width = max(ours.spec().width + theirs.spec().width for _, ours, theirs in rows) + 30
        sheet = oiio.ImageBuf(oiio.ImageSpec(width, len(rows) * (SHEET_HEIGHT + LABEL_HEIGHT + 10), 3, oiio.FLOAT))
        oiio.ImageBufAlgo.fill(sheet, (0.08, 0.08, 0.08))
        for index, (label, ours, theirs) in enumerate(rows):
            top = index * (SHEET_HEIGHT + LABEL_HEIGHT + 10)
            oiio.ImageBufAlgo.render_text(sheet, 10, top + LABEL_HEIGHT - 8, label, 18, "", (1, 1, 1))
            oiio.ImageBufAlgo.paste(sheet, 10, top + LABEL_HEIGHT, 0, 0, ours)
            oiio.ImageBufAlgo.paste(sheet, 20 + ours.spec().width, top + LABEL_HEIGHT, 0, 0, theirs)
        path = out / f"contact_sheet_{first // SHEET_ROWS + 1}.png"
        if not sheet.write(str(path)):
            raise RuntimeError(f"could not write {path}: {sheet.geterror()}")
        sheets.append(path)
    return sheets


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=640, help="render width in pixels (default 640)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    parser.add_argument("--only", nargs="+", metavar="NAME", choices=[asset.name for asset in ASSETS],
                        help="these assets only")
    parser.add_argument("--out", type=Path, help="where renders and sheets go (default: a new temporary folder)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not SCENES.is_dir():
        log.info("bench_defaults: %s is absent; skipped", SCENES)
        return 0
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_defaults."))
    out.mkdir(parents=True, exist_ok=True)
    assets = [asset for asset in ASSETS if not args.only or asset.name in args.only]

    rendered: list[Rendered] = []
    speed: list[tuple[str, float, float]] = []
    try:
        for asset in assets:
            stage, exr = SCENES / asset.stage, out / f"{asset.name}.exr"
            resolution = resolution_like(SCENES / asset.reference, args.width)
            if asset.name in SPEED_ASSETS:  # compile both kinds of kernels first
                for extra in (("--no-index",), OLD_NO_INDEX):
                    render(stage, out / "warm-up.exr", (32, 32), 1, "--no-previews", *extra)
            seconds = render(stage, exr, resolution, args.spp, "--no-index")
            auto_camera = oiio.ImageBuf(str(exr)).spec().getattribute("pxrLayers/autoCamera") is not None
            coverage = subject_coverage(exr) if auto_camera else None
            rendered.append(Rendered(asset, exr, exr.with_suffix(".rgba.png"), seconds, auto_camera, coverage))
            log.info("  %-20s %4d x %-4d %7.1f s  %s", asset.name, *resolution, seconds,
                     "own camera" if not auto_camera else
                     "nothing covered" if coverage is None else
                     f"subject spans {coverage[0]:.0%} of the width, {coverage[1]:.0%} of the height")
            if asset.name in SPEED_ASSETS:
                with_norms = render(stage, out / f"{asset.name}.norms.exr", resolution, args.spp, "--no-previews",
                                    *OLD_NO_INDEX)
                speed.append((asset.name, with_norms, seconds))
    except RuntimeError as error:
        log.error("bench_defaults: %s", error)
        return 1
    sheets = write_sheets(rendered, out)

    log.info("\nframing by the automatic camera (target: the larger span %d-%d %%)",
             *(round(100 * bound) for bound in COVERAGE_TARGET))
    for item in rendered:
        if item.auto_camera:
            span = 0.0 if item.coverage is None else max(item.coverage)
            met = COVERAGE_TARGET[0] <= span <= COVERAGE_TARGET[1]
            log.info("  %-20s %5.0f %%  %s", item.asset.name, 100 * span, "met" if met else "MISSED")
    log.info("\n--no-index: with the norms it computed before over none (target >= %.1fx, %d spp)",
             SPEED_TARGET, args.spp)
    for name, with_norms, without in speed:
        ratio = with_norms / without
        log.info("  %-20s %7.1f s / %7.1f s = %.2fx  %s", name, with_norms, without, ratio,
                 "met" if ratio >= SPEED_TARGET else "MISSED")
    log.info("\ncontact sheets:\n%s", "\n".join(f"  {sheet}" for sheet in sheets))
    return 0


if __name__ == "__main__":
    sys.exit(main())
