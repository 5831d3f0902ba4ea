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
* ``kelvin``: null, or a colour temperature from MIN_KELVIN to MAX_KELVIN, passed to the
  grade as it is (its meaning is the grade's)
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import fields

from ..layers.kelvin import KELVIN_MAX, KELVIN_MIN
from ..layers.nuke import LayerGrade, LayerMask
from ..lpe.labels import closest_labels
from ..recipe.model import CRYPTOMATTE_KINDS
from .session import ViewError, _number, _shown, _stops

MAX_TINT = 1e6
"""Largest tint channel a page may send."""
MIN_KELVIN, MAX_KELVIN = KELVIN_MIN, KELVIN_MAX
"""The colour temperatures a grade's ``kelvin`` may take (layers/kelvin.py: where the
Planckian locus a light's colorTemperature follows is defined)."""
MAX_MASK_NAMES = 10_000
"""Most names one mask may list."""


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
    extra = {}
    if entry.get("kelvin") is not None:
        extra["kelvin"] = _kelvin(entry["kelvin"], what)
        if "kelvin" not in {f.name for f in fields(LayerGrade)}:
            raise ViewError(f"{what}: kelvin: this version of pxr-layers does not grade by colour temperature")
    mask = mask_from_json(entry.get("mask"), f"{what}: mask", known)
    return LayerGrade(stops=stops, tint=tint, mask=mask, **flags, **extra)


def _kelvin(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not MIN_KELVIN <= value <= MAX_KELVIN:
        raise ViewError(f"{what}: kelvin is null or a colour temperature from {MIN_KELVIN:g} to {MAX_KELVIN:g} K, "
                        f"not {_shown(value)}")
    return float(value)


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
