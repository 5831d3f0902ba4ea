"""A Nuke script (.nk, plain text) that rebuilds a graded stack of layers from a multipart EXR.

The script computes the inspector's composite rule (pxr_layers/view/composite.py), so a
look saved from ``pxr-layers view`` opens in Nuke as it was seen::

    no layer soloed:   out = beauty + Σ_i (w_i − 1) · layer_i
    some layer soloed: out = Σ_{i soloed} w_i · layer_i
    then · 2^exposure

    w_i = 1 + m_i · (g_i − 1),  g_i = 2^stops_i · tint_i (0 if muted),  m_i the mask (1 without)

as a graph a compositor knows (Nuke's stack syntax: a node takes its inputs from the top of
the stack, input 0 = B from the top; ``set N [stack 0]`` names the top, ``push $N`` pushes
it again)::

    Read ─┬─ Shuffle_<layer> (in <layer>, alpha black) ─ Grade_<layer> (multiply 2^stops·tint) ─┐ A
          │                                                                                     │
          ├─ Grade Black_base ─ Merge2 plus Rest ─ Merge2 plus Merge_<layer> ─ … ─ Grade Exposure
          │   (rgb × 0, the     (rgb only) │ A      B
          │   beauty's alpha)              │
          └─ Merge2 from Rest_of_beauty ───┘   beauty − Σ ungraded layers; both only when the
                                               layers do not partition the beauty

Each layer is added by its own ``Merge2 operation plus``; a muted layer, and when some
layer is soloed every other layer and the rest branch, has that Merge disabled (a disabled
Merge passes B, the trunk, through): its Grade keeps the artist's values and enabling the
Merge brings it back. When the layers partition the beauty there is no rest branch (their
sum is the beauty, :func:`pxr_layers.layers.previews.layers_partition`); otherwise the rest
makes unit gains give the beauty again (exactly but for float32 rounding of the
subtraction and the sums). The trunk starts from the beauty with black RGB, so the result
carries the beauty's alpha (every layer's alpha is black) and a disabled first Merge still
leaves a black base.

A masked layer (LayerGrade.mask) gets a Cryptomatte gizmo of its own on the Read,
``Mask_<layer>`` (``cryptoLayer`` the mask kind's Cryptomatte layer, ``matteList`` the
mask's names, :func:`matte_list`), wired to its Grade's mask input (``inputs 1+1``,
``maskChannelInput rgba.alpha``): Nuke's Grade blends graded and ungraded by the mask,
layer + m·(g·layer − layer) = w·layer, the composite's weight. Its Merge is as any other's,
but a muted masked layer keeps its Merge enabled and grades by 0 (the layer taken away
inside its mask only, as the composite does). The keyer reads the Cryptomatte from the same
Read: a look saved with masks writes the Cryptomattes they key into its EXR.

Knobs and node types are those of every Nuke since 12.0 (the classic Shuffle, not
Shuffle2). Every Grade has ``black_clamp false`` (Nuke's default clamps negatives to 0,
which the composite does not do). Nuke reads our channels ``NAME.R/G/B`` as the layer
``NAME`` with channels ``NAME.red/green/blue`` and part 0's ``R G B A`` as ``rgba``
(its exrReader takes the layer from the channel name whenever a channel name holds a
``.``, and maps R, G, B, A to red, green, blue, alpha); ``add_layer`` declares each layer so
the Shuffles parse before the Read has opened the file. Layers that Nuke would read as
something else are refused: its own layers (``rgb``, ``alpha``, ``depth``, ...), ``main``
(the default view) and ``Ci`` (RenderMan's beauty, read into ``rgba``).

Cryptomatte layers (``cryptomattes``: NAME → depth, its parts ``NAME00``, ``NAME01``, ...) get a
Cryptomatte node each (Psyop's gizmo, ``nuke/Cryptomatte.gizmo``) on the Read, beside the
trunk: ``cryptoLayer`` NAME with ``cryptoLayerLock`` so the gizmo keeps it, its hidden
``in00`` ... knobs naming the parts as its own update would, and an empty ``matteList`` for
the artist to pick names into (a comma-separated list; the gizmo writes the matte into
alpha). The gizmo finds the manifest in the Read's metadata, i.e. part 0's header.

The Root sets Nuke's own colour management with the nuke-default config, whose ``linear``
is the EXR's colour space (linear, Rec.709 primaries), so the Read converts nothing; the
inspector's OCIO display and view are for the viewer to choose.

A .nk is a Tcl script, so every string in it is written by :func:`tcl_word` (its comment by
:func:`tcl_escaped`): no file name can end a word, a node block or the comment early, nor
substitute anything, and a part or Cryptomatte name is an identifier (``LAYER_NAME``, whole).
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from .. import __version__
from ..errors import OutputError
from ..outputs import check_output, write_atomically
from ..recipe.model import BEAUTY_PART, CRYPTOMATTE_KINDS, LAYER_NAME, MAX_CRYPTOMATTE_DEPTH, cryptomatte_parts
from .kelvin import blackbody, check_kelvin
from .previews import layers_partition

logger = logging.getLogger(__name__)

NUKE_SCRIPT_SUFFIX = ".nk"
"""A Nuke script's file name ends so (Nuke's File > Open lists only these)."""
NUKE_VERSION = "12.0 v1"
"""The oldest Nuke the script is written for (its ``version`` line)."""
NUKE_RESERVED_LAYERS = frozenset({"rgba", "rgb", "alpha", "depth", "motion", "forward", "backward", "mask",
                                  "mask_extra", "main", "Ci"})
"""Part names Nuke does not read as a layer of their own: its built-in layers, the default
view ``main`` and RenderMan's ``Ci`` (both read into ``rgba``)."""
_COLUMN = 150  # node graph spacing, Nuke units
_ROW = 80


@dataclass(frozen=True)
class LayerMask:
    """Where a layer's grade applies: the objects, materials or assets ``names`` (as the
    Cryptomatte manifest of ``kind`` names them: prim paths, material paths, model roots),
    keyed from the render's Cryptomatte of that kind (CRYPTOMATTE_KINDS: object, material,
    asset). Its matte m (layers.cryptomatte.coverage) makes the layer's weight
    1 + m·(gain·tint − 1): the grade inside, unity outside (view/composite.py)."""

    kind: str
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        if self.kind not in CRYPTOMATTE_KINDS:
            raise ValueError(f"a mask's kind is one of {', '.join(CRYPTOMATTE_KINDS)}, not {self.kind!r}")
        if isinstance(self.names, str) or not self.names or not all(isinstance(n, str) and n for n in self.names):
            raise ValueError(f"a mask names at least one {self.kind} (non-empty strings), not {self.names!r}")
        object.__setattr__(self, "names", tuple(self.names))

    @property
    def source(self) -> str:
        """The Cryptomatte source of the kind (``CryptoObject``, ...): the layer a saved look writes."""
        return CRYPTOMATTE_KINDS[self.kind]


@dataclass(frozen=True)
class LayerGrade:
    """How the inspector shows one layer.

    stops : exposure in stops (gain 2^stops)
    tint  : linear RGB multiplier, each >= 0
    mute  : the layer counts with gain 0
    solo  : when any layer is soloed, only the soloed layers (not muted) are shown
    kelvin: None (off), or a colour temperature in K (layers/kelvin.py's range): the layer
            is multiplied by the blackbody colour a UsdLux light of that temperature has
    mask  : the grade applies where the mask's names are (their Cryptomatte coverage m), unity elsewhere
    """

    stops: float = 0.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    mute: bool = False
    solo: bool = False
    kelvin: float | None = None
    mask: LayerMask | None = None

    def __post_init__(self):
        object.__setattr__(self, "kelvin", check_kelvin(self.kelvin))

    @property
    def multiply(self) -> tuple[float, float, float]:
        """The Grade's multiply: 2^stops · tint · blackbody(kelvin) (the mute is the disabled
        Merge, not this)."""
        gain = 2.0 ** self.stops
        temperature = (1.0, 1.0, 1.0) if self.kelvin is None else blackbody(self.kelvin)
        return tuple(gain * float(channel) * warmth for channel, warmth in zip(self.tint, temperature, strict=True))


def nuke_script(exr_path: str | os.PathLike, parts: Sequence[str], grades: Mapping[str, LayerGrade], *,
                resolution: tuple[int, int], partition: bool, beauty_part: str = BEAUTY_PART,
                exposure: float = 0.0, cryptomattes: Mapping[str, int] | None = None,
                pixel_aspect_ratio: float = 1.0, mask_layers: Mapping[str, str] | None = None) -> str:
    """The text of a Nuke script rebuilding ``parts`` of ``exr_path`` graded by ``grades``.

    exr_path    : the Read's file: relative (to the script's folder, read through
                  ``[file dirname [value root.name]]``) or absolute
    parts       : the layer parts, in stack order (each a colour layer ``NAME.R/G/B``)
    grades      : part → its grade; a part without one is ungraded (LayerGrade())
    resolution  : (width, height) in pixels, the Root's and the Read's format
    pixel_aspect_ratio : a pixel's width over its height (the EXR's), that format's pixel aspect
    partition   : the parts sum to the beauty (no rest branch)
    beauty_part : the Nuke layer of the beauty: ``rgba`` (part 0 ``R G B A``), or another
                  part, shuffled out like a layer
    exposure    : stops of the final Grade (the inspector's viewing exposure)
    cryptomattes: Cryptomatte layer name → its depth (ranks): a Cryptomatte gizmo on the Read for each
    mask_layers : mask kind (LayerMask.kind) → the Cryptomatte layer of ``cryptomattes`` a
                  masked grade of that kind is keyed from; by default the kind's source
                  (``CryptoObject``, ...), the name a saved look gives it

    Raises OutputError for a part Nuke would not read as its own layer, a part given twice,
    a grade that is not finite, or a mask whose Cryptomatte is not in ``cryptomattes`` or
    whose names the gizmo's matte list cannot hold; ValueError for a grade of a part not in
    ``parts``.
    """
    parts = list(parts)
    cryptomattes = dict(cryptomattes or {})
    mask_layers = {**CRYPTOMATTE_KINDS, **(mask_layers or {})}
    _check(parts + [part for name, depth in cryptomattes.items() for part in cryptomatte_parts(name, depth)],
           grades, beauty_part, exposure)
    masks = {part: grade.mask for part, grade in grades.items() if grade.mask is not None}
    for part, mask in masks.items():
        if mask_layers.get(mask.kind) not in cryptomattes:
            raise OutputError(f"Nuke script: the mask of {part!r} keys the {mask.kind} Cryptomatte "
                              f"{mask_layers.get(mask.kind)!r}, which the EXR does not hold "
                              f"(it holds {', '.join(cryptomattes) or 'no Cryptomatte'})")
    for name, depth in cryptomattes.items():
        if not LAYER_NAME.fullmatch(name) or not 1 <= depth <= MAX_CRYPTOMATTE_DEPTH:
            raise OutputError(f"Nuke script: the Cryptomatte {name!r} of depth {depth} is not one the gizmo keys "
                              f"(a name Nuke keeps, 1 to {MAX_CRYPTOMATTE_DEPTH} ranks: "
                              f"{len(cryptomatte_parts(name, MAX_CRYPTOMATTE_DEPTH))} parts)")
    width, height = (int(value) for value in resolution)
    writer = _Script()
    writer.comment(f"pxr-layers {__version__}: {len(parts)} layers of {os.fspath(exr_path)} graded as in "
                   "`pxr-layers view`")
    writer.line(f"version {NUKE_VERSION}")
    aspect = f"{pixel_aspect_ratio:g}"
    format_name = f"pxrLayers_{width}x{height}" + ("" if aspect == "1" else f"_par{aspect.replace('.', 'p')}")
    frame_format = f"{width} {height} 0 0 {width} {height} {aspect} {format_name}"
    writer.node("Root", {"inputs": "0", "first_frame": "1", "last_frame": "1", "format": frame_format,
                         "colorManagement": "Nuke", "OCIO_config": "nuke-default", "workingSpaceLUT": "linear"})
    for part in parts:
        writer.add_layer(part, ("red", "green", "blue"))
    if beauty_part != BEAUTY_PART:
        writer.add_layer(beauty_part, ("red", "green", "blue", "alpha"))
    for name, depth in cryptomattes.items():
        for part in cryptomatte_parts(name, depth):
            writer.add_layer(part, ("red", "green", "blue", "alpha"))

    writer.node("Read", {"inputs": "0", "file_type": "exr", "file": _file_knob(exr_path),
                         "format": f"{width} {height} 0 0 {width} {height} {aspect} ", "first": "1",
                         "last": "1", "origfirst": "1", "origlast": "1", "origset": "true",
                         "colorspace": "linear", "name": "Read_layers", "xpos": "0", "ypos": "0"})
    writer.set("Read_layers")
    beauty = "Read_layers"
    if beauty_part != BEAUTY_PART:  # its own alpha: the classic Shuffle's default
        beauty = "Beauty"  # not Shuffle_…: no layer's node can take its name
        writer.node("Shuffle", {"in": beauty_part, "name": beauty, **_at(-1, 1)})
        writer.set(beauty)
    for column, part in enumerate(parts, start=1):
        writer.push("Read_layers")
        writer.node("Shuffle", {"in": part, "alpha": "black", "name": f"Shuffle_{part}", **_at(column, 1)})
        writer.set(f"Shuffle_{part}")

    for column, (name, depth) in enumerate(cryptomattes.items(), start=len(parts) + 1):
        writer.push("Read_layers")
        inputs = {f"in{number:02d}": part for number, part in enumerate(cryptomatte_parts(name, depth))}
        writer.node("Cryptomatte", {"name": f"Cryptomatte_{name}", "cryptoLayer": name, "cryptoLayerLock": "true",
                                    "matteList": "", **inputs, **_at(column, 1)})

    # A masked layer's keyer: the gizmo's matte of the mask's names, in alpha, for its Grade's mask input.
    for column, part in enumerate(parts, start=1):
        mask = masks.get(part)
        if mask is None:
            continue
        name = mask_layers[mask.kind]
        writer.push("Read_layers")
        inputs = {f"in{number:02d}": layer for number, layer in enumerate(cryptomatte_parts(name, cryptomattes[name]))}
        writer.node("Cryptomatte", {"name": f"Mask_{part}", "label": f"mask of {part}: {mask.kind}",
                                    "cryptoLayer": name, "cryptoLayerLock": "true",
                                    "matteList": matte_list(mask.names), **inputs, **_at(column, 2)})
        writer.set(f"Mask_{part}")

    soloing = any(grades.get(part, LayerGrade()).solo for part in parts)
    if not partition:
        # The rest: beauty − ((l0 + l1) + l2 ...), the ungraded layers taken off the beauty.
        if parts:
            writer.push(f"Shuffle_{parts[0]}")
            for column, part in enumerate(parts[1:], start=2):
                writer.push(f"Shuffle_{part}")
                writer.node("Merge2", {"inputs": "2", "operation": "plus", "name": f"Sum_{part}",
                                       **_at(column, 2)})
        writer.push(beauty)
        if parts:
            writer.node("Merge2", {"inputs": "2", "operation": "from", "name": "Rest_of_beauty",
                                   "label": "beauty - the sum of the ungraded layers", **_at(1, 3)})
    writer.push(beauty)
    writer.node("Grade", {"multiply": _vector(0, 0, 0, 1), "black_clamp": "false", "name": "Black_base",
                          "label": "black rgb, the beauty's alpha", **_at(0, 4)})
    trunk = "Black_base"
    if not partition:  # B: the black base on top; A: the rest beneath it
        # On rgb only: the rest's alpha is the beauty's too, and the base already holds it.
        trunk = "Rest"
        writer.node("Merge2", {"inputs": "2", "operation": "plus", "Achannels": "rgb", "Bchannels": "rgb",
                               "output": "rgb", **_disabled(soloing), "name": trunk, **_at(0, 5)})
    writer.set(trunk)

    for column, part in enumerate(parts, start=1):
        grade = grades.get(part, LayerGrade())
        if grade.mask is None:
            writer.push(f"Shuffle_{part}")
            writer.node("Grade", {"multiply": _vector(*grade.multiply, 1.0), "black_clamp": "false",
                                  "name": f"Grade_{part}", **_at(column, 5 + column)})
        else:  # graded inside the mask, as is outside: the weight 1 + m·(gain − 1); muted: gain 0
            writer.push(f"Mask_{part}")
            writer.push(f"Shuffle_{part}")
            multiply = (0.0, 0.0, 0.0) if grade.mute else grade.multiply
            writer.node("Grade", {"inputs": "1+1", "multiply": _vector(*multiply, 1.0), "black_clamp": "false",
                                  "maskChannelInput": "rgba.alpha", "name": f"Grade_{part}",
                                  **({"label": "muted inside the mask"} if grade.mute else {}),
                                  **_at(column, 5 + column)})
        writer.push(trunk)
        # a muted layer adds nothing, but a masked one still adds itself outside its mask
        off = (grade.mute and grade.mask is None) or (soloing and not grade.solo)
        trunk = f"Merge_{part}"
        writer.node("Merge2", {"inputs": "2", "operation": "plus", **_disabled(off), "name": trunk,
                               **_at(0, 5 + column)})
        writer.set(trunk)
    writer.node("Grade", {"multiply": _vector(*(2.0 ** exposure,) * 3, 1.0), "black_clamp": "false",
                          "name": "Exposure", "label": f"viewing exposure {exposure:+g} stops",
                          **_at(0, 6 + len(parts))})
    return writer.text()


def write_nuke_script(path: str | os.PathLike, exr_path: str | os.PathLike, parts: Sequence[str],
                      grades: Mapping[str, LayerGrade], *, resolution: tuple[int, int], partition: bool,
                      beauty_part: str = BEAUTY_PART, exposure: float = 0.0,
                      cryptomattes: Mapping[str, int] | None = None, pixel_aspect_ratio: float = 1.0,
                      mask_layers: Mapping[str, str] | None = None) -> Path:
    """Write :func:`nuke_script` at ``path`` (atomically); returns where the file is now
    (its temporary while an OutputSet holds it).

    ``exr_path`` is the EXR as this process sees it (absolute, or relative to the working
    directory); the script reads it relative to its own folder when it lies in that folder
    or below (the two can move together), else by its absolute path: either way the script
    opens from any working directory. Both folders are compared as the file system has them
    (links and ``..`` resolved), so ``out/../out/x.exr`` is beside ``out/x.nk``.

    Raises OutputError when ``path`` does not end in NUKE_SCRIPT_SUFFIX or cannot be
    written (:func:`~pxr_layers.outputs.check_output`).
    """
    path = check_output(path, "Nuke script", (NUKE_SCRIPT_SUFFIX,))
    exr = Path(exr_path)
    exr = exr.parent.resolve() / exr.name  # the folder resolved, not the file: a link to an EXR stays the link
    folder = path.parent.resolve()  # likewise: Nuke's root.name is the script as opened
    file_name = exr.relative_to(folder) if exr.is_relative_to(folder) else exr
    text = nuke_script(file_name, parts, grades, resolution=resolution, partition=partition,
                       beauty_part=beauty_part, exposure=exposure, cryptomattes=cryptomattes,
                       pixel_aspect_ratio=pixel_aspect_ratio, mask_layers=mask_layers)
    written = write_atomically(path, lambda temporary: temporary.write_text(text, encoding="utf-8"))
    logger.info("wrote the Nuke script %s: %d layers of %s", path, len(parts), exr)
    return written


def write_product_script(path: str | os.PathLike, exr_path: str | os.PathLike, beauty, colour: Mapping,
                         cryptomattes: Mapping[str, int], pixel_aspect_ratio: float = 1.0) -> Path:
    """The script of a whole product at ``path`` with unit grades (what ``pxr-layers nuke``
    and ``--nuke-script`` write): ``beauty`` (h, w, ≥3) its part 0, ``colour`` its colour
    layers in part order (name → (h, w, ≥3)), ``cryptomattes`` its Cryptomatte layers'
    depths, ``pixel_aspect_ratio`` its pixels' width over height. Returns where the file is
    now, as :func:`write_nuke_script`."""
    height, width = beauty.shape[:2]
    return write_nuke_script(path, exr_path, list(colour), {}, resolution=(width, height),
                             partition=layers_partition(beauty, [image[..., :3] for image in colour.values()]),
                             cryptomattes=cryptomattes, pixel_aspect_ratio=pixel_aspect_ratio)


MATTE_LIST_REFUSED = frozenset('\\*?[]"')
"""Characters of a name the gizmo's matte list reads as an escape, a quote or a wildcard
(cryptomatte_utilities.StringEncoder): a mask naming one is refused (USD paths have none)."""


def matte_list(names: Sequence[str]) -> str:
    """The Cryptomatte gizmo's ``matteList`` of ``names``: comma-and-space separated, a name
    holding a space or a comma double-quoted (the gizmo's own encoding). Raises OutputError
    for a name with a character of MATTE_LIST_REFUSED."""
    words = []
    for name in names:
        refused = sorted(set(name) & MATTE_LIST_REFUSED)
        if refused:
            raise OutputError(f"Nuke script: the mask name {name!r} holds {' '.join(refused)}, which the "
                              "Cryptomatte gizmo's matte list reads as escapes or wildcards")
        words.append(f'"{name}"' if " " in name or "," in name else name)
    return ", ".join(words)


def _check(parts: list[str], grades: Mapping[str, LayerGrade], beauty_part: str, exposure: float) -> None:
    for part in [*parts, beauty_part]:
        if not LAYER_NAME.fullmatch(part):  # Nuke drops leading digits and turns other characters into _
            raise OutputError(f"Nuke script: the part {part!r} is not a name Nuke keeps as a layer "
                              "(letters, digits, _; not starting with a digit)")
    for part in parts:
        if part in NUKE_RESERVED_LAYERS:
            raise OutputError(f"Nuke script: Nuke does not read a part named {part!r} as a layer of its own "
                              "(it is one of Nuke's layers, its default view, or RenderMan's beauty): "
                              "rename the layer")
        if part == beauty_part:
            raise OutputError(f"Nuke script: the part {part!r} is the beauty, not a layer")
        if parts.count(part) > 1:
            raise OutputError(f"Nuke script: the part {part!r} is given twice")
    unknown = sorted(set(grades) - set(parts))
    if unknown:
        raise ValueError(f"grades of parts that are not in the stack: {', '.join(unknown)}")
    for part, grade in grades.items():
        if not math.isfinite(grade.stops) or len(grade.tint) != 3 or not all(
                math.isfinite(c) and c >= 0 for c in grade.tint):
            raise OutputError(f"Nuke script: the grade of {part!r} must have finite stops and three finite "
                              f"tints >= 0, not stops {grade.stops}, tint {tuple(grade.tint)}")
    if not math.isfinite(exposure):
        raise OutputError(f"Nuke script: the exposure must be finite, not {exposure}")


class _Script:
    """Lines of a .nk script, with Nuke's node block and stack command syntax."""

    def __init__(self) -> None:
        self._lines: list[str] = []

    def line(self, text: str) -> None:
        self._lines.append(text)

    def comment(self, text: str) -> None:
        """A ``#`` line: its text escaped as in a word, so no newline (nor a backslash before
        the line's end, which would continue it) ends the comment early."""
        self._lines.append(f"# {tcl_escaped(text)}")

    def add_layer(self, layer: str, channels: Sequence[str]) -> None:
        self.line("add_layer " + _list([layer, *(f"{layer}.{channel}" for channel in channels)]))

    def node(self, kind: str, knobs: Mapping[str, str | _Vector]) -> None:
        """A node block; each knob's value a string (written by :func:`tcl_word`) or a vector."""
        self._lines.append(f"{_identifier(kind)} {{")
        self._lines.extend(f" {_identifier(name)} {_list(value) if isinstance(value, _Vector) else tcl_word(value)}"
                           for name, value in knobs.items())
        self._lines.append("}")

    def set(self, name: str) -> None:
        self._lines.append(f"set N_{_identifier(name)} [stack 0]")

    def push(self, name: str) -> None:
        self._lines.append(f"push $N_{_identifier(name)}")

    def text(self) -> str:
        return "\n".join(self._lines) + "\n"


def _at(column: int, row: int) -> dict[str, str]:
    return {"xpos": str(column * _COLUMN), "ypos": str(row * _ROW)}


def _disabled(off: bool) -> dict[str, str]:
    return {"disable": "true"} if off else {}


def _number(value: float) -> str:
    """Shortest text that reads back as the same double (``1``, ``0.5``, ``1.4142135623730951``)."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


class _Vector(tuple):
    """A knob's numbers, written as a braced Tcl list ``{1 0.5 2 1}``."""


def _vector(*values: float) -> _Vector:
    return _Vector(_number(value) for value in values)


_BARE = re.compile(r"[A-Za-z0-9_.+-]+")
"""Words written as they are: nothing in them is special to Tcl, in a script or a list."""
_SPECIAL = re.compile(r'[\\"$\[{}]|[^\S ]|[\x00-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]')
"""What :func:`tcl_escaped` escapes: backslash, quote, ``$``, ``[``, braces, and every
character that is not a printing one or a space (newlines, tabs, other whitespace,
controls, Unicode line and paragraph separators, lone surrogates)."""
_ESCAPES = {"\n": r"\n", "\r": r"\r", "\t": r"\t"}


def tcl_escaped(text: str) -> str:
    r"""``text`` with every character special to Tcl backslash-escaped: what goes between a
    Tcl word's double quotes, or into text Tcl substitutes (``subst``, a Nuke file knob),
    to read back as ``text`` exactly.

    ``\ " $ [ { }`` get a backslash (braces too, so they never count in the braces of the
    node block around a knob); newline, carriage return and tab become ``\n \r \t``, any
    other whitespace, control or line-breaking character ``\uXXXX`` (four digits: read alike
    by every Tcl since 8.0). ``]`` is left as is: it ends nothing outside a ``[...]``. Other
    characters, spaces and non-ASCII letters included, stay as they are."""
    def escape(match: re.Match) -> str:
        character = match.group()
        if character in _ESCAPES:
            return _ESCAPES[character]
        return "\\" + character if character in '\\"$[{}' else f"\\u{ord(character):04x}"
    return _SPECIAL.sub(escape, text)


def tcl_word(text: str) -> str:
    """``text`` as one Tcl word that reads back as exactly ``text``, with no substitution, in
    a script (a command's argument, a knob line) as in a list (a node block's body): bare
    when it is only letters, digits and ``_ . + -``, else double-quoted with
    :func:`tcl_escaped`."""
    return text if _BARE.fullmatch(text) else f'"{tcl_escaped(text)}"'


def _list(words: Sequence[str]) -> str:
    """A braced Tcl list of ``words`` (each by :func:`tcl_word`)."""
    return "{" + " ".join(tcl_word(word) for word in words) + "}"


def _identifier(name: str) -> str:
    """A node kind, knob or node name as is: these are always identifiers (part names are
    checked by :func:`_check`)."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ValueError(f"Nuke script: {name!r} is not an identifier")
    return name


def _file_knob(exr_path: str | os.PathLike) -> str:
    """The Read's ``file``: an absolute path as is, a relative one after the script's folder
    (``[file dirname [value root.name]]``, evaluated by Nuke when it reads the file).

    Nuke substitutes a file knob's value as Tcl (``[...]``, ``$``, backslashes) when it opens
    the file, so the path in it is escaped (:func:`tcl_escaped`) to come out of that as it is;
    the knob's value is then written as a word like any other."""
    path = Path(exr_path)
    escaped = tcl_escaped(path.as_posix())
    return escaped if path.is_absolute() else "[file dirname [value root.name]]/" + escaped
