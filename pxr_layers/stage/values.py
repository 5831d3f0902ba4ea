"""Authored values of the type their schema gives them, or a StageError naming the attribute.

USD keeps the type a layer authored: ``string faceVertexCounts = "4"`` or ``int3[] points``
compose without complaint and ``Get()`` returns the string or the integer vectors, where a
C++ renderer's typed ``Get<VtIntArray>`` would fail. Read through these functions, a value
of another type is one StageError naming the file, the prim and the attribute, with the type
found and the type wanted, instead of a ValueError deep in numpy or numbers silently
truncated (``float[] faceVertexIndices``) or reshaped (``float[] points``).

Types are compared without their roles (``point3f[]`` is ``float3[]``), and precisions are
interchangeable (half, float, double); a real where an integer is wanted is refused; an
integer scalar where a real is wanted is taken, integer vectors and arrays are not.

Numbers, once typed, go through one rule (:func:`checked`): an authored number that is NaN
or infinite, or outside the range its attribute can mean, is a StageError naming the file,
the prim and the attribute (or shader input): one edit fixes it, and no pixel can be made
of it. Lights and materials (UsdPreviewSurface and MaterialX) use it; ranges belong to
the attribute (a size is ≥ 0, a radiance at most MAX_RADIANCE, ...).

Arrays are bounded too (MAX_ARRAY_VALUES): a small .usdc can declare a billion values
(crate files compress runs), and one is refused as soon as USD hands it over, before numpy
copies it.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import Sdf, Usd

from pxr_layers.errors import StageError

from .budgets import MAX_SCENE_TRIANGLES

_INTEGERS = ("int", "uint", "int64", "uint64", "uchar")
_REALS = ("half", "float", "double")

MAX_RADIANCE = 1e20
"""The brightest radiance a scene may hold (render units: a directly seen light of radiance 1
gives pixel value 1): a light's intensity · 2^exposure · colour (times its IES profile's
peak), an emissive material's colour, a light image's texel. Far above anything real (the
Sun's disc is about 1.6e9 cd/m², and a small normalized light's radiance rarely reaches
1e9), and far enough below float32's 3.4e38 that a pixel's sums, a dome's sampling tables
over up to 2^32 texels and a path's throughput stay finite."""

MAX_ARRAY_VALUES = 3 * MAX_SCENE_TRIANGLES
"""The most values one array attribute read here may hold (points, face counts and indices,
instance arrays, subsets): a mesh within the scene's triangle budget has at most 3 corners
per triangle. Checked before numpy copies the array (as float64: 24 bytes a point)."""


def usd_type_name(value) -> str:
    """The USD type name of a value, without a role (``int[]``, ``float3[]``), for messages."""
    found = Sdf.GetValueTypeNameForValue(value)
    return str(found) if found else type(value).__name__


def _refused(attribute: Usd.Attribute, value, wanted: str, file: str | None) -> StageError:
    # The type of the strongest opinion, with its role and precision ("point3f[]", "float"),
    # not the schema's (GetTypeName) nor the value's ("float3[]", "double")
    specs = attribute.GetPropertyStack(Usd.TimeCode.Default())
    authored = str(specs[0].typeName) if specs and specs[0].typeName else usd_type_name(value)
    return StageError(f"{attribute.GetName()} is authored as {authored}: it must be {wanted}",
                      file=file, prim=str(attribute.GetPrim().GetPath()))


def checked(value: float, name: str, *, file: str | None, prim: str | None, least: float | None = None,
            most: float | None = None) -> float:
    """``value`` of the attribute or shader input ``name`` of ``prim`` when it is a finite number
    within [least, most] (a bound of None: none); else a StageError naming the file, the prim
    and ``name``, the value found and the range wanted."""
    if math.isfinite(value) and (least is None or value >= least) and (most is None or value <= most):
        return value
    if least is not None and most is not None:
        bound = f"a finite number from {least:g} to {most:g}"
    elif least is not None or most is not None:
        bound = f"a finite number {'≥' if least is not None else '≤'} {least if least is not None else most:g}"
    else:
        bound = "a finite number"
    raise StageError(f"{name} is {value:g}: it must be {bound}", file=file, prim=prim)


def checked_all(values, name: str, *, file: str | None, prim: str | None, least: float | None = None,
                most: float | None = None) -> tuple[float, ...]:
    """:func:`checked` of each number of ``values`` (a colour, a vector), as a tuple of floats."""
    return tuple(checked(float(value), name, file=file, prim=prim, least=least, most=most) for value in values)


def _bounded(attribute: Usd.Attribute, value, file: str | None):
    """``value`` (an array USD returned) unless it holds more than MAX_ARRAY_VALUES values."""
    if len(value) > MAX_ARRAY_VALUES:
        raise StageError(f"{attribute.GetName()} holds {len(value):,} values: more than the {MAX_ARRAY_VALUES:,} "
                         f"an array may hold (3 per triangle of a scene's {MAX_SCENE_TRIANGLES:,})",
                         file=file, prim=str(attribute.GetPrim().GetPath()))
    return value


def real(attribute: Usd.Attribute, time: Usd.TimeCode, file: str | None) -> float | None:
    """A scalar number attribute as a float (None when it has no value); StageError for
    another type. NaN and infinities are returned: what a valid value is, is the caller's."""
    value = attribute.Get(time)
    if value is None:
        return None
    if str(Sdf.GetValueTypeNameForValue(value)) not in (*_REALS, *_INTEGERS):
        raise _refused(attribute, value, "a number", file)
    return float(value)


def reals(attribute: Usd.Attribute, time: Usd.TimeCode, width: int, file: str | None) -> tuple[float, ...] | None:
    """A vector attribute (``float2 clippingRange``) as ``width`` floats, or None; StageError
    for another type."""
    value = attribute.Get(time)
    if value is None:
        return None
    if str(Sdf.GetValueTypeNameForValue(value)) not in tuple(f"{real}{width}" for real in _REALS):
        raise _refused(attribute, value, f"float{width}", file)
    return tuple(float(component) for component in value)


def integer_array(attribute: Usd.Attribute, time: Usd.TimeCode, file: str | None) -> np.ndarray:
    """(n,) int64 of an integer array attribute; empty when it has no value; StageError for
    another type (strings, reals, vectors of integers, a single integer)."""
    value = attribute.Get(time) if attribute else None
    if value is None:
        return np.zeros(0, dtype=np.int64)
    if str(Sdf.GetValueTypeNameForValue(value)) not in tuple(f"{integer}[]" for integer in _INTEGERS):
        raise _refused(attribute, value, "int[]", file)
    return np.asarray(_bounded(attribute, value, file), dtype=np.int64)


def real_array(attribute: Usd.Attribute, time: Usd.TimeCode, width: int, file: str | None,
               wanted: str) -> np.ndarray:
    """(n, width) float64 of an array of ``width``-vectors of reals (of quaternions, as Gf
    stores them: i, j, k, real, when ``wanted`` is a quat type); (0, width) when it has no
    value; StageError for another type.

    wanted : the schema's type, for the message (``point3f[]``, ``float[]``, ``quath[]``)
    """
    value = attribute.Get(time) if attribute else None
    if value is None:
        return np.zeros((0, width))
    if wanted.startswith("quat"):
        elements = ("quath", "quatf", "quatd")
    else:
        elements = _REALS if width == 1 else tuple(f"{real}{width}" for real in _REALS)
    if str(Sdf.GetValueTypeNameForValue(value)) not in tuple(f"{element}[]" for element in elements):
        raise _refused(attribute, value, wanted, file)
    return np.asarray(_bounded(attribute, value, file), dtype=np.float64).reshape(-1, width)
