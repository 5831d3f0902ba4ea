"""A stack entry the page sends (``/api/save``'s ``layers``) read into a LayerGrade, each
field checked: a mistake is one ViewError line naming the layer and the field.

An entry is ``{"id", "stops", "tint", "mute", "solo", "mask", "kelvin"}``, every field but
the id optional (its default that of LayerGrade):

* ``stops`` : a number within ±MAX_PREVIEW_STOPS
* ``tint``  : three numbers from 0 to MAX_TINT
* ``mute``, ``solo`` : true or false
* ``mask``  : null, or ``{"kind": "object" | "material" | "asset", "names": [name, ...]}``
  (at least one name, as the Cryptomatte manifest of the kind names it: the session's
  ``cryptomattes``)
* ``kelvin``: null, or a colour temperature from KELVIN_MIN to KELVIN_MAX, passed to the
  grade as it is (its meaning is the grade's)
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

from ..layers.kelvin import KELVIN_MAX, KELVIN_MIN, check_kelvin
from ..layers.nuke import LayerGrade, LayerMask
from ..errors import PxrLayersError
from ..lpe.labels import closest_labels
from ..recipe.model import CRYPTOMATTE_KINDS, MAX_PREVIEW_STOPS

MAX_TINT = 1e6
"""Largest tint channel a page may send."""
MAX_MASK_NAMES = 10_000
"""Most names one mask may list."""


class ViewError(PxrLayersError):
    """A request the session cannot serve: ``status`` is its HTTP status (400 a bad request,
    404 an unknown layer, 409 a conflict with what is there); ``position`` the LPE position."""

    def __init__(self, message: str, status: int = 400, position: int | None = None):
        super().__init__(message)
        self.status, self.position = status, position


def _shown(value) -> str:
    """repr(value), cut short: an error message stays one readable line."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _number(value, what: str, low: float, high: float) -> float:
    """`value` as a float within [low, high] (a number of the JSON body, not a bool or a string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        raise ViewError(f"{what} must be a number from {low:g} to {high:g}, not {_shown(value)}")
    return float(value)


def _stops(value, what: str) -> float:
    return _number(value, f"{what} (stops)", -MAX_PREVIEW_STOPS, MAX_PREVIEW_STOPS)


def grade_from_json(entry: dict, what: str, *, known: Mapping[str, Collection[str]] | None = None) -> LayerGrade:
    """The LayerGrade of a page's stack entry. ``what`` names the layer in messages
    (``"layer 'key'"``); ``known``: kind → the names its Cryptomatte has (the session's
    :meth:`~pxr_layers.view.session.Session.mask_names`), when given a mask naming another
    is refused with the nearest names. Raises ViewError (400) naming ``what`` and the field."""
    if not isinstance(entry, dict):
        raise ViewError(f"{what}: a stack entry is an object {{id, stops, tint, mute, solo, mask}}, "
                        f"not {_shown(entry)}")
    stops = _stops(entry.get("stops", 0.0), f"{what}: stops")
    tint = entry.get("tint", [1.0, 1.0, 1.0])
    if not isinstance(tint, list) or len(tint) != 3:
        raise ViewError(f"{what}: tint is three numbers from 0 to {MAX_TINT:g}, not {_shown(tint)}")
    tint = tuple(_number(channel, f"{what}: tint", 0.0, MAX_TINT) for channel in tint)
    flags = {}
    for field in ("mute", "solo"):
        value = entry.get(field, False)
        if not isinstance(value, bool):
            raise ViewError(f"{what}: {field} is true or false, not {_shown(value)}")
        flags[field] = value
    kelvin = None if entry.get("kelvin") is None else _kelvin(entry["kelvin"], what)
    mask = mask_from_json(entry.get("mask"), f"{what}: mask", known)
    return LayerGrade(stops=stops, tint=tint, kelvin=kelvin, mask=mask, **flags)


def _kelvin(value, what: str) -> float:
    """check_kelvin's rule (layers/kelvin.py), as a 400 naming the layer."""
    try:
        return check_kelvin(value)
    except ValueError:
        raise ViewError(f"{what}: kelvin is null or a colour temperature from {KELVIN_MIN:g} to {KELVIN_MAX:g} K, "
                        f"not {_shown(value)}") from None


def mask_from_json(value, what: str, known: Mapping[str, Collection[str]] | None = None) -> LayerMask | None:
    """A stack entry's ``mask`` (null, or {"kind", "names"}) as a LayerMask; else a
    ViewError starting with ``what`` (``"layer 'key': mask"``), also, with ``known``, for a
    kind the render has no Cryptomatte of or a name its Cryptomatte does not know."""
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) - {"kind", "names"}:
        raise ViewError(f"{what} is null or {{\"kind\": {' | '.join(map(repr, CRYPTOMATTE_KINDS))}, "
                        f"\"names\": [...]}}, not {_shown(value)}")
    kind, names = value.get("kind"), value.get("names")
    if kind not in CRYPTOMATTE_KINDS:
        raise ViewError(f"{what} kind {_shown(kind)}: one of {', '.join(CRYPTOMATTE_KINDS)}")
    if not isinstance(names, list) or not names or len(names) > MAX_MASK_NAMES \
            or not all(isinstance(name, str) and name for name in names):
        raise ViewError(f"{what} names are a list of 1 to {MAX_MASK_NAMES} {kind} names (strings), "
                        f"not {_shown(names)}")
    if known is not None:
        check_names(kind, names, known, what)
    return LayerMask(kind, tuple(dict.fromkeys(names)))


def check_names(kind: str, names, known: Mapping[str, Collection[str]], what: str) -> None:
    """ViewError (400) unless the render has a Cryptomatte of ``kind`` knowing every one of
    ``names``: one line naming the first unknown name and the nearest known ones."""
    if kind not in known:
        raise ViewError(f"{what}: the render wrote no {kind} Cryptomatte"
                        + (f" (it has {', '.join(sorted(known))})" if known else " (render with --cryptomatte)"))
    names_known = known[kind]
    for name in names:
        if name not in names_known:
            close = closest_labels(name, names_known)
            hint = f"; nearest: {', '.join(close)}" if close else ""
            raise ViewError(f"{what}: no {kind} {_shown(name)} in the render's Cryptomatte{hint}")
