"""Object motion over the camera's shutter: which gprims move, and where they are at the
time steps the tracer interpolates between.

A gprim moves when its world transform (any xformOp of it or an ancestor) or its points
(time samples, or ``velocities`` and ``accelerations`` in scene units per second, with the
stage's timeCodesPerSecond: UsdGeomPointBased's rules, through ComputePointsAtTimes) differ
over [shutter:open, shutter:close]. Embree interpolates a moving mesh linearly between k
evenly spaced time steps, one count for the whole scene (scene.Mesh.motion_points): the
most any moving gprim needs, which is its authored samples within the shutter, at least 3
with accelerations, and enough that no step turns it by more than MAX_STEP_ROTATION (a
rotation's chords stay within 0.4 % of its radius), up to MAX_MOTION_STEPS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pxr import Gf, Usd, UsdGeom

from .context import ReadContext
from .transforms import column_matrix, nearest_rotation

MAX_MOTION_STEPS = 16
MAX_STEP_ROTATION = math.radians(10.0)


@dataclass(frozen=True)
class Shutter:
    """The frame's shutter as absolute time codes, open < close."""

    open: float
    close: float

    @classmethod
    def of(cls, time: Usd.TimeCode, shutter: tuple[float, float], motion_blur: bool) -> Shutter | None:
        """The shutter of a camera (scene.Camera.shutter, frames relative to `time`); None when
        nothing can move: motion blur off, an instant shutter, or a stage without time."""
        if not motion_blur or shutter[1] <= shutter[0] or time.IsDefault():
            return None
        frame = time.GetValue()
        return cls(frame + shutter[0], frame + shutter[1])

    def times(self, steps: int) -> np.ndarray:
        """(steps,) float64 evenly spaced time codes, open to close."""
        return np.linspace(self.open, self.close, steps)


class GprimMotion:
    """Motion of the gprims of one read (``context.shutter`` not None)."""

    def __init__(self, context: ReadContext):
        assert context.shutter is not None
        self._context = context
        self._shutter = context.shutter
        self._interval = Gf.Interval(self._shutter.open, self._shutter.close)
        self._xform_caches: dict[float, UsdGeom.XformCache] = {}

    def steps(self, prim: Usd.Prim) -> int:
        """The time steps `prim` needs over the shutter: 1 when it stands still."""
        transform_times = self._transform_times(prim)
        transforms = [self.world_from_local(prim, time) for time in transform_times]
        moves = not all(np.allclose(matrix, transforms[0], rtol=0, atol=1e-12) for matrix in transforms)
        steps = len(transform_times) if moves else 1
        if moves:
            turned = sum(_rotation_angle(a[:3, :3], b[:3, :3]) for a, b in zip(transforms, transforms[1:]))
            steps = max(steps, math.ceil(turned / MAX_STEP_ROTATION) + 1)
        deforming = self.deforms(prim)
        if deforming:
            point_based = UsdGeom.PointBased(prim)
            samples = {self._shutter.open, self._shutter.close,
                       *point_based.GetPointsAttr().GetTimeSamplesInInterval(self._interval)}
            steps = max(steps, len(samples), 3 if point_based.GetAccelerationsAttr().HasAuthoredValue() else 2)
        return min(steps, MAX_MOTION_STEPS)

    def deforms(self, prim: Usd.Prim) -> bool:
        """Whether `prim`'s points change over the shutter (samples or velocities)."""
        if not prim.IsA(UsdGeom.PointBased):
            return False
        point_based = UsdGeom.PointBased(prim)
        velocities = point_based.GetVelocitiesAttr().Get(self._context.time)
        if velocities is not None and len(velocities) and np.any(np.asarray(velocities)):
            return True
        points = point_based.GetPointsAttr()
        if not points.ValueMightBeTimeVarying():
            return False
        times = [self._shutter.open, *points.GetTimeSamplesInInterval(self._interval), self._shutter.close]
        first = np.asarray(points.Get(times[0]))
        return any(not np.array_equal(np.asarray(points.Get(time)), first) for time in times[1:])

    def topology_change(self, prim: Usd.Prim) -> str | None:
        """What changes `prim`'s topology over the shutter (the number of points, or a mesh's
        faces), said for an error; None when nothing does. USD's point interpolation holds the
        frame's sample when counts differ: the motion would silently stop."""
        frame = self._context.time
        attributes = [UsdGeom.PointBased(prim).GetPointsAttr()]
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            attributes += [mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()]
        for attribute in attributes:
            if not attribute.ValueMightBeTimeVarying():
                continue
            at_frame = attribute.Get(frame)
            for time in [self._shutter.open, *attribute.GetTimeSamplesInInterval(self._interval), self._shutter.close]:
                value = attribute.Get(time)
                if attribute.GetName() == UsdGeom.Tokens.points:
                    if len(value or ()) != len(at_frame or ()):
                        return (f"its points change in number over the shutter ({len(at_frame or ())} at the frame, "
                                f"{len(value or ())} at time {time:g})")
                elif value != at_frame:
                    return f"its {attribute.GetName()} change over the shutter (at time {time:g})"
        return None

    def points_at(self, prim: Usd.Prim, times: np.ndarray) -> list[np.ndarray]:
        """`prim`'s points (v, 3) float64, stage units, its own space, at each time code of
        `times`: interpolated between samples, or moved by velocities and accelerations from
        the sample at or before the frame (UsdGeomPointBased.ComputePointsAtTimes). USD
        applies velocities to time-sampled points only; velocities beside points that have no
        samples move them from the frame's time too, as renderers do with such data."""
        point_based = UsdGeom.PointBased(prim)
        computed = [np.asarray(points, np.float64)
                    for points in point_based.ComputePointsAtTimes([Usd.TimeCode(t) for t in times], self._context.time)]
        if point_based.GetPointsAttr().GetNumTimeSamples() == 0:
            points = np.asarray(point_based.GetPointsAttr().Get(self._context.time), np.float64)
            velocities = point_based.GetVelocitiesAttr().Get(self._context.time)
            if velocities is not None and len(velocities) == len(points):
                accelerations = point_based.GetAccelerationsAttr().Get(self._context.time)
                accelerations = (np.asarray(accelerations, np.float64)
                                 if accelerations is not None and len(accelerations) == len(points) else 0.0)
                seconds = (np.asarray(times) - self._context.time.GetValue()) / prim.GetStage().GetTimeCodesPerSecond()
                computed = [points + np.asarray(velocities, np.float64) * s + 0.5 * accelerations * s * s
                            for s in seconds]
        return computed

    def world_from_local(self, prim: Usd.Prim, time: float) -> np.ndarray:
        """(4, 4) float64 column convention, stage units: `prim`'s world transform at `time`."""
        cache = self._xform_caches.get(time)
        if cache is None:
            cache = self._xform_caches[time] = UsdGeom.XformCache(Usd.TimeCode(time))
        return column_matrix(cache.GetLocalToWorldTransform(prim))

    def _transform_times(self, prim: Usd.Prim) -> list[float]:
        """The shutter's ends and every transform sample of `prim` and its ancestors between."""
        times = {self._shutter.open, self._shutter.close}
        ancestor = prim
        while ancestor and not ancestor.IsPseudoRoot():
            xformable = UsdGeom.Xformable(ancestor)
            if xformable:
                times.update(xformable.GetTimeSamplesInInterval(self._interval))
            ancestor = ancestor.GetParent()
        return sorted(times)


def _rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle in radians of the rotation between the orthogonal parts of linear maps a and b."""
    relative = nearest_rotation(b) @ nearest_rotation(a).T
    return math.acos(float(np.clip((np.trace(relative) - 1) / 2, -1.0, 1.0)))
