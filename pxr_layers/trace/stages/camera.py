"""Stage 1: camera rays, one per path (pixel · spp + sample), jittered in the pixel."""

from __future__ import annotations

import math

import numpy as np

from .. import rng
from ..camera import ThinLensCamera
from ...compiled import inline, kernel
from .queues import PathQueue


def camera_rays(camera: ThinLensCamera, frame_key: np.uint64, resolution: tuple[int, int], spp: int,
                first_path: int, stop_path: int, jitter: bool = True) -> PathQueue:
    """The PathQueue of paths [first_path, stop_path): unit throughput, rays through the
    film at each pixel's jittered position (its centre without `jitter`), from a point of
    the lens drawn uniformly on its disc (radii stratified over a pixel's samples; its
    centre without `jitter`: data passes are sharp) toward where the pinhole's ray meets
    the plane in focus, the camera posed at the path's time, drawn over the shutter (stratified
    with the lens radius, rng.van_der_corput; the shutter's middle without `jitter`), which
    every later ray of the path keeps (moving geometry) (camera.py)."""
    count = stop_path - first_path
    width, height = resolution
    queue = PathQueue(
        pixel=np.empty(count, np.int64), sample=np.empty(count, np.int32), key=np.empty(count, np.uint64),
        depth=np.zeros(count, np.int32), previous_pdf=np.zeros(count, np.float32),
        previous_singular=np.ones(count, bool),  # the camera: what it sees directly is not MIS'd
        previous_triangle=np.full(count, -1, np.int32), previous_lobe=np.full(count, -1, np.int8),
        throughput=np.ones((count, 3), np.float32), travelled=np.zeros(count, np.float32),
        vertex_travelled=np.zeros(count, np.float32),
        origin=np.empty((count, 3), np.float32), direction=np.empty((count, 3), np.float32),
        t_max=np.full(count, camera.t_max, np.float32), node=np.zeros(count, np.int64),
        row=np.full(count, -1, np.int64), time=np.empty(count, np.float32))
    pose = np.empty((4, 3))  # the kernel's working pose: world_from_camera's rows, then the position
    pose[:3], pose[3] = camera.world_from_camera, camera.position
    _camera_kernel(first_path, spp, width, height, frame_key, pose, camera.motion_times, camera.motion_rotations,
                   camera.motion_positions, camera.half_width, camera.half_height, camera.offset_x,
                   camera.offset_y, camera.lens_radius if jitter else 0.0, camera.focus_distance, jitter, queue.pixel,
                   queue.sample, queue.key, queue.origin, queue.direction, queue.time)
    return queue


@kernel
def _camera_kernel(first_path, spp, width, height, frame_key, pose, motion_times, motion_rotations, motion_positions,
                   half_width, half_height, offset_x, offset_y, lens_radius, focus_distance, jitter, pixel_out,
                   sample_out, key_out, origin_out, direction_out, time_out):
    rotation, position = pose[:3], pose[3]
    for lane in range(len(pixel_out)):
        path = first_path + lane
        pixel = path // spp
        sample = path % spp
        key = rng.path_key(frame_key, pixel, sample)
        # the time stratified over the pixel's samples, and jointly with the lens radius
        time = rng.van_der_corput(frame_key, pixel, sample, rng.TIME) if jitter else 0.5
        if len(motion_times) > 1:
            _pose_at(time, motion_times, motion_rotations, motion_positions, pose)
        jx = rng.uniform(key, 0) if jitter else 0.5
        jy = rng.uniform(key, 1) if jitter else 0.5
        film_x = ((pixel % width) + jx) / width
        film_y = ((pixel // width) + jy) / height
        x = (2.0 * film_x - 1.0) * half_width + offset_x
        y = (1.0 - 2.0 * film_y) * half_height + offset_y
        z = -1.0
        lens_x = lens_y = 0.0
        if lens_radius > 0:
            # toward the pinhole ray's point on the plane in focus, (x, y, −1)·focus_distance,
            # from a lens point whose radius is stratified over the pixel's samples (the
            # blur's spread, its mean squared radius, is then nearly exact) and whose angle
            # is independent of it
            radius = lens_radius * math.sqrt(rng.stratified(frame_key, pixel, sample, spp, rng.LENS))
            angle = 2.0 * math.pi * rng.uniform(key, rng.LENS + 1)
            lens_x, lens_y = radius * math.cos(angle), radius * math.sin(angle)
            x, y, z = x * focus_distance - lens_x, y * focus_distance - lens_y, -focus_distance
        wx = rotation[0, 0] * x + rotation[0, 1] * y + rotation[0, 2] * z
        wy = rotation[1, 0] * x + rotation[1, 1] * y + rotation[1, 2] * z
        wz = rotation[2, 0] * x + rotation[2, 1] * y + rotation[2, 2] * z
        scale = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
        pixel_out[lane], sample_out[lane], key_out[lane], time_out[lane] = pixel, sample, key, time
        for axis in range(3):
            origin_out[lane, axis] = position[axis] + rotation[axis, 0] * lens_x + rotation[axis, 1] * lens_y
        direction_out[lane, 0], direction_out[lane, 1], direction_out[lane, 2] = wx * scale, wy * scale, wz * scale


@inline
def _pose_at(time, times, rotations, positions, pose):
    """Writes into pose (4, 3) the camera's rotation (rows 0–2) and position (row 3) at
    `time`, a shutter fraction: between the known poses around it, positions lerped and the
    unit quaternions (w, x, y, z) slerped."""
    segment = 0
    while segment < len(times) - 2 and time >= times[segment + 1]:
        segment += 1
    span = times[segment + 1] - times[segment]
    f = (time - times[segment]) / span if span > 0 else 0.0
    for axis in range(3):
        pose[3, axis] = positions[segment, axis] + f * (positions[segment + 1, axis] - positions[segment, axis])
    cosine = 0.0
    for c in range(4):
        cosine += rotations[segment, c] * rotations[segment + 1, c]
    if cosine > 0.9995:  # nearly the same rotation: lerp (slerp's sine would divide by ~0)
        a, b = 1.0 - f, f
    else:
        angle = math.acos(min(cosine, 1.0))
        a, b = math.sin((1.0 - f) * angle) / math.sin(angle), math.sin(f * angle) / math.sin(angle)
    w = a * rotations[segment, 0] + b * rotations[segment + 1, 0]
    x = a * rotations[segment, 1] + b * rotations[segment + 1, 1]
    y = a * rotations[segment, 2] + b * rotations[segment + 1, 2]
    z = a * rotations[segment, 3] + b * rotations[segment + 1, 3]
    norm = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w * norm, x * norm, y * norm, z * norm
    pose[0, 0], pose[0, 1], pose[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    pose[1, 0], pose[1, 1], pose[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    pose[2, 0], pose[2, 1], pose[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
