#!/usr/bin/env python3
"""Regenerate the striped scene's two textures in ``render/textures/``.

Both are 256 × 256, RGB, 16-bit, linear values (the materials read them with
``sourceColorSpace = "raw"``), K = 6 cycles across the image on each axis they vary along:

* ``stripes_6.png``: 0.5 + 0.4 sin(2π K t), stripes that vary along t (up the image) only;
* ``checker_6.png``: 0.5 + 0.4 sin(2π K s) sin(2π K t), a smooth checker of the same
  frequency along both s and t.

Their texture operators have the same largest eigenvalue (T = √(0.4/0.9)·K per texture
unit on the stripes' t axis, and on both axes of the checker: the checker's four side bands
at (±K, ±K) carry 0.1 each, the stripes' two at ±K carry 0.2), so the norm T alone does not
tell them apart; the whole Σ does (render/striped.usda).

The PNGs are tagged linear (gAMA 1.0). Pixels are sampled at their centres,
s = (i + 0.5) / width, t = 1 − (j + 0.5) / height for row j (row 0 is the top), and
quantised with round(v · 65535): the output is deterministic.

Usage: ``python render/tools/make_striped_textures.py [--out DIR]`` (default: the
``textures/`` directory next to this script's parent).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from make_showcase_textures import write_png  # the same 16-bit linear PNG writer (this folder)

SIZE = 256
CYCLES = 6.0
MEAN = 0.5
AMPLITUDE = 0.4
STRIPES = "stripes_6.png"
CHECKER = "checker_6.png"


def coordinates(size: int = SIZE) -> tuple[np.ndarray, np.ndarray]:
    """s (1, size) and t (size, 1) at the texel centres, t = 1 at the top row."""
    centres = (np.arange(size, dtype=np.float64) + 0.5) / size
    return centres[None, :], 1.0 - centres[:, None]


def stripes(size: int = SIZE) -> np.ndarray:
    """(size, size, 3) float64 linear values of the stripes, varying along t only."""
    s, t = coordinates(size)
    values = np.broadcast_to(MEAN + AMPLITUDE * np.sin(2.0 * np.pi * CYCLES * t), (size, s.shape[1]))
    return np.repeat(values[..., None], 3, axis=2)


def checker(size: int = SIZE) -> np.ndarray:
    """(size, size, 3) float64 linear values of the smooth checker."""
    s, t = coordinates(size)
    values = MEAN + AMPLITUDE * np.sin(2.0 * np.pi * CYCLES * s) * np.sin(2.0 * np.pi * CYCLES * t)
    return np.repeat(values[..., None], 3, axis=2)


def write(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    return [write_png(out_dir / STRIPES, stripes()), write_png(out_dir / CHECKER, checker())]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent.parent / "textures",
                        help="output directory (default: render/textures)")
    args = parser.parse_args(argv)
    for path in write(args.out):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
