#!/usr/bin/env python3
"""Regenerate the showcase scene's texture(s) in ``render/textures/``.

``two_frequencies.png`` (1024 × 512, RGB, 16-bit, linear values: the material reads it
with ``sourceColorSpace = "raw"``) holds vertical stripes, a sinusoid along u only:

* left half  (u < 0.5):  0.5 + 0.3 sin(2π · 8 u),   4 cycles across the half;
* right half (u ≥ 0.5):  0.5 + 0.3 sin(2π · 16 u),  8 cycles across the half,

i.e. exactly twice the left frequency. Both halves are 0.5 at u = 0.5 (the seam is
continuous) and span [0.2, 0.8]. On the showcase's 1.6 m × 0.8 m ``texturedPanel`` each
half is 0.8 m wide: 5 cycles/m (period 0.2 m) on the left, 10 cycles/m (period 0.1 m)
on the right.

The PNG is tagged linear (gAMA 1.0, no sRGB chunk). Pixels are sampled at their centres,
u = (i + 0.5) / width, and quantised with round(v · 65535): the output is deterministic
(the tests regenerate it and compare pixels).

Usage: ``python render/tools/make_showcase_textures.py [--out DIR]`` (default: the
``textures/`` directory next to this script's parent).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

WIDTH = 1024
HEIGHT = 512
MEAN = 0.5
AMPLITUDE = 0.3
CYCLES_PER_U_LEFT = 8.0  # 4 cycles over u in [0, 0.5): 5 cycles/m on the 1.6 m panel
CYCLES_PER_U_RIGHT = 16.0  # 8 cycles over u in [0.5, 1]: 10 cycles/m on the panel
FILENAME = "two_frequencies.png"


def two_frequencies(width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """The texture as (height, width, 3) float64 linear values before quantisation."""
    u = (np.arange(width, dtype=np.float64) + 0.5) / width
    cycles = np.where(u < 0.5, CYCLES_PER_U_LEFT, CYCLES_PER_U_RIGHT)
    row = MEAN + AMPLITUDE * np.sin(2.0 * np.pi * cycles * u)
    return np.broadcast_to(row[None, :, None], (height, width, 3)).copy()


def quantise(values: np.ndarray) -> np.ndarray:
    """Linear [0, 1] values to uint16 codes."""
    return np.round(np.clip(values, 0.0, 1.0) * 65535.0).astype(np.uint16)


def write_png(path: Path, values: np.ndarray) -> Path:
    """(h, w, 3) linear [0, 1] values as a 16-bit PNG tagged linear (gAMA 1.0, not OIIO's
    default sRGB chunk). make_striped_textures.py writes its textures with it too."""
    import OpenImageIO as oiio

    pixels = quantise(values)
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.UINT16)
    spec.attribute("oiio:ColorSpace", "lin_rec709_scene")
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise RuntimeError(f"OpenImageIO cannot write {path}: {oiio.geterror()}")
    try:
        if not out.open(str(path), spec) or not out.write_image(pixels):
            raise RuntimeError(f"writing {path} failed: {out.geterror()}")
    finally:
        out.close()
    return path


def write(out_dir: Path) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    return write_png(out_dir / FILENAME, two_frequencies())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).resolve().parent.parent / "textures",
        help="output directory (default: render/textures)",
    )
    args = parser.parse_args(argv)
    print(write(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
