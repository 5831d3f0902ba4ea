"""What to render and how: one :class:`RenderRequest`, declared once.

Every render option is one field of :class:`RenderRequest` declared with :func:`option`:
its type (a :class:`Kind`, which parses and validates it), its default, its help, and the
``pxr-layers render`` flag and the job file key it is set by. :data:`OPTIONS` lists them;
the command line (:func:`pxr_layers.cli.render.add_request_flags`) and the job files
(:mod:`pxr_layers.jobs.definition`) derive their flags, keys, help and error messages from
it, so everything ``render`` can do, ``job run`` can do, with the same defaults and the
same bytes out.

Plain data (no pxr): it travels to Dask workers and into tests as it is.
"""

from __future__ import annotations

import difflib
import math
import os
import re
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

from .errors import RenderSettingsError
from .inputs import input_problem
from .paths.format import SUFFIX as INDEX_SUFFIX
from .recipe.model import (
    COVARIANCE_MODES,
    CRYPTOMATTE_KINDS,
    DEFAULT_CRYPTOMATTE_DEPTH,
    DEFAULT_INDEX_BOUNCES,
    INDEX_MODES,
    MAX_CRYPTOMATTE_DEPTH,
    MAX_INDEX_BOUNCES,
    PER_LIGHT_MODES,
)
from .recipe.presets import PRESETS, preset

DEFAULT_SPP = 64
DEFAULT_MAX_DEPTH = 8
DEFAULT_SEED = 0
NO_CLAMP = 0.0
"""The clamp_indirect value that turns the clamp off: indirect contributions as traced."""
DEFAULT_RESOLUTION = (512, 512)
"""(width, height) in pixels of a stage whose recipe (or lack of one) names no resolution."""
MAX_SPP = 1 << 16
"""Samples per pixel at most (65536: far past convergence; more is a typo)."""
MAX_PIXELS = 1 << 28
"""Pixels of one image at most (16384 × 16384): every per-pixel buffer must fit in memory."""
MAX_DEPTH = 1024
"""Scattering events per path at most (Russian roulette ends paths long before; more is a typo)."""
MAX_SEED = (1 << 64) - 1
"""The largest seed: seeds key 64-bit random streams, so a larger one would wrap silently."""
AUTO_CAMERA_VIEWS = ("front", "three-quarter")
"""How a stage without a camera may be framed (stage/defaults.frame_auto_camera), the default first."""
MAX_SUBDIV_LEVEL = 6
"""Past this a level multiplies a production mesh's triangles by another 4x: a mistake, not a
look (a 100 k-face cage at 6 is 400 M quads)."""
MAX_SUBDIVISION_TRIANGLES = 1 << 22
"""The most triangles a scene's subdivision surfaces are refined to (4,194,304), every placed
copy counted: about 2 GB of render memory (stage.budgets.MAX_SCENE_TRIANGLES says 500 bytes
a triangle). Each level multiplies a mesh's triangles by 4; past the budget the reader lowers
the highest levels first (a dense cage, the OpenChessSet's 20 k-face pieces, is already finer
than a pixel at shot resolution and loses least), with one warning naming them."""
DEFAULT_TEXTURE_MEMORY = 0.25
"""The material textures' default budget (trace/texture_cache.py), a fraction of the machine's
physical memory, at most MAX_DEFAULT_TEXTURE_MIB."""
MAX_DEFAULT_TEXTURE_MIB = 4096
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
AS_AUTHORED = "recipe"
"""The per-light word for "each product's pxrLayers:perLight as authored" (the default)."""


# -- kinds: how one option's value is read from a flag or a job file, and checked -------------


class Kind:
    """How the values of one option are read and checked. Every method raises ValueError
    with a message that fits after the flag or key (``--spp: must be at least 1, not 0``).

    A flag's words that no value of the option could be (not a number, below its minimum,
    an unknown word) are a usage error (exit 2); a value past a stated limit (more samples
    or pixels than a render takes) is refused when the request is made, as a job file's
    is, with one line naming it (exit 1)."""

    metavar = "VALUE"
    nargs: int | None = None

    def from_text(self, text: str) -> Any:
        """A command-line argument (one word; a repeated flag's values are collected)."""
        return self.check(text)

    def from_toml(self, value: Any, base: Path) -> Any:
        """A job file's value (TOML types); relative paths are relative to ``base``."""
        return self.check(value)

    def check(self, value: Any) -> Any:
        """A Python value (the request's field as given) → the field's value."""
        return value

    def describe(self, default: Any) -> str:
        """The default as the help and the docs say it."""
        return "none" if default is None else str(default)


class EntryError(ValueError):
    """A list's entry ``number`` is wrong: ``message`` says how."""

    def __init__(self, number: int, message: str):
        super().__init__(f"[{number}]: {message}")
        self.number, self.message = number, message


def type_name(value: Any) -> str:
    """How an error names the type of a value it refuses (TOML's words: "a table")."""
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "a list",
            tuple: "a list", dict: "a table"}.get(type(value), type(value).__name__)


@dataclass(frozen=True)
class Integer(Kind):
    """A whole number from ``minimum`` to ``maximum`` (None: no limit); ``unit`` follows the
    limit in messages (``must be at most 65536 samples per pixel``)."""

    minimum: int
    maximum: int | None = None
    unit: str = ""
    metavar = "N"

    def from_text(self, text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise ValueError(f"must be an integer, not {text!r}") from None
        self._at_least(value)
        return value  # the maximum: checked by the request (Kind's docstring)

    def check(self, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"must be an integer, not {type_name(value)} ({value!r})")
        self._at_least(value)
        if self.maximum is not None and value > self.maximum:
            raise ValueError(f"must be at most {self.maximum}{self._unit}, not {value}")
        return value

    def _at_least(self, value: int) -> None:
        if value < self.minimum:
            raise ValueError(f"must be at least {self.minimum}, not {value}")

    @property
    def _unit(self) -> str:
        return f" {self.unit}" if self.unit else ""


@dataclass(frozen=True)
class Number(Kind):
    """A finite real number of at least ``minimum`` (an integer is taken as a number)."""

    minimum: float
    metavar = "X"

    def from_text(self, text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"must be a number, not {text!r}") from None
        return self.check(value)

    def check(self, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"must be a number, not {type_name(value)} ({value!r})")
        if not math.isfinite(value):
            raise ValueError(f"must be a finite number, not {value!r}")
        if value < self.minimum:
            raise ValueError(f"must be at least {self.minimum:g}, not {value!r}")
        return float(value)

    def describe(self, default: Any) -> str:
        return f"{default:g}"


@dataclass(frozen=True)
class Switch(Kind):
    """On or off: a flag of its own on the command line (``--strict``, ``--no-index``)."""

    def from_toml(self, value: Any, base: Path) -> bool:
        if not isinstance(value, bool):
            raise ValueError(f"must be true or false, not {type_name(value)} ({value!r})")
        return value

    def check(self, value: Any) -> bool:
        return bool(value)

    def describe(self, default: Any) -> str:
        return "true" if default else "false"


@dataclass(frozen=True)
class Choice(Kind):
    """One word of ``allowed``; ``unset``, when given, is also allowed and means None."""

    allowed: tuple[str, ...]
    unset: str | None = None
    metavar = "WORD"

    def check(self, value: Any) -> str | None:
        if value is None or (self.unset is not None and value == self.unset):
            return None
        if not isinstance(value, str):
            raise ValueError(f"must be a string, not {type_name(value)} ({value!r})")
        if value not in self.allowed:
            words = (*self.allowed, *((self.unset,) if self.unset else ()))
            raise ValueError(f"unknown value {value!r} (allowed: {', '.join(words)})")
        return value

    def describe(self, default: Any) -> str:
        return self.unset if default is None and self.unset else super().describe(default)


_PRIM_PATH = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")


@dataclass(frozen=True)
class PrimPath(Kind):
    metavar = "PRIM"

    def check(self, value: Any) -> str | None:
        if value is None:
            return None
        if not isinstance(value, str):
            raise ValueError(f"must be a string, not {type_name(value)} ({value!r})")
        if not _PRIM_PATH.fullmatch(value):
            raise ValueError(f"not an absolute prim path: {value!r} (e.g. \"/Render/Settings\")")
        return value


@dataclass(frozen=True)
class Resolution(Kind):
    """(width, height) pixels, at most MAX_PIXELS in all."""

    metavar = ("W", "H")
    nargs = 2

    def from_text(self, words: Sequence[str]) -> tuple[int, int]:  # the flag's two words
        try:
            numbers = [int(word) for word in words]
        except ValueError:
            raise ValueError(f"must be two integers W H, not {' '.join(words)!r}") from None
        if min(numbers) <= 0:
            raise ValueError(f"must be positive, not {' '.join(words)}")
        return tuple(numbers)  # MAX_PIXELS: checked by the request (Kind's docstring)

    def check(self, value: Any) -> tuple[int, int] | None:
        if value is None:
            return None
        if (not isinstance(value, (list, tuple)) or len(value) != 2
                or any(isinstance(v, bool) or not isinstance(v, int) for v in value)):
            raise ValueError(f"must be [width, height] in pixels, not {value!r}")
        width, height = int(value[0]), int(value[1])
        if width <= 0 or height <= 0:
            raise ValueError(f"must be positive, not {list(value)!r}")
        try:
            check_work((width, height), 1)
        except RenderSettingsError as error:
            raise ValueError(str(error)) from None
        return width, height


@dataclass(frozen=True)
class Words(Kind):
    """A list: repeated flags on the command line (or one comma-separated flag when
    ``comma``), a TOML list (or one string); ``item`` reads each entry."""

    item: Kind
    comma: bool = False

    @property
    def metavar(self):
        return self.item.metavar

    def from_text(self, text: str) -> tuple:
        if self.comma:
            return self.check([word.strip() for word in text.split(",") if word.strip()] or [text])
        return (self.item.from_text(text),)

    def from_toml(self, value: Any, base: Path) -> tuple:
        entries = [value] if isinstance(value, str) else value
        if not isinstance(entries, list):
            raise ValueError(f"must be a list, not {type_name(value)}")
        if self.comma and len(entries) == 1 and isinstance(entries[0], str) and "," in entries[0]:
            entries = [word.strip() for word in entries[0].split(",") if word.strip()]
        return self._each(entries, lambda entry: self.item.from_toml(entry, base))

    def check(self, value: Any) -> tuple:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise ValueError(f"must be a list, not {type_name(value)}")
        return self._each(value, self.item.check)

    @staticmethod
    def _each(entries, read) -> tuple:
        values = []
        for number, entry in enumerate(entries):
            try:
                values.append(read(entry))
            except ValueError as error:
                raise EntryError(number, str(error)) from None
        return tuple(dict.fromkeys(values))  # once each, in the order given

    def describe(self, default: Any) -> str:
        return "[]" if not default else str(list(default))


@dataclass(frozen=True)
class Variant(Kind):
    metavar = "PRIM:SET=VALUE"

    def check(self, value: Any) -> VariantSelection:
        if isinstance(value, VariantSelection):
            return value
        if not isinstance(value, str):
            raise ValueError(f"must be a \"PRIM:SET=VALUE\" string, not {type_name(value)} ({value!r})")
        try:
            return VariantSelection.parse(value, where="variant")
        except RenderSettingsError as error:
            raise ValueError(str(error)) from None


@dataclass(frozen=True)
class RecipeLayer(Kind):
    """A preset name (no folder, no USD suffix: ``light_passes``) or a USD file. A file that
    is not there is found by :meth:`check`, when the request is made: a user error naming
    it (exit 1), not a usage error."""

    metavar = "RECIPE"

    def from_text(self, text: str) -> Path:
        return recipe_layer(text, Path.cwd())

    def from_toml(self, value: Any, base: Path) -> Path:
        if not isinstance(value, str):
            raise ValueError(f"must be a string (a preset name or a USD file), not {type_name(value)} ({value!r})")
        return self.check(recipe_layer(value, base))

    def check(self, value: Any) -> Path:
        if not isinstance(value, (str, os.PathLike)):
            raise ValueError(f"must be a path, not {type_name(value)} ({value!r})")
        path = Path(os.path.abspath(value))
        problem = input_problem(path, "USD file")  # inputs.py: a FIFO would block the open
        if problem is not None:
            raise ValueError(f"recipe layer {path}: {problem}")
        return path


def is_preset_name(text: str) -> bool:
    """A recipe layer is a preset name when it has no directory and no USD suffix."""
    return "/" not in text and "\\" not in text and not text.lower().endswith(USD_SUFFIXES)


def recipe_layer(text: str, base: Path) -> Path:
    """A recipe layer's text → its file: a preset's, or ``text`` relative to ``base``.
    ValueError for an unknown preset (with the closest name)."""
    if not text.strip():
        raise ValueError("must be a preset name or a USD file, not an empty string")
    if is_preset_name(text):
        if text not in PRESETS:
            close = difflib.get_close_matches(text, list(PRESETS), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ValueError(f"unknown recipe preset {text!r} ({hint}presets: {', '.join(PRESETS)}; "
                             "a file needs a USD suffix such as .usda)")
        return preset(text)
    return (base / Path(text).expanduser()).resolve()


@dataclass(frozen=True)
class Cryptomattes(Kind):
    """object, material, asset → CryptoObject, CryptoMaterial, CryptoAsset."""

    metavar = "TYPES"

    def check(self, value: Any) -> str:
        sources = {**CRYPTOMATTE_KINDS, **{source: source for source in CRYPTOMATTE_KINDS.values()}}
        if not isinstance(value, str) or value not in sources:
            raise ValueError(f"expected a comma-separated list of {', '.join(CRYPTOMATTE_KINDS)}, got {value!r}")
        return sources[value]


# -- the request ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Option:
    """One render option as the command line and the job files know it.

    name : the RenderRequest field; kind : how its values are read and checked
    flag : the ``pxr-layers render`` flag (``--spp``; ``--no-index`` for a switch that is on
           by default); job_key : the job file's dotted key (``render.spp``)
    default : the field's default; default_text : how the help and docs say it
    flag_help : what the flag does, where it turns a switch off (else ``help``)
    """

    name: str
    kind: Kind
    help: str
    flag: str
    job_key: str
    default: Any
    default_text: str
    flag_help: str


def option(default: Any, kind: Kind, help: str, *, flag: str | None = None, job_key: str | None = None,
           default_text: str | None = None, flag_help: str | None = None):
    """A RenderRequest field declared as a render option (see :data:`OPTIONS`). ``flag``
    defaults to ``--NAME`` (``--no-NAME`` for a switch that is on by default), ``job_key``
    to ``render.NAME``, ``default_text`` to the kind's way of saying the default."""
    spec = {"kind": kind, "help": help, "flag": flag, "job_key": job_key, "default_text": default_text,
            "flag_help": flag_help}
    if isinstance(default, (tuple, list)):
        return field(default=tuple(default), metadata={"option": spec})
    return field(default=default, metadata={"option": spec})


@dataclass(frozen=True)
class VariantSelection:
    """``PRIM:SET=VALUE``: select ``value`` in the variant set ``variant_set`` of ``prim``."""

    prim: str
    variant_set: str
    value: str

    _SYNTAX = re.compile(r"(?P<prim>/[^:=]*):(?P<set>[^:=/]+)=(?P<value>[^=]*)")

    @classmethod
    def parse(cls, text: str, *, where: str = "--variant") -> VariantSelection:
        """``"/World/Teapot:modelVariant=Fancy"`` → the selection; RenderSettingsError when
        it is not of that form (``where`` names the flag or job key in the message)."""
        match = cls._SYNTAX.fullmatch(text.strip())
        if match is None:
            raise RenderSettingsError(f"{where} {text!r}: expected PRIM:SET=VALUE, e.g. /World/Teapot:modelVariant=Fancy")
        return cls(match["prim"].rstrip("/") or "/", match["set"], match["value"])

    def __str__(self) -> str:
        return f"{self.prim}:{self.variant_set}={self.value}"


@dataclass(frozen=True)
class RenderRequest:
    """A shot render, before the stage is read: ``stage`` and every render option (see
    :data:`OPTIONS`: each field's help says what it does)."""

    stage: Path
    recipe_layers: tuple[Path, ...] = option(
        (), Words(RecipeLayer()), "a USD layer recipe composed over the stage (a file, or a preset name: "
        f"{', '.join(PRESETS)}); repeat for more, the first is the strongest", flag="--recipe",
        job_key="recipe.layers")
    variants: tuple[VariantSelection, ...] = option(
        (), Words(Variant()), "select a variant, e.g. /World/Teapot:modelVariant=Fancy; repeat for more",
        flag="--variant", job_key="variants")
    settings: str | None = option(
        None, PrimPath(), "the RenderSettings prim to use (default: the renderSettingsPrimPath of the last "
        "recipe layer that sets one, else the stage's, else its only RenderSettings prim)",
        job_key="settings", default_text="the recipe's")
    camera: str | None = option(
        None, PrimPath(), "camera prim path (default: the recipe's camera, else the stage's first, else an "
        "automatic one that frames the stage)", default_text="the recipe's")
    per_light: str | None = option(
        None, Choice(PER_LIGHT_MODES, unset=AS_AUTHORED), "per-light layers for every product: none, lights "
        "(one layer per light) or groups (one per pxrLayers:lightGroup); recipe: each product's "
        "pxrLayers:perLight as authored", job_key="recipe.per_light")
    resolution: tuple[int, int] | None = option(
        None, Resolution(), f"image size in pixels (default: the recipe's, else {DEFAULT_RESOLUTION[0]} "
        f"{DEFAULT_RESOLUTION[1]}; at most {MAX_PIXELS:,} pixels)", default_text="the settings'")
    spp: int = option(DEFAULT_SPP, Integer(1, MAX_SPP, "samples per pixel"), f"samples per pixel, at most {MAX_SPP}")
    max_depth: int = option(DEFAULT_MAX_DEPTH, Integer(0, MAX_DEPTH),
                            f"most scattering events per path; 1 = direct light only (at most {MAX_DEPTH})")
    seed: int = option(DEFAULT_SEED, Integer(0, MAX_SEED),
                       "random seed (with the frame, pixel and sample, it keys every random stream)")
    clamp_indirect: float = option(
        NO_CLAMP, Number(0.0), "firefly clamp: each indirect contribution (light arriving after a bounce past "
        "the first visible hit; direct light and emitters seen directly are never clamped) is scaled down, all "
        "three channels alike, so that its largest channel is at most this value; the beauty, the path index "
        "and every layer cut from it see the clamped light (biased: darker, less noisy); 0 = off",
        default_text="0 (off)")
    norm_bounces: int | None = option(
        None, Integer(0, MAX_INDEX_BOUNCES), "events per path (camera side) whose covariance norms C, T, R "
        f"the path index keeps (default: the products' pxrLayers:index:bounces, else {DEFAULT_INDEX_BOUNCES}, "
        "raised to the max depth when a layer has a covariance condition; none with --no-index and no condition, "
        f"which nothing would read; 0: none; at most {MAX_INDEX_BOUNCES})",
        default_text="the products'")
    index_mode: str | None = option(
        None, Choice(INDEX_MODES), "merged: one index record per pixel, path class and covariance bin (bins "
        "of ratio 2^(1/4); the index grows with the distinct classes, not with spp); records: one per "
        "contribution with its sample number and float16 norms (default: the products' pxrLayers:index:mode)",
        default_text="the products'")
    index_covariance: str | None = option(
        None, Choice(COVARIANCE_MODES), "norms: the index keeps C, T, R per event; sigma: also the whole "
        "4x4 covariance, for conditions on S11 ... S44 (default: the products' pxrLayers:index:covariance)",
        default_text="the products'")
    subdiv_level: int | None = option(
        None, Integer(0, MAX_SUBDIV_LEVEL), "refinement level of every subdivision surface (catmullClark, "
        f"loop, bilinear), 0 the cage, at most {MAX_SUBDIV_LEVEL} (default: a level per mesh from its size on the "
        "image, for refined edges of a few pixels; few levels out of view); either way "
        f"the highest levels are lowered first where the scene would pass {MAX_SUBDIVISION_TRIANGLES:,} "
        "refined triangles", default_text="automatic (from the projected size)")
    default_lights: bool = option(
        True, Switch(), "a stage that nothing lights (no light, no emissive material) gets a turntable rig under "
        "/pxrLayers/defaultLights (dome, key, fill and rim, placed from the camera)",
        flag_help="a stage that nothing lights stays unlit (default: it gets a turntable rig under "
        "/pxrLayers/defaultLights: dome, key, fill and rim, placed from the camera)")
    auto_camera: str = option(
        AUTO_CAMERA_VIEWS[0], Choice(AUTO_CAMERA_VIEWS), "how a stage without a camera is framed by "
        "/pxrLayers/autoCamera: front (looking down -Z on a Y-up stage, +Y on a Z-up one, as usdview's free "
        "camera) "
        "or three-quarter (30 degrees to the right, 20 above; a flat subject is seen from 45 degrees above); "
        "either way the bounds fill the render's frame with a small margin")
    strict: bool = option(
        False, Switch(), "any composition error (a missing or unreadable reference, payload or sublayer) is "
        "fatal, exit 1 (default: a warning, and the rest renders)")
    keep_index: bool = option(
        True, Switch(), f"keep the path index STEM{INDEX_SUFFIX}: what lets `pxr-layers extract` cut new "
        "layers later without rendering again", flag="--no-index", job_key="render.index",
        flag_help=f"do not keep the path index STEM{INDEX_SUFFIX} once the products are written (it is what "
        "lets `pxr-layers extract` cut new layers later without rendering again)")
    previews: bool = option(True, Switch(), "write the PNG previews and contact sheets beside every product",
                            flag_help="do not write the PNG previews and contact sheets")
    nuke_scripts: bool = option(
        False, Switch(), "also write PRODUCT.nk beside every product: the Nuke script `pxr-layers nuke` writes",
        flag="--nuke-script", job_key="render.nuke_script")
    cryptomattes: tuple[str, ...] = option(
        (), Words(Cryptomattes(), comma=True), "add Cryptomatte layers to every product, a comma-separated "
        f"list of {', '.join(CRYPTOMATTE_KINDS)}: CryptoObject (prim paths), CryptoMaterial (bound materials), "
        "CryptoAsset (model roots by kind, else top-level prims); recipes ask with raw RenderVars of those "
        "sourceNames (docs/compositing.md)", flag="--cryptomatte", job_key="render.cryptomatte")
    cryptomatte_depth: int = option(
        DEFAULT_CRYPTOMATTE_DEPTH, Integer(1, MAX_CRYPTOMATTE_DEPTH), "ids per pixel of every Cryptomatte "
        f"layer, two per part NAME00, NAME01, ... (at most {MAX_CRYPTOMATTE_DEPTH})")
    denoise: bool = option(
        False, Switch(), "also write every product's denoised twin PRODUCT.denoised.exr (Intel Open Image Denoise "
        "with the render's albedo and normal guides; the same parts and channels, colour layers denoised and the "
        "beauty their sum, data and Cryptomatte layers as they are); previews show it")
    texture_memory: int | None = option(
        None, Integer(16, None, "MiB"), "the most memory, in MiB, the material textures may take: each is held "
        "from the MIP level the frame's view of it needs, in its file's precision, and past the budget the "
        "largest are held coarser, with a warning naming them", default_text=f"1/{round(1 / DEFAULT_TEXTURE_MEMORY)} of "
        f"the machine's memory, at most {MAX_DEFAULT_TEXTURE_MIB}")
    debug_covariance: bool = option(
        False, Switch(), "also write the first bounce's covariance norms beside the index: STEM.covariance.exr "
        "(channels C 1/m, T cycles/m, R cycles/rad) and STEM.covariance.{C,T,R}.png colour maps")

    def __post_init__(self) -> None:
        # Absolute: the paths end up in the files' metadata, which must not depend on the cwd.
        object.__setattr__(self, "stage", Path(os.path.abspath(self.stage)))
        for spec in OPTIONS:
            value = getattr(self, spec.name)
            if value is None and spec.default is None:
                continue
            try:
                object.__setattr__(self, spec.name, spec.kind.check(value))
            except EntryError as error:
                raise RenderSettingsError(f"{spec.name.replace('_', ' ')}[{error.number}]: {error.message}") from None
            except ValueError as error:
                said = str(error)
                separator = " " if said.startswith("must") else ": "  # "max depth must be at most 1024"
                raise RenderSettingsError(f"{spec.name.replace('_', ' ')}{separator}{said}") from None

    def resolved_norm_bounces(self, product_bounces: int, has_conditions: bool) -> int:
        """The norm-bounce rule: the request's own number; else none when nothing reads them
        (no index kept, no covariance condition, no ``debug_covariance``: tracing covariance
        costs 2-4x); else the products' index bounces raised to ``max_depth`` (at most
        MAX_INDEX_BOUNCES) when a layer has a covariance condition (a condition under ``.*``
        may test any event of the path); at least 1 for ``debug_covariance``, whose maps are
        the first bounce's norms."""
        if self.norm_bounces is not None:
            bounces = self.norm_bounces
        elif not (self.keep_index or has_conditions or self.debug_covariance):
            bounces = 0
        elif has_conditions:
            bounces = max(product_bounces, min(self.max_depth, MAX_INDEX_BOUNCES))
        else:
            bounces = product_bounces
        return max(bounces, 1) if self.debug_covariance else bounces


def _options() -> tuple[Option, ...]:
    declared = []
    for spec in fields(RenderRequest):
        if "option" not in spec.metadata:
            continue
        meta = spec.metadata["option"]
        kind, default = meta["kind"], (None if spec.default is MISSING else spec.default)
        flag = meta["flag"] or ("--no-" if isinstance(kind, Switch) and default else "--") + spec.name.replace("_", "-")
        declared.append(Option(spec.name, kind, meta["help"], flag, meta["job_key"] or f"render.{spec.name}",
                               default, meta["default_text"] or kind.describe(default),
                               meta["flag_help"] or meta["help"]))
    return tuple(declared)


OPTIONS: tuple[Option, ...] = _options()
"""Every render option, in RenderRequest's order."""
OPTIONS_BY_NAME = {spec.name: spec for spec in OPTIONS}


def check_work(resolution: tuple[int, int] | None, spp: int) -> None:
    """Raise RenderSettingsError when a render would be beyond MAX_SPP samples per pixel or
    MAX_PIXELS pixels, before anything is allocated for it."""
    if spp > MAX_SPP:
        raise RenderSettingsError(f"{spp} samples per pixel is more than the {MAX_SPP} a render takes")
    if resolution is not None and resolution[0] * resolution[1] > MAX_PIXELS:
        raise RenderSettingsError(f"a {resolution[0]}×{resolution[1]} image is more than the {MAX_PIXELS} pixels "
                                  "(16384 × 16384) a render takes")
