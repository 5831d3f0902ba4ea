"""UsdGeomBasisCurves and UsdGeomPoints as scene.Strands: the control points Embree sweeps
into round tubes, and the spheres it draws at points, in world metres.

Curves: ``type`` linear or cubic, cubic ``basis`` bezier, bspline or catmullRom, ``wrap``
nonperiodic, periodic (the curve closes on its first vertices) or pinned (a phantom
vertex 2·P0 − P1 before each curve and its mirror after it, so a catmullRom curve starts
and ends at its end points); ``widths`` (diameters) constant, uniform (one per curve),
varying (one per segment end, spread over the vertices) or vertex; with ``normals`` (of any
interpolation), flat ribbons facing them (a linear ribbon becomes the bezier of the same
straight segments, Embree's normal-oriented curves being cubic).
Points: ``widths`` constant or vertex. Missing widths draw 1 scene unit wide (Storm's
fallback), with a note. A placement's scale (uniform: |det|^(1/3)) scales the widths.

Values that no curve has are errors naming the prim and the attribute: vertex counts that
do not add up to the points, curves with too few vertices for their basis, negative or not
finite widths or points, an unknown type, basis or wrap.
"""

from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom

from pxr_layers.errors import StageError
from pxr_layers.scene import FLOAT, INDEX, Strands

from .context import ReadContext
from .transforms import normal_matrix

CUBIC_BASES = ("bezier", "bspline", "catmullRom")
DEFAULT_WIDTH = 1.0  # scene units, when none is authored (Storm draws such curves and points so)


def read_strands(context: ReadContext, prim: Usd.Prim, world_from_local: np.ndarray, path: str, name: str,
                 material: int, points: np.ndarray | None = None) -> Strands | None:
    """The Strands of a BasisCurves or Points `prim` placed by `world_from_local` ((4, 4)
    column convention, stage units); None when it has no points. points: (v, 3) its points
    at another time than the frame's (a step of its motion), else read."""
    time, file = context.time, context.file
    if points is None:
        points = _array(prim.GetAttribute(UsdGeom.Tokens.points), time, file, path, 3)
    widths_attribute = prim.GetAttribute(UsdGeom.Tokens.widths)
    widths = _array(widths_attribute, time, file, path, 1)[:, 0] if widths_attribute.HasAuthoredValue() else None
    if widths is not None and (np.any(widths < 0) or not np.isfinite(widths).all()):
        bad = widths[~(widths >= 0)][0]
        raise StageError(f"widths holds {bad:g}: widths are diameters, 0 or more", file=file, prim=path)
    if widths is None or not len(widths):
        context.diagnostics.note("default-widths", f"curves and points without widths drawn {DEFAULT_WIDTH:g} scene "
                                 "unit wide: {prims}", path)
        widths = np.full(1, DEFAULT_WIDTH)
    if not len(points):
        return None
    interpolation = UsdGeom.Primvar(widths_attribute).GetInterpolation() if len(widths) > 1 else "constant"
    normals = None
    if prim.IsA(UsdGeom.Points):
        shape = "sphere"
        radii = _per_vertex(widths, interpolation, len(points), None, path, file) / 2
        vertices = np.column_stack([points, radii])
        segments = np.arange(len(points), dtype=INDEX)
    else:
        curves = UsdGeom.BasisCurves(prim)
        normals_attribute = curves.GetNormalsAttr()
        if normals_attribute.HasAuthoredValue():
            normals = _array(normals_attribute, time, file, path, 3)
            counts = _array(curves.GetCurveVertexCountsAttr(), time, file, path, 1)[:, 0].astype(np.int64)
            normals = np.column_stack([_per_vertex(normals[:, axis], curves.GetNormalsInterpolation(), len(points),
                                                   counts, path, file, "normals") for axis in range(3)])
            vertices = np.column_stack([points, normals])  # carried through the curves' wrapping
        shape, vertices, segments = _curves(curves, points if normals is None else vertices, widths, interpolation,
                                            time, file, path)
        if normals is not None:
            vertices, normals = vertices[:, [0, 1, 2, 6]], vertices[:, 3:6]
            if shape == "linear":
                shape, vertices, normals, segments = "bezier", *_as_bezier(vertices, normals, segments)
    linear = world_from_local[:3, :3]
    scale = abs(float(np.linalg.det(linear))) ** (1 / 3) * context.meters_per_unit
    placed = np.empty((len(vertices), 4), np.float64)
    placed[:, :3] = (vertices[:, :3] @ linear.T + world_from_local[:3, 3]) * context.meters_per_unit
    placed[:, 3] = vertices[:, 3] * scale
    if not np.isfinite(placed).all():
        raise StageError("its points are not finite where they are placed", file=file, prim=path)
    if normals is not None:
        normals = normals @ normal_matrix(linear).T
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        if not np.all(length > 0):
            raise StageError("normals holds a zero vector: a ribbon faces its normals", file=file, prim=path)
        normals = (normals / length).astype(FLOAT)
    return Strands(name=name, path=path, shape=shape, vertices=placed.astype(FLOAT), segments=segments,
                   material=material, normals=normals)


def _as_bezier(vertices: np.ndarray, normals: np.ndarray, segments: np.ndarray):
    """Linear segments (vertices (v, 4), normals (v, 3), segments (s,)) as the cubic bezier
    segments of the same straight lines: (vertices (3s + ..., 4), normals, segments)."""
    starts, ends = segments, segments + 1
    steps = np.array([0.0, 1 / 3, 2 / 3])[None, :, None]
    cubic = vertices[starts, None] + steps * (vertices[ends] - vertices[starts])[:, None]  # (s, 3, 4)
    faced = normals[starts, None] + steps * (normals[ends] - normals[starts])[:, None]
    # each segment its own 4 vertices (its end repeated as the next one's start: simple, and exact)
    cubic = np.concatenate([cubic, vertices[ends, None]], axis=1).reshape(-1, 4)
    faced = np.concatenate([faced, normals[ends, None]], axis=1).reshape(-1, 3)
    return cubic, faced, (4 * np.arange(len(segments))).astype(INDEX)


def _curves(curves: UsdGeom.BasisCurves, points: np.ndarray, widths: np.ndarray, interpolation: str,
            time: Usd.TimeCode, file: str, path: str) -> tuple[str, np.ndarray, np.ndarray]:
    """(shape, vertices (v, 4) x y z and radius in stage units, segments (s,) int32 first vertex)."""
    kind = str(curves.GetTypeAttr().Get(time))
    basis = str(curves.GetBasisAttr().Get(time))
    wrap = str(curves.GetWrapAttr().Get(time))
    if kind not in ("linear", "cubic"):
        raise StageError(f"type is {kind!r}: BasisCurves are linear or cubic", file=file, prim=path)
    if kind == "cubic" and basis not in CUBIC_BASES:
        raise StageError(f"basis is {basis!r}: cubic curves are drawn as bezier, bspline or catmullRom",
                         file=file, prim=path)
    if wrap not in ("nonperiodic", "periodic", "pinned"):
        raise StageError(f"wrap is {wrap!r}: curves are nonperiodic, periodic or pinned", file=file, prim=path)
    counts = _array(curves.GetCurveVertexCountsAttr(), time, file, path, 1)[:, 0].astype(np.int64)
    if counts.sum() != len(points) or np.any(counts < 0):
        raise StageError(f"curveVertexCounts add up to {int(counts.sum())} vertices but points has {len(points)}",
                         file=file, prim=path)
    shape = "linear" if kind == "linear" else basis
    radii = _per_vertex(widths, interpolation, len(points), counts, path, file) / 2
    step = 3 if shape == "bezier" else 1
    order = 2 if shape == "linear" else 4
    if wrap == "nonperiodic" or shape in ("linear", "bezier") and wrap == "pinned":
        return shape, *_open_curves(shape, np.column_stack([points, radii]), counts, order, step, file, path)
    vertices, segments = [], []
    start = emitted = 0
    for curve, count in enumerate(counts.tolist()):
        own = np.column_stack([points[start:start + count], radii[start:start + count]])
        start += count
        if wrap == "periodic":
            minimum = order - 1 if shape != "bezier" else 3
            if count < max(minimum, 2) or (shape == "bezier" and count % 3):
                raise StageError(f"curve {curve} has {count} vertices: too few for a periodic {shape} curve"
                                 + (" (bezier: a multiple of 3)" if shape == "bezier" else ""), file=file, prim=path)
            own = np.concatenate([own, own[:order - 1 if shape != "bezier" else 1]])
        elif wrap == "pinned" and shape in ("bspline", "catmullRom"):
            if count < 2:
                raise StageError(f"curve {curve} has {count} vertices: a pinned curve needs 2", file=file, prim=path)
            own = np.concatenate([2 * own[:1] - own[1:2], own, 2 * own[-1:] - own[-2:-1]])
        if len(own) < order or (shape == "bezier" and (len(own) - 1) % 3):
            raise StageError(f"curve {curve} has {count} vertices: a {shape} curve needs "
                             + ("3k + 1" if shape == "bezier" else f"{order} or more"), file=file, prim=path)
        segments.append(emitted + np.arange(0, len(own) - order + 1, step))
        vertices.append(own)
        emitted += len(own)
    return shape, np.concatenate(vertices), np.concatenate(segments).astype(INDEX)


def _open_curves(shape: str, vertices: np.ndarray, counts: np.ndarray, order: int, step: int, file: str,
                 path: str) -> tuple[np.ndarray, np.ndarray]:
    """Nonperiodic curves, every curve's vertices as authored: (vertices, segments (s,) int32),
    in whole-array steps (a groom's hundred thousand curves need no loop)."""
    short = (counts < order) | ((counts - 1) % step != 0)
    if short.any():
        curve = int(np.flatnonzero(short)[0])
        raise StageError(f"curve {curve} has {int(counts[curve])} vertices: a {shape} curve needs "
                         + ("3k + 1" if shape == "bezier" else f"{order} or more"), file=file, prim=path)
    starts = np.cumsum(counts) - counts
    per_curve = (counts - order) // step + 1
    first = np.cumsum(per_curve) - per_curve
    rank = np.arange(int(per_curve.sum())) - np.repeat(first, per_curve)  # a segment's place in its curve
    return vertices, (np.repeat(starts, per_curve) + step * rank).astype(INDEX)


def _per_vertex(widths: np.ndarray, interpolation: str, count: int, curve_counts: np.ndarray | None, path: str,
                file: str, name: str = "widths") -> np.ndarray:
    """(count,) float64 values of `name` (widths, or a normals component) at every vertex, from
    values of any interpolation."""
    if len(widths) == 1 or interpolation == "constant":
        return np.full(count, widths[0], np.float64)
    if len(widths) == count:  # vertex (or varying on linear curves, which is the same)
        return widths.astype(np.float64)
    if curve_counts is not None and interpolation == "uniform" and len(widths) == len(curve_counts):
        return np.repeat(widths, curve_counts).astype(np.float64)
    if curve_counts is not None and interpolation in ("varying", "faceVarying"):
        ends = [max(int(n) - 2, 1) for n in curve_counts]  # cubic nonperiodic: one value per segment end
        if len(widths) == sum(ends):
            spread, first = [], 0
            for n, own in zip(curve_counts.tolist(), ends):
                spread.append(np.interp(np.linspace(0, 1, n), np.linspace(0, 1, own), widths[first:first + own]))
                first += own
            return np.concatenate(spread)
    raise StageError(f"{name} has {len(widths)} values ({interpolation}), which match none of its "
                     f"{count} vertices", file=file, prim=path)


def _array(attribute: Usd.Attribute, time: Usd.TimeCode, file: str, path: str, width: int) -> np.ndarray:
    """(n, width) float64 values of an array attribute (empty when unauthored)."""
    value = attribute.Get(time) if attribute else None
    if value is None:
        return np.zeros((0, width))
    array = np.asarray(value, np.float64).reshape(len(value), -1)
    if array.shape[1] != width or not np.isfinite(array).all():
        raise StageError(f"{attribute.GetName()} holds values that are not finite numbers", file=file, prim=path)
    return array
