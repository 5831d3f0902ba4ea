"""The covariance norms C, T, R of one bounce, from the hit's geometry, texture and lobe.

These are the norms of the covariance operators each bounce applies (COVARIANCE.md,
"What the index stores per bounce"; conventions in ``pxr_layers.covariance``):

* C = max(|k1|, |k2|), 1/m: the principal curvatures of the hit triangle (``World``);
  exactly 0 on planar geometry, 1/r on a sphere of radius r.
* T = √λmax(T), cycles/m: the texture operator of the texture driving the material's
  diffuseColor (the albedo, which multiplies the reflected light), looked up through its
  uv transform (UsdTransform2d, MaterialX place2d/tiledimage), measured per tile and mip level
  (``covariance.texture_spectrum``), mapped from texture units to metres by the uv
  Jacobian of the triangle in the shading frame. Untextured materials give 0. The mip
  level follows the camera sample's ray cone (``sigma.RayCone``): the pixel angle times the
  distance the path has travelled, plus a lens's defocus width, divided by the cosine at the hit.
* R = √λmax(B), cycles/rad: the bandwidth of the lobe the bounce took. Diffuse 0, GGX
  lobes 1/(2πα) with α = roughness². Singular lobes (perfect mirror, smooth glass) get
  the value of the sharpest GGX lobe the renderer evaluates, 1/(2π·SINGULAR_ALPHA) ≈
  1592, so R is finite and grows monotonically as roughness decreases. Hair lobes (R, TT,
  TRT) 1/(2π√v), v the lobe's longitudinal variance (hair.py).

Straight pass-through (cut-outs) and light events apply no operator: their norms are 0.
"""

from __future__ import annotations

import hashlib
import math
import threading
import weakref
from collections import OrderedDict

import numpy as np

from ..covariance import (
    curvature_norm,
    ggx_bandwidth,
    reflectance_norm,
    texture_norm,
    texture_to_tangent,
)
from ..covariance.texture_spectrum import TextureSpectrum
from ..scene import FLOAT, SceneData
from . import bsdf, hair
from ..compiled import inline, kernel
from ..paths import events
from .shading import MaterialTable, diffuse_texture
from .texture_cache import FINEST
from .vectors import dot
from .world import World

SINGULAR_REFLECTANCE = float(reflectance_norm(ggx_bandwidth(bsdf.SINGULAR_ALPHA), ggx_bandwidth(bsdf.SINGULAR_ALPHA)))


_SPECTRA: OrderedDict[bytes, TextureSpectrum] = OrderedDict()
_SPECTRA_LOCK = threading.Lock()  # frames may be prepared on several threads of a process
SPECTRA_KEPT = 32
"""Texture spectra a process keeps, by image content (see :func:`texture_spectrum`)."""


def texture_spectrum(pixels: np.ndarray, level: int = 0) -> TextureSpectrum:
    """``TextureSpectrum.of_image(pixels, level)``, remembered by content: the frames of a
    shot are prepared one after another in one process, and textures rarely change between
    them, so the FFTs of a 4K texture are not redone per frame (hashing is far cheaper)."""
    pixels = np.ascontiguousarray(pixels)
    digest = _content_digest(pixels) + bytes([level])
    with _SPECTRA_LOCK:
        if digest not in _SPECTRA:
            _SPECTRA[digest] = TextureSpectrum.of_image(pixels, level)
            while len(_SPECTRA) > SPECTRA_KEPT:
                _SPECTRA.popitem(last=False)
        _SPECTRA.move_to_end(digest)
        return _SPECTRA[digest]


_DIGESTS: dict[int, tuple[weakref.ref, bytes]] = {}


def _content_digest(pixels: np.ndarray) -> bytes:
    """A hash of the pixels, their shape and type. An array that owns its data and was made
    read-only (the stage reader's textures, shared by the frames it reads) is taken as
    frozen and hashed once; a read-only view of writable data is hashed every time."""
    frozen = not pixels.flags.writeable and pixels.base is None
    if frozen:
        known = _DIGESTS.get(id(pixels))
        if known is not None and known[0]() is pixels:
            return known[1]
    key = hashlib.blake2b(pixels.view(np.uint8), digest_size=16)
    key.update(repr((pixels.shape, pixels.dtype.str)).encode())
    digest = key.digest()
    if frozen:
        with _SPECTRA_LOCK:
            for dead in [number for number, (array, _) in _DIGESTS.items() if array() is None]:
                del _DIGESTS[dead]
            _DIGESTS[id(pixels)] = (weakref.ref(pixels), digest)
    return digest


class BounceNorms:
    """Per-scene tables for C and T, built once per frame, shared read-only by threads."""

    def __init__(self, scene: SceneData, world: World, materials: MaterialTable):
        self.world = world
        self.curvature = curvature_norm(world.curvature_k1, world.curvature_k2).astype(FLOAT)
        driving = [diffuse_texture(material) for material in scene.materials]
        textured = [-1 if found is None else found[0] for found in driving]
        self.material_texture = np.array(textured + [-1], np.int64)  # the last entry: no material
        # (m + 1, 2, 3) the affine map from the mesh's st to the texture's uv
        self.material_uv = np.array([np.eye(3)[:2] if found is None else np.reshape(found[1], (2, 3))
                                     for found in driving] + [np.eye(3)[:2]])
        # each texture's spectrum of its finest resident level (texture units, as T's lookups)
        rows, resident = materials.texture_rows, materials.resident
        self.spectra = {}
        for index in sorted(set(textured) & set(rows)):  # one linear copy of a level at a time
            pixels = resident.finest_linear(rows[index])
            if pixels is not None:
                self.spectra[index] = texture_spectrum(pixels, int(resident.info[rows[index], FINEST]))

    def texture(self, surfaces, footprint: np.ndarray) -> None:
        """Fill ``surfaces.texture`` (T, cycles/m) of a SurfaceQueue's textured lanes, for
        footprints (n,) metres wide."""
        if not self.spectra:
            return
        scattering = np.flatnonzero(surfaces.scatters)
        for chosen, block_uv, grad_s, grad_t in self._textured(surfaces.triangle[scattering], surfaces.st[scattering],
                                                              footprint[scattering]):
            lanes = scattering[chosen]
            tx, ty = surfaces.frame[lanes, 0].T, surfaces.frame[lanes, 1].T
            # J = ∂(u, v)/∂(t̂x, t̂y), texture units per metre
            jacobian = np.stack([np.stack([dot(grad_s, tx), dot(grad_s, ty)], -1),
                                 np.stack([dot(grad_t, tx), dot(grad_t, ty)], -1)], -2).astype(np.float64)
            surfaces.texture[lanes] = texture_norm(texture_to_tangent(block_uv, jacobian))

    def uv_texture(self, triangle: np.ndarray, st: np.ndarray, footprint: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The texture operator of hits in the texture's own uv, as ``texture`` looks it up.

        triangle (n,), st (n, 2) the mesh's st, footprint (n,) metres. Returns block_uv
        (n, 2, 2) float64 cycles² per texture unit² and the world gradients grad_u, grad_v
        (3, n) float64 of the texture's uv, 1/m (zeros on untextured hits), so that
        T = Jᵀ block_uv J with J = [[∇u·a, ∇u·b], [∇v·a, ∇v·b]] for any tangent axes a, b.
        """
        n = len(triangle)
        block_uv, grad_u, grad_v = np.zeros((n, 2, 2)), np.zeros((3, n)), np.zeros((3, n))
        for chosen, block, grad_s, grad_t in self._textured(triangle, st, footprint):
            block_uv[chosen], grad_u[:, chosen], grad_v[:, chosen] = block, grad_s, grad_t
        return block_uv, grad_u, grad_v

    def _textured(self, triangle: np.ndarray, st: np.ndarray, footprint: np.ndarray):
        """Per texture driving some of the hits (triangle (n,), st (n, 2), footprint (n,)
        metres): (positions among the n, block_uv (k, 2, 2), ∇u, ∇v (3, k) of the texture's
        own uv)."""
        material = np.take(self.world.triangle_material, triangle)
        texture_index = np.take(self.material_texture, material)
        for index, spectrum in self.spectra.items():
            chosen = np.flatnonzero(texture_index == index)
            if not len(chosen):
                continue
            tri = triangle[chosen]
            uv_map = self.material_uv[material[chosen]]  # (k, 2, 3): the texture's uv from st
            grad_s = np.take(self.world.gradient_s, tri, axis=1)
            grad_t = np.take(self.world.gradient_t, tri, axis=1)
            # the gradients of the texture's own uv: A · ∇(s, t)
            grad_s, grad_t = (uv_map[:, 0, 0] * grad_s + uv_map[:, 0, 1] * grad_t,
                              uv_map[:, 1, 0] * grad_s + uv_map[:, 1, 1] * grad_t)
            texels_per_metre = np.maximum(np.linalg.norm(grad_s, axis=0) * spectrum.width,
                                          np.linalg.norm(grad_t, axis=0) * spectrum.height)
            hit_st = st[chosen].astype(np.float64)
            uv = np.einsum("kij,kj->ik", uv_map, np.concatenate([hit_st, np.ones((len(hit_st), 1))], axis=1))
            yield chosen, spectrum.lookup(uv, footprint[chosen] * texels_per_metre), grad_s, grad_t


@inline
def reflectance(lobes, lane, lobe):
    """R of `lobe` taken at the hit whose lobe row is lobes[lane] (bsdf.py); a hair lobe's
    from its longitudinal width w (hair.py), as a GGX lobe's from α: 1/(2π·w)."""
    if lobe == bsdf.DIFFUSE:
        return 0.0
    if lobe >= events.LOBE_HAIR_R:
        return 1.0 / (2.0 * math.pi * hair.lobe_width(lobes[lane], lobe - events.LOBE_HAIR_R))
    alpha = lobes[lane, bsdf.ALPHA] if lobe == bsdf.SPECULAR else lobes[lane, bsdf.COAT_ALPHA]
    if lobe == bsdf.GLASS or alpha < bsdf.SINGULAR_ALPHA:
        return SINGULAR_REFLECTANCE
    return 1.0 / (2.0 * math.pi * alpha)


def lobe_reflectance(lobes: np.ndarray, lobe: np.ndarray) -> np.ndarray:
    """R (n,) float32 of the lobes `lobe` (n,) ids taken at hits with lobe rows (n,
    LOBE_FIELDS) (bsdf.py)."""
    out = np.empty(len(lobe), FLOAT)
    _reflectance_kernel(lobes, np.asarray(lobe, np.int64), out)
    return out


@kernel
def _reflectance_kernel(lobes, lobe, out):
    for lane in range(len(lobe)):
        out[lane] = reflectance(lobes, lane, lobe[lane])
