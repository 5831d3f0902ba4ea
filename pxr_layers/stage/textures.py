"""Decode textures once per (asset, colour space) with OpenImageIO.

Pixels are stored linear, float32, (h, w, c) with row 0 = the top row of the file and the
file's own channels (1 grey, 2 grey + alpha, 3 RGB, 4 RGBA), as scene.TextureImage
documents: a grey roughness map costs one channel, not four. Lookups expand them as
UsdUVTexture does (grey is rgb, a missing alpha is 1); channels past the fourth are dropped
because no UsdUVTexture output can reach them.

Textures arrive as resolved asset paths (Sdf.AssetPath.resolvedPath). A plain file on disk is
opened by OIIO directly; anything else USD's asset resolver (Ar) resolved, a member of a
package (``/x/shot.usdz[textures/rough.png]``) or a path of a custom resolver, is read through
``Ar.GetResolver().OpenAsset`` and its bytes decoded by OIIO.

Texels no lookup can use are replaced by 0 when a file is decoded, with one warning naming
the file and how many texels changed (_repaired): NaN and infinite ones in every texture
(a NaN roughness or albedo makes NaN pixels, and an infinite one NaN as soon as it is
multiplied by 0), and in the images of lights (``light=True``: a dome's lat-long image, a
rect light's colour map) negative ones too, which would be negative radiance, while texels
above MAX_LIGHT_TEXEL are lowered to it. Those of materials keep their sign, which normal
maps, displacement and scale/bias offsets need.

Images are bounded (a 20000 × 20000 PNG of one colour is a 1 MB file that decodes to 4.8 GB
of float32): the header is read first, before any pixel. A file of more than
MAX_FILE_TEXELS is not decoded at all (a warning, and the fallback value, as for any
unreadable texture). One of more than MAX_TEXTURE_TEXELS is read at a reduced resolution
within that budget, with a warning naming the file and both sizes: the first MIP level that
fits when the file has levels (a tiled EXR or .tx), else the file decoded a band of rows at a
time and averaged over n × n texel blocks (the values as stored: 8-bit sRGB is averaged
before it is decoded), so memory never holds more than the reduced image and one band.
A studio's 16k texture still renders, at 8k, rather than stopping the shot or taking the
machine's memory; a texture cache would read such a file at a coarser MIP level too.

The textures of the last stage read are remembered in the process by identity (see
_texture_identity): the frames of a shot read the same files one after another, and the next
read takes the decoded images instead of decoding them again. The images are read-only
arrays, shared by the scenes of those frames.
"""

from __future__ import annotations

import dataclasses
import glob
import logging
import os
import tempfile
import threading
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import OpenImageIO as oiio
from pxr import Ar, Sdf, Usd

from pxr_layers.inputs import input_problem
from pxr_layers.scene import FLOAT, TextureImage, WrapMode

from .diagnostics import Diagnostics
from .values import MAX_RADIANCE

logger = logging.getLogger(__name__)

ColorSpace = Literal["raw", "sRGB"]
# An image as a read uses it: its colour space, and whether a light emits it (_repaired).
_Use = tuple[ColorSpace, bool]
MAX_LIGHT_TEXEL = MAX_RADIANCE
"""Light texels above this are lowered to it: a light's texel is a radiance (values.MAX_RADIANCE:
far above any sun an HDRI holds, far enough below float32's range that the dome sampler's
sums over an image of up to 2^32 texels stay finite)."""
MAX_TEXTURE_TEXELS = 1 << 26
"""The most texels (width × height) a texture is held at in memory: 8192 × 8192, 1 GiB as RGBA
float32. A larger file is read reduced to fit (see the module docstring): a 16k × 8k lat-long
sky is read at 8k × 4k."""
MAX_FILE_TEXELS = 1 << 30
"""The most texels an image file may declare (32768 × 32768, the largest texture a paint
package exports) and still be read: decoding more takes tens of seconds before anything is
reduced, and a header claiming more is a decompression bomb or a damaged file."""
_BAND_BYTES = 1 << 24
"""About how many bytes of float32 rows a reduced read decodes at a time (16 MiB)."""
UDIM = "<UDIM>"  # the tile token of a texture path (Mari's convention, as USD and MaterialX use it)

# OIIO's "wrapmodes" metadata ("s,t") uses RenderMan words; scene.py uses UsdUVTexture's.
_OIIO_WRAP: dict[str, WrapMode] = {
    "black": "black",
    "clamp": "clamp",
    "periodic": "repeat",
    "mirror": "mirror",
}


@dataclass(frozen=True)
class _DecodedFile:
    """One file as stored: (h, w, c) float32 values in [0, 1] for integer formats.

    reduced_from : (width, height) of the file when it was read reduced to fit
                   MAX_TEXTURE_TEXELS, else None
    """

    pixels: np.ndarray
    is_uint8: bool
    wrap_modes: tuple[WrapMode | None, WrapMode | None]
    reduced_from: tuple[int, int] | None = None


@dataclass
class _FileTexture:
    """A file's images as this read uses them; ``decoded`` is None when the images come
    from an earlier read (decoded again only for a colour space that read did not use)."""

    identity: tuple | None  # see _texture_identity; None: not remembered
    is_uint8: bool
    channels: int
    wrap_modes: tuple[WrapMode | None, WrapMode | None]
    reduced_from: tuple[int, int] | None  # _DecodedFile.reduced_from
    decoded: _DecodedFile | None = None
    images: dict[_Use, np.ndarray] = field(default_factory=dict)  # (h, w, c) read-only
    repaired: dict[_Use, int] = field(default_factory=dict)  # texels _repaired in images[use]


_REMEMBERED: dict[tuple, _FileTexture] = {}
_REMEMBERED_LOCK = threading.Lock()  # frames may be read on several threads of a process


def _file_identity(path: str) -> tuple | None:
    """What tells a file's content apart: path, device and inode, size, modification and
    change times (a copy that keeps the old mtime, cp -p or rsync -a, still changes ctime)."""
    try:
        status = os.stat(path)
    except OSError:
        return None
    return (path, status.st_dev, status.st_ino, status.st_size, status.st_mtime_ns, status.st_ctime_ns)


def _texture_identity(resolved_path: str) -> tuple | None:
    """What tells a texture's content apart, None when nothing does (it is then not remembered).

    A plain file: _file_identity. A package member ``pkg.usdz[inner]``: the package file's
    identity and the member's name (a package's members change only with the package). Any
    other resolver path: the path and the modification time the resolver reports for it.
    """
    if not Ar.IsPackageRelativePath(resolved_path):
        identity = _file_identity(resolved_path)
        if identity is not None:
            return identity
    else:
        package, member = Ar.SplitPackageRelativePathOuter(resolved_path)
        package_identity = _file_identity(package)
        if package_identity is not None:
            return ("package member", package_identity, member)
    timestamp = Ar.GetResolver().GetModificationTimestamp(resolved_path, Ar.ResolvedPath(resolved_path))
    return ("resolved asset", resolved_path, timestamp.GetTime()) if timestamp.IsValid() else None


@dataclass(frozen=True)
class LoadedTexture:
    """A texture ready to reference: its index in SceneData.textures and the file's wrap modes."""

    index: int
    wrap_modes: tuple[WrapMode | None, WrapMode | None]  # (s, t) from metadata, None = absent


def anchored_asset_path(attribute: Usd.Attribute, asset: Sdf.AssetPath, time: Usd.TimeCode) -> str:
    """Where an unresolvable asset path points: anchored to the layer that authored it.

    ``resolvedPath`` is empty for a missing file, and the authored "../maps/x.exr" alone
    does not tell the user which directory was searched.
    """
    for spec in attribute.GetPropertyStack(time):
        if spec.HasDefaultValue() or spec.layer.GetNumTimeSamplesForPath(spec.path):
            anchored = spec.layer.ComputeAbsolutePath(asset.path)
            if not os.path.isabs(anchored) and spec.layer.realPath:
                # Search paths ("maps/x.png", no ./) stay unanchored in Sdf, but the
                # default resolver looks next to the layer first: report that place.
                anchored = os.path.join(os.path.dirname(spec.layer.realPath), anchored)
            return os.path.normpath(anchored)
    return asset.path


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """The sRGB EOTF (IEC 61966-2-1), elementwise; values below 0 stay on the linear segment."""
    # np.maximum keeps the power's base positive so negative inputs cannot produce NaN.
    curved = ((np.maximum(values, 0.04045) + 0.055) / 1.055) ** 2.4
    return np.where(values <= 0.04045, values / 12.92, curved).astype(FLOAT)


def udim_tiles(pattern: str) -> list[tuple[int, str]]:
    """(tile, file) of the UDIM tiles 1001–9999 on disk for a path containing <UDIM>."""
    head, tail = pattern.split(UDIM, 1)
    found = []
    for path in glob.glob(glob.escape(head) + "[1-9][0-9][0-9][0-9]" + glob.escape(tail)):
        tile = int(path[len(head):len(head) + 4])  # four digits: the glob says so
        if tile >= 1001 and os.path.isfile(path):
            found.append((tile, path))
    return sorted(found)


class TextureLibrary:
    """Decoded images for one stage read, appended to ``images`` in first-use order."""

    def __init__(self, diagnostics: Diagnostics) -> None:
        self.images: list[TextureImage] = []
        self._diagnostics = diagnostics
        self._files: dict[str, _FileTexture | None] = {}
        self._indices: dict[tuple[str, ColorSpace, bool], int] = {}

    def load(
        self, path: str, source_color_space: str, user_prim: str, *, light: bool = False
    ) -> LoadedTexture | None:
        """Decode ``path`` (a resolved asset path: a file, a package member, any resolver
        path) for the prim ``user_prim``.

        source_color_space : "raw", "sRGB" or "auto" (UsdUVTexture's sourceColorSpace);
                             "auto" decodes 8-bit files with 3+ channels as sRGB and
                             everything else (float, 16-bit, grey) as raw.
        light              : the image of a light: negative texels are read as 0 too, not
                             only NaN and infinite ones, and those above MAX_LIGHT_TEXEL as
                             it (see the module docstring)
        Returns None after a warning (once per file) when the file cannot be read.
        """
        texture = self._file(path, user_prim)
        if texture is None:
            return None
        if source_color_space == "sRGB":
            color_space: ColorSpace = "sRGB"
        elif source_color_space == "raw":
            color_space = "raw"
        else:
            if source_color_space != "auto":
                self._diagnostics.note(
                    "unknown-color-space",
                    "unknown sourceColorSpace values treated as 'auto' on: {prims}",
                    user_prim,
                )
            color_space = "sRGB" if texture.is_uint8 and texture.channels >= 3 else "raw"
        use: _Use = (color_space, light)
        key = (path, *use)
        if key not in self._indices:
            if use not in texture.images:
                if texture.decoded is None:  # remembered from an earlier read in another use
                    try:
                        texture.decoded = _read_texture(path)
                    except OSError as error:
                        self._unreadable(path, user_prim, error)
                        return None
                pixels = _linear(texture.decoded.pixels, color_space)
                texture.repaired[use] = _repaired(pixels, light)
                pixels.flags.writeable = False
                texture.images[use] = pixels
            if texture.reduced_from is not None:  # said at every read, as below
                (width, height), pixels = texture.reduced_from, texture.images[use]
                self._diagnostics.warn(
                    f"texture {path} (used by {user_prim}): {width}×{height} texels, more than the "
                    f"{MAX_TEXTURE_TEXELS:,} a texture may hold: read at {pixels.shape[1]}×{pixels.shape[0]}",
                    once_key=f"texture-reduced:{path}",
                )
            if texture.repaired[use]:  # said at every read: each frame's warnings are its own
                pixels = texture.images[use]
                what = (f"NaN, infinite or negative (read as 0) or above {MAX_LIGHT_TEXEL:g} (read as that)"
                        if light else "NaN or infinite (read as 0)")
                self._diagnostics.warn(
                    f"texture {path} (used by {user_prim}): {texture.repaired[use]} of "
                    f"{pixels.shape[0] * pixels.shape[1]} texels are {what}",
                    once_key=f"texture-repaired:{path}:{light}",
                )
            self._indices[key] = len(self.images)
            self.images.append(TextureImage(path=path, pixels=texture.images[use]))
        return LoadedTexture(self._indices[key], texture.wrap_modes)

    def load_tiles(self, path: str, source_color_space: str, user: str) -> list[tuple[int, LoadedTexture]]:
        """[(tile, texture)] of a texture path: ((0, texture),) for a plain file, every UDIM
        tile on disk for a path with <UDIM> (udim_tiles); after a warning naming `user`
        (the prim or node reading it), an empty list when there is nothing to read."""
        if UDIM not in path:
            loaded = self.load(path, source_color_space, user)
            return [] if loaded is None else [(0, loaded)]
        tiles = [(tile, self.load(file, source_color_space, user)) for tile, file in udim_tiles(path)]
        tiles = [(tile, loaded) for tile, loaded in tiles if loaded is not None]
        if not tiles:
            self._diagnostics.warn(f"no UDIM tiles found for {path} (used by {user}); using its fallback value",
                                   once_key=f"texture:{path}")
        return tiles

    def remember(self) -> None:
        """Keep this read's images for the next read in the process (replacing the last)."""
        global _REMEMBERED
        kept = {texture.identity: dataclasses.replace(texture, decoded=None, images=dict(texture.images),
                                                      repaired=dict(texture.repaired))
                for texture in self._files.values() if texture is not None and texture.identity is not None}
        with _REMEMBERED_LOCK:
            _REMEMBERED = kept

    def _file(self, path: str, user_prim: str) -> _FileTexture | None:
        if path in self._files:
            return self._files[path]
        identity = _texture_identity(path)
        with _REMEMBERED_LOCK:
            earlier = _REMEMBERED.get(identity) if identity is not None else None
        if earlier is not None:
            texture = dataclasses.replace(earlier, images=dict(earlier.images), repaired=dict(earlier.repaired))
        else:
            texture = None
            try:
                decoded = _read_texture(path)
                texture = _FileTexture(identity, decoded.is_uint8, decoded.pixels.shape[2], decoded.wrap_modes,
                                       decoded.reduced_from, decoded)
            except OSError as error:
                self._unreadable(path, user_prim, error)
        self._files[path] = texture
        return texture

    def _unreadable(self, path: str, user_prim: str, error: OSError) -> None:
        self._diagnostics.warn(
            f"cannot read texture {path} (used by {user_prim}): {error}; using the fallback value instead",
            once_key=f"texture:{path}",
        )


def on_disk(resolved_path: str, what: str) -> bool:
    """Whether a resolved asset path is a file on disk, to be opened directly (False: a path
    only USD's asset resolver can open, a package member or a custom resolver's); OSError
    when it is on disk but not a regular file (a FIFO would block the read: inputs.py)."""
    if Ar.IsPackageRelativePath(resolved_path) or not os.path.lexists(resolved_path):
        return False
    problem = input_problem(resolved_path, what)
    if problem is not None:
        raise OSError(problem)
    return True


def _read_texture(resolved_path: str) -> _DecodedFile:
    """Decode a resolved asset path: a plain file directly, anything else through Ar."""
    if on_disk(resolved_path, "texture"):
        return _read_file(resolved_path)
    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved_path))
    if not asset:
        raise OSError("USD's asset resolver cannot open it")
    with asset:  # releases the package's file as soon as the bytes are copied
        contents = asset.GetBuffer()
    if contents is None:
        raise OSError("USD's asset resolver cannot read it")
    # OpenImageIO's Python binding has no IOProxy (OIIO's in-memory reader), so the bytes are
    # decoded from a private temporary file (mode 0600), deleted as soon as the pixels are read,
    # whatever happens. It keeps the asset's extension: OIIO picks its reader by extension first.
    extension = Ar.GetResolver().GetExtension(resolved_path)
    descriptor, temporary = tempfile.mkstemp(prefix="pxr_layers_texture_",
                                             suffix=f".{extension}" if extension else "")
    try:
        with os.fdopen(descriptor, "wb") as file:
            file.write(contents)
        return _read_file(temporary, name=resolved_path)
    except OSError as error:  # OIIO names the file it opened: name the asset instead
        raise OSError(str(error).replace(temporary, resolved_path)) from None
    finally:
        os.unlink(temporary)


def _read_file(path: str, name: str | None = None) -> _DecodedFile:
    """Decode the image file ``path``; ``name`` is what log lines call it (default ``path``)."""
    config = oiio.ImageSpec()
    # OIIO premultiplies PNG/TIFF colour by alpha unless told otherwise; UsdUVTexture reads
    # channels exactly as stored.
    config.attribute("oiio:UnassociatedAlpha", 1)
    image_input = oiio.ImageInput.open(path, config)
    if image_input is None:
        raise OSError(oiio.geterror() or "unreadable image")
    reduced_from = None
    try:
        spec = image_input.spec()  # the header alone: nothing is decoded yet
        width, height = spec.width, spec.height
        if spec.depth > 1:
            raise OSError(f"a volume image ({width}×{height}×{spec.depth}) is not a texture")
        if width * height > MAX_FILE_TEXELS:
            raise OSError(f"{width}×{height} texels: more than the {MAX_FILE_TEXELS:,} a texture file may have")
        if width * height > MAX_TEXTURE_TEXELS:
            reduced_from = (width, height)
            pixels = _read_reduced(image_input, spec)
        else:
            pixels = image_input.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            raise OSError(image_input.geterror() or "cannot decode pixels")
    finally:
        image_input.close()
    if reduced_from is None:
        pixels = np.asarray(pixels, dtype=FLOAT).reshape(spec.height, spec.width, spec.nchannels)
    wrap_modes: list[WrapMode | None] = [None, None]
    metadata = spec.get_string_attribute("wrapmodes")
    if metadata:
        words = metadata.split(",")
        words = words if len(words) == 2 else [words[0], words[0]]
        wrap_modes = [_OIIO_WRAP.get(word.strip()) for word in words]
    logger.debug("decoded %s: %dx%d, %d channels of %s", name or path, spec.width, spec.height,
                 spec.nchannels, spec.format)
    return _DecodedFile(
        pixels=pixels,
        is_uint8=spec.format.basetype == oiio.UINT8,
        wrap_modes=(wrap_modes[0], wrap_modes[1]),
        reduced_from=reduced_from,
    )


def _read_reduced(image_input: oiio.ImageInput, spec: oiio.ImageSpec) -> np.ndarray | None:
    """(h', w', c) float32 of an image of more than MAX_TEXTURE_TEXELS, within it: its first MIP
    level that fits, or its full resolution averaged over n × n blocks (the smallest n that
    fits; the blocks of the last row and column may be partial), decoded a band of n-row
    strips at a time. None when a read fails (image_input.geterror() says why)."""
    channels = spec.nchannels
    level = 1
    while True:  # a MIP level's spec has width 0 past the last level
        level_spec = image_input.spec_dimensions(0, level)
        if level_spec.width == 0:
            break
        if level_spec.width * level_spec.height <= MAX_TEXTURE_TEXELS:
            pixels = image_input.read_image(0, level, 0, channels, oiio.FLOAT)
            return None if pixels is None else np.asarray(pixels, FLOAT).reshape(
                level_spec.height, level_spec.width, channels)
        level += 1
    width, height = spec.width, spec.height
    factor = 2
    while -(-width // factor) * -(-height // factor) > MAX_TEXTURE_TEXELS:
        factor += 1
    # 8- and 16-bit files are decoded as stored (a quarter or half the bytes of float32: most
    # of a large PNG's read time) and scaled to [0, 1] as OIIO's float conversion does.
    stored = {oiio.UINT8: (oiio.UINT8, 1.0 / 255.0), oiio.UINT16: (oiio.UINT16, 1.0 / 65535.0)}
    decoded_as, scale = stored.get(spec.format.basetype, (oiio.FLOAT, 1.0))
    reduced = np.empty((-(-height // factor), -(-width // factor), channels), FLOAT)
    strips_per_band = max(1, _BAND_BYTES // (factor * width * channels * 4))
    for first in range(0, height, factor * strips_per_band):
        last = min(first + factor * strips_per_band, height)
        band = image_input.read_scanlines(0, 0, first, last, 0, 0, channels, decoded_as)
        if band is None:
            return None
        band = np.asarray(band).reshape(last - first, width, channels)
        means = _block_means(band, factor)
        reduced[first // factor:first // factor + len(means)] = means * FLOAT(scale)
    return reduced


def _block_means(band: np.ndarray, factor: int) -> np.ndarray:
    """(⌈r/n⌉, ⌈w/n⌉, c) float32 means of the n × n blocks (``factor`` n) of the (r, w, c) ``band``;
    the blocks of its last row and column hold what is left. Summed one strided offset at a
    time (n vectorised additions per axis), far faster than numpy's reductions over short axes."""
    rows, width, channels = band.shape
    row_sums = np.zeros((-(-rows // factor), width, channels), FLOAT)
    for offset in range(min(factor, rows)):
        part = band[offset::factor]
        row_sums[:len(part)] += part
    sums = np.zeros((len(row_sums), -(-width // factor), channels), FLOAT)
    for offset in range(min(factor, width)):
        part = row_sums[:, offset::factor]
        sums[:, :part.shape[1]] += part
    row_counts = np.minimum(factor, rows - factor * np.arange(sums.shape[0])).astype(FLOAT)
    column_counts = np.minimum(factor, width - factor * np.arange(sums.shape[1])).astype(FLOAT)
    return sums / (row_counts[:, None, None] * column_counts[None, :, None])


def _repaired(pixels: np.ndarray, light: bool) -> int:
    """Replace, in the (h, w, c) float32 ``pixels``, the values no lookup can use by 0: NaN and
    infinities, and with ``light`` negative values too (and lower those above MAX_LIGHT_TEXEL
    to it). Returns how many texels (pixels, any channel) changed."""
    unusable = ~np.isfinite(pixels)
    too_bright = None
    if light:
        unusable |= pixels < 0.0
        too_bright = ~unusable & (pixels > MAX_LIGHT_TEXEL)
    changed = unusable if too_bright is None else unusable | too_bright
    count = int(np.count_nonzero(changed.any(axis=2)))
    if count:
        pixels[unusable] = 0.0
        if too_bright is not None:
            pixels[too_bright] = MAX_LIGHT_TEXEL
    return count


def _linear(pixels: np.ndarray, color_space: ColorSpace) -> np.ndarray:
    """(h, w, c) stored values → (h, w, min(c, 4)) linear float32; the EOTF never touches alpha."""
    channels = min(pixels.shape[2], 4)
    linear = np.array(pixels[:, :, :channels], dtype=FLOAT)  # a copy: the decoded file stays as stored
    if color_space == "sRGB":
        colour = 3 if channels >= 3 else 1
        # A band of rows at a time: the EOTF's temporaries stay small beside a large image.
        rows = max(1, _BAND_BYTES // (4 * linear.shape[1] * colour))
        for top in range(0, linear.shape[0], rows):
            band = linear[top:top + rows, :, :colour]
            band[...] = srgb_to_linear(band)
    return linear
