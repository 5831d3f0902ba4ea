"""The inspector's working state, kept beside the render: ``TITLE.view.json``.

The page (static/document.js) holds the document and sends it whole after every edit
(PUT /api/document); the server checks it here and writes it atomically; on a reload, and
when the view is opened again, /api/session gives it back. Saving a look writes the look's
own document, ``NAME.view.json``, so that opening ``NAME.exr`` shows exactly what was saved.

The document (every field required, nothing else)::

    {"format": 1, "exposure": stops,
     "entries": [ENTRY, ...],                       # the stack, beauty first
     "snapshots": [{"name", "exposure", "entries": [ENTRY, ...]}, ...],
     "saved": null | {"name", "exposure", "entries"},  # the last saved look's grades
     "view": {"fit": bool, "scale": device px per image px, "cx", "cy": image point at the centre (0..1)},
     "compare": {"mode": "one" | "wipe" | "side", "against": "beauty" | "saved" | "snapshot:N", "wipe": 0..1},
     "denoised": bool,
     "display_view": null | a view of the products' display (null: the products' own)}

    ENTRY = {"id": unique key, "source": the server layer it shows, "name": its layer name,
             "kind": "beauty" | "layer", "expression": LPE or "", "group": "" or a name,
             "note": "" or a line saying what it holds (a suggested layer's explanation),
             "stops", "tint": [r, g, b], "kelvin": null | K, "mute", "solo",
             "mask": null | {"kind", "names": [...]}}
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

from ..errors import PxrLayersError
from ..outputs import write_atomically
from ..recipe.model import CRYPTOMATTE_KINDS, LAYER_NAME, MAX_PREVIEW_STOPS
from ..layers.kelvin import KELVIN_MAX, KELVIN_MIN
from .grades import MAX_MASK_NAMES, MAX_TINT

log = logging.getLogger(__name__)

SUFFIX = ".view.json"
FORMAT = 1
MAX_ENTRIES = 256
MAX_SNAPSHOTS = 64
MAX_TEXT = 200
"""Longest id, source, snapshot or group name (characters)."""
MAX_EXPRESSION = 4096
MAX_NOTE = 1000
COMPARE_MODES = ("one", "wipe", "side")
ENTRY_KEYS = {"id", "source", "name", "kind", "expression", "group", "note", "stops", "tint", "kelvin", "mute", "solo",
              "mask"}
DOCUMENT_KEYS = {"format", "exposure", "entries", "snapshots", "saved", "view", "compare", "denoised", "display_view"}


class DocumentError(PxrLayersError):
    """A document that is not one: its message names the field."""


def document_path(folder: Path, title: str) -> Path:
    return folder / f"{title}{SUFFIX}"


def load(path: Path) -> dict | None:
    """The document at `path`, checked; None when there is none. One that cannot be read is
    a warning naming it (the session starts from the render's own stack), never a failure."""
    if not path.is_file():
        return None
    try:
        return checked(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError, DocumentError) as error:
        log.warning("%s: not read, the stack starts as rendered (%s)", path, str(error).splitlines()[0][:200])
        return None


def write(path: Path, document: dict) -> None:
    """Write `document` (checked) at `path` atomically."""
    text = json.dumps(document, indent=1, allow_nan=False)
    write_atomically(path, lambda temporary: temporary.write_text(text + "\n", encoding="utf-8"))


def checked(document) -> dict:
    """`document` if it is one (module docstring); raises DocumentError naming the field."""
    _object(document, DOCUMENT_KEYS, "the document")
    if document["format"] != FORMAT:
        raise DocumentError(f"format {document['format']!r}: this version reads format {FORMAT}")
    _number(document["exposure"], "exposure", -MAX_PREVIEW_STOPS, MAX_PREVIEW_STOPS)
    entries = _entries(document["entries"], "entries")
    if not entries or entries[0]["kind"] != "beauty" or any(entry["kind"] == "beauty" for entry in entries[1:]):
        raise DocumentError("entries: the beauty first, and only there")
    snapshots = _list(document["snapshots"], "snapshots", MAX_SNAPSHOTS)
    for at, snapshot in enumerate(snapshots):
        _look(snapshot, f"snapshots[{at}]")
    if document["saved"] is not None:
        _look(document["saved"], "saved")
    view = _object(document["view"], {"fit", "scale", "cx", "cy"}, "view")
    _bool(view["fit"], "view.fit")
    _number(view["scale"], "view.scale", 1 / 1024, 1024)
    _number(view["cx"], "view.cx", -16, 16)
    _number(view["cy"], "view.cy", -16, 16)
    compare = _object(document["compare"], {"mode", "against", "wipe"}, "compare")
    if compare["mode"] not in COMPARE_MODES:
        raise DocumentError(f"compare.mode: one of {', '.join(COMPARE_MODES)}, not {_shown(compare['mode'])}")
    _text(compare["against"], "compare.against")
    _number(compare["wipe"], "compare.wipe", 0, 1)
    _bool(document["denoised"], "denoised")
    if document["display_view"] is not None:
        _text(document["display_view"], "display_view")
    return document


def sources(document: dict) -> dict[str, str]:
    """Every server layer the document shows (its entries', its snapshots' and its saved
    look's) → its expression ("" when it has none)."""
    found: dict[str, str] = {}
    looks = [document["entries"], *(snapshot["entries"] for snapshot in document["snapshots"])]
    if document["saved"] is not None:
        looks.append(document["saved"]["entries"])
    for entries in looks:
        for entry in entries:
            found.setdefault(entry["source"], entry["expression"])
    return found


def _look(look, what: str) -> None:
    _object(look, {"name", "exposure", "entries"}, what)
    _text(look["name"], f"{what}.name")
    _number(look["exposure"], f"{what}.exposure", -MAX_PREVIEW_STOPS, MAX_PREVIEW_STOPS)
    _entries(look["entries"], f"{what}.entries")


def _entries(entries, what: str) -> list[dict]:
    entries = _list(entries, what, MAX_ENTRIES)
    ids, names = set(), set()
    for at, entry in enumerate(entries):
        where = f"{what}[{at}]"
        _object(entry, ENTRY_KEYS, where)
        for key in ("id", "source"):
            _text(entry[key], f"{where}.{key}")
        if entry["kind"] not in ("beauty", "layer"):
            raise DocumentError(f"{where}.kind: beauty or layer, not {_shown(entry['kind'])}")
        if entry["kind"] == "layer" and not LAYER_NAME.fullmatch(entry["name"] if isinstance(entry["name"], str) else ""):
            raise DocumentError(f"{where}.name: letters, digits and _, not starting with a digit; not {_shown(entry['name'])}")
        if entry["id"] in ids or entry["name"] in names:
            raise DocumentError(f"{where}: a second entry with the id {entry['id']!r} or the name {entry['name']!r}")
        ids.add(entry["id"])
        names.add(entry["name"])
        if not isinstance(entry["expression"], str) or len(entry["expression"]) > MAX_EXPRESSION:
            raise DocumentError(f"{where}.expression: a string of at most {MAX_EXPRESSION} characters")
        if entry["group"] != "":
            _text(entry["group"], f"{where}.group")
        if entry["note"] != "":
            _text(entry["note"], f"{where}.note", MAX_NOTE)
        _number(entry["stops"], f"{where}.stops", -MAX_PREVIEW_STOPS, MAX_PREVIEW_STOPS)
        tint = entry["tint"]
        if not isinstance(tint, list) or len(tint) != 3:
            raise DocumentError(f"{where}.tint: three numbers >= 0, not {_shown(tint)}")
        for channel in tint:
            _number(channel, f"{where}.tint", 0, MAX_TINT)
        if entry["kelvin"] is not None:
            _number(entry["kelvin"], f"{where}.kelvin", KELVIN_MIN, KELVIN_MAX)
        _bool(entry["mute"], f"{where}.mute")
        _bool(entry["solo"], f"{where}.solo")
        if entry["mask"] is not None:
            mask = _object(entry["mask"], {"kind", "names"}, f"{where}.mask")
            if mask["kind"] not in CRYPTOMATTE_KINDS:
                raise DocumentError(f"{where}.mask.kind: one of {', '.join(CRYPTOMATTE_KINDS)}, not {_shown(mask['kind'])}")
            # no names yet is a mask being picked (save refuses it: view/grades.py)
            for name in _list(mask["names"], f"{where}.mask.names", MAX_MASK_NAMES):
                if not isinstance(name, str) or len(name) > 4096:
                    raise DocumentError(f"{where}.mask.names: names (strings)")
    return entries


def _object(value, keys: set[str], what: str) -> dict:
    if not isinstance(value, dict) or set(value) != keys:
        given = sorted(value) if isinstance(value, dict) else type(value).__name__
        raise DocumentError(f"{what}: an object with exactly {', '.join(sorted(keys))}; got {_shown(given)}")
    return value


def _list(value, what: str, most: int) -> list:
    if not isinstance(value, list) or len(value) > most:
        raise DocumentError(f"{what}: a list of at most {most}")
    return value


def _text(value, what: str, most: int = MAX_TEXT) -> None:
    if not isinstance(value, str) or not value or len(value) > most or not value.isprintable():
        raise DocumentError(f"{what}: 1 to {most} printable characters, not {_shown(value)}")


def _number(value, what: str, low: float, high: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not low <= value <= high:
        raise DocumentError(f"{what}: a number from {low:g} to {high:g}, not {_shown(value)}")


def _bool(value, what: str) -> None:
    if not isinstance(value, bool):
        raise DocumentError(f"{what}: true or false, not {_shown(value)}")


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
