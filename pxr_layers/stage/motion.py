"""Object motion over the camera's shutter: which gprims move, and where they are at the
time steps the tracer interpolates between.

A gprim moves when its world transform (any xformOp of it or an ancestor) or its points
(time samples, or ``velocities`` and ``accelerations`` in scene units per second, with the
stage's timeCodesPerSecond, moving the time sample they go with: UsdGeomPointBased's rules,
through ComputePointsAtTimes; a note names velocities beside unsampled points) differ
over [shutter:open, shutter:close]; a point instance, when its instance's transform does
(positions, orientations, scales and their samples, ``velocities``, ``accelerations`` and
``angularVelocities``: UsdGeomPointInstancer.ComputeInstanceTransformsAtTimes) or a top-level
instancer's own world transform. Embree interpolates a moving mesh linearly between k
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
from .transforms import column_matrix
from .walk import InstancerLink

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
        self._instancers: dict[tuple, np.ndarray | None] = {}  # (instancer path, top level) → steps
        self._deforms: dict[str, bool] = {}  # gprim path → deforms
        self._instance_transforms: dict[tuple, np.ndarray | None] = {}  # (path, times) → (T, n, 4, 4)

    @property
    def interval(self) -> Gf.Interval:
        """The shutter, time codes."""
        return self._interval

    def steps(self, prim: Usd.Prim, placement: InstancerLink | None = None, instance: int = -1) -> int:
        """The time steps a gprim needs over the shutter, placed by its own world transform or
        as point instance `instance` of `placement`: 1 when it stands still."""
        if placement is None:
            times = transform_times(prim, self._interval)
            steps = _steps(np.stack([self.world_from_local(prim, time) for time in times])[:, None])[0]
        else:
            per_instance = self._instancer_steps(placement)
            steps = per_instance[instance] if per_instance is not None else 1
        if self.deforms(prim):
            point_based = UsdGeom.PointBased(prim)
            samples = {self._shutter.open, self._shutter.close,
                       *point_based.GetPointsAttr().GetTimeSamplesInInterval(self._interval)}
            steps = max(steps, len(samples), 3 if point_based.GetAccelerationsAttr().HasAuthoredValue() else 2)
        return min(int(steps), MAX_MOTION_STEPS)

    def placements(self, prim: Usd.Prim, placement: InstancerLink | None, instance: int,
                   times: np.ndarray) -> np.ndarray:
        """(k, 4, 4) float64 column convention, stage units: the gprim's world_from_local at
        each time code of `times` (as :meth:`steps` places it)."""
        if placement is None:
            return np.stack([self.world_from_local(prim, time) for time in times])
        transforms = self._transforms_of(placement.prim, tuple(times))[:, instance]
        return self._instancer_worlds(placement, times) @ transforms @ placement.proto_from_prim

    def deforms(self, prim: Usd.Prim) -> bool:
        """Whether `prim`'s points change over the shutter (samples or velocities)."""
        key = str(prim.GetPath())
        if key not in self._deforms:
            self._deforms[key] = prim.IsA(UsdGeom.PointBased) and self._points_move(UsdGeom.PointBased(prim))
        return self._deforms[key]

    def _points_move(self, point_based: UsdGeom.PointBased) -> bool:
        points = point_based.GetPointsAttr()
        velocities = point_based.GetVelocitiesAttr().Get(self._context.time)
        if velocities is not None and len(velocities) and np.any(np.asarray(velocities)):
            if points.GetNumTimeSamples():
                return True
            self._note_unsampled(point_based.GetPrim())
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
        the sample at or before the frame (UsdGeomPointBased.ComputePointsAtTimes)."""
        computed = UsdGeom.PointBased(prim).ComputePointsAtTimes([Usd.TimeCode(t) for t in times], self._context.time)
        return [np.asarray(points, np.float64) for points in computed]

    def world_from_local(self, prim: Usd.Prim, time: float) -> np.ndarray:
        """(4, 4) float64 column convention, stage units: `prim`'s world transform at `time`."""
        cache = self._xform_caches.get(time)
        if cache is None:
            cache = self._xform_caches[time] = UsdGeom.XformCache(Usd.TimeCode(time))
        return column_matrix(cache.GetLocalToWorldTransform(prim))

    def _instancer_steps(self, placement: InstancerLink) -> np.ndarray | None:
        """(n,) int the steps each instance of the instancer needs (1: still), from its
        transforms at the shutter's ends and at every sample of its arrays between; None
        when USD cannot compute them (the walk composed the frame's from the arrays)."""
        # a nested instancer's placement is the same at every time: it changes no instance's steps
        key = (str(placement.prim.GetPath()), placement.world_from_instancer is None)
        if key not in self._instancers:
            instancer = UsdGeom.PointInstancer(placement.prim)
            if not instancer.GetPositionsAttr().GetNumTimeSamples() and (
                    instancer.GetVelocitiesAttr().HasAuthoredValue() or instancer.GetAngularVelocitiesAttr().HasAuthoredValue()):
                self._note_unsampled(placement.prim)
            times = {self._shutter.open, self._shutter.close}
            if placement.world_from_instancer is None:  # a top-level instancer: its own transform too
                times.update(transform_times(placement.prim, self._interval))
            for attribute in (instancer.GetPositionsAttr(), instancer.GetOrientationsAttr(),
                              instancer.GetOrientationsfAttr(), instancer.GetScalesAttr(),
                              instancer.GetVelocitiesAttr(), instancer.GetAngularVelocitiesAttr()):
                times.update(attribute.GetTimeSamplesInInterval(self._interval))
            times = sorted(times)
            transforms = self._transforms_of(placement.prim, tuple(times))
            if transforms is None:
                self._instancers[key] = None
            else:
                worlds = self._instancer_worlds(placement, np.asarray(times))
                steps = _steps(worlds[:, None] @ transforms)
                if instancer.GetAccelerationsAttr().HasAuthoredValue():
                    steps = np.where(steps > 1, np.maximum(steps, 3), 1)
                self._instancers[key] = steps
        return self._instancers[key]

    def _note_unsampled(self, prim: Usd.Prim) -> None:
        self._context.diagnostics.note(
            "unsampled-velocities", "velocities ignored beside points or positions without time samples (USD moves "
            "a sample by its velocities, UsdGeomPointBased and UsdGeomPointInstancer): {prims}", str(prim.GetPath()))

    def _instancer_worlds(self, placement: InstancerLink, times: np.ndarray) -> np.ndarray:
        if placement.world_from_instancer is not None:
            return np.repeat(placement.world_from_instancer[None], len(times), 0)
        return np.stack([self.world_from_local(placement.prim, time) for time in times])

    def _transforms_of(self, prim: Usd.Prim, times: tuple[float, ...]) -> np.ndarray | None:
        """(T, n, 4, 4) column convention: the instancer's instancer_from_instance at each time
        (the prototype root's transform included); None when USD cannot compute them."""
        key = (str(prim.GetPath()), times)
        if key not in self._instance_transforms:
            computed = UsdGeom.PointInstancer(prim).ComputeInstanceTransformsAtTimes(
                [Usd.TimeCode(t) for t in times], self._context.time, UsdGeom.PointInstancer.IncludeProtoXform,
                UsdGeom.PointInstancer.IgnoreMask)
            arrays = [np.asarray(transforms, np.float64) for transforms in computed]
            usable = len(arrays) == len(times) and len({a.shape for a in arrays}) == 1 and arrays[0].ndim == 3
            self._instance_transforms[key] = np.stack(arrays).transpose(0, 1, 3, 2) if usable else None
        return self._instance_transforms[key]



def transform_times(prim: Usd.Prim, interval: Gf.Interval) -> list[float]:
    """The ends of `interval` (time codes) and every transform sample of `prim` and its
    ancestors between them, ascending."""
    times = {interval.GetMin(), interval.GetMax()}
    ancestor = prim
    while ancestor and not ancestor.IsPseudoRoot():
        xformable = UsdGeom.Xformable(ancestor)
        if xformable:
            times.update(xformable.GetTimeSamplesInInterval(interval))
        ancestor = ancestor.GetParent()
    return sorted(times)


def _steps(transforms: np.ndarray) -> np.ndarray:
    """(n,) int the steps each of n placements needs, from its transforms (T, n, 4, 4) at T
    times over the shutter: 1 when they are all equal, else the T times, and more when it
    turns by more than MAX_STEP_ROTATION a step."""
    moving = ~np.all(np.isclose(transforms, transforms[:1], rtol=0, atol=1e-12), axis=(0, 2, 3))
    linear = transforms[..., :3, :3]
    scale = np.cbrt(np.abs(np.linalg.det(linear)))[..., None, None]
    rotation = linear / np.where(scale > 0, scale, 1.0)  # a similarity's rotation (a shear's, nearly)
    relative = rotation[1:] @ np.swapaxes(rotation[:-1], -1, -2)
    turned = np.arccos(np.clip((np.trace(relative, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)).sum(axis=0)
    needed = np.maximum(len(transforms), np.ceil(turned / MAX_STEP_ROTATION).astype(int) + 1)
    return np.where(moving, needed, 1)
