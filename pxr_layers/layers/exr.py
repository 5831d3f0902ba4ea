"""OpenEXR output, and reading an EXR whole. Files appear whole (pxr_layers.outputs: a
temporary name, then a rename); a file cut short or damaged elsewhere (a copy interrupted, a
full disk of another program) is refused by :func:`read_exr`, never read in part."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenEXR

from ..cores import available_cores
from ..errors import OutputError
from ..outputs import write_atomically

# Linear Rec.709 / sRGB primaries and D65 white: the rendering colour space.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
METADATA_PREFIX = "pxrLayers/"
EXR_MAGIC = b"\x76\x2f\x31\x01"
"""The first four bytes of every OpenEXR file (its specification's magic number, 20000630)."""


def use_cores() -> None:
    """Let OpenEXR compress a file's line blocks on every core this process may use. Its
    global thread pool is empty until set, and one core then compresses the whole file (a
    512² product with three Cryptomatte parts: 0.094 s on one core, 0.064 s on two)."""
    cores = available_cores()
    if OpenEXR.global_thread_count() < cores:
        OpenEXR.set_global_thread_count(cores)


def header(compression=OpenEXR.ZIP_COMPRESSION, metadata: dict | None = None, *,
           pixel_aspect_ratio: float = 1.0) -> dict:
    """A scanline part's header in the rendering colour space, with namespaced metadata.

    pixel_aspect_ratio : a pixel's width over its height, OpenEXR's ``pixelAspectRatio``
                         (which OpenEXR writes as 1 when not given: the same bytes)
    """
    fields = {"compression": compression, "type": OpenEXR.scanlineimage, "chromaticities": REC709_CHROMATICITIES,
              "pixelAspectRatio": float(pixel_aspect_ratio)}
    for key, value in (metadata or {}).items():
        fields[METADATA_PREFIX + key] = str(value)
    return fields


def write_channels(path: str | os.PathLike, channels: dict[str, np.ndarray],
                   metadata: dict[str, str] | None = None) -> Path:
    """Write named float32 images (each (h, w), or (h, w, 4) for "RGBA") as one part, ZIP."""
    path = Path(path)
    fields = header(metadata=metadata)
    pixels = {name: np.ascontiguousarray(image, dtype=np.float32) for name, image in channels.items()}
    use_cores()
    write_atomically(path, lambda temporary: OpenEXR.File(fields, pixels).write(str(temporary)))
    return path


def read_exr(path: str | os.PathLike, *, header_only: bool = False,
             separate_channels: bool = False) -> OpenEXR.File:
    """Every part of the EXR at ``path``, pixels and all (``header_only``,
    ``separate_channels``: as the binding's arguments; with ``header_only`` the pixels are
    still checked, the same way, so that a later read of them cannot fail).

    Raises OutputError naming the file when it cannot be read whole. The OpenEXR binding
    reads a file whose last bytes are cut off without an error: it leaves out the parts whose
    pixels it could not read (printing to stdout and stderr), and a product would silently
    lose layers. So OpenImageIO, which reports such a part as an error and prints nothing,
    first reads the chunks at both ends of each part (where a truncation shows whichever the
    line order; :func:`unreadable_part`), and a read that still yields fewer parts than the
    file declares is refused.
    """
    problem, declared = unreadable_part(path)
    if problem is not None:
        raise OutputError(f"{path}: {problem}")
    try:
        exr = OpenEXR.File(str(path), header_only=header_only, separate_channels=separate_channels)
    except Exception as error:  # the binding raises RuntimeError and others for a damaged file
        raise OutputError(f"{path}: OpenEXR cannot read the file ({_one_line(error)})") from None
    if len(exr.parts) != declared:
        raise OutputError(f"{path}: OpenEXR reads {len(exr.parts)} of its {declared} parts: the file is damaged")
    return exr


def unreadable_part(path: str | os.PathLike) -> tuple[str | None, int]:
    """(why a part of the EXR at ``path`` cannot be read, or None; how many parts its
    headers declare).

    Reads each scanline part's first and last scanline (their chunks: a file cut short loses
    the chunks written last, the last rows in increasing line order, the first in
    decreasing), a tiled part whole; deep parts are left to the reader. Cheap: two chunks a
    part for the files pxr-layers writes."""
    import OpenImageIO as oiio

    with open(path, "rb") as stream:
        if stream.read(len(EXR_MAGIC)) != EXR_MAGIC:
            return "not an OpenEXR file (it does not begin with OpenEXR's magic number)", 0
    image = oiio.ImageInput.open(str(path))
    if image is None:
        return f"OpenImageIO cannot open it as an image ({_one_line(oiio.geterror())})", 0
    try:
        part = 0
        while image.seek_subimage(part, 0):
            spec = image.spec()
            if not spec.deep:
                if spec.tile_width:
                    pixels = [image.read_image(part, 0, 0, spec.nchannels, "float")]
                else:
                    pixels = [image.read_scanlines(part, 0, y, y + 1, spec.z, 0, spec.nchannels, "float")
                              for y in sorted({spec.y, spec.y + spec.height - 1})]
                error = image.geterror()  # always taken: OpenImageIO prints errors left untaken
                if error or any(rows is None for rows in pixels):
                    name = spec.get_string_attribute("name") or str(part)
                    return (f"part {part} ({name!r}) cannot be read ({_one_line(error) or 'no pixels'}): "
                            "the file is cut short or damaged", part + 1)
            part += 1
        return None, part
    finally:
        image.close()


def _one_line(error: object) -> str:
    """A library's message on one line (OpenImageIO joins its errors with newlines)."""
    return " ".join(str(error).split())
