"""Two-level scenes (issue 35): meshes that share a surface (scene.Mesh.prototype) are traced
as Embree instances of one prototype, and every stage sees a hit through an instance as it
sees the same triangle placed in the world (trace/instances.py).

The reference is the same scene with the instances flattened (trace.world.flatten_instances:
each placement's points and normals transformed on the host, as the stage reader places an
uninstanced mesh): the pictures, the path classes and their energy, the names, the light
links and the data AOVs agree, up to float rounding of the hit points (Embree intersects an
instance in its own space).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings, render_data_aovs
from pxr_layers.trace.render import prepare
from pxr_layers.trace.world import build_world, flatten_instances

from tracing import trace_image

RESOLUTION = (48, 48)
SETTINGS = TraceSettings(spp=8, max_depth=4, norm_bounces=2, record_paths=True, first_bounce_norms=True)


def turned(angle: float, scale: float, offset, mirror: bool = False) -> np.ndarray:
    """(4, 4) float64: a turn of `angle` radians about +Y about the box's centre, a uniform
    `scale`, then a translation by `offset` metres (a mirror in X first, if asked)."""
    centre = np.array([0.37, 0.0, 0.35])
    cos, sin = np.cos(angle), np.sin(angle)
    linear = scale * np.array([[cos, 0, sin], [0, 1, 0], [-sin, 0, cos]])
    if mirror:
        linear = linear @ np.diag([-1.0, 1, 1])
    placement = np.eye(4)
    placement[:3, :3] = linear
    placement[:3, 3] = centre - linear @ centre + np.asarray(offset, np.float64)
    return placement


# clear of each other and of the short box (coplanar faces would make which one a ray
# hits first a matter of rounding)
PLACEMENTS = (np.eye(4), turned(0.6, 0.35, [0.05, 0.0, -0.23]), turned(-0.3, 0.35, [0.0, 0.34, 0.0], mirror=True))


@pytest.fixture(scope="module")
def cornell(shipped_scene):
    """The Cornell box whose tall box is a prototype placed three times: as authored, turned
    and smaller in front of it, mirrored and smaller above it."""
    scene, spec = load_stage(shipped_scene("cornell.usda"))
    meshes = []
    for mesh in scene.meshes:
        if mesh.name != "tallBox":
            meshes.append(mesh)
            continue
        for number, placement in enumerate(PLACEMENTS):
            meshes.append(dataclasses.replace(mesh, name=f"tallBox{number}", path=f"{mesh.path}/copy_{number}",
                                              prototype=0, world_from_points=placement))
    return dataclasses.replace(scene, meshes=tuple(meshes)), dataclasses.replace(spec, resolution=RESOLUTION)


def test_the_world_keeps_one_prototype_and_three_instances(cornell):
    scene, _ = cornell
    world = build_world(scene)
    flat = build_world(flatten_instances(scene))
    assert len(world.prototype_triangles) == 1 and len(world.instance_object) == 3
    assert world.triangle_count == flat.triangle_count - 2 * 12  # the prototype's 12 rows once, not three times
    assert world.object_names == flat.object_names  # every placement is an object of its own name
    np.testing.assert_allclose(world.center, flat.center, atol=1e-6)
    assert world.radius == pytest.approx(flat.radius, rel=1e-6)


def test_instanced_and_flattened_scenes_render_alike(cornell):
    scene, spec = cornell
    instanced = trace_image(scene, spec, SETTINGS, threads=2)
    flattened = trace_image(flatten_instances(scene), spec, SETTINGS, threads=2)
    assert instanced.integrator.instance_rows is not None and flattened.integrator.instance_rows is None
    difference = np.abs(instanced.rgba - flattened.rgba)[..., :3]
    # float rounding of the hit points lets a few paths part ways; nearly every pixel is equal
    assert np.mean(difference.max(axis=-1) < 1e-4) > 0.98
    assert difference.mean() < 2e-3 * flattened.rgba[..., :3].mean()
    np.testing.assert_allclose(instanced.first_bounce_norms, flattened.first_bounce_norms, rtol=1e-3, atol=1e-3)


def test_instanced_renders_do_not_depend_on_threads_or_batches(cornell):
    """Placed rows are per thread, but what a row holds is the hit's alone."""
    scene, spec = cornell
    settings = dataclasses.replace(SETTINGS, record_paths=False)
    one = trace_image(scene, spec, settings, threads=1, batch_paths=1024).rgba
    two = trace_image(scene, spec, settings, threads=2, batch_paths=4096).rgba
    np.testing.assert_array_equal(one, two)


def test_path_classes_name_each_instance_and_carry_its_energy(cornell):
    scene, spec = cornell
    sums = []
    for version in (scene, flatten_instances(scene)):
        traced = trace_image(version, spec, SETTINGS, threads=1)
        vocabulary, energy = traced.vocabulary, {}
        for batch in traced.batches:
            records = batch.records
            keys = [tuple(vocabulary.event(key).name for key in keys)
                    for keys in _class_events(records)]
            for path_class, rgb in zip(records.path_class.tolist(), records.rgb.sum(axis=1).tolist()):
                energy[keys[path_class]] = energy.get(keys[path_class], 0.0) + rgb
        sums.append(energy)
    instanced, flattened = sums
    total = sum(flattened.values())
    for number in range(len(PLACEMENTS)):
        assert any(f"tallBox{number}" in key for key in instanced)
    # paths that part ways (rounding) make rare classes of their own: a sliver of the energy
    assert sum(value for key, value in instanced.items() if key not in flattened) < 2e-3 * total
    assert sum(value for key, value in flattened.items() if key not in instanced) < 2e-3 * total
    for key, value in flattened.items():
        if value > 2e-3 * total:
            assert instanced[key] == pytest.approx(value, rel=0.02), key


def _class_events(records):
    """Each path class of a batch's Contributions as its event keys after the camera."""
    from pxr_layers.paths.trie import ClassTrie

    trie = ClassTrie()
    nodes = trie.merge(records.trie_parent, records.trie_event)[records.class_nodes]
    return trie.sequences(nodes)


def test_data_aovs_see_each_instance(cornell):
    scene, spec = cornell
    names = ("primId", "normal", "depth")
    instanced = render_data_aovs(prepare(scene, spec, TraceSettings(spp=1)), names)
    flattened = render_data_aovs(prepare(flatten_instances(scene), spec, TraceSettings(spp=1)), names)
    assert np.mean(instanced["primId"] == flattened["primId"]) > 0.99
    seen = set(np.unique(instanced["primId"]).tolist())
    world = build_world(scene)
    assert {int(world.instance_object[k]) for k in range(3)} <= seen
    close = np.isclose(instanced["depth"], flattened["depth"], rtol=0, atol=1e-4)  # misses: inf in both
    assert close.mean() > 0.99
    np.testing.assert_allclose(instanced["normal"][close[..., 0]], flattened["normal"][close[..., 0]], atol=1e-4)


def test_light_links_follow_each_instance(cornell):
    """A light linked to one placement lights that one alone: the other two get only what
    the other lights send."""
    scene, spec = cornell
    linked = scene.meshes.index(next(mesh for mesh in scene.meshes if mesh.name == "tallBox1"))
    lights = tuple(dataclasses.replace(light, light_link=(linked,)) for light in scene.lights)
    scene = dataclasses.replace(scene, lights=lights)
    direct = dataclasses.replace(SETTINGS, max_depth=1, record_paths=False, norm_bounces=0, first_bounce_norms=False)
    instanced = trace_image(scene, spec, direct, threads=2).rgba
    flattened = trace_image(flatten_instances(scene), spec, direct, threads=2).rgba
    assert np.mean(np.abs(instanced - flattened)[..., :3].max(axis=-1) < 1e-4) > 0.98
    assert instanced[..., :3].max() > 0


def test_an_emissive_instanced_surface_is_refused(cornell):
    """The stage reader never instances an emitter (light sampling reads flat rows only)."""
    scene, spec = cornell
    prototype = next(mesh for mesh in scene.meshes if mesh.prototype == 0)
    glowing = dataclasses.replace(scene.materials[int(prototype.triangle_material[0])], emissive_color=(1.0, 1.0, 1.0))
    materials = list(scene.materials)
    materials[int(prototype.triangle_material[0])] = glowing
    with pytest.raises(ValueError, match="emissive"):
        prepare(dataclasses.replace(scene, materials=tuple(materials)), spec, TraceSettings(spp=1))


# -- the stage reader's side: which placements become instances

def _stage_with_balls(path, *, count: int = 40, stretched: bool = False, emissive: bool = False,
                      native: int = 0) -> str:
    """A PointInstancer of `count` tessellated spheres (3,968 triangles each) turned and
    scaled at random (stretched: (1, 2, 1) scales, not a similarity), a sun, and
    `native` instanceable references of one sphere asset. Returns the file's path."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    points = UsdGeom.PointInstancer.Define(stage, "/World/Balls")
    UsdGeom.Sphere.Define(stage, "/World/Balls/protos/ball").GetRadiusAttr().Set(0.4)
    points.GetPrototypesRel().AddTarget("/World/Balls/protos/ball")
    rng = np.random.default_rng(7)
    points.GetProtoIndicesAttr().Set(Vt.IntArray([0] * count))
    points.GetPositionsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(float(i % 8), 0.0, -float(i // 8)) for i in range(count)]))
    turns = rng.normal(size=(count, 4))
    turns /= np.linalg.norm(turns, axis=1, keepdims=True)
    points.GetOrientationsAttr().Set(Vt.QuathArray([Gf.Quath(*map(float, turn)) for turn in turns]))
    sizes = rng.uniform(0.5, 1.0, count)
    points.GetScalesAttr().Set(Vt.Vec3fArray([Gf.Vec3f(float(s), float(2 * s if stretched else s), float(s))
                                              for s in sizes]))
    if emissive:
        material = UsdShade.Material.Define(stage, "/World/Glow")
        shader = UsdShade.Shader.Define(stage, "/World/Glow/surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(1, 1, 1))
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/World/Balls/protos/ball")).Bind(material)
    asset = UsdGeom.Xform.Define(stage, "/Asset")
    asset.GetPrim().SetSpecifier(Sdf.SpecifierClass)
    UsdGeom.Sphere.Define(stage, "/Asset/ball").GetRadiusAttr().Set(0.3)
    for number in range(native):
        holder = UsdGeom.Xform.Define(stage, f"/World/Native{number}")
        holder.GetPrim().GetReferences().AddInternalReference("/Asset")
        holder.GetPrim().SetInstanceable(True)
        holder.AddTranslateOp().Set(Gf.Vec3d(2.0 * number, 1.5, 0.0))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateNormalizeAttr(True)  # the intensity is the irradiance, whatever the sun's angle
    stage.GetRootLayer().Save()
    return str(path)


def test_point_instances_of_one_surface_are_instanced_and_render_as_copies_would(tmp_path):
    scene, spec = load_stage(_stage_with_balls(tmp_path / "balls.usda"))
    spec = dataclasses.replace(spec, resolution=RESOLUTION)
    balls = [mesh for mesh in scene.meshes if "/World/Balls/" in mesh.path]
    assert len(balls) == 40 and {mesh.prototype for mesh in balls} == {0}
    assert all(mesh.points is balls[0].points for mesh in balls)  # one geometry, not 40
    assert [mesh.instance for mesh in balls] == list(range(40))
    settings = dataclasses.replace(SETTINGS, record_paths=False)
    instanced = trace_image(scene, spec, settings, threads=2).rgba
    flattened = trace_image(flatten_instances(scene), spec, settings, threads=2).rgba
    assert instanced[..., :3].mean() > 1e-3  # the balls are in the picture, lit
    assert np.mean(np.abs(instanced - flattened)[..., :3].max(axis=-1) < 1e-3) > 0.98


def test_placements_that_are_not_similarities_or_that_emit_are_copies(tmp_path):
    stretched, _ = load_stage(_stage_with_balls(tmp_path / "stretched.usda", stretched=True))
    assert all(mesh.prototype < 0 for mesh in stretched.meshes)
    glowing, _ = load_stage(_stage_with_balls(tmp_path / "glowing.usda", emissive=True))
    assert all(mesh.prototype < 0 for mesh in glowing.meshes)


def test_native_instances_share_their_prototype_surface(tmp_path):
    scene, _ = load_stage(_stage_with_balls(tmp_path / "native.usda", count=1, native=20))
    natives = [mesh for mesh in scene.meshes if mesh.path.startswith("/World/Native")]
    assert len(natives) == 20 and len({mesh.prototype for mesh in natives}) == 1 and natives[0].prototype >= 0
    assert len({mesh.path for mesh in natives}) == 20  # each its own object, at its own path
    alone = next(mesh for mesh in scene.meshes if mesh.path.startswith("/World/Balls/"))
    assert alone.prototype < 0  # one placement: nothing to share
