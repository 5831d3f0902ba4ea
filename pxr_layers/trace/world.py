"""Flatten SceneData into the tracer's world: one triangle soup with per-triangle tables.

Meshes come first, then the tessellated shapes of the area lights (rect, disk, sphere,
cylinder), so a ray that reaches a light hits real geometry and the same triangles are
sampled for next-event estimation. Light triangles are wound so that their geometric
normal points the way the light emits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RenderSettingsError
from ..scene import FLOAT, INDEX, Light, SceneData
from .curvature import triangle_curvatures

NOT_A_LIGHT = -1
DISK_SEGMENTS = 64
SPHERE_RINGS, SPHERE_SEGMENTS = 24, 48
CYLINDER_SEGMENTS = 48


@dataclass(frozen=True)
class World:
    """The scene as flat arrays, t triangles over v vertices, world space in metres.

    vertices         : (v, 3) float32 (Embree's input layout)
    triangles        : (t, 3) int32
    geometric_normal : (3, t) float32 unit, right-handed from the winding
    area             : (t,) float32 square metres
    corner_positions : (3 corners, 3, t) float32
    corner_normals   : (3 corners, 3, t) float32 unit shading normals (flat where none
                       authored)
    corner_uvs       : (3 corners, 2, t) float32 (zeros where none authored)
    curvature_k1, curvature_k2 : (t,) float32 principal curvatures, 1/m, k1 ≥ k2, from
                       the shading normals (see curvature.py; 0 on flat geometry)
    principal_direction : (3, t) float32 unit direction of k1
    gradient_s, gradient_t : (3, t) float32 world-space gradients of the texture
                       coordinates over each triangle, 1/m (in the triangle's plane; zero
                       where the uvs are degenerate): ∂(s, t)/∂(a, b) = [[∇s·a, ∇s·b],
                       [∇t·a, ∇t·b]] for any tangent axes a, b

    Per-triangle vectors are component-major (see vectors.py): gathering lanes with
    np.take(..., axis=-1) yields (3, n) rows directly.
    triangle_object  : (t,) int32 index into object_names / object_paths
    triangle_material: (t,) int32 index into SceneData.materials, -1 on light shapes
    triangle_light   : (t,) int32 index into SceneData.lights, -1 on surfaces
    object_instance  : (objects,) int32 per object (object_names order): the instance
                       number N of a point-instanced mesh (scene.Mesh.instance), -1 for
                       other meshes and for lights
    center, radius   : bounding sphere of all vertices (metres)
    """

    vertices: np.ndarray
    triangles: np.ndarray
    geometric_normal: np.ndarray
    area: np.ndarray
    corner_positions: np.ndarray
    corner_normals: np.ndarray
    corner_uvs: np.ndarray
    curvature_k1: np.ndarray
    curvature_k2: np.ndarray
    principal_direction: np.ndarray
    gradient_s: np.ndarray
    gradient_t: np.ndarray
    triangle_object: np.ndarray
    triangle_material: np.ndarray
    triangle_light: np.ndarray
    object_names: tuple[str, ...]
    object_paths: tuple[str, ...]
    object_instance: np.ndarray
    center: np.ndarray
    radius: float

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)


def build_world(scene: SceneData) -> World:
    """Concatenate every mesh and area-light shape of `scene` into one World."""
    pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray, int]] = []
    names: list[str] = []
    paths: list[str] = []
    instances: list[int] = []
    for mesh in scene.meshes:
        if len(mesh.triangles) == 0:
            continue
        pieces.append((mesh.points, mesh.triangles, mesh.normals, mesh.uvs, mesh.triangle_material, NOT_A_LIGHT))
        names.append(mesh.name)
        paths.append(mesh.path)
        instances.append(mesh.instance)
    for light_index, light in enumerate(scene.lights):
        shape = light_shape(light)
        if shape is None:
            continue
        points, triangles = shape
        materials = np.full(len(triangles), -1, dtype=INDEX)
        pieces.append((points, triangles, None, None, materials, light_index))
        names.append(light.name)
        paths.append(light.path)
        instances.append(-1)
    if not pieces and not scene.lights:
        raise RenderSettingsError(f"{scene.stage_path}: nothing to render (no geometry and no lights)")
    if not pieces:
        # A sky alone (dome or distant lights, no geometry): every camera ray escapes. One empty
        # piece keeps every table below well formed, with zero rows.
        pieces.append((np.zeros((0, 3), FLOAT), np.zeros((0, 3), INDEX), None, None, np.zeros(0, INDEX), NOT_A_LIGHT))
        names.append("")
        paths.append("")
        instances.append(-1)

    vertex_offset = 0
    vertices, triangles, normals, uvs, objects, materials, lights = [], [], [], [], [], [], []
    for object_index, (points, tris, corner_normals, corner_uvs, tri_material, light_index) in enumerate(pieces):
        points = np.asarray(points, dtype=FLOAT)
        tris = np.asarray(tris, dtype=INDEX)
        vertices.append(points)
        triangles.append(tris + vertex_offset)
        normals.append(None if corner_normals is None else np.asarray(corner_normals, dtype=FLOAT))
        uvs.append(np.zeros((len(tris), 3, 2), FLOAT) if corner_uvs is None else np.asarray(corner_uvs, dtype=FLOAT))
        objects.append(np.full(len(tris), object_index, dtype=INDEX))
        materials.append(np.asarray(tri_material, dtype=INDEX))
        lights.append(np.full(len(tris), light_index, dtype=INDEX))
        vertex_offset += len(points)

    all_vertices = np.concatenate(vertices)
    all_triangles = np.concatenate(triangles)
    corners = all_vertices[all_triangles]  # (t, 3, 3)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    unit_normal = (cross / np.maximum(double_area, 1e-30)[:, None]).astype(FLOAT)
    flat = np.repeat(unit_normal[:, None, :], 3, axis=1)
    corner_normals = np.concatenate(
        [flat[start:start + len(t)] if n is None else n for n, t, start in zip(normals, triangles, _starts(triangles))]
    )

    corner_positions = _corner_major(corners)
    corner_normals = _corner_major(corner_normals)
    k1, k2, principal_direction = triangle_curvatures(corner_positions, corner_normals)
    corner_uvs = _corner_major(np.concatenate(uvs))
    gradient_s, gradient_t = uv_gradients(corner_positions, corner_uvs)
    low, high = (all_vertices.min(axis=0), all_vertices.max(axis=0)) if len(all_vertices) else (np.zeros(3),) * 2
    center = (low + high) / 2
    return World(
        vertices=all_vertices,
        triangles=all_triangles,
        geometric_normal=np.ascontiguousarray(unit_normal.T),
        area=(double_area / 2).astype(FLOAT),
        corner_positions=corner_positions,
        corner_normals=corner_normals,
        corner_uvs=corner_uvs,
        curvature_k1=k1,
        curvature_k2=k2,
        principal_direction=principal_direction,
        gradient_s=gradient_s,
        gradient_t=gradient_t,
        triangle_object=np.concatenate(objects),
        triangle_material=np.concatenate(materials),
        triangle_light=np.concatenate(lights),
        object_names=tuple(names),
        object_paths=tuple(paths),
        object_instance=np.asarray(instances, dtype=INDEX),
        center=center.astype(np.float64),
        radius=float(np.linalg.norm(high - low) / 2) or 1.0,
    )


def uv_gradients(corner_positions: np.ndarray, corner_uvs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of s and t over each triangle: (3, t) float32 each, in 1/m.

    Each gradient g lies in the triangle's plane with g·(p_k − p_0) = uv_k − uv_0 for the
    two edges from corner 0; degenerate triangles get zero.
    """
    p = corner_positions.astype(np.float64)
    uv = corner_uvs.astype(np.float64)
    edge_1, edge_2 = p[1] - p[0], p[2] - p[0]
    g11 = np.sum(edge_1 * edge_1, axis=0)
    g12 = np.sum(edge_1 * edge_2, axis=0)
    g22 = np.sum(edge_2 * edge_2, axis=0)
    determinant = g11 * g22 - g12 * g12
    regular = determinant > 1e-12 * np.maximum(g11 * g22, 1e-300)
    inverse = np.where(regular, 1.0 / np.where(regular, determinant, 1.0), 0.0)
    gradients = []
    for component in (0, 1):
        d1 = uv[1, component] - uv[0, component]
        d2 = uv[2, component] - uv[0, component]
        alpha = (g22 * d1 - g12 * d2) * inverse
        beta = (g11 * d2 - g12 * d1) * inverse
        gradients.append((alpha * edge_1 + beta * edge_2).astype(FLOAT))
    return gradients[0], gradients[1]


def _corner_major(per_triangle: np.ndarray) -> np.ndarray:
    """(t, 3 corners, k) -> contiguous (3 corners, k, t) float32."""
    return np.ascontiguousarray(per_triangle.transpose(1, 2, 0), dtype=FLOAT)


def _starts(arrays: list[np.ndarray]) -> list[int]:
    return list(np.cumsum([0] + [len(a) for a in arrays[:-1]]))


def light_shape(light: Light) -> tuple[np.ndarray, np.ndarray] | None:
    """World-space triangles of an area light, wound so the normal is the emitting side.

    Returns (points (v, 3) float32 metres, triangles (t, 3) int32), or None for lights with
    no shape (distant, dome).
    """
    if light.kind == "rect":
        w, h = light.width / 2, light.height / 2
        local = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], dtype=np.float64)
        # Counter-clockwise seen from +Z gives a +Z normal; rect lights emit along -Z.
        triangles = np.array([[0, 2, 1], [0, 3, 2]])
    elif light.kind == "disk":
        angles = np.linspace(0, 2 * np.pi, DISK_SEGMENTS, endpoint=False)
        rim = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1) * light.radius
        local = np.vstack([[0.0, 0.0, 0.0], rim])
        nxt = np.roll(np.arange(DISK_SEGMENTS), -1) + 1
        triangles = np.stack([np.zeros(DISK_SEGMENTS, int), nxt, np.arange(DISK_SEGMENTS) + 1], axis=1)
    elif light.kind == "sphere":
        local, triangles = _uv_sphere(light.radius)
    elif light.kind == "cylinder":
        local, triangles = _open_cylinder(light.radius, light.length)
    else:
        return None
    homogeneous = np.hstack([local, np.ones((len(local), 1))])
    world = (homogeneous @ np.asarray(light.world_from_light, dtype=np.float64).T)[:, :3]
    if np.linalg.det(np.asarray(light.world_from_light)[:3, :3]) < 0:
        triangles = triangles[:, ::-1]  # a mirroring transform flips the winding
    return world.astype(FLOAT), np.ascontiguousarray(triangles, dtype=INDEX)


def _uv_sphere(radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Outward-facing UV sphere: (points, triangles)."""
    theta = np.linspace(0, np.pi, SPHERE_RINGS + 1)
    phi = np.linspace(0, 2 * np.pi, SPHERE_SEGMENTS, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    points = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3) * radius
    ring = lambda i, j: i * SPHERE_SEGMENTS + (j % SPHERE_SEGMENTS)
    triangles = []
    for i in range(SPHERE_RINGS):
        for j in range(SPHERE_SEGMENTS):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j), ring(i + 1, j + 1)
            if i > 0:
                triangles.append([a, b, c])
            if i < SPHERE_RINGS - 1:
                triangles.append([b, d, c])
    return points, np.array(triangles)


def _open_cylinder(radius: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Outward-facing tube along local X (UsdLux CylinderLight): (points, triangles)."""
    phi = np.linspace(0, 2 * np.pi, CYLINDER_SEGMENTS, endpoint=False)
    ring = np.stack([np.zeros_like(phi), np.cos(phi) * radius, np.sin(phi) * radius], axis=1)
    points = np.vstack([ring + [-length / 2, 0, 0], ring + [length / 2, 0, 0]])
    j = np.arange(CYLINDER_SEGMENTS)
    k = (j + 1) % CYLINDER_SEGMENTS
    n = CYLINDER_SEGMENTS
    triangles = np.vstack([np.stack([j, k, j + n], 1), np.stack([k, k + n, j + n], 1)])
    return points, triangles
