"""What denoising buys and costs (issue 37): each light pass's error before and after, the
two ways of making the stack add up, and the time of a 1080p stack.

    python benchmarks/bench_denoise.py [--spp 16] [--reference-spp 2048] [--resolution 256 256]
                                       [--stages cornell showcase]

1. For each stage (render/cornell.usda, render/showcase.usda with the light_passes recipe):
   renders it at --spp with ``--denoise`` and at --reference-spp without, and prints each
   layer's relMSE (mean of (x − ref)² / (ref² + 0.01)) raw and denoised, the gain, and
   whether it meets the target (a layer above 1e-3 at least 4× lower; none worse), and how
   far the denoised stack's sum is from the denoised beauty (target: 1e-5 of its mean).
2. The other ways of making the stack exact: the beauty denoised on its own and the layers
   redistributed to add up to it (their relMSE beside ours: layers.denoise keeps the layers
   as filtered and makes the beauty their sum), and the energy Octane's "denoised
   remainder" part would hold.
3. A 1920×1080 stack of 9 layers (the Cornell light passes at 1 spp): the seconds
   denoising takes and its share of the whole frame's command.

Exits 0 (a measurement: each figure says met or MISSED), 1 when a render fails.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.deliver import denoised_path
from pxr_layers.layers.denoise import denoise_images, denoise_stack
from pxr_layers.layers.multipart import read_multipart
from pxr_layers.recipe.presets import preset
from pxr_layers.request import RenderRequest

GAIN_TARGET = 4.0
NOISY = 1e-3
SUM_TARGET = 1e-5


def relative_mse(image: np.ndarray, reference: np.ndarray) -> float:
    image, reference = np.asarray(image, np.float64), np.asarray(reference, np.float64)
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + 0.01)))


def render(stage: str, folder: Path, resolution, spp: int, denoise: bool):
    request = RenderRequest(stage=stage, recipe_layers=(preset("light_passes"),), resolution=tuple(resolution),
                            spp=spp, denoise=denoise, previews=False, keep_index=False)
    start = time.perf_counter()
    result = render_frame(request, output=folder)
    return result, time.perf_counter() - start


def verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def redistributed(beauty: np.ndarray, layers: dict, denoised_beauty: np.ndarray, denoised: dict) -> dict:
    """The other way (not layers.denoise's): the layers moved to add up to a separately
    denoised beauty, the gap shared by their denoised magnitude at each pixel and channel."""
    names = [name for name in denoised if np.any(layers[name])]
    stack = np.stack([denoised[name] for name in names]).astype(np.float64)
    raw_gap = beauty.astype(np.float64) - sum(layers[name].astype(np.float64) for name in names)
    gap = denoised_beauty - stack.sum(axis=0) - raw_gap
    magnitude = np.abs(stack)
    total = magnitude.sum(axis=0)
    share = np.where(total > 0, magnitude / np.where(total > 0, total, 1.0), 1.0 / len(names))
    return {**denoised, **{name: stack[k] + share[k] * gap for k, name in enumerate(names)}}


def stage_figures(name: str, stage: str, folder: Path, args) -> None:
    noisy, seconds = render(stage, folder / f"{name}-noisy", args.resolution, args.spp, True)
    reference, reference_seconds = render(stage, folder / f"{name}-reference", args.resolution,
                                          args.reference_spp, False)
    raw = read_multipart(noisy.delivered[0].exr)
    twin = read_multipart(denoised_path(noisy.delivered[0].exr))
    truth = read_multipart(reference.delivered[0].exr)
    print(f"\n{name}: {args.resolution[0]}x{args.resolution[1]}, {args.spp} spp ({seconds:.1f} s with denoising) "
          f"against {args.reference_spp} spp ({reference_seconds:.0f} s)")
    layers, raw_layers, twin_layers = truth.colour_layers(), raw.colour_layers(), twin.colour_layers()
    # the other way: the beauty denoised on its own (same filter, scale and guides), the layers moved to it
    alone_beauty = denoise_images(raw.beauty, {"beauty": raw.beauty}, *noisy.guides)["beauty"].astype(np.float64)
    moved = redistributed(raw.beauty[..., :3], raw_layers, alone_beauty, twin_layers)
    gap = alone_beauty - sum(image.astype(np.float64) for image in twin_layers.values())
    print(f"  {'layer':18}{'raw':>10}{'denoised':>10}{'gain':>8}  target   {'redistributed':>14}")
    rows = [(layer, raw_layers[layer], twin_layers[layer], layers[layer], moved[layer]) for layer in layers]
    rows.append(("beauty", raw.beauty[..., :3], twin.beauty[..., :3], truth.beauty[..., :3], alone_beauty))
    for layer, before_image, after_image, reference_image, other_image in rows:
        before, after = relative_mse(before_image, reference_image), relative_mse(after_image, reference_image)
        if before == 0 and after == 0:
            print(f"  {layer:18}{'empty':>10}")
            continue
        gain = before / after if after > 0 else float("inf")
        ok = after <= before and (before <= NOISY or gain >= GAIN_TARGET)
        print(f"  {layer:18}{before:10.2e}{after:10.2e}{gain:8.1f}  {verdict(ok):7}  "
              f"{relative_mse(other_image, reference_image):14.2e}")
    beauty = twin.beauty[..., :3].astype(np.float64)
    total = sum(image.astype(np.float64) for image in twin_layers.values())
    error = float(np.abs(total - beauty).max() / beauty.mean())
    print(f"  stack sum vs denoised beauty: max |difference| / mean = {error:.1e}  (target <= {SUM_TARGET:g}: "
          f"{verdict(error <= SUM_TARGET)})")
    print(f"  (redistributed: the layers moved to add up to the beauty denoised on its own, beauty row: that "
          f"beauty; the gap between it and the layers' sum is {float(np.abs(gap).sum() / np.abs(alone_beauty).sum()):.1%}"
          " of its energy, L1: what Octane's remainder part would hold)")


def full_hd(folder: Path) -> None:
    stage = str(resources.files("pxr_layers.render").joinpath("cornell.usda"))
    _, plain = render(stage, folder / "hd-plain", (1920, 1080), 1, False)
    result, denoised = render(stage, folder / "hd", (1920, 1080), 1, True)
    raw = read_multipart(result.delivered[0].exr)
    start = time.perf_counter()
    denoise_stack(raw.beauty, raw.colour_layers(), *result.guides)
    alone = time.perf_counter() - start
    print(f"\n1920x1080, {len(raw.colour_layers())} layers + beauty: denoising takes {alone:.1f} s; the render command "
          f"{plain:.1f} s without it, {denoised:.1f} s with it: {(denoised - plain) / denoised:.0%} of the frame")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--reference-spp", type=int, default=2048)
    parser.add_argument("--resolution", type=int, nargs=2, default=(256, 256), metavar=("W", "H"))
    parser.add_argument("--stages", nargs="+", default=["cornell", "showcase"], choices=["cornell", "showcase"])
    parser.add_argument("--skip-hd", action="store_true", help="leave out the 1920x1080 timing")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_denoise-") as scratch:
        folder = Path(scratch)
        for name in args.stages:
            stage_figures(name, str(resources.files("pxr_layers.render").joinpath(f"{name}.usda")), folder, args)
        if not args.skip_hd:
            full_hd(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
