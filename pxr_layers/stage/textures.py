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

Material textures that are files on disk are not decoded here: their header is read (size,
channels, stored type, levels, wrap modes; a file that cannot be a texture is a warning and
its fallback value) and they reach the tracer as scene.TextureImage without pixels, which
its texture cache (trace/texture_cache.py) reads at the MIP levels the frame needs. The
images of lights (the samplers need every texel) and textures only USD's resolver can open
are decoded here, bounded as texture_files.py says (a file of more than MAX_TEXTURE_TEXELS
is read at its first MIP level within it, with a warning naming it).

Texels no lookup can use are replaced by 0 when a file is decoded, with one warning naming
the file and how many texels changed (texture_files.repaired): NaN and infinite ones in every texture
(a NaN roughness or albedo makes NaN pixels, and an infinite one NaN as soon as it is
multiplied by 0), and in the images of lights (``light=True``: a dome's lat-long image, a
rect light's colour map) negative ones too, which would be negative radiance, while texels
above MAX_LIGHT_TEXEL are lowered to it. Those of materials keep their sign, which normal
maps, displacement and scale/bias offsets need.

The decoded textures of the last stage read are remembered in the process by identity (see
_texture_identity): the frames of a shot read the same files one after another, and the next
read takes the decoded images instead of decoding them again. The images are read-only
arrays, shared by the scenes of those frames.
"""

from __future__ import annotations

import dataclasses
import glob
import logging
import math
import os
import tempfile
import threading
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pxr import Ar, Sdf, Usd

from pxr_layers.inputs import input_problem
from pxr_layers.scene import TextureHeader, TextureImage, WrapMode
from pxr_layers.texture_files import (MAX_TEXTURE_TEXELS, file_identity, level_size, linear, read_header, read_level,
                                      repaired)

from .diagnostics import Diagnostics
from .values import MAX_RADIANCE

logger = logging.getLogger(__name__)

ColorSpace = Literal["raw", "sRGB"]
# An image as a read uses it: its colour space, and whether a light emits it (texture_files.repaired).
_Use = tuple[ColorSpace, bool]
MAX_LIGHT_TEXEL = MAX_RADIANCE
"""Light texels above this are lowered to it: a light's texel is a radiance (values.MAX_RADIANCE:
far above any sun an HDRI holds, far enough below float32's range that the dome sampler's
sums over an image of up to 2^32 texels stay finite)."""
UDIM = "<UDIM>"  # the tile token of a texture path (Mari's convention, as USD and MaterialX use it)

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
    repaired: dict[_Use, int] = field(default_factory=dict)  # texels repaired in images[use]


_REMEMBERED: dict[tuple, _FileTexture] = {}
_REMEMBERED_LOCK = threading.Lock()  # frames may be read on several threads of a process



def _texture_identity(resolved_path: str) -> tuple | None:
    """What tells a texture's content apart, None when nothing does (it is then not remembered).

    A plain file: file_identity. A package member ``pkg.usdz[inner]``: the package file's
    identity and the member's name (a package's members change only with the package). Any
    other resolver path: the path and the modification time the resolver reports for it.
    """
    if not Ar.IsPackageRelativePath(resolved_path):
        identity = file_identity(resolved_path)
        if identity is not None:
            return identity
    else:
        package, member = Ar.SplitPackageRelativePathOuter(resolved_path)
        package_identity = file_identity(package)
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
    """The images of one stage read (decoded, or headers for the tracer to read), appended to
    ``images`` in first-use order."""

    def __init__(self, diagnostics: Diagnostics) -> None:
        self.images: list[TextureImage] = []
        self._diagnostics = diagnostics
        self._files: dict[str, _FileTexture | None] = {}
        self._headers: dict[str, TextureHeader | None | bool] = {}  # see _lazy_header
        self._indices: dict[tuple[str, ColorSpace, bool], int] = {}

    def load(
        self, path: str, source_color_space: str, user_prim: str, *, light: bool = False
    ) -> LoadedTexture | None:
        """The texture ``path`` (a resolved asset path: a file, a package member, any resolver
        path) for the prim ``user_prim``: a material's file on disk by its header alone
        (the tracer decodes it), anything else decoded.

        source_color_space : "raw", "sRGB" or "auto" (UsdUVTexture's sourceColorSpace);
                             "auto" decodes 8-bit files with 3+ channels as sRGB and
                             everything else (float, 16-bit, grey) as raw.
        light              : the image of a light: decoded, and negative texels are read as
                             0 too, not only NaN and infinite ones, and those above
                             MAX_LIGHT_TEXEL as it (see the module docstring)
        Returns None after a warning (once per file) when the file cannot be read.
        """
        header = None if light else self._lazy_header(path, user_prim)
        if header is False:
            return None
        texture = None
        if header is None:
            texture = self._file(path, user_prim)
            if texture is None:
                return None
        uint8, channels = (header.stored == "uint8", header.channels) if header else (texture.is_uint8,
                                                                                   texture.channels)
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
            color_space = "sRGB" if uint8 and channels >= 3 else "raw"
        key = (path, color_space, light)
        if key not in self._indices:
            if header:
                image = TextureImage(path, None, header, color_space, user_prim)
            else:
                try:
                    image = TextureImage(path, self._decoded(texture, path, color_space, light, user_prim))
                except OSError as error:
                    self._unreadable(path, user_prim, error)
                    return None
            self._indices[key] = len(self.images)
            self.images.append(image)
        return LoadedTexture(self._indices[key], header.wrap_modes if header else texture.wrap_modes)

    def _lazy_header(self, path: str, user_prim: str) -> TextureHeader | None | bool:
        """A material texture's header when the tracer reads it lazily (a file on disk);
        None when it is decoded here instead (only USD's resolver opens it); False after a
        warning, when it cannot be read."""
        if path not in self._headers:
            try:
                self._headers[path] = read_header(path) if on_disk(path, "texture") else None
            except OSError as error:
                self._unreadable(path, user_prim, error)
                self._headers[path] = False
        return self._headers[path]

    def _decoded(self, texture: _FileTexture, path: str, color_space: ColorSpace, light: bool,
                 user_prim: str) -> np.ndarray:
        """The read-only linear pixels of `texture` for one use; OSError when a decode fails."""
        use: _Use = (color_space, light)
        if use not in texture.images:
            if texture.decoded is None:  # remembered from an earlier read in another use
                texture.decoded = _read_texture(path)
            pixels = linear(texture.decoded.pixels, color_space)
            texture.repaired[use] = repaired(pixels, MAX_LIGHT_TEXEL if light else None)
            pixels.flags.writeable = False
            texture.images[use] = pixels
        pixels = texture.images[use]
        if texture.reduced_from is not None:  # said at every read, as below
            width, height = texture.reduced_from
            self._diagnostics.warn(
                f"texture {path} (used by {user_prim}): {width}×{height} texels, more than the "
                f"{MAX_TEXTURE_TEXELS:,} a texture may hold: read at {pixels.shape[1]}×{pixels.shape[0]}",
                once_key=f"texture-reduced:{path}",
            )
        if texture.repaired[use]:  # said at every read: each frame's warnings are its own
            what = (f"NaN, infinite or negative (read as 0) or above {MAX_LIGHT_TEXEL:g} (read as that)"
                    if light else "NaN or infinite (read as 0)")
            self._diagnostics.warn(
                f"texture {path} (used by {user_prim}): {texture.repaired[use]} of "
                f"{pixels.shape[0] * pixels.shape[1]} texels are {what}",
                once_key=f"texture-repaired:{path}:{light}",
            )
        return pixels

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
    """Decode the image file ``path`` as float32 (its finest MIP level within
    MAX_TEXTURE_TEXELS); ``name`` is what log lines call it (default ``path``)."""
    header = read_header(path)
    level = 0
    while math.prod(level_size(header.width, header.height, level)) > MAX_TEXTURE_TEXELS:
        level += 1
    _, pixels = read_level(path, level, "float")
    logger.debug("decoded %s: %dx%d, %d channels of %s", name or path, header.width, header.height,
                 header.channels, header.stored)
    return _DecodedFile(pixels=pixels, is_uint8=header.stored == "uint8", wrap_modes=header.wrap_modes,
                        reduced_from=(header.width, header.height) if level else None)
