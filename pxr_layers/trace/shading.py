"""Surface points and UsdPreviewSurface inputs evaluated for batches of ray hits.

Vectors and colours are component-major (3, n) arrays (see vectors.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import FLOAT, Material, SceneData, TextureInput
from .textures import sample_bilinear
from .vectors import normalize
from .world import World

_COLOR_INPUTS = ("diffuse_color", "emissive_color", "specular_color")
_SCALAR_INPUTS = ("roughness", "metallic", "opacity", "clearcoat", "clearcoat_roughness")


@dataclass
class SurfacePoints:
    """Geometry at n hit points (world space, metres).

    position         : (3, n) float32
    geometric_normal : (3, n) float32 unit, from the triangle's winding (not flipped)
    shading_normal   : (3, n) float32 unit, interpolated
    st               : (2, n) float32
    triangle         : (n,) int32
    """

    position: np.ndarray
    geometric_normal: np.ndarray
    shading_normal: np.ndarray
    st: np.ndarray
    triangle: np.ndarray


def surface_points(world: World, triangle: np.ndarray, u: np.ndarray, v: np.ndarray) -> SurfacePoints:
    """Interpolate position, normal and st at barycentrics (u, v) of `triangle` (all (n,))."""
    position = interpolate(world.corner_positions, triangle, u, v)
    shading = normalize(interpolate(world.corner_normals, triangle, u, v), 1e-12)
    st = interpolate(world.corner_uvs, triangle, u, v)
    normal = np.take(world.geometric_normal, triangle, axis=1)
    return SurfacePoints(position, normal, shading, st, triangle)


def interpolate(corners: np.ndarray, triangle: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(1 − u − v)·c0 + u·c1 + v·c2 of corner data (3 corners, k, t) at `triangle`, u, v
    (all (n,)) -> (k, n) float32."""
    u = u.astype(FLOAT, copy=False)
    v = v.astype(FLOAT, copy=False)
    c0 = np.take(corners[0], triangle, axis=1)
    c1 = np.take(corners[1], triangle, axis=1)
    c2 = np.take(corners[2], triangle, axis=1)
    return c0 + (c1 - c0) * u + (c2 - c0) * v


@dataclass
class SurfaceInputs:
    """UsdPreviewSurface inputs at n points; (3, n) for colours, (n,) for scalars."""

    diffuse_color: np.ndarray
    emissive_color: np.ndarray
    specular_color: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    opacity: np.ndarray
    clearcoat: np.ndarray
    clearcoat_roughness: np.ndarray
    use_specular_workflow: np.ndarray  # (n,) bool
    ior: np.ndarray
    opacity_threshold: np.ndarray


class MaterialTable:
    """Every material's constant inputs as arrays, plus the list of texture-driven inputs."""

    def __init__(self, scene: SceneData):
        materials = scene.materials or (Material(name="default", path="<default>"),)
        self._textures = scene.textures
        self._constants: dict[str, np.ndarray] = {}
        self._textured: list[tuple[str, int, TextureInput]] = []
        for name in _COLOR_INPUTS + _SCALAR_INPUTS:
            width = 3 if name in _COLOR_INPUTS else 1
            table = np.zeros((width, len(materials)), FLOAT)
            for index, material in enumerate(materials):
                value = getattr(material, name)
                if isinstance(value, TextureInput):
                    self._textured.append((name, index, value))
                else:
                    table[:, index] = value
            self._constants[name] = table if width == 3 else table[0]
        self._use_specular_workflow = np.array([m.use_specular_workflow for m in materials], bool)
        self._ior = np.array([m.ior for m in materials], FLOAT)
        self._opacity_threshold = np.array([m.opacity_threshold for m in materials], FLOAT)
        self.cutout = self._opacity_threshold > 0  # (materials,) bool: can cut a surface out
        self.emissive = (self._constants["emissive_color"].max(axis=0) > 0) | np.array(
            [isinstance(m.emissive_color, TextureInput) for m in materials]
        )

    def evaluate(self, material: np.ndarray, st: np.ndarray) -> SurfaceInputs:
        """Inputs of `material` (n,) int32 at texture coordinates st (2, n)."""
        values = self._lookup_all(material, st, self._constants)
        return SurfaceInputs(
            **values,
            use_specular_workflow=np.take(self._use_specular_workflow, material),
            ior=np.take(self._ior, material),
            opacity_threshold=np.take(self._opacity_threshold, material),
        )

    def emission(self, material: np.ndarray, st: np.ndarray) -> np.ndarray:
        """emissiveColor (3, n) at st (2, n) of `material` (n,)."""
        wanted = {"emissive_color": self._constants["emissive_color"]}
        return self._lookup_all(material, st, wanted)["emissive_color"]

    def _lookup_all(self, material, st, tables) -> dict[str, np.ndarray]:
        values = {name: np.take(table, material, axis=-1) for name, table in tables.items()}
        for name, material_index, texture_input in self._textured:
            if name not in values:
                continue
            lanes = np.flatnonzero(material == material_index)
            if len(lanes):
                values[name][..., lanes] = self._texture(texture_input, st[:, lanes], values[name].ndim)
        return values

    def _texture(self, texture_input: TextureInput, st: np.ndarray, ndim: int) -> np.ndarray:
        image = self._textures[texture_input.texture].pixels
        texels = sample_bilinear(image, st, texture_input.wrap_s, texture_input.wrap_t)
        channels = list(texture_input.channels)
        scale = np.asarray(texture_input.scale, FLOAT)[channels, None]
        bias = np.asarray(texture_input.bias, FLOAT)[channels, None]
        value = texels[channels] * scale + bias
        if ndim == 1:
            return value[0]
        return value if len(value) == 3 else np.repeat(value[:1], 3, axis=0)
