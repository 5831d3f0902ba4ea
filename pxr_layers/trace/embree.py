"""The one place that talks to Embree: bindings to the Embree 4 C API of the libembree4 that
the embreex wheel ships (``embreex.libs/`` beside the ``embreex`` package; embreex's own
Python wrapper is not used, the wheel only carries the library).

Scenes are built on the host through ctypes, once per World. Queries are numba kernels that
call ``rtcIntersect1`` / ``rtcOccluded1`` one ray per lane, without the GIL, so the render
drives several batches from a thread pool; the per-ray helpers (:func:`cast_closest`,
:func:`cast_any`) inline into any other kernel. Kernels name Embree's functions by symbol
(numba ``ExternalFunction``), which LLVM resolves in the library loaded at import: no
address is baked into the machine code, so the on-disk kernel cache stays valid from one
process to the next.

Structures and enum values are those of Embree 4.4's headers (include/embree4/rtcore_*.h).
Scenes are built as embreex built them (RTC_SCENE_FLAG_ROBUST, the default medium build
quality, tnear 0, every ray mask bit set), so hits are the same as before the bindings.
"""

from __future__ import annotations

import ctypes
import importlib.util
import weakref
from pathlib import Path

import numpy as np
from llvmlite import binding as llvm
from numba import types

from ..compiled import inline, kernel
from ..scene import FLOAT
from .world import World

MISS = -1
"""Triangle, geometry or instance id of no hit: Embree's RTC_INVALID_GEOMETRY_ID,
(unsigned) -1, read as int32."""
MOVING = -2
"""The instance RayCaster.intersect reports for a hit on a moving row (World.moving_first):
not an instance, but a row to place at the ray's time like one (trace/instances.py)."""
STRAND = -3
"""A hit on segment (or point) k of a strand reports instance STRAND − k and the strand's row
(World.strand_first on): placed from the hit point and Embree's normal (trace/instances.py)."""

# Enum values (rtcore_common.h, rtcore_device.h, rtcore_scene.h, rtcore_buffer.h,
# rtcore_geometry.h).
RTC_SCENE_FLAG_ROBUST = 1 << 2
RTC_BUILD_QUALITY_MEDIUM = 1
RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_GEOMETRY_TYPE_INSTANCE = 121
STRAND_GEOMETRY_TYPES = {"linear": 16, "bezier": 24, "bspline": 32, "catmullRom": 58, "sphere": 50}
"""scene.Strands shapes as Embree geometry: ROUND_LINEAR, ROUND_BEZIER, ROUND_BSPLINE,
ROUND_CATMULL_ROM curves (tubes swept by a sphere of the radius there), SPHERE_POINT."""
RIBBON_GEOMETRY_TYPES = {"bezier": 26, "bspline": 34, "catmullRom": 60}
"""Cubic shapes with normals as NORMAL_ORIENTED curves: flat ribbons facing the normals."""
RTC_BUFFER_TYPE_NORMAL = 3
RTC_BUFFER_TYPE_INDEX = 0
RTC_BUFFER_TYPE_VERTEX = 1
RTC_FORMAT_UINT = 0x5001
RTC_FORMAT_UINT3 = 0x5003
RTC_FORMAT_FLOAT4 = 0x9004
RTC_FORMAT_FLOAT3 = 0x9003
RTC_FORMAT_FLOAT3X4_ROW_MAJOR = 0x9134

RAYHIT = np.dtype({
    # struct RTCRayHit (rtcore_ray.h): RTCRay (48 bytes) then RTCHit, both 16-byte aligned,
    # every member 4 bytes. The library is Embree's official build (one instance level,
    # instance arrays on): RTCHit ends with instID[1] and instPrimID[1], 36 bytes padded to
    # 48. The unsigned ids are read as int32, so RTC_INVALID_GEOMETRY_ID reads as MISS.
    "names": ["org_x", "org_y", "org_z", "tnear", "dir_x", "dir_y", "dir_z", "time",
              "tfar", "mask", "id", "flags",
              "Ng_x", "Ng_y", "Ng_z", "u", "v", "primID", "geomID", "instID", "instPrimID"],
    "formats": ["<f4"] * 9 + ["<i4"] * 3 + ["<f4"] * 5 + ["<i4"] * 4,
    "offsets": [4 * field for field in range(21)],
    "itemsize": 96,
})
"""One RTCRayHit as a numpy record; a query's scratch is a (1,) array of it at a 16-byte
aligned address (:func:`rayhit_scratch`)."""

RAYHIT_ALIGNMENT = 16


def _library_path() -> Path:
    """libembree4 in embreex's wheel: ``embreex.libs/`` beside the ``embreex`` package."""
    spec = importlib.util.find_spec("embreex")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("pxr-layers needs the embreex wheel, which ships libembree4: pip install embreex")
    libraries = Path(next(iter(spec.submodule_search_locations))).parent / "embreex.libs"
    found = sorted(libraries.glob("libembree4*.so*"))
    if not found:
        raise ImportError(f"no libembree4 in {libraries}: reinstall the embreex wheel")
    return found[0]


def _load_api(path: Path) -> ctypes.CDLL:
    """The host-side C API through ctypes (which releases the GIL during each call).
    Handles are void pointers, passed and returned as Python ints."""
    # LLVM must resolve the kernels' rtcIntersect1/rtcOccluded1 symbols: the same library
    # (dlopen of one path is one handle), loaded where the JIT linker looks.
    llvm.load_library_permanently(str(path))
    library = ctypes.CDLL(str(path))
    handle, c_int, c_uint, c_size = ctypes.c_void_p, ctypes.c_int, ctypes.c_uint, ctypes.c_size_t
    signatures = {  # name: (result, arguments), as declared in include/embree4/rtcore_*.h
        "rtcNewDevice": (handle, [ctypes.c_char_p]),
        "rtcReleaseDevice": (None, [handle]),
        "rtcGetDeviceError": (c_int, [handle]),
        "rtcGetDeviceLastErrorMessage": (ctypes.c_char_p, [handle]),
        "rtcNewScene": (handle, [handle]),
        "rtcSetSceneFlags": (None, [handle, c_int]),
        "rtcSetSceneBuildQuality": (None, [handle, c_int]),
        "rtcCommitScene": (None, [handle]),
        "rtcReleaseScene": (None, [handle]),
        "rtcNewGeometry": (handle, [handle, c_int]),
        "rtcSetSharedGeometryBuffer": (None, [handle, c_int, c_uint, c_int, handle, c_size, c_size, c_size]),
        "rtcSetGeometryTimeStepCount": (None, [handle, c_uint]),
        "rtcSetGeometryInstancedScene": (None, [handle, handle]),
        "rtcSetGeometryTransform": (None, [handle, c_uint, c_int, handle]),
        "rtcCommitGeometry": (None, [handle]),
        "rtcAttachGeometry": (c_uint, [handle, handle]),
        "rtcReleaseGeometry": (None, [handle]),
    }
    for name, (result, arguments) in signatures.items():
        function = getattr(library, name)
        function.restype, function.argtypes = result, arguments
    return library


_api = _load_api(_library_path())

# The queries, by symbol name. Pointers (scene, RTCRayHit*, the NULL arguments) are passed as
# 64-bit integers: the same registers as pointers in the x86-64 and AArch64 calling conventions.
_rtc_intersect1 = types.ExternalFunction("rtcIntersect1", types.void(types.intp, types.intp, types.intp))
_rtc_occluded1 = types.ExternalFunction("rtcOccluded1", types.void(types.intp, types.intp, types.intp))


class Device:
    """An Embree device (its handle an int). Released by :meth:`close`, or when collected."""

    def __init__(self):
        handle = _api.rtcNewDevice(None)
        if not handle:
            raise RuntimeError(f"Embree: no device: {_error_message(None)}")
        self.handle: int = handle
        self._release = weakref.finalize(self, _api.rtcReleaseDevice, handle)

    def check(self, doing: str) -> None:
        """Raise if an Embree call of this thread on this device failed since the last check."""
        code = _api.rtcGetDeviceError(self.handle)
        if code:
            raise RuntimeError(f"Embree failed {doing}: {_error_message(self.handle)} (RTCError {code})")

    def close(self) -> None:
        self._release()


def _error_message(device: int | None) -> str:
    message = _api.rtcGetDeviceLastErrorMessage(device)
    return message.decode(errors="replace") if message else "no message"


class Scene:
    """An Embree scene of `device` (its handle an int, what the kernels take), robust, built
    at medium quality. It holds what Embree reads without owning: the shared vertex and index
    arrays and the instanced child scenes. Released by :meth:`close`, or when collected."""

    def __init__(self, device: Device):
        self.device = device
        self.handle: int = _api.rtcNewScene(device.handle)
        device.check("creating a scene")
        self._release = weakref.finalize(self, _api.rtcReleaseScene, self.handle)
        _api.rtcSetSceneFlags(self.handle, RTC_SCENE_FLAG_ROBUST)
        _api.rtcSetSceneBuildQuality(self.handle, RTC_BUILD_QUALITY_MEDIUM)
        self._shared: list = []

    def commit(self) -> None:
        """Build the BVH (instanced scenes first). Before any query: the build takes no lock."""
        _api.rtcCommitScene(self.handle)
        self.device.check("building the scene's BVH")

    def close(self) -> None:
        self._release()


def _share_vertex_steps(geometry, steps: np.ndarray, count: int, vertex_format: int) -> None:
    """Give `geometry` the vertex buffers of `steps` (k, ≥ count, c) float32, C-contiguous
    rows: one step, or k ≥ 2 evenly spaced over the shutter (Embree's time steps)."""
    if len(steps) > 1:
        _api.rtcSetGeometryTimeStepCount(geometry, len(steps))
    for step in range(len(steps)):
        _api.rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, step, vertex_format, steps[step].ctypes.data,
                                        0, steps.strides[1], count)


def add_triangles(scene: Scene, vertices: np.ndarray, triangles: np.ndarray) -> int:
    """Attach a triangle mesh to `scene` (before its commit); returns its geometry id.

    vertices  : (v, 3) float metres, or (k, v, 3) at k ≥ 2 evenly spaced times over the
                shutter (a motion-blurred mesh: Embree interpolates linearly between them at
                each ray's time) (copied: Embree reads 16 bytes at each vertex, so the shared
                copy has one row more than the mesh)
    triangles : (t, 3) integer vertex indices, counter-clockwise front
    """
    vertices, triangles = np.asarray(vertices), np.asarray(triangles)
    steps = vertices.reshape(-1, *vertices.shape[-2:]) if vertices.ndim == 3 else vertices[None]
    if steps.shape[-1] != 3 or vertices.ndim not in (2, 3) or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise ValueError(f"triangles need vertices (v, 3) or (k, v, 3) and indices (t, 3), not {vertices.shape} "
                         f"and {triangles.shape}")
    count = steps.shape[1]
    if triangles.size and (triangles.min() < 0 or triangles.max() >= count):
        raise ValueError(f"triangle indices outside the {count} vertices")
    padded = np.zeros((len(steps), count + 1, 3), np.float32)
    padded[:, :-1] = steps
    indices = np.ascontiguousarray(triangles, np.uint32)
    geometry = _api.rtcNewGeometry(scene.device.handle, RTC_GEOMETRY_TYPE_TRIANGLE)
    _share_vertex_steps(geometry, padded, count, RTC_FORMAT_FLOAT3)
    _api.rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, indices.ctypes.data,
                                    0, indices.strides[0], len(indices))
    return _attach(scene, geometry, (padded, indices), "adding triangles")


def add_strands(scene: Scene, shape: str, vertices: np.ndarray, segments: np.ndarray,
                normals: np.ndarray | None = None) -> int:
    """Attach curves or points (scene.Strands) to `scene` (before its commit); returns the
    geometry id. vertices (v, 4) x, y, z, radius, metres, or (k, v, 4) at k ≥ 2 evenly spaced
    times over the shutter (a motion-blurred geometry: Embree interpolates at each ray's
    time); segments (s,) each segment's first vertex (ignored for points: one sphere per
    vertex); normals (v, 3): a cubic shape's ribbons face them (None: round tubes)."""
    shared = np.ascontiguousarray(vertices, np.float32)
    steps = shared if shared.ndim == 3 else shared[None]
    count = steps.shape[1]
    kind = STRAND_GEOMETRY_TYPES[shape] if normals is None else RIBBON_GEOMETRY_TYPES[shape]
    geometry = _api.rtcNewGeometry(scene.device.handle, kind)
    _share_vertex_steps(geometry, steps, count, RTC_FORMAT_FLOAT4)
    kept = (shared,)
    if normals is not None:
        facing = np.zeros((count + 1, 3), np.float32)  # one row more: Embree reads 16 bytes a vertex
        facing[:-1] = normals
        for step in range(len(steps)):  # a ribbon faces its frame's normals at every step
            _api.rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_NORMAL, step, RTC_FORMAT_FLOAT3,
                                            facing.ctypes.data, 0, facing.strides[0], count)
        kept = (shared, facing)
    if shape != "sphere":
        indices = np.ascontiguousarray(segments, np.uint32)
        _api.rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT, indices.ctypes.data, 0,
                                        indices.strides[0], len(indices))
        kept = (*kept, indices)
    return _attach(scene, geometry, kept, f"adding {shape} strands")


def add_instance(scene: Scene, child: Scene, transform: np.ndarray) -> int:
    """Attach an instance of the committed scene `child` to `scene` (before its commit);
    returns its geometry id, which hits through it report as their instance id.

    transform : (3, 4) float32, child space to `scene` space: p' = transform[:, :3] p + transform[:, 3];
                or (k, 3, 4), k ≥ 2, at evenly spaced times over the shutter (a moving
                instance: Embree interpolates the matrices linearly at each ray's time)
    """
    matrix = np.ascontiguousarray(transform, np.float32)
    steps = matrix.reshape(-1, *matrix.shape[-2:])
    if matrix.shape[-2:] != (3, 4) or matrix.ndim not in (2, 3):
        raise ValueError(f"an instance transform is (3, 4) or (k, 3, 4), not {matrix.shape}")
    geometry = _api.rtcNewGeometry(scene.device.handle, RTC_GEOMETRY_TYPE_INSTANCE)
    _api.rtcSetGeometryInstancedScene(geometry, child.handle)
    if len(steps) > 1:
        _api.rtcSetGeometryTimeStepCount(geometry, len(steps))
    for step in range(len(steps)):
        _api.rtcSetGeometryTransform(geometry, step, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, steps[step].ctypes.data)  # copied
    return _attach(scene, geometry, (child,), "adding an instance")


def _attach(scene: Scene, geometry: int, shared: tuple, doing: str) -> int:
    _api.rtcCommitGeometry(geometry)
    geometry_id = _api.rtcAttachGeometry(scene.handle, geometry)
    _api.rtcReleaseGeometry(geometry)  # the scene holds it now
    scene.device.check(doing)
    scene._shared.extend(shared)
    return geometry_id


def rayhit_scratch() -> np.ndarray:
    """A query's working RTCRayHit: (1,) RAYHIT at a 16-byte aligned address, as Embree requires.
    One per thread: queries write it."""
    raw = np.zeros(RAYHIT.itemsize + RAYHIT_ALIGNMENT, np.uint8)
    start = -raw.ctypes.data % RAYHIT_ALIGNMENT
    return raw[start:start + RAYHIT.itemsize].view(RAYHIT)


@inline
def _set_ray(rayhit, ox, oy, oz, dx, dy, dz, tnear, tfar, time):
    ray = rayhit[0]
    ray.org_x, ray.org_y, ray.org_z, ray.tnear = ox, oy, oz, tnear
    ray.dir_x, ray.dir_y, ray.dir_z, ray.time = dx, dy, dz, time
    ray.tfar, ray.mask, ray.id, ray.flags = tfar, -1, 0, 0


@inline
def cast_closest(scene, ox, oy, oz, dx, dy, dz, tnear, tfar, time, rayhit):
    """The closest hit along o + t d, tnear ≤ t ≤ tfar (d need not be unit; t in its units),
    at `time`, a shutter fraction in [0, 1] (where moving geometry is).

    scene  : a committed Scene's handle (int)
    rayhit : rayhit_scratch() of the calling thread
    Returns (primID, geomID, instID int32, MISS for none; u, v float32 barycentrics,
    p = (1 − u − v) p0 + u p1 + v p2, 0 on a miss; t float32, tfar on a miss).
    """
    _set_ray(rayhit, ox, oy, oz, dx, dy, dz, tnear, tfar, time)
    hit = rayhit[0]
    hit.u, hit.v, hit.primID, hit.geomID, hit.instID = 0.0, 0.0, MISS, MISS, MISS
    _rtc_intersect1(scene, rayhit.ctypes.data, 0)
    return hit.primID, hit.geomID, hit.instID, hit.u, hit.v, hit.tfar


@inline
def cast_any(scene, ox, oy, oz, dx, dy, dz, tnear, tfar, time, rayhit):
    """Whether anything lies along o + t d, tnear ≤ t ≤ tfar (arguments as cast_closest)."""
    _set_ray(rayhit, ox, oy, oz, dx, dy, dz, tnear, tfar, time)
    _rtc_occluded1(scene, rayhit.ctypes.data, 0)
    return rayhit[0].tfar < 0.0  # Embree marks an occluded ray with tfar = −inf


@kernel
def intersect_kernel(scene, origins, directions, t_max, time, rayhit, instance_first_row, moving_geometry,
                     moving_first, strand_geometry, strand_count, strand_first, triangle_out, instance_out, u_out,
                     v_out, t_out, normal_out):
    """cast_closest over a batch: origins, directions (n, 3) float32, t_max, time (n,) float32;
    instance_first_row (i,) int64 the first World row of each instance's prototype;
    moving_geometry the top-level geometry id of the moving rows (MISS: none), moving_first
    their first World row; strand_geometry the first of strand_count consecutive strand
    geometry ids, strand_first the first strand row. Writes triangle_out (n,) int32 the World
    row hit (MISS for none): a flat hit's primID, an instanced hit's prototype row, a moving
    hit's row, a strand's row; instance_out (n,) int32 the instance (MISS: none; MOVING: a
    moving row; STRAND − k: segment k of a strand); u_out, v_out, t_out (n,) float32;
    normal_out (n, 3) float32 Embree's geometric normal (unnormalised), or (0, 3): not wanted."""
    wants_normal = len(normal_out) > 0
    for lane in range(len(t_max)):
        prim, geometry, instance, u, v, t = cast_closest(
            scene, origins[lane, 0], origins[lane, 1], origins[lane, 2], directions[lane, 0], directions[lane, 1],
            directions[lane, 2], 0.0, t_max[lane], time[lane], rayhit)
        if prim != MISS:
            if instance != MISS:
                prim += instance_first_row[instance]
            elif geometry == moving_geometry:
                prim += moving_first
                instance = MOVING
            elif strand_geometry <= geometry < strand_geometry + strand_count:
                instance = STRAND - prim
                prim = strand_first + geometry - strand_geometry
        triangle_out[lane], instance_out[lane], u_out[lane], v_out[lane], t_out[lane] = prim, instance, u, v, t
        if wants_normal:
            hit = rayhit[0]
            normal_out[lane, 0], normal_out[lane, 1], normal_out[lane, 2] = hit.Ng_x, hit.Ng_y, hit.Ng_z


@kernel
def occluded_kernel(scene, origins, directions, t_max, time, rayhit, occluded_out):
    """cast_any over a batch (arguments as intersect_kernel); writes occluded_out (n,) bool."""
    for lane in range(len(t_max)):
        occluded_out[lane] = cast_any(scene, origins[lane, 0], origins[lane, 1], origins[lane, 2],
                                      directions[lane, 0], directions[lane, 1], directions[lane, 2],
                                      0.0, t_max[lane], time[lane], rayhit)


class RayCaster:
    """Closest-hit and any-hit queries against a World (committed here, before any thread
    queries it): a top-level Embree scene of an instance per World instance (geometry id =
    instance number, so a hit's instID is it) of one child scene per prototype, the flat rows
    as one mesh and the moving rows as one motion-blurred mesh of World.motion_steps time
    steps. Calls from several threads at once are safe; each releases the GIL."""

    def __init__(self, world: World):
        # A world without triangles (a dome alone) has no Embree scene: every ray misses.
        self._scene = None
        self._closed = False
        self._moving_geometry, self._moving_first = MISS, world.moving_first
        self._strand_geometry, self._strand_count = MISS, len(world.strand_shapes)
        self._strand_first = world.strand_first
        if not world.triangle_count:
            return
        device = Device()
        scene = Scene(device)
        prototypes = []
        for vertices, triangles in zip(world.prototype_vertices, world.prototype_triangles):
            child = Scene(device)
            add_triangles(child, vertices, triangles)
            child.commit()
            prototypes.append(child)
        for instance, (prototype, transform) in enumerate(zip(world.instance_prototype.tolist(),
                                                              world.instance_transform)):
            moving = world.instance_motion_index[instance]
            add_instance(scene, prototypes[prototype], transform if moving < 0 else world.instance_motion[moving])
        if len(world.triangles):
            add_triangles(scene, world.vertices, world.triangles)
        if len(world.moving_triangles):
            self._moving_geometry = add_triangles(scene, world.moving_vertices, world.moving_triangles)
        if world.strand_shapes:
            strands = world.strands
            vertex_bounds = np.append(strands.vertex_first, len(strands.vertices))
            segment_bounds = np.append(strands.segment_first, len(strands.segments))
            geometries = []  # consecutive ids, as the intersect kernel reads them
            for number, shape in enumerate(world.strand_shapes):
                own = slice(vertex_bounds[number], vertex_bounds[number + 1])
                segments = strands.segments[segment_bounds[number]:segment_bounds[number + 1]] - own.start
                first = strands.motion_first[number]
                vertices = (strands.vertices[own] if first < 0
                            else strands.motion[:, first:first + own.stop - own.start])
                geometries.append(add_strands(scene, shape, vertices, segments,
                                              strands.normals[own] if strands.ribbon[number] else None))
            self._strand_geometry = geometries[0]
        scene.commit()
        self._scene = scene
        self._instance_first_row = np.ascontiguousarray(world.prototype_first[world.instance_prototype], np.int64)

    @property
    def has_strands(self) -> bool:
        """Whether some hits are on strands, whose placing needs their normals (intersect)."""
        return self._strand_count > 0

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray, time: np.ndarray | None = None,
                  normal: np.ndarray | None = None):
        """Closest hits.

        origins, directions : (n, 3) float32 (directions need not be unit; t is in their units)
        t_max               : (n,) float32
        time                : (n,) float32 shutter fractions in [0, 1] (None: 0), where moving
                              rows are met
        normal              : (n, 3) float32 written with each hit's geometric normal
                              (Embree's, unnormalised), or None
        Returns (triangle (n,) int32 the World row hit, MISS for none (through an instance:
        its prototype's row); instance (n,) int32 the World instance hit through, MISS for
        none, MOVING for a moving row; u (n,), v (n,), t (n,) float32). u and v are Embree's
        barycentrics: p = (1 - u - v) p0 + u p1 + v p2; a miss has u = v = 0 and t = t_max.
        """
        self._check_open()
        n = len(t_max)
        triangle, instance = np.full(n, MISS, np.int32), np.full(n, MISS, np.int32)
        u, v, t = np.zeros(n, FLOAT), np.zeros(n, FLOAT), np.array(t_max, FLOAT)
        if self._scene is not None and n:
            intersect_kernel(self._scene.handle, _rows(origins), _rows(directions), np.ascontiguousarray(t_max, FLOAT),
                             _times(time, n), rayhit_scratch(), self._instance_first_row, self._moving_geometry,
                             self._moving_first, self._strand_geometry, self._strand_count, self._strand_first,
                             triangle, instance, u, v, t, np.zeros((0, 3), FLOAT) if normal is None else normal)
        return triangle, instance, u, v, t

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray,
                 time: np.ndarray | None = None) -> np.ndarray:
        """Any hit with t < t_max for origins, directions (n, 3) at `time` (as intersect): (n,) bool."""
        self._check_open()
        blocked = np.zeros(len(t_max), bool)
        if self._scene is not None and len(t_max):
            occluded_kernel(self._scene.handle, _rows(origins), _rows(directions), np.ascontiguousarray(t_max, FLOAT),
                            _times(time, len(t_max)), rayhit_scratch(), blocked)
        return blocked

    def close(self) -> None:
        """Release the Embree scene and device now (no query may be running; later ones raise)."""
        if self._scene is not None:
            self._scene.close()
            self._scene.device.close()
            self._scene = None
        self._closed = True

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("RayCaster queried after close()")


def _rows(vectors: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(vectors, FLOAT)


def _times(time: np.ndarray | None, count: int) -> np.ndarray:
    return np.zeros(count, FLOAT) if time is None else np.ascontiguousarray(time, FLOAT)
