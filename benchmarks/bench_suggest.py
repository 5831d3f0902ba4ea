"""`suggest` on the Cornell box at 256×256, 256 spp (issue 21's target: ≤ 5 s on 2 cores).

    python benchmarks/bench_suggest.py [--spp 256] [--mode merged] [--index FILE] [-k 6] [--repeats 3]

1. renders ``render/cornell.usda`` at 256×256 with ``pxr-layers render`` (``--mode``:
   merged, the default index, or records: one record per contribution, 25 M at 256 spp)
   into a temporary folder (``--index`` reuses an index instead);
2. times ``suggest(indexes, k)`` in this process at 2 threads, per strategy, best of
   ``--repeats``, and where the time goes (the read of the index, the search, the partition
   check), with the index's records and classes.

The target is the whole of ``suggest`` (beam, the default) ≤ 5 s; a miss is printed as missed.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_SECONDS = 5.0
THREADS = 2
RENDER_DIR = Path(__file__).resolve().parents[1] / "render"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--index", type=Path, help="an index to time (default: render the Cornell box)")
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--mode", choices=("merged", "records"), default="merged")
    parser.add_argument("-k", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    with tempfile.TemporaryDirectory(prefix="bench_suggest_") as folder:
        index_path = args.index
        if index_path is None:
            started = time.perf_counter()
            subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", "render", str(RENDER_DIR / "cornell.usda"),
                            "-o", folder, "-q", "--resolution", "256", "256", "--spp", str(args.spp),
                            "--index-mode", args.mode, "--threads", str(THREADS), "--no-previews"], check=True)
            print(f"rendered the Cornell box 256x256 at {args.spp} spp ({args.mode} index) in "
                  f"{time.perf_counter() - started:.0f} s")
            index_path = Path(folder) / "cornell.pxlidx"
        return _time(index_path, args.k, args.repeats)


def _time(index_path: Path, k: int, repeats: int) -> int:
    from pxr_layers.paths.reader import PathIndex
    from pxr_layers.suggest import STRATEGIES, suggest, check_partition
    from pxr_layers.suggest.atoms import gather
    from pxr_layers.suggest.search import Searcher

    index = PathIndex(index_path)
    print(f"{index_path.name}: {index.mode} index, {index.record_count:,} records, {len(index.classes):,} classes, "
          f"{index.manifest['resolution'][0]}x{index.manifest['resolution'][1]}, {index.manifest.get('spp')} spp")
    missed = False
    for strategy in STRATEGIES:
        best, suggestion = float("inf"), None
        for _ in range(repeats):
            started = time.perf_counter()
            suggestion = suggest([PathIndex(index_path)], k, strategy=strategy, threads=THREADS)
            best = min(best, time.perf_counter() - started)
        verdict = "" if best <= TARGET_SECONDS else f"  MISSED (target {TARGET_SECONDS:.0f} s)"
        missed |= strategy == STRATEGIES[0] and best > TARGET_SECONDS
        print(f"suggest -k {k} --strategy {strategy}: {best:.2f} s on {THREADS} threads, objective "
              f"{suggestion.objective:.4f}{verdict}")
        for name, expression in suggestion.layers.items():
            print(f"    {name:<32} {suggestion.shares[name]:6.1%}  {expression}")
    started = time.perf_counter()
    atoms = gather([index], threads=THREADS)
    read = time.perf_counter()
    searcher = Searcher(atoms)
    searcher.search(k, STRATEGIES[0])
    searched = time.perf_counter()
    check_partition(index, suggestion.layers)
    checked = time.perf_counter()
    print(f"where the time goes: read {read - started:.2f} s ({len(atoms.keys)} atoms), search "
          f"{searched - read:.2f} s, partition check {checked - searched:.2f} s")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
