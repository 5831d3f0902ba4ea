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
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd

from pxr_layers.errors import StageError

_INTEGERS = ("int", "uint", "int64", "uint64", "uchar")
_REALS = ("half", "float", "double")


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
    return np.asarray(value, dtype=np.int64)


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
    return np.asarray(value, dtype=np.float64).reshape(-1, width)
