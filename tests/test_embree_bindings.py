"""The Embree 4 bindings (trace/embree.py) against geometry: analytic triangles, a brute-force
Möller–Trumbore reference, instances under a transform, threads, and the on-disk kernel cache
in a fresh process."""

import os
import subprocess
import sys
import textwrap
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numba
import numpy as np
import pytest

from pxr_layers.trace import embree
from pxr_layers.trace.embree import MISS, RayCaster


NO_INSTANCES = {"prototype_vertices": (), "prototype_triangles": (), "prototype_first": np.zeros(0, np.int64),
                "instance_prototype": np.zeros(0, np.int32), "instance_transform": np.zeros((0, 3, 4), np.float32),
                "moving_vertices": np.zeros((0, 0, 3), np.float32), "moving_triangles": np.zeros((0, 3), np.int32),
                "moving_first": 0, "strand_shapes": (), "strand_first": 0, "strands": None}


def world_of(vertices, triangles):
    """What RayCaster reads of a World."""
    triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
    return SimpleNamespace(vertices=np.asarray(vertices, np.float32).reshape(-1, 3), triangles=triangles,
                           triangle_count=len(triangles), **NO_INSTANCES)


def rays(*pairs):
    origins, directions = zip(*pairs)
    return np.array(origins, np.float32), np.array(directions, np.float32)


# Two triangles facing z: triangle 0 in z = 1, triangle 1 (larger) in z = 3 behind it.
TWO_PLANES = world_of([[0, 0, 1], [1, 0, 1], [0, 1, 1], [-2, -2, 3], [4, -2, 3], [-2, 4, 3]],
                      [[0, 1, 2], [3, 4, 5]])


def test_closest_hit_reports_triangle_barycentrics_and_t():
    caster = RayCaster(TWO_PLANES)
    # p = (1 - u - v) p0 + u p1 + v p2; on triangle 0 that is (u, v, 1).
    origins, directions = rays(([0.2, 0.3, 0], [0, 0, 1]),      # through triangle 0 at u 0.2, v 0.3
                               ([0.2, 0.3, 0], [0, 0, 4]),      # the same, direction 4x: t in its units
                               ([0.9, 0.9, 0], [0, 0, 1]),      # beside triangle 0: triangle 1 at z = 3
                               ([0.1, 0.1, 5], [0, 0, -1]))     # from behind: triangle 1 first, seen from its back
    triangle, _, u, v, t = caster.intersect(origins, directions, np.full(4, 100, np.float32))
    assert triangle.dtype == np.int32 and u.dtype == v.dtype == t.dtype == np.float32
    np.testing.assert_array_equal(triangle, [0, 0, 1, 1])
    np.testing.assert_allclose(t, [1, 0.25, 3, 2], rtol=1e-6)
    np.testing.assert_allclose(u[:2], 0.2, rtol=1e-6)
    np.testing.assert_allclose(v[:2], 0.3, rtol=1e-6)
    # triangle 1: (x, y) = (-2, -2) + 6 u (1, 0) + 6 v (0, 1)
    np.testing.assert_allclose([u[2], v[2]], [(0.9 + 2) / 6, (0.9 + 2) / 6], rtol=1e-6)
    np.testing.assert_allclose([u[3], v[3]], [(0.1 + 2) / 6, (0.1 + 2) / 6], rtol=1e-6)


def test_misses_keep_t_max():
    caster = RayCaster(TWO_PLANES)
    origins, directions = rays(([9, 9, 0], [0, 0, 1]),          # beside everything
                               ([0.2, 0.3, 0], [0, 0, -1]),     # away from everything
                               ([0.2, 0.3, 0], [0, 0, 1]))      # stops short of triangle 0
    t_max = np.array([100, 100, 0.5], np.float32)
    triangle, _, u, v, t = caster.intersect(origins, directions, t_max)
    np.testing.assert_array_equal(triangle, MISS)
    np.testing.assert_array_equal(t, t_max)
    np.testing.assert_array_equal(u, 0)
    np.testing.assert_array_equal(v, 0)


def test_occlusion_respects_t_max():
    caster = RayCaster(TWO_PLANES)
    origins, directions = rays(*[([0.2, 0.3, 0], [0, 0, 2])] * 2, ([9, 9, 0], [0, 0, 1]))
    blocked = caster.occluded(origins, directions, np.array([0.49, 0.51, 100], np.float32))  # triangle 0 at t 0.5
    assert blocked.dtype == bool
    np.testing.assert_array_equal(blocked, [False, True, False])


def test_a_world_without_triangles_misses_everything():
    caster = RayCaster(world_of(np.zeros((0, 3)), np.zeros((0, 3))))
    origins, directions = rays(([0, 0, 0], [0, 0, 1]), ([1, 2, 3], [1, 0, 0]))
    t_max = np.array([5, 7], np.float32)
    triangle, _, u, v, t = caster.intersect(origins, directions, t_max)
    np.testing.assert_array_equal(triangle, MISS)
    np.testing.assert_array_equal(t, t_max)
    assert not caster.occluded(origins, directions, t_max).any()


def random_soup(rng, count):
    """`count` small random triangles in the unit cube: (3 count, 3) vertices, (count, 3) indices."""
    centers = rng.uniform(0, 1, (count, 1, 3))
    vertices = (centers + rng.normal(0, 0.06, (count, 3, 3))).reshape(-1, 3).astype(np.float32)
    return vertices, np.arange(3 * count).reshape(count, 3)


def random_rays(rng, count):
    """Rays from a sphere of radius 3 around the cube toward points in it, directions not unit."""
    towards = rng.uniform(0, 1, (count, 3))
    away = rng.normal(size=(count, 3))
    origins = 0.5 + 3 * away / np.linalg.norm(away, axis=1, keepdims=True)
    directions = (towards - origins) * rng.uniform(0.5, 2, (count, 1))
    return origins.astype(np.float32), directions.astype(np.float32)


def moller_trumbore(origins, directions, t_max, vertices, triangles, chunk=250):
    """Every ray against every triangle in float64: (closest triangle or MISS, its t, u and
    v, the second-closest t)."""
    p0, p1, p2 = (vertices[triangles[:, corner]].astype(np.float64) for corner in range(3))
    e1, e2 = p1 - p0, p2 - p0
    n = len(origins)
    closest, t_first, t_second = np.full(n, MISS), np.full(n, np.inf), np.full(n, np.inf)
    u_first, v_first = np.zeros(n), np.zeros(n)
    for start in range(0, n, chunk):
        o = origins[start:start + chunk, None].astype(np.float64)
        d = directions[start:start + chunk, None].astype(np.float64)
        pvec = np.cross(d, e2)
        det = np.einsum("rtk,tk->rt", pvec, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = 1 / det
            tvec = o - p0
            u = np.einsum("rtk,rtk->rt", tvec, pvec) * inverse
            qvec = np.cross(tvec, e1)
            v = np.einsum("rtk,rtk->rt", d, qvec) * inverse
            t = np.einsum("tk,rtk->rt", e2, qvec) * inverse
        hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= t_max[start:start + chunk, None])
        t = np.where(hit, t, np.inf)
        order = np.argsort(t, axis=1)[:, :2]
        rows = np.arange(len(t))
        first, second = t[rows, order[:, 0]], t[rows, order[:, 1]]
        lanes = slice(start, start + len(t))
        closest[lanes] = np.where(np.isfinite(first), order[:, 0], MISS)
        t_first[lanes], t_second[lanes] = first, second
        u_first[lanes], v_first[lanes] = u[rows, order[:, 0]], v[rows, order[:, 0]]
    return closest, t_first, u_first, v_first, t_second


def test_many_triangles_match_brute_force(rng):
    vertices, triangles = random_soup(rng, 2000)
    origins, directions = random_rays(rng, 10_000)
    t_max = np.full(len(origins), 1e30, np.float32)
    triangle, _, u, v, t = RayCaster(world_of(vertices, triangles)).intersect(origins, directions, t_max)
    expected, t_expected, u_expected, v_expected, t_second = moller_trumbore(origins, directions, t_max, vertices,
                                                                             triangles)
    # Rays whose answer float32 cannot settle (a near tie, a hit on an edge) are left out.
    edge = np.minimum(np.minimum(u_expected, v_expected), 1 - u_expected - v_expected)
    clear = (t_second > t_expected * (1 + 1e-4)) & ((expected == MISS) | (edge > 1e-5))
    assert clear.mean() > 0.95 and (expected[clear] != MISS).mean() > 0.5
    np.testing.assert_array_equal(triangle[clear], expected[clear])
    hits = clear & (expected != MISS)
    np.testing.assert_allclose(t[hits], t_expected[hits], rtol=1e-5)
    # Barycentrics compared as the points they name (on slim triangles float32 leaves u, v
    # loose across the thin side, where it moves the point little), within the distance that
    # t's tolerance allows along the path, twice over.
    corners = vertices[triangles[expected[hits]]].astype(np.float64)

    def point(u, v):
        return (1 - u - v)[:, None] * corners[:, 0] + u[:, None] * corners[:, 1] + v[:, None] * corners[:, 2]

    error = np.linalg.norm(point(u[hits], v[hits]) - point(u_expected[hits], v_expected[hits]), axis=1)
    path = t_expected[hits] * np.linalg.norm(directions[hits], axis=1)
    assert (error <= 2e-5 * path).all(), (error / path).max()


@numba.njit
def closest_hits_of(scene, origins, directions, rayhit, out):
    """Another kernel calling the per-ray helper: (n, 6) rows of prim, geom, inst, u, v, t."""
    for lane in range(len(origins)):
        prim, geom, inst, u, v, t = embree.cast_closest(
            scene, origins[lane, 0], origins[lane, 1], origins[lane, 2], directions[lane, 0], directions[lane, 1],
            directions[lane, 2], np.float32(0), np.float32(1e30), np.float32(0), rayhit)
        out[lane, 0], out[lane, 1], out[lane, 2], out[lane, 3], out[lane, 4], out[lane, 5] = prim, geom, inst, u, v, t


def test_instances_are_hit_where_their_transform_puts_them():
    device = embree.Device()
    child = embree.Scene(device)
    child_geometry = embree.add_triangles(child, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    child.commit()
    parent = embree.Scene(device)
    embree.add_triangles(parent, [[10, 10, 10], [11, 10, 10], [10, 11, 10]], [[0, 1, 2]])  # out of the way
    # A quarter turn about x (child +y to parent +z), then a move by (5, 0, 0): the child's
    # triangle stands in the plane y = 0, spanning x 5..6, z 0..1.
    turned = np.array([[1, 0, 0, 5], [0, 0, -1, 0], [0, 1, 0, 0]], np.float32)
    first = embree.add_instance(parent, child, turned)
    second = embree.add_instance(parent, child, np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -4]], np.float32))
    parent.commit()
    origins, directions = rays(([5.2, -1, 0.3], [0, 0.5, 0]),    # child point (0.2, 0.3) through `first`
                               ([0.2, 0.3, -9], [0, 0, 1]),      # the same point through `second` (z = -4)
                               ([5.2, 0.3, -1], [0, 0, 1]))      # where `first` would be unturned: nothing
    out = np.zeros((3, 6))
    closest_hits_of(parent.handle, origins, directions, embree.rayhit_scratch(), out)
    np.testing.assert_array_equal(out[:, :3], [[0, child_geometry, first], [0, child_geometry, second],
                                               [MISS, MISS, MISS]])
    np.testing.assert_allclose(out[:2, 3:], [[0.2, 0.3, 2], [0.2, 0.3, 5]], rtol=1e-6)


def test_embree_writes_within_the_rayhit_record():
    """RAYHIT's size is that of the library's RTCRayHit: a hit through an instance (which
    writes every hit field) leaves the next record's bytes alone."""
    device = embree.Device()
    child = embree.Scene(device)
    embree.add_triangles(child, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    child.commit()
    parent = embree.Scene(device)
    embree.add_instance(parent, child, np.eye(3, 4, dtype=np.float32))
    parent.commit()
    raw = np.zeros(2 * embree.RAYHIT.itemsize + embree.RAYHIT_ALIGNMENT, np.uint8)
    start = -raw.ctypes.data % embree.RAYHIT_ALIGNMENT
    pair = raw[start:start + 2 * embree.RAYHIT.itemsize].view(embree.RAYHIT)
    pair[1:].view(np.uint8)[:] = 0xA5
    origins, directions = rays(([0.2, 0.3, -1], [0, 0, 1]))
    out = np.zeros((1, 6))
    closest_hits_of(parent.handle, origins, directions, pair[:1], out)
    assert out[0, 2] == 0  # hit through the instance
    assert (pair[1:].view(np.uint8) == 0xA5).all()


def test_threads_sharing_one_scene_agree_with_one_thread(rng):
    vertices, triangles = random_soup(rng, 20_000)
    origins, directions = random_rays(rng, 200_000)
    t_max = rng.uniform(1, 5, len(origins)).astype(np.float32)
    caster = RayCaster(world_of(vertices, triangles))
    alone = caster.intersect(origins, directions, t_max)
    blocked_alone = caster.occluded(origins, directions, t_max)
    parts = np.array_split(np.arange(len(origins)), 8)
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda lanes: caster.intersect(origins[lanes], directions[lanes], t_max[lanes]), parts))
        blocked = list(pool.map(lambda lanes: caster.occluded(origins[lanes], directions[lanes], t_max[lanes]), parts))
    for expected, pieces in zip(alone, zip(*together)):
        np.testing.assert_array_equal(np.concatenate(pieces), expected)
    np.testing.assert_array_equal(np.concatenate(blocked), blocked_alone)
    assert (alone[0] != MISS).mean() > 0.2 and blocked_alone.mean() > 0.2


def test_a_fresh_process_runs_the_disk_cached_kernels(tmp_path):
    """The kernels call Embree by symbol name: their cached machine code works in a process
    that loaded the library at another address."""
    script = textwrap.dedent("""
        import numpy as np
        from types import SimpleNamespace
        from pxr_layers.trace import embree
        world = SimpleNamespace(vertices=np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32),
                                triangles=np.array([[0, 1, 2]], np.int32), triangle_count=1, prototype_vertices=(),
                                prototype_triangles=(), prototype_first=np.zeros(0, np.int64),
                                instance_prototype=np.zeros(0, np.int32),
                                instance_transform=np.zeros((0, 3, 4), np.float32),
                        moving_vertices=np.zeros((0, 0, 3), np.float32), moving_triangles=np.zeros((0, 3), np.int32),
                        moving_first=0, strand_shapes=(), strand_first=0, strands=None)
        caster = embree.RayCaster(world)
        origins = np.array([[0.2, 0.3, 0], [2, 2, 0]], np.float32)
        directions = np.array([[0, 0, 1], [0, 0, 1]], np.float32)
        t_max = np.array([9, 9], np.float32)
        print(*caster.intersect(origins, directions, t_max)[0], *caster.occluded(origins, directions, t_max),
              sum(embree.intersect_kernel.stats.cache_hits.values()), sum(embree.occluded_kernel.stats.cache_hits.values()))
    """)
    env = {**os.environ, "PXR_LAYERS_CACHE_DIR": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600,
                           check=True).stdout.split() for _ in range(2)]
    assert runs[0] == ["0", "-1", "True", "False", "0", "0"]  # compiled, then cached
    assert runs[1] == ["0", "-1", "True", "False", "1", "1"]  # loaded from the cache


def test_bad_geometry_is_refused_in_one_line():
    scene = embree.Scene(embree.Device())
    with pytest.raises(ValueError, match="outside the 3 vertices"):
        embree.add_triangles(scene, np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(ValueError, match=r"\(3, 4\)"):
        embree.add_instance(scene, scene, np.eye(4))


def test_a_closed_caster_refuses_queries():
    caster = RayCaster(TWO_PLANES)
    caster.close()
    caster.close()
    origins, directions = rays(([0.2, 0.3, 0], [0, 0, 1]))
    with pytest.raises(RuntimeError, match="after close"):
        caster.intersect(origins, directions, np.ones(1, np.float32))


def test_a_moving_mesh_is_where_its_time_steps_put_it_at_each_ray_time():
    # one triangle in z = 1 over x in [0, 1] at the shutter's open, [2, 3] at its close
    # (three steps: the middle one at [1, 2]), after one still triangle's row
    triangle = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32)
    world = SimpleNamespace(**{**vars(world_of([[5, 5, 5], [6, 5, 5], [5, 6, 5]], [[0, 1, 2]])),
                               "moving_vertices": np.stack([triangle + [shift, 0, 0] for shift in (0, 1, 2)]),
                               "moving_triangles": np.array([[0, 1, 2]], np.int32), "moving_first": 1})
    world.triangle_count = 2
    caster = RayCaster(world)
    origins = np.array([[0.25, 0.25, 0], [1.25, 0.25, 0], [1.25, 0.25, 0], [2.25, 0.25, 0], [0.25, 0.25, 0]], np.float32)
    directions = np.tile(np.float32([0, 0, 1]), (5, 1))
    time = np.array([0, 0.5, 0.25, 1, 1], np.float32)
    triangle_hit, instance, u, _, t = caster.intersect(origins, directions, np.full(5, 10, np.float32), time)
    # at time 0.25 the triangle spans [0.5, 1.5]: x = 1.25 is inside it (u = 0.75)
    np.testing.assert_array_equal(triangle_hit, [1, 1, 1, 1, MISS])
    np.testing.assert_array_equal(instance, [embree.MOVING] * 4 + [MISS])
    np.testing.assert_allclose(u[:4], [0.25, 0.25, 0.75, 0.25], atol=1e-6)
    np.testing.assert_allclose(t[:4], 1.0)
    np.testing.assert_array_equal(caster.occluded(origins, directions, np.full(5, 10, np.float32), time),
                                  [True] * 4 + [False])
