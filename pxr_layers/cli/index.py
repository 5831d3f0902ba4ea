"""`pxr-layers index info INDEX`: what a path index holds, and where the light went."""

from __future__ import annotations

import argparse

import numpy as np

from ..cores import available_cores
from ..paths.events import path_text
from ..paths.reader import PathIndex
from . import logging_flags
from .render import nonempty_path

HELP = "inspect a path index (.pxlidx)"
DESCRIPTION = "Inspect a path index written by `pxr-layers render` beside its EXR."
TOP_CLASSES = 12
PROGRESS_RECORDS = 1 << 22
"""Indexes of this many records or more show --verify's progress: about a second of reading
(verify checks some 3 M records a second), below which a bar would only flicker."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    info = actions.add_parser(
        "info", help="records, classes, labels, size, and the top path classes by energy",
        description="Print what INDEX holds: records, path classes, labels, size on disk, bytes per "
        "record, the render it came from, and the path classes carrying the most energy. The header, "
        "trailer and tables are read, and the light of every chunk (to rank the classes; the chunks' "
        "checksums are checked): --verify checks all of every chunk too.",
        parents=[logging_flags(nested=True)],
    )
    info.add_argument("index", type=nonempty_path, metavar="INDEX", help="a .pxlidx file")
    info.add_argument("--top", type=_count, default=TOP_CLASSES, metavar="N",
                      help=f"how many path classes to list (default {TOP_CLASSES})")
    info.add_argument("--verify", action="store_true",
                      help="read every chunk and check its CRC-32 and contents (sizes, class ids, pixels, "
                      "finite rgb, each class's records): exit 1 naming the first bad chunk and "
                      "its byte offset")


def run(args: argparse.Namespace) -> int:
    index = PathIndex(args.index)
    verified = index.verify(show_progress=args.show_progress and index.record_count >= PROGRESS_RECORDS) \
        if args.verify else None
    for line in info_lines(index, args.top, verified):
        print(line)
    return 0


def _count(text: str) -> int:
    if not text.strip().isdigit():
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return int(text)


def info_lines(index: PathIndex, top: int, verified: int | None = None) -> list[str]:
    """The `index info` report as lines of text; verified: the chunks PathIndex.verify
    checked, None if it was not run."""
    manifest = index.manifest
    records = index.record_count
    lines = [
        f"path index   {index.path}",
        f"format       version {manifest['format_version']}",
        f"stage        {manifest.get('stage', '?')}  (sha256 {manifest.get('stage_sha256', '?')[:12]}…)",
        (f"render       frame {manifest.get('frame', '?')}, camera {manifest.get('camera', '?')}, "
        f"{manifest.get('resolution', ['?', '?'])[0]}×{manifest.get('resolution', ['?', '?'])[1]}, "
        f"{manifest.get('spp', '?')} spp, seed {manifest.get('seed', '?')}"),
        f"mode         {_mode(manifest)}",
        (f"covariance   C, T, R of the first {manifest['norm_slots']} events "
        f"({', '.join(f'{name} in {unit}' for name, unit in manifest['norms'].items())})"
        + (", and each event's whole 4×4 Σ" if manifest["covariance"] == "sigma" else "")),
        f"records      {records:,}" + (f" (merged from {manifest['contributions']:,} contributions)"
                                           if manifest["mode"] == "merged" else ""),
        f"classes      {index.class_count:,}",
        f"labels       {len(index.labels):,}",
        (f"size         {index.size:,} bytes ({index.size / max(records, 1):.2f} bytes per record, "
        f"{_per_pixel(index)}{len(index.chunks)} chunks)"),
        ("chunks       light read, not verified (--verify checks all of every chunk)" if verified is None
         else f"chunks       verified: {verified} chunks, CRC-32 and contents ok"),
        "",
    ]
    energy = class_energy(index)
    total = float(energy.sum()) or 1.0
    ranked = np.argsort(-energy, kind="stable")[:top].tolist()
    lines.append(f"top {len(ranked)} path classes by share of the energy (R + G + B):")
    lines.append(f"  {'share':>7}  {'records':>10}  path")
    for rank in ranked:
        path_class = index.classes[rank]
        lines.append(f"  {energy[rank] / total:7.2%}  {path_class.records:>10,}  {path_text(path_class.events)}")
    return lines


def class_energy(index: PathIndex) -> np.ndarray:
    """(classes,) float64: the light (R + G + B, summed over the image) of each class, from
    the sums of every chunk (the footer keeps no light per class: it would be a tenth of a
    small index)."""
    energy = np.zeros(index.class_count)
    for chunk in index.records(norms=False, threads=available_cores()):
        energy += np.bincount(chunk.class_id, weights=chunk.rgb.sum(axis=1, dtype=np.float64),
                              minlength=index.class_count)
    return energy


def _mode(manifest) -> str:
    """How the index keeps the light, and its bins."""
    if manifest["mode"] != "merged":
        return "records: one per contribution, norms as float16"
    bins, rgb = manifest.get("bins", {}), manifest.get("rgb", {})
    per_octave = rgb.get("bins_per_octave", "?")
    width = f" (×{2 ** (1 / per_octave):.4f})" if isinstance(per_octave, int) and per_octave > 0 else ""
    return (f"merged: one record per pixel, path class and covariance bin; covariance in {bins.get('kind', '?')}, "
            f"exact at {bins.get('exact', '?')}; rgb in {per_octave} bins an octave{width}, one exact record per "
            "pixel and channel carrying the rest")


def _per_pixel(index: PathIndex) -> str:
    """'669 bytes per pixel, ' when the index says its resolution (what a frame costs grows
    with it, whatever the spp), else ''."""
    width, height = index.manifest.get("resolution") or (0, 0)
    return f"{index.size / (width * height):,.0f} bytes per pixel, " if width * height else ""
