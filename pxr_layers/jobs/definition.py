"""Shot job definitions: a TOML job file (and the files it extends) → a frozen :class:`Job`.

A job says what to render for one shot: the stage, the frames, the layer recipe, the
render quality, where the files go and how to spread the work over Dask. A show-level file
holds the defaults and each shot file extends it::

    # pipelines/shows/demo/shot010.toml
    extends = "show.toml"                     # relative to this file
    stage = "../../../render/showcase_animated.usda"
    frames = "1-24"                           # "1-24x4", "1-10,20,30-40x2", [1, 5, 9]

    [recipe]
    add_layers = ["showcase", "shot010_recipe.usda"]   # after the show's layers
    per_light = "lights"

    [output]
    stem = "shot010.$F4"                      # shot010.0001.exr, shot010.0001.pxlidx

Rules (pipelines/README.md has the full table of keys and defaults):

* ``extends`` names one parent file, relative to the file that says it. Tables merge key by
  key, the child wins; a list replaces the parent's list, except ``recipe.add_layers``,
  which appends to the layers the parent resolved to. A cycle is an error.
* Every relative path is relative to the file that sets it (a show file's recipe layers are
  found next to the show file even when a shot in another folder extends it).
* Output templates: ``$F`` is the frame number, ``$F4`` (``${F4}``) the frame zero-padded to
  4 digits (any 1..9), a run of ``#`` the frame padded to the run's length (as USD
  productName), ``$JOB`` the job file's stem.

Every mistake is a :class:`~pxr_layers.errors.JobError` naming the file that sets the value
and its dotted key (``shot010.toml: render.spp: must be at least 1, not 0``).

This module reads TOML and the keys; :mod:`pxr_layers.jobs.frames` reads frame ranges and
output templates. Neither imports pxr, so a status command can load a job without USD or
Embree.
"""

from __future__ import annotations

import difflib
import ipaddress
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as a package
    import tomli as tomllib

from ..cores import available_cores
from ..inputs import input_problem
from ..outputs import confined_name_problem
from ..paths.format import SUFFIX as INDEX_SUFFIX
from ..request import OPTIONS, OPTIONS_BY_NAME, EntryError, Option, RenderRequest, type_name
from .frames import check_template, expand_template, has_frame_token, job_error, parse_frames, shortened

DEFAULT_BATCH_PIXELS = 16384
DEFAULT_RETRIES = 2
DEFAULT_DIRECTORY = "out/$JOB"
DEFAULT_STEM = "$JOB.$F4"

BEAUTY_SUFFIX = ".exr"
DONE_SUFFIX = ".done.json"
"""A frame's commit record, written last (jobs/executor.py)."""
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
LOCAL_SCHEDULER = "local"    # scheduler: a LocalCluster (the default)
MAX_LOCAL_WORKERS = 256
"""LocalCluster worker processes at most: each is a Python process of about 200 MB with its
own Embree scene, so more than a big workstation's cores is a typo (a farm scales with its
own scheduler, `dask.scheduler`, not with this number)."""
NAME_MAX = 255
"""Bytes in one file name on the file systems studios use (ext4, XFS, NFS, SMB)."""
OVERRIDES = "(overrides)"    # the "file" of load_job's overrides in error messages


def default_workers() -> int:
    """The LocalCluster default: one worker process per core this process may use."""
    return available_cores()


@dataclass(frozen=True)
class Job:
    """A resolved shot job: every path absolute, every value checked.

    file           : the job file given to load_job
    name           : its stem (``shot010``), ``$JOB`` in templates
    sources        : the job file, then each file it extends, in order (leaf first)
    request        : what every frame renders, as ``pxr-layers render`` would for the same
                     flags (stage, recipe layers, variants, settings, per-light mode, spp,
                     seed, depth, norm bounces, resolution, subdiv level, default lights, strict)
    frames         : the frames (USD time codes) to render, whole numbers, in the order given;
                     at most MAX_FRAMES
    output_directory : where every file of the job goes
    output_template  : the stem template of the beauty and the index (``shot010.$F4``), inside
                     output_directory (a subfolder at most, never ``..``)
    batch_pixels   : pixels per task (a frame is split into batches of this many pixels)
    retries        : how many times Dask retries a failed task
    scheduler      : a Dask scheduler address (``tcp://host:8786``), None = a LocalCluster
    workers        : LocalCluster worker processes
    """

    file: Path
    name: str
    request: RenderRequest
    frames: tuple[float, ...]
    output_directory: Path = Path(".")
    output_template: str = DEFAULT_STEM
    batch_pixels: int = DEFAULT_BATCH_PIXELS
    retries: int = DEFAULT_RETRIES
    scheduler: str | None = None
    workers: int = field(default_factory=default_workers)
    sources: tuple[Path, ...] = ()

    def output_stem(self, frame: float) -> str:
        """The frame's file stem: the template expanded (``shot010.0001``)."""
        return expand_template(self.output_template, frame, self.name)

    def beauty_path(self, frame: float) -> Path:
        """``<output_directory>/<stem>.exr``: the beauty EXR of a frame."""
        return self.output_directory / (self.output_stem(frame) + BEAUTY_SUFFIX)

    def index_path(self, frame: float) -> Path:
        """``<output_directory>/<stem>.pxlidx``: the path index of a frame."""
        return self.output_directory / (self.output_stem(frame) + INDEX_SUFFIX)

    def frame_directory(self, frame: float) -> Path:
        """``<output_directory>/<stem>/``: a directory of the frame's own, for what is not a
        deliverable (per-batch partial results, logs). Not created here."""
        return self.output_directory / self.output_stem(frame)

    def product_path(self, product_name: str, frame: float) -> Path:
        """Where a recipe product (its productName, e.g. ``light_passes.exr``) of a frame goes.

        A name with a frame token (``####``, ``$F4``) is expanded in the output directory
        (``shot010_extra.####.exr`` → ``shot010_extra.0001.exr``); any other name gets the
        frame's stem in front so frames do not overwrite each other
        (``shot010.0001.light_passes.exr``). An absolute name is kept (expanded).
        """
        if has_frame_token(product_name):
            path = Path(expand_template(product_name, frame, self.name))
        else:
            path = Path(f"{self.output_stem(frame)}.{expand_template(product_name, frame, self.name)}")
        return path if path.is_absolute() else self.output_directory / path


# -- the keys ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Key:
    """One TOML key: its dotted name, how to check one file's value, and its default text."""

    name: str
    check: Callable[[Any, Path, str, str], Any]  # (value, base directory, file, key) → parsed
    default: str
    doc: str


def _integer(minimum: int, maximum: int | None = None) -> Callable[[Any, Path, str, str], int]:
    def check(value: Any, base: Path, file: str, key: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise job_error(f"must be an integer, not {type_name(value)} ({value!r})", file, key)
        if value < minimum:
            raise job_error(f"must be at least {minimum}, not {value}", file, key)
        if maximum is not None and value > maximum:
            raise job_error(f"must be at most {maximum}, not {value}", file, key)
        return value
    return check


def _string(value: Any, file: str, key: str) -> str:
    if not isinstance(value, str):
        raise job_error(f"must be a string, not {type_name(value)} ({value!r})", file, key)
    return value


def _path(value: Any, base: Path, file: str, key: str) -> Path:
    text = _string(value, file, key)
    if not text.strip():
        raise job_error("must be a path, not an empty string", file, key)
    return (base / Path(text).expanduser()).resolve()


def _frames_value(value: Any, base: Path, file: str, key: str) -> tuple[float, ...]:
    return parse_frames(value, file=file, key=key)


def _option(spec: Option) -> Callable[[Any, Path, str, str], Any]:
    """A request option's job key: its kind reads the TOML value, the error naming file and key."""
    def check(value: Any, base: Path, file: str, key: str) -> Any:
        try:
            return spec.kind.from_toml(value, base)
        except EntryError as error:  # a list's entry: its own key, "variants[2]"
            raise job_error(error.message, file, f"{key}[{error.number}]") from None
        except ValueError as error:
            raise job_error(str(error), file, key) from None
    return check


def _directory(value: Any, base: Path, file: str, key: str) -> str:
    text = _string(value, file, key)
    if not text.strip():
        raise job_error("must be a directory, not an empty string", file, key)
    check_template(text, file=file, key=key, frame_tokens=False)
    # $JOB may stay in the text: it is expanded once the leaf job file is known.
    return str(base / Path(text).expanduser())


def _stem(value: Any, base: Path, file: str, key: str) -> str:
    text = _string(value, file, key)
    if not text.strip():
        raise job_error("must be a file stem, not an empty string", file, key)
    if text.lower().endswith((BEAUTY_SUFFIX, INDEX_SUFFIX)):
        raise job_error(f"a stem, without a suffix: {text!r} names both the .exr and the .pxlidx", file, key)
    # A stem may name a subfolder (beauty/$F4), never a way out of the output directory:
    # every file of the job, and the scratch folders a run removes, stay inside it.
    escape = confined_name_problem(text)
    if escape:
        raise job_error(escape, file, key)
    parts = re.split(r"[/\\]", text)
    if not parts[-1].strip():
        raise job_error(f"must end with a file name, not a folder: {text!r}", file, key)
    # The longest name a frame gets: the stem, 9 digits of frame number, the longest suffix.
    longest = max(len(part.encode()) for part in parts) + 9 + len(DONE_SUFFIX)
    if longest > NAME_MAX:
        raise job_error(f"a part of {shortened(text)} is too long for a file name: the frames' files "
                        f"would be {longest} bytes, more than the {NAME_MAX} a file system takes", file, key)
    check_template(text, file=file, key=key)
    return text


_HOST_LABEL = re.compile(r"[A-Za-z0-9_]([A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?")


def _valid_host(host: str) -> bool:
    """An IP address, or a host name of at most 253 characters in labels of 1 to 63 that
    are not all digits (so that 256.1.1.1 is a bad address at once, not a 30 s timeout)."""
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        labels = host.rstrip(".").split(".")
        return (len(host) <= 253 and all(_HOST_LABEL.fullmatch(label) for label in labels)
                and not labels[-1].isdigit())


def _scheduler(value: Any, base: Path, file: str, key: str) -> str | None:
    text = _string(value, file, key).strip()
    if text == LOCAL_SCHEDULER:
        return None
    match = re.fullmatch(r"(?:(?P<scheme>[a-z]+)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                         r":(?P<port>\d{1,5})/?", text)
    example = f"e.g. \"tcp://host:8786\", or \"{LOCAL_SCHEDULER}\" for a LocalCluster"
    if not match:
        raise job_error(f"bad scheduler address {text!r} ({example})", file, key)
    scheme = match["scheme"] or "tcp"
    if scheme not in SCHEDULER_SCHEMES:
        raise job_error(f"bad scheduler address {text!r}: unknown protocol {scheme!r} "
                     f"(allowed: {', '.join(SCHEDULER_SCHEMES)})", file, key)
    host = match["host"]
    if not _valid_host(host.strip("[]")):
        raise job_error(f"bad scheduler address {text!r}: {host!r} is neither an IP address nor a host name",
                        file, key)
    port = int(match["port"])
    if not 0 < port < 65536:
        raise job_error(f"bad scheduler address {text!r}: port {port} is not 1..65535", file, key)
    return f"{scheme}://{match['host']}:{port}"


_JOB_KEYS: tuple[_Key, ...] = (
    _Key("extends", _path, "none", "a parent job file, relative to this one; this file wins"),
    _Key("stage", _path, "required", "the USD stage, relative to the file that sets it"),
    _Key("frames", _frames_value, "required", '"1-24", "1-24x4" (every 4th), "1-10,20", or [1, 5, 9]'),
    _Key("recipe.add_layers", _option(OPTIONS_BY_NAME["recipe_layers"]), "[]",
         "appended to the layers the parent resolved to"),
    _Key("output.directory", _directory, f'"{DEFAULT_DIRECTORY}"',
         "where the files go, relative to the file that sets it ($JOB allowed)"),
    _Key("output.stem", _stem, f'"{DEFAULT_STEM}"', "beauty and index stem: $F, $F4, ####, $JOB"),
    _Key("dask.scheduler", _scheduler, f'"{LOCAL_SCHEDULER}"',
         'a scheduler address "tcp://host:8786"; "local" = a LocalCluster'),
    _Key("dask.workers", _integer(1, MAX_LOCAL_WORKERS), "CPU count",
         f"LocalCluster worker processes, at most {MAX_LOCAL_WORKERS}"),
    _Key("dask.batch_pixels", _integer(1), str(DEFAULT_BATCH_PIXELS), "pixels per task"),
    _Key("dask.retries", _integer(0), str(DEFAULT_RETRIES), "retries of a failed task"),
)
KEYS: tuple[_Key, ...] = (*_JOB_KEYS, *(_Key(spec.job_key, _option(spec), spec.default_text, spec.help)
                                       for spec in OPTIONS))
"""Every key of a job file: the job's own, then one per render option (request.OPTIONS)."""
_BY_NAME = {key.name: key for key in KEYS}
_REQUEST_FIELDS = {spec.job_key: spec.name for spec in OPTIONS}
"""Job keys → the RenderRequest fields they set."""
TABLES = tuple(dict.fromkeys(key.name.split(".")[0] for key in KEYS if "." in key.name))


# -- reading and merging ----------------------------------------------------------------------


@dataclass(frozen=True)
class _Setting:
    value: Any
    file: str  # the file that set it (for errors about the value)
    key: str


def _read_toml(path: Path, child: str | None) -> dict[str, Any]:
    problem = input_problem(path, "job file")  # a FIFO would block the open
    if problem is not None:
        raise job_error(f"{path}: {problem}" if child else problem, child or str(path), "extends" if child else None)
    try:
        with open(path, "rb") as stream:
            return tomllib.load(stream)
    except tomllib.TOMLDecodeError as error:
        raise job_error(f"not valid TOML: {error}", str(path), None) from None
    except RecursionError:  # tomllib recurses once per nested table or array
        raise job_error("not a job file: its tables or arrays are nested thousands deep", str(path), None) from None
    except UnicodeDecodeError as error:
        raise job_error(f"not a text file (byte {error.start} is not UTF-8): not valid TOML", str(path), None) from None
    except OSError as error:
        raise job_error(f"cannot read: {error.strerror}", str(path), None) from None


def _flatten(data: Mapping[str, Any], file: str) -> dict[str, Any]:
    """One file's TOML → {dotted key: value}, refusing unknown keys and tables."""
    flat: dict[str, Any] = {}
    for name, value in data.items():
        if name in TABLES:
            if not isinstance(value, dict):
                raise job_error(f"must be a table ([{name}]), not {type_name(value)}", file, name)
            for sub, sub_value in value.items():
                dotted = f"{name}.{sub}"
                if dotted not in _BY_NAME:
                    raise job_error(f"unknown key{_did_you_mean(dotted)}", file, dotted)
                flat[dotted] = sub_value
        elif name in _BY_NAME:
            flat[name] = value
        else:
            raise job_error(f"unknown key{_did_you_mean(name)}", file, name)
    return flat


def _did_you_mean(dotted: str) -> str:
    table, _, leaf = dotted.rpartition(".")
    same_leaf = [key.name for key in KEYS if key.name.rpartition(".")[2] == leaf and key.name != dotted]
    if same_leaf:
        return f" (did you mean {same_leaf[0]}?)"
    siblings = [key.name for key in KEYS if key.name.rpartition(".")[0] == table]
    close = difflib.get_close_matches(dotted, siblings, n=1, cutoff=0.6)
    if not close:
        leaves = {key.name.rpartition(".")[2]: key.name for key in KEYS}
        close = [leaves[m] for m in difflib.get_close_matches(leaf, list(leaves), n=1, cutoff=0.75)]
    if not close and not table:
        close = difflib.get_close_matches(dotted, list(TABLES), n=1, cutoff=0.6)
        if close:
            return f" (did you mean the table [{close[0]}]?)"
    return f" (did you mean {close[0]}?)" if close else ""


def _parse_file(flat: Mapping[str, Any], base: Path, file: str) -> dict[str, _Setting]:
    return {name: _Setting(_BY_NAME[name].check(value, base, file, name), file, name)
            for name, value in flat.items()}


def _merge(parent: dict[str, _Setting], child: dict[str, _Setting]) -> dict[str, _Setting]:
    merged = {**parent, **{k: v for k, v in child.items() if k != "recipe.add_layers"}}
    added = child.get("recipe.add_layers")
    if added is not None:
        base = merged.get("recipe.layers")
        layers = (base.value if base else ()) + added.value
        merged["recipe.layers"] = _Setting(layers, added.file, added.key)
    merged.pop("extends", None)
    return merged


def load_job(path: str | os.PathLike[str], overrides: Mapping[str, Any] | None = None) -> Job:
    """Read a job file and every file it extends into a checked :class:`Job`.

    overrides : {dotted key: value} applied over the files (e.g. from command-line flags:
                ``{"frames": "1-4", "render.spp": 4}``), in TOML types; their relative paths
                are relative to the current directory. They cannot set ``extends``.

    Raises JobError naming the file and key: unknown key (with a close match), bad value,
    bad frame range (with its position), missing stage or recipe file, unknown preset, a
    cycle or missing file in ``extends``, bad scheduler address.
    """
    leaf = Path(path).expanduser().resolve()
    chain: list[tuple[Path, dict[str, _Setting]]] = []
    current: Path | None = leaf
    child: str | None = None
    while current is not None:
        visited = [p for p, _ in chain]
        if current in visited:
            cycle = " -> ".join(p.name for p in [*visited[visited.index(current):], current])
            raise job_error(f"extends cycle: {cycle}", child, "extends")
        settings = _parse_file(_flatten(_read_toml(current, child), str(current)), current.parent, str(current))
        chain.append((current, settings))
        extends = settings.get("extends")
        child, current = str(current), (extends.value if extends else None)

    merged: dict[str, _Setting] = {}
    for _, settings in reversed(chain):
        merged = _merge(merged, settings)
    if overrides:
        for name in overrides:
            if name == "extends":
                raise job_error("cannot be overridden", OVERRIDES, name)
            if name not in _BY_NAME:
                raise job_error(f"unknown key{_did_you_mean(name)}", OVERRIDES, name)
        merged = _merge(merged, _parse_file(overrides, Path.cwd(), OVERRIDES))
    return _resolve(leaf, [p for p, _ in chain], merged)


def _resolve(leaf: Path, sources: list[Path], merged: dict[str, _Setting]) -> Job:
    name = leaf.stem

    def value(key: str, default: Any = None) -> Any:
        setting = merged.get(key)
        return setting.value if setting else default

    def required(key: str, example: str) -> _Setting:
        if key not in merged:
            raise job_error(f"not set in {' or '.join(p.name for p in sources)} (e.g. {key} = {example})",
                         str(leaf), key)
        return merged[key]

    stage = required("stage", '"shot.usda"')
    problem = input_problem(stage.value, "USD file")
    if problem is not None:
        raise job_error(f"{stage.value}: {problem}", stage.file, "stage")
    frames = required("frames", '"1-24"')

    directory_text = value("output.directory", str(leaf.parent / DEFAULT_DIRECTORY))
    directory = Path(expand_template(directory_text, None, name)).resolve()
    stem = merged.get("output.stem")
    template = stem.value if stem else DEFAULT_STEM
    if len(frames.value) > 1 and not has_frame_token(template):
        raise job_error(f"{template!r} has no frame number ($F4 or ####): all {len(frames.value)} frames "
                     "would write the same files", stem.file if stem else str(leaf), "output.stem")

    # Keys not set take RenderRequest's own defaults, the ones `pxr-layers render` has.
    request = RenderRequest(stage=stage.value, **{field: merged[key].value for key, field in _REQUEST_FIELDS.items() if key in merged})
    return Job(
        file=leaf, name=name, sources=tuple(sources), request=request, frames=frames.value,
        output_directory=directory, output_template=template,
        batch_pixels=value("dask.batch_pixels", DEFAULT_BATCH_PIXELS),
        retries=value("dask.retries", DEFAULT_RETRIES), scheduler=value("dask.scheduler"),
        workers=value("dask.workers") or default_workers(),
    )
