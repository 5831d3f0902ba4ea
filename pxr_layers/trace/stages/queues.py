"""The queues the stages pass each other: structure-of-arrays dataclasses, lane-major.

Every field of a queue has the lanes on its first axis, so ``take(lanes)`` compacts all of
them at once and no stage keeps arrays in step by hand. Vectors are (n, 3) float32, the
layout Embree reads.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

MAX_PASS_THROUGH = 16  # see-through surfaces a path or shadow ray may cross on top of its bounces
T_INFINITY = np.float32(1e30)  # the t_max of rays that go on until they hit something


class _Queue:
    def take(self, lanes: np.ndarray):
        """The queue of `lanes` (int64 indices), every field gathered."""
        return type(self)(**{name: np.take(value, lanes, axis=0) for name, value in vars(self).items()})

    def __len__(self) -> int:
        return len(next(iter(vars(self).values())))


@dataclass
class PathQueue(_Queue):
    """The live paths of a batch and the ray each casts next (n lanes).

    pixel (n,) int64; sample (n,) int32; key (n,) uint64 random stream (rng.py)
    depth (n,) int32 scattering events so far; previous_pdf (n,) float32 density of the
    last scattering direction (MIS); previous_singular (n,) bool (camera or delta: no MIS)
    previous_triangle (n,) int32 the surface of the last scattering vertex (−1: the
    camera) and previous_lobe (n,) int8 the lobe it took (bsdf.py, −1: the camera), which
    light linking and the lights' diffuse/specular multipliers read
    throughput (n, 3) float32; travelled (n,) float32 metres from the camera (ray cones);
    vertex_travelled (n,) float32 its value at the path's last scattering vertex (0 at the
    camera): the distance from that vertex is what light sampling's density measures, even
    when the path has crossed see-through surfaces since
    origin, direction (n, 3) float32 (directions unit); t_max (n,) float32 metres
    node (n,) int64 the path's class so far, row (n,) int64 its last event's norms row:
    the PathRecorder's columns (0 and −1 when nothing is recorded)
    time (n,) float32 the path's time, a fraction of the shutter in [0, 1]: where the
    camera and moving geometry are for every ray of the path
    """

    pixel: np.ndarray
    sample: np.ndarray
    key: np.ndarray
    depth: np.ndarray
    previous_pdf: np.ndarray
    previous_singular: np.ndarray
    previous_triangle: np.ndarray
    previous_lobe: np.ndarray
    throughput: np.ndarray
    travelled: np.ndarray
    vertex_travelled: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    t_max: np.ndarray
    node: np.ndarray
    row: np.ndarray
    time: np.ndarray


@dataclass
class Hits(_Queue):
    """Closest hits of a PathQueue's rays: triangle (n,) int32 (−1: none), Embree's
    barycentrics u, v (n,) float32 and the distance t (n,) float32."""

    triangle: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray


@dataclass
class SurfaceQueue(_Queue):
    """Shading points of a PathQueue's hits (n lanes, the PathQueue's).

    Lanes that hit nothing or a light have cut and scatters False and nothing else set.

    position (n, 3) float32 metres; facing (n, 3) geometric normal on the viewer's side
    frame (n, 3, 3) float32 shading frame rows: tangent, bitangent, normal (toward the viewer)
    wo (n, 3) float32 toward the previous vertex, in the shading frame
    lobes (n, LOBE_FIELDS) float32 (bsdf.py); cut (n,) bool: cut out (pass straight through)
    scatters (n,) bool: may scatter (not cut, below max depth)
    triangle (n,) int32; st (n, 2) float32
    curvature, texture (n,) float32 the covariance norms C, T (0 unless asked for)
    through (n,) float32 metres: GeometryArrays.thickness of the hit (a strand's diameter):
        where a direction that leaves below the hit starts, past the object (hair)
    """

    position: np.ndarray
    facing: np.ndarray
    frame: np.ndarray
    wo: np.ndarray
    lobes: np.ndarray
    cut: np.ndarray
    scatters: np.ndarray
    triangle: np.ndarray
    st: np.ndarray
    curvature: np.ndarray
    texture: np.ndarray
    through: np.ndarray


@dataclass
class ShadowQueue(_Queue):
    """Light samples waiting for their shadow ray (n entries).

    lane (n,) int64 the path (PathQueue / SurfaceQueue lane) the sample belongs to
    origin, direction (n, 3) float32; t_max (n,) float32
    radiance (n, 3 lobes, 3) float32 the tentative contribution of each glossy lobe
    (DIFFUSE, SPECULAR, COAT), throughput and MIS weight included: added if visible
    light (n,) int32 the sampled light (−1: an emissive surface); triangle (n,) int32 the
    sampled emitting triangle (−1: distant or dome)
    visible (n,) bool: the shadow ray reached the light (set by next_event.cast_shadows)
    """

    lane: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    t_max: np.ndarray
    radiance: np.ndarray
    light: np.ndarray
    triangle: np.ndarray
    visible: np.ndarray


@dataclass
class Splats(_Queue):
    """Contributions a stage adds to the film (n entries).

    lane (n,) int64 the contributing path; rgb (n, 3) float32
    light (n,) int32 the light reached (−1: an emissive surface or none)
    triangle (n,) int32 the emitting triangle reached (−1: an infinite light)
    """

    lane: np.ndarray
    rgb: np.ndarray
    light: np.ndarray
    triangle: np.ndarray


def trimmed(queue, count: int):
    """The first `count` lanes of a queue a kernel filled from the start."""
    return type(queue)(**{field.name: getattr(queue, field.name)[:count] for field in dataclasses.fields(queue)})

