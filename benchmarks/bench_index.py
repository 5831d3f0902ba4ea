"""What the path index costs: bytes per pixel, per record and per sample, growth with spp, with
and without the whole Σ, and a check that a merged index answers as full precision does
within the rule paths/format.py states.

    python benchmarks/bench_index.py [--stages cornell showcase chess] [--resolutions 128 256]
                                     [--spp 64 256] [--covariance norms sigma] [--overhead]
                                     [--check-resolution 64 48] [--check-spp 16] [--no-check]

1. Size. For each stage, resolution, spp and covariance (``index_covariance``: "norms", the
   C, T, R norms of N = 5 events; "sigma", each event's whole 4×4 Σ too), one render through
   ``render_frame`` as `pxr-layers render` does (merged index, the default): records,
   classes, size on disk, bytes per record, per pixel and per sample, render seconds, then
   per stage, resolution and covariance the growth of the size from the lowest to the
   highest spp. ``--overhead`` also renders without covariance or index, for the render-time
   overhead of the index (doubles the run). Stages: ``cornell`` and ``showcase`` (shipped),
   ``chess`` (the USD working group's OpenChessSet, CHESS_SET: skipped with a message when
   absent), or a path to a stage.
2. Check (``--no-check`` skips it). Each stage rendered at ``--check-resolution`` and
   ``--check-spp`` twice with the same seed: a ``records`` index (one record per
   contribution, full-precision rgb: the reference) and a ``merged`` one. Layers are
   extracted from both: the standard passes and the per-light layers (each must sum to the
   beauty exactly: 1e-5 of each pixel), and conditional layers on the first bounce's norms
   at powers of two (exact: within the rgb rule alone) and at thresholds between (within
   the rgb rule plus the light whose value lies in the threshold's octave). The worst ratio
   of an answer's difference to what the rule allows is printed (≤ 1 holds).

Targets (issue 38, merged, covariance "norms"): ≤ 150 bytes per pixel at 256 spp on the Cornell
stage at 128² and 256²; ≤ 1.3× growth from 64 to 256 spp. A figure that misses is printed as
missed. The peak memory of the process (``resource.getrusage``'s maxrss: every render runs in
it) is printed after each row and at the end.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.lpe import STANDARD_PASSES
from pxr_layers.lpe.passes import per_light_passes
from pxr_layers.paths.format import NormBins, RgbBins
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest

NORM_BOUNCES = 5
CHESS_SET = Path("/work/shared/scenes/usd-wg/full_assets/OpenChessSet/chess_set.usda")
SHIPPED = ("cornell", "showcase")
BYTES_PER_PIXEL_TARGET = 150
GROWTH_TARGET = 1.3
TARGET_STAGE = "cornell"
TARGET_SPP = 256
NORM_COLUMNS = {"C": 0, "T": 1, "R": 2}
PARTITION_TOLERANCE = 1e-5
"""A partition's layers sum to the beauty within this, relative to each pixel (a floor of 1e-3 of
the peak), as tests/test_extract.py checks: float32 rounding of the layers."""


def stage_path(name: str) -> Path | None:
    """The stage a --stages name means; None (and a message) for an absent OpenChessSet."""
    if name in SHIPPED:
        return Path(str(resources.files("pxr_layers.render").joinpath(f"{name}.usda")))
    path = CHESS_SET if name == "chess" else Path(name)
    if not path.is_file():
        print(f"{name}: {path} is absent, skipped", flush=True)
        return None
    return path


def peak_memory() -> str:
    """This process's peak resident memory (maxrss: kilobytes on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return f"{peak / (1 << 30 if sys.platform == 'darwin' else 1 << 20):.2f} GB"


def verdict(met: bool) -> str:
    return "met" if met else "MISSED"


def render(stage: Path, resolution, spp: int, folder: Path, *, mode: str = "merged", covariance: str = "norms",
           bounces: int = NORM_BOUNCES, keep_index: bool = True, seed: int = 0):
    return render_frame(RenderRequest(stage=stage, resolution=resolution, spp=spp, index_mode=mode,
                                      index_covariance=covariance, norm_bounces=bounces, keep_index=keep_index,
                                      previews=False, seed=seed), output=folder)


def measure_sizes(args, stages: dict[str, Path], folder: Path) -> None:
    print(f"\n1. size: merged index, N = {NORM_BOUNCES}; bytes per pixel target ≤ {BYTES_PER_PIXEL_TARGET} at "
          f"{TARGET_SPP} spp on {TARGET_STAGE}, growth ≤ {GROWTH_TARGET}x from {min(args.spp)} to {max(args.spp)} spp")
    print(f"{'stage':10} {'res':>9} {'Σ':6} {'spp':>4} {'records':>11} {'classes':>8} {'size MB':>8} {'B/record':>8} "
          f"{'B/pixel':>8} {'B/sample':>8} {'render s':>8}" + (f" {'plain s':>8} {'overhead':>8}" if args.overhead else "")
          + f" {'peak mem':>9}")
    sizes = {}
    for name, stage in stages.items():
        render(stage, (16, 16), 4, folder)  # compile and warm every kernel first: the timings are the render's
        for side in args.resolutions:
            resolution = (side, side)
            for covariance in args.covariance:
                for spp in args.spp:
                    start = time.perf_counter()
                    result = render(stage, resolution, spp, folder, covariance=covariance)
                    seconds = time.perf_counter() - start
                    index = PathIndex(result.index_path)
                    pixels = side * side
                    sizes[name, side, covariance, spp] = index.size
                    row = (f"{name:10} {f'{side}x{side}':>9} {covariance:6} {spp:>4} {index.record_count:>11,} "
                           f"{index.class_count:>8,} {index.size / 1e6:>8.2f} "
                           f"{index.size / max(index.record_count, 1):>8.2f} {index.size / pixels:>8.1f} "
                           f"{index.size / (pixels * spp):>8.3f} {seconds:>8.2f}")
                    if args.overhead:
                        start = time.perf_counter()
                        render(stage, resolution, spp, folder, bounces=0, keep_index=False)
                        plain = time.perf_counter() - start
                        row += f" {plain:>8.2f} {seconds / plain - 1:>+8.1%}"
                    print(row + f" {peak_memory():>9}", flush=True)
                    if name == TARGET_STAGE and spp == TARGET_SPP and covariance == "norms":
                        print(f"  → {index.size / pixels:.1f} B/px at {TARGET_SPP} spp, {side}²: target ≤ "
                              f"{BYTES_PER_PIXEL_TARGET}: {verdict(index.size / pixels <= BYTES_PER_PIXEL_TARGET)}")
    low, high = min(args.spp), max(args.spp)
    for (name, side, covariance, spp), size in sizes.items():
        if spp == high and low != high and (name, side, covariance, low) in sizes:
            growth = size / sizes[name, side, covariance, low]
            target = f" (target ≤ {GROWTH_TARGET}x: {verdict(growth <= GROWTH_TARGET)})" \
                if name == TARGET_STAGE and covariance == "norms" else ""
            print(f"{name} {side}² Σ {covariance}: size grows {growth:.2f}x from {low} to {high} spp{target}")


def layer_images(index: PathIndex, layers: dict[str, str]) -> dict[str, np.ndarray]:
    return {name: image.astype(np.float64) for name, image in extract(index, layers).layers.items()}


def norm_values(index: PathIndex, column: int) -> np.ndarray:
    """The nonzero values of one norm at the first event (full precision: a records index)."""
    values = np.concatenate([chunk.norms[:, 0, column] for chunk in index.records()])
    return values[values > 0].astype(np.float64)


def check(name: str, stage: Path, resolution, spp: int, folder: Path) -> float:
    """The worst ratio, over the layers and pixels, of |merged − records| to what the rule
    allows (paths/format.py); partitions must sum to the beauty (their ratio: the error over
    PARTITION_TOLERANCE of each pixel)."""
    indexes = {mode: PathIndex(render(stage, resolution, spp, folder / mode, mode=mode, seed=3).index_path)
               for mode in ("records", "merged")}
    records, merged = indexes["records"], indexes["merged"]
    beauty = layer_images(records, {"all": "C.*"})["all"]
    rule = (RgbBins.WIDTH - 1) * np.abs(beauty) + 1e-6 * np.abs(beauty).max()  # + float32 rounding
    worst = {}

    def compare(kind: str, layers: dict[str, str], allowed: dict[str, np.ndarray] | None = None) -> None:
        full, cut = layer_images(records, layers), layer_images(merged, layers)
        for layer in layers:
            bound = rule + (0 if allowed is None else allowed.get(layer, 0))
            worst[kind] = max(worst.get(kind, 0.0), float((np.abs(cut[layer] - full[layer]) / bound).max()))

    lights = [event.name for event in merged.events if event.type == "L" and event.name]
    partitions = {"passes": STANDARD_PASSES, "lights": per_light_passes(lights)}
    scale = np.maximum(np.abs(beauty), 1e-3 * np.abs(beauty).max())
    for kind, layers in partitions.items():
        total = sum(layer_images(merged, layers).values())
        worst[f"{kind} sum"] = float((np.abs(total - beauty) / (PARTITION_TOLERANCE * scale)).max())
        compare(kind, layers)
    for norm, column in NORM_COLUMNS.items():
        values = norm_values(records, column)
        if len(values) < 10:
            continue
        exponents = np.unique(np.floor(np.log2(values)).astype(int))
        edges = {f"{norm}{op}2^{e}": f"C<R.>@(|S_{norm}| {op} {2.0 ** e!r}).*"
                 for e in exponents.tolist()[::max(1, len(exponents) // 4)] for op in (">", "<=", "=")}
        compare("powers of two", edges)
        between = {}
        allowed = {}
        for quantile in (0.25, 0.5, 0.75):
            threshold = float(np.quantile(values, quantile))
            low, high = NormBins.edges(int(NormBins.code(np.array([threshold]))[0]))
            layer = f"{norm}>{threshold:.4g}"
            between[layer] = f"C<R.>@(|S_{norm}| > {threshold!r}).*"
            allowed[layer] = layer_images(records, {"in": f"C<R.>@(|S_{norm}| > {low!r} and |S_{norm}| < "
                                                          f"{high!r}).*"})["in"]
        compare("other thresholds", between, allowed)
    print(f"{name} {resolution[0]}x{resolution[1]} {spp} spp: merged {merged.record_count:,} records vs "
          f"{records.record_count:,}; worst |merged − full| / rule allowed: "
          + ", ".join(f"{kind} {ratio:.3f}" for kind, ratio in worst.items())
          + f" → {'holds' if max(worst.values()) <= 1 else 'VIOLATED'}; peak memory {peak_memory()}", flush=True)
    return max(worst.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stages", nargs="+", default=["cornell", "showcase", "chess"],
                        help="cornell, showcase, chess (OpenChessSet) or stage paths")
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 256], metavar="SIDE")
    parser.add_argument("--spp", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--covariance", nargs="+", choices=("norms", "sigma"), default=["norms", "sigma"])
    parser.add_argument("--overhead", action="store_true", help="also time plain renders (no index)")
    parser.add_argument("--check-resolution", type=int, nargs=2, default=(64, 48), metavar=("W", "H"))
    parser.add_argument("--check-spp", type=int, default=16)
    parser.add_argument("--no-check", action="store_true")
    args = parser.parse_args()
    stages = {name: path for name in args.stages if (path := stage_path(name)) is not None}
    with tempfile.TemporaryDirectory(prefix="bench_index.") as scratch:
        measure_sizes(args, stages, Path(scratch))
        if not args.no_check:
            print(f"\n2. check: merged vs records index, same render; the rule: every layer within "
                  f"{RgbBins.WIDTH - 1:.2%} of the beauty per pixel, thresholds at 0 and powers of two exact, "
                  "others off by at most the light in their octave; partitions sum to the beauty")
            worst = max(check(name, stage, tuple(args.check_resolution), args.check_spp, Path(scratch) / name)
                        for name, stage in stages.items())
            print(f"check: {'the rule holds' if worst <= 1 else 'the rule is VIOLATED'} (worst ratio {worst:.3f})")
    print(f"peak memory (maxrss) of the run: {peak_memory()}")


if __name__ == "__main__":
    main()
