"""Per-triangle principal curvatures (trace/curvature.py) against exact geometry."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from pxr_layers.stage import load_stage
from pxr_layers.trace.curvature import triangle_curvatures
from pxr_layers.trace.world import build_world


def world_of(path):
    scene, _ = load_stage(str(path))
    return build_world(scene)


def per_object(world, name):
    index = world.object_names.index(name)
    mask = world.triangle_object == index
    return world.curvature_k1[mask], world.curvature_k2[mask], world.principal_direction[:, mask]


def test_showcase_flat_objects_are_exactly_flat_and_the_sphere_is_one_over_r():
    world = world_of(resources.files("pxr_layers.render").joinpath("showcase.usda"))
    for flat in ("floor", "backdrop", "texturedPanel", "matteBox", "glossyBox", "mirrorPanel"):
        k1, k2, _ = per_object(world, flat)
        assert np.all(k1 == 0) and np.all(k2 == 0), flat
    k1, k2, _ = per_object(world, "curvedSphere")  # radius 0.4 m
    np.testing.assert_allclose(k1, 2.5, rtol=1e-3)
    np.testing.assert_allclose(k2, 2.5, rtol=1e-3)


def _stage_with(tmp_path, build):
    stage = Usd.Stage.CreateNew(str(tmp_path / "shape.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.Camera.Define(stage, "/camera")
    build(stage)
    stage.Save()
    return tmp_path / "shape.usda"


def test_cylinder_side_has_one_over_r_across_and_zero_along_its_axis(tmp_path):
    def build(stage):
        cylinder = UsdGeom.Cylinder.Define(stage, "/tube")
        cylinder.GetRadiusAttr().Set(0.5)
        cylinder.GetHeightAttr().Set(2.0)
        cylinder.GetAxisAttr().Set("Y")

    world = world_of(_stage_with(tmp_path, build))
    k1, k2, direction = per_object(world, "tube")
    side = k1 > 1.0  # caps are flat
    assert side.sum() > 0 and np.all((k1[~side] == 0) & (k2[~side] == 0))
    np.testing.assert_allclose(k1[side], 2.0, rtol=1e-3)
    np.testing.assert_allclose(k2[side], 0.0, atol=1e-3)
    np.testing.assert_allclose(direction[1, side], 0.0, atol=1e-3)  # k1 runs around the axis


def test_metres_per_unit_scales_curvature(tmp_path):
    def build(stage):
        UsdGeom.SetStageMetersPerUnit(stage, 0.01)  # centimetres
        UsdGeom.Sphere.Define(stage, "/ball").GetRadiusAttr().Set(50.0)  # 0.5 m

    k1, k2, _ = per_object(world_of(_stage_with(tmp_path, build)), "ball")
    np.testing.assert_allclose(k1, 2.0, rtol=1e-3)
    np.testing.assert_allclose(k2, 2.0, rtol=1e-3)


@pytest.mark.parametrize("radius, sign", [(0.25, 1.0), (3.0, -1.0)])
def test_sign_follows_the_normal_side(rng, radius, sign):
    """Random triangles on a sphere: outward normals give +1/r, inward −1/r."""
    directions = rng.normal(size=(3, 3, 200))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    corners = radius * directions
    k1, k2, _ = triangle_curvatures(corners.astype(np.float32), (sign * directions).astype(np.float32))
    np.testing.assert_allclose(k1, sign / radius, rtol=1e-3)
    np.testing.assert_allclose(k2, sign / radius, rtol=1e-3)


def test_degenerate_triangles_get_zero_curvature():
    corners = np.zeros((3, 3, 1), np.float32)
    normals = np.zeros((3, 3, 1), np.float32)
    normals[:, 2] = 1
    k1, k2, _ = triangle_curvatures(corners, normals)
    assert k1[0] == 0 and k2[0] == 0


def test_uv_gradients_map_texture_units_to_metres():
    """The showcase panel is 1.6 m × 0.8 m with st over [0, 1]²: ∇s = 1/1.6, ∇t = 1/0.8 per m."""
    world = world_of(resources.files("pxr_layers.render").joinpath("showcase.usda"))
    mask = world.triangle_object == world.object_names.index("texturedPanel")
    np.testing.assert_allclose(np.linalg.norm(world.gradient_s[:, mask], axis=0), 0.625, rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(world.gradient_t[:, mask], axis=0), 1.25, rtol=1e-5)
    np.testing.assert_allclose(np.sum(world.gradient_s[:, mask] * world.gradient_t[:, mask], axis=0), 0, atol=1e-6)
    floor = world.triangle_object == world.object_names.index("floor")  # no st authored
    assert np.all(world.gradient_s[:, floor] == 0) and np.all(world.gradient_t[:, floor] == 0)


def test_the_closed_form_solve_equals_the_linear_algebra_reference(rng):
    from pxr_layers.trace.curvature import reference_triangle_curvatures

    count = 5000
    positions = rng.normal(size=(3, 3, count)).astype(np.float32)
    normals = positions + 0.3 * rng.normal(size=(3, 3, count)).astype(np.float32)  # bent, not flat
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    k1, k2, direction = triangle_curvatures(positions, normals)
    r1, r2, reference_direction = reference_triangle_curvatures(positions, normals)
    np.testing.assert_allclose(k1, r1, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(k2, r2, rtol=1e-5, atol=1e-6)
    distinct = np.abs(r1 - r2) > 1e-3 * np.maximum(np.abs(r1), 1.0)  # the direction of an umbilic is arbitrary
    alignment = np.abs(np.sum(direction * reference_direction, axis=0))
    assert (alignment[distinct] > 1 - 1e-4).all()
