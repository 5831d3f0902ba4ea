"""The Nuke script of a graded stack, evaluated by a small independent Nuke: it gives the
beauty at unit gains and the inspector's composite rule with gains, mutes and solos.

The parser and interpreter below are written from Nuke's documented and public behaviour,
not from pxr_layers/layers/nuke.py:

* script syntax: node blocks ``Type {`` … ``}`` with one knob per line (``name value``,
  values bare, ``{…}`` or Tcl double-quoted with Tcl's backslash substitutions);
  ``set NAME [stack 0]`` names the top of the node stack, ``push $NAME`` pushes a named node, ``push 0`` an empty
  input; a node pops its ``inputs`` (default 1) from the stack, input 0 first (from the
  top), and pushes itself; ``add_layer {layer layer.c …}`` declares a layer's channels;
* the Read of an EXR names channels as Nuke's exrReader does (Foundry's NDK example
  ExrChannelNameToNuke.cpp): when a channel name holds a ``.`` the part names are
  ignored, the text before the last ``.`` is the layer, R G B A become red green blue alpha,
  and channels without a layer are ``rgba``'s;
* the classic Shuffle (``in`` layer → out rgba, ``red``/``green``/``blue``/``alpha`` the
  source of each: the ``in`` layer's channel of that rank, or black / white), Grade
  (``multiply`` on ``channels``, default rgb, ``black_clamp`` default true; with a mask input,
  ``inputs 1+1`` and ``maskChannelInput``, the result is in + (graded − in) · mask, the
  mask's channel read from input 1, as every NukeWrapper node blends by its mask), Merge2
  (B = input 0, A = input 1; plus A+B, from B−A, minus A−B on its channels, rgba unless
  ``Achannels``/``Bchannels``/``output`` say otherwise; the rest of B kept),
  and ``disable true``: the node passes its input 0;
* Psyop's Cryptomatte gizmo (nuke/Cryptomatte.gizmo, cryptomatte_utilities.py): ``matteList``
  a comma-separated list of names (quoted when they hold a space or a comma), each keyed
  by its id (test_cryptomatte.spec_id); the matte, Σ over the ``in00`` ... layers of
  ``green`` where ``red`` is an id and ``alpha`` where ``blue`` is, goes into alpha.

Pixels are float32, as Nuke computes them.
"""

from __future__ import annotations

import csv
import math
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from pxr_layers.cli.main import main
from pxr_layers.cli.nuke import write_product_script
from pxr_layers.errors import OutputError
from pxr_layers.layers.multipart import write_multipart
from pxr_layers.layers.nuke import LayerGrade, nuke_script, write_nuke_script

ROOT = Path(__file__).resolve().parents[1]
UNIT_ROUNDOFF = 2.0 ** -24  # float32
RGBA = ("rgba.red", "rgba.green", "rgba.blue", "rgba.alpha")
NUKE_CHANNEL = {"R": "red", "r": "red", "Red": "red", "RED": "red", "G": "green", "g": "green", "Green": "green",
                "GREEN": "green", "B": "blue", "b": "blue", "Blue": "blue", "BLUE": "blue", "A": "alpha",
                "a": "alpha", "Alpha": "alpha", "ALPHA": "alpha"}


# --- the script's syntax ------------------------------------------------------------------


@dataclass
class Node:
    kind: str
    knobs: dict[str, str] = field(default_factory=dict)

    def knob(self, name: str, default: str | None = None) -> str | None:
        return self.knobs.get(name, default)


@dataclass
class Command:
    """``set``, ``push``, ``add_layer``, ``version``: a line outside any node block."""

    words: list[str]


TCL_ESCAPES = {"a": "\a", "b": "\b", "f": "\f", "n": "\n", "r": "\r", "t": "\t", "v": "\v"}


def tcl_backslash(text: str, position: int) -> tuple[str, int]:
    """Tcl's backslash substitution of the sequence at ``text[position] == "\\"`` (Tcl(n),
    rule [9], as Tcl 8.6 reads it): (its character, the position after it)."""
    following = text[position + 1]
    if following in TCL_ESCAPES:
        return TCL_ESCAPES[following], position + 2
    for prefix, pattern, base in (("u", r"[0-9A-Fa-f]{1,4}", 16), ("x", r"[0-9A-Fa-f]{1,2}", 16)):
        if following == prefix:
            digits = re.compile(pattern).match(text, position + 2)
            if digits:
                return chr(int(digits.group(), base)), digits.end()
            return following, position + 2
    digits = re.compile(r"[0-7]{1,3}").match(text, position + 1)
    if digits:
        return chr(int(digits.group(), 8) & 0xFF), digits.end()
    return following, position + 2


def tcl_words(text: str) -> list[str]:
    """Split one line into Tcl words: bare, {braced} (kept without the outer braces; an
    escaped brace does not count) or "quoted" (backslash sequences substituted)."""
    words, position = [], 0
    while position < len(text):
        if text[position].isspace():
            position += 1
        elif text[position] == "{":
            depth, start = 0, position
            while True:
                if text[position] == "\\":
                    position += 2
                    continue
                depth += {"{": 1, "}": -1}.get(text[position], 0)
                position += 1
                if depth == 0:
                    break
            words.append(text[start + 1:position - 1])
        elif text[position] == '"':
            position += 1
            word = []
            while text[position] != '"':
                if text[position] == "\\":
                    character, position = tcl_backslash(text, position)
                    word.append(character)
                    continue
                word.append(text[position])
                position += 1
            position += 1
            words.append("".join(word))
        else:
            match = re.compile(r"\S+").match(text, position)
            words.append(match.group())
            position = match.end()
    return words


def parse(script: str) -> list[Node | Command]:
    items: list[Node | Command] = []
    node: Node | None = None
    for line in script.splitlines():
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if node is None:
            opening = re.fullmatch(r"(\w+) \{", stripped)
            if opening:
                node = Node(opening.group(1))
            else:
                items.append(Command(tcl_words(stripped)))
        elif stripped == "}":
            items.append(node)
            node = None
        else:
            name, value = tcl_words(stripped)
            assert name not in node.knobs, f"{node.kind}: knob {name} twice"
            node.knobs[name] = value
    assert node is None, "an unclosed node block"
    return items


# --- a small Nuke ---------------------------------------------------------------------------

Image = dict[str, np.ndarray]  # Nuke channel name → (h, w) float32


def nuke_channel_name(exr_name: str) -> str:
    """ExrChannelNameToNuke: the EXR channel's Nuke name (views: only Nuke's default 'main')."""
    pieces = [re.sub(r"[^A-Za-z0-9]", "_", piece.lstrip("0123456789")) for piece in exr_name.split(".")]
    pieces = [piece for piece in pieces if piece]
    layer = "_".join(piece for piece in pieces[:-1] if piece != "main")
    channel = NUKE_CHANNEL.get(pieces[-1], pieces[-1])
    if layer == "Ci":
        layer = ""
    return f"{layer}.{channel}" if layer else f"rgba.{channel}"


def read_exr(path: Path) -> tuple[Image, tuple[int, int]]:
    exr = OpenEXR.File(str(path), separate_channels=True)
    names = [name for part in exr.parts for name in part.channels]
    assert any("." in name for name in names), "a legacy file (layers in part names): not modelled here"
    image: Image = {}
    for part in exr.parts:
        for name, channel in part.channels.items():
            nuke_name = nuke_channel_name(name)
            assert nuke_name not in image, f"two EXR channels read as {nuke_name}"
            image[nuke_name] = channel.pixels.astype(np.float32)
    height, width = next(iter(image.values())).shape
    return image, (width, height)


def tcl_value(text: str, script_path: Path) -> str:
    """A knob's text with its Tcl substitutions done (as Nuke does to a file knob): backslash
    sequences, and the commands ``[value root.name]`` (the script's path) and ``[file
    dirname X]``; a substituted result is one word, never split again (Tcl's rule), so paths
    with spaces survive. A ``$`` variable is not modelled."""
    out, position = [], 0
    while position < len(text):
        assert text[position] != "$", f"a Tcl variable in {text!r}"
        if text[position] == "\\":
            character, position = tcl_backslash(text, position)
            out.append(character)
            continue
        if text[position] != "[":
            out.append(text[position])
            position += 1
            continue
        end = matching_bracket(text, position)
        out.append(tcl_command(text[position + 1:end], script_path))
        position = end + 1
    return "".join(out)


def matching_bracket(text: str, start: int) -> int:
    depth, position = 0, start
    while position < len(text):
        if text[position] == "\\":
            position += 2
            continue
        depth += {"[": 1, "]": -1}.get(text[position], 0)
        if depth == 0:
            return position
        position += 1
    raise ValueError(f"unbalanced [ in {text!r}")


def tcl_command(body: str, script_path: Path) -> str:
    words, position = [], 0
    while position < len(body):
        if body[position].isspace():
            position += 1
            continue
        start = position
        while position < len(body) and not body[position].isspace():
            position = matching_bracket(body, position) + 1 if body[position] == "[" else position + 1
        words.append(tcl_value(body[start:position], script_path))
    if words == ["value", "root.name"]:
        return str(script_path)
    if words[:2] == ["file", "dirname"] and len(words) == 3:
        return str(Path(words[2]).parent)
    raise NotImplementedError(f"Tcl command [{body}]")


def numbers(text: str, count: int) -> np.ndarray:
    values = [float(word) for word in text.split()]
    return np.array(values * count if len(values) == 1 else values, dtype=np.float64)


class Nuke:
    """Evaluates a parsed script: every node's image, eagerly, as Nuke would compute it."""

    def __init__(self, script_path: Path):
        self.script_path = script_path
        self.stack: list[tuple[Node, Image] | None] = []
        self.named: dict[str, tuple[Node, Image]] = {}
        self.layers: dict[str, list[str]] = {"rgba": list(RGBA), "rgb": list(RGBA[:3]), "alpha": [RGBA[3]]}
        self.format: tuple[int, int] | None = None
        self.nodes: dict[str, Node] = {}

    def run(self, items: list[Node | Command]) -> Image:
        for item in items:
            if isinstance(item, Command):
                self.command(item.words)
            else:
                self.node(item)
        return self.stack[-1][1]

    def command(self, words: list[str]) -> None:
        if words[0] == "set":
            assert words[2:] == ["[stack", "0]"], words
            self.named[words[1]] = self.stack[-1]
        elif words[0] == "push":
            self.stack.append(None if words[1] == "0" else self.named[words[1].removeprefix("$")])
        elif words[0] == "add_layer":
            name, *channels = words[1].split()
            assert all(channel.startswith(name + ".") for channel in channels)
            self.layers[name] = channels
        elif words[0] != "version":
            raise NotImplementedError(f"command {words[0]}")

    def node(self, node: Node) -> None:
        name = node.knob("name")
        assert name is None or name not in self.nodes, f"node name {name} twice"
        self.nodes[name] = node
        count = sum(int(number) for number in node.knob("inputs", "1").split("+"))  # "1+1": an input and a mask
        inputs = [self.stack.pop() for _ in range(count)]  # input 0 from the top
        images = [None if entry is None else entry[1] for entry in inputs]
        if node.knob("disable") == "true":
            image = images[0]
        else:
            image = getattr(self, node.kind.lower())(node, *images)
        self.stack.append((node, image))

    def root(self, node: Node) -> Image:
        width, height, *_ = node.knob("format").split()
        self.format = (int(width), int(height))
        assert node.knob("colorManagement") == "Nuke" and node.knob("OCIO_config") == "nuke-default"
        return {}

    def read(self, node: Node) -> Image:
        assert node.knob("colorspace") in ("linear", None) or node.knob("raw") == "true"  # no conversion
        image, size = read_exr(Path(tcl_value(node.knob("file"), self.script_path)))
        assert size == self.format == tuple(int(v) for v in node.knob("format").split()[:2])
        return image

    def shuffle(self, node: Node, source: Image) -> Image:
        assert set(node.knobs) <= {"in", "alpha", "red", "green", "blue", "out", "name", "label", "xpos", "ypos"}
        assert node.knob("out", "rgba") == "rgba"
        layer = self.layers[node.knob("in", "rgba")]
        zeros = np.zeros_like(next(iter(source.values())))
        image = dict(source)
        for rank, (target, default) in enumerate(zip(RGBA, ("red", "green", "blue", "alpha"), strict=True)):
            choice = node.knob(target.split(".")[1], default)
            if choice == "black":
                image[target] = zeros
            elif choice == "white":
                image[target] = zeros + 1
            else:
                assert choice == default, choice  # the in layer's channel of this rank
                image[target] = source.get(layer[rank], zeros) if rank < len(layer) else zeros
        return image

    def grade(self, node: Node, source: Image, mask_input: Image | None = None) -> Image:
        assert set(node.knobs) <= {"multiply", "channels", "black_clamp", "white_clamp", "name", "label",
                                   "xpos", "ypos", "inputs", "maskChannelInput"}
        assert (node.knob("inputs") == "1+1") == (mask_input is not None) == ("maskChannelInput" in node.knobs)
        channels = {"rgb": RGBA[:3], "rgba": RGBA, "alpha": RGBA[3:]}[node.knob("channels", "rgb")]
        multiply = numbers(node.knob("multiply", "1"), 4).astype(np.float32)
        image = dict(source)
        for channel in channels:
            value = source[channel] * multiply[RGBA.index(channel)]
            if node.knob("black_clamp", "true") == "true":
                value = np.maximum(value, 0)
            if mask_input is not None:
                mask = mask_input[node.knob("maskChannelInput")]
                value = source[channel] + (value - source[channel]) * mask
            image[channel] = value
        return image

    def merge2(self, node: Node, b: Image, a: Image | None) -> Image:
        assert set(node.knobs) <= {"inputs", "operation", "Achannels", "Bchannels", "output", "name", "label",
                                   "xpos", "ypos", "disable"}
        operation = {"plus": lambda a, b: a + b, "from": lambda a, b: b - a, "minus": lambda a, b: a - b,
                     "over": None}[node.knob("operation", "over")]
        channels = {node.knob(knob, "rgba") for knob in ("Achannels", "Bchannels", "output")}
        assert len(channels) == 1, "A, B and output channels that differ: not modelled here"
        zeros = np.zeros_like(next(iter(b.values())))
        image = dict(b)  # what the operation does not write comes from B
        for channel in {"rgba": RGBA, "rgb": RGBA[:3]}[channels.pop()]:
            image[channel] = operation((a or {}).get(channel, zeros), b.get(channel, zeros))
        return image


    def cryptomatte(self, node: Node, source: Image) -> Image:
        assert set(node.knobs) <= {"name", "label", "cryptoLayer", "cryptoLayerLock", "matteList", "xpos", "ypos",
                                   *(f"in{number:02d}" for number in range(12))}
        from test_cryptomatte import spec_id

        text = tcl_value(node.knob("matteList", '""'), self.script_path)
        names = next(csv.reader([text.strip('"')], skipinitialspace=True), []) if text.strip('"') else []
        ids = np.array([spec_id(name) for name in names], np.float32)
        zeros = np.zeros_like(next(iter(source.values())))
        total = zeros.copy()
        for number in range(12):
            layer = node.knob(f"in{number:02d}")
            if layer is None:
                break
            red, green, blue, alpha = (source.get(channel, zeros) for channel in self.layers[layer])
            total = total + np.where(np.isin(red, ids), green, 0) + np.where(np.isin(blue, ids), alpha, 0)
        return {**source, "rgba.alpha": total}


def evaluate(script: str, script_path: Path) -> tuple[np.ndarray, Nuke]:
    """(the script's (h, w, 4) rgba, the interpreter: its nodes) for a script saved at script_path."""
    nuke = Nuke(script_path)
    image = nuke.run(parse(script))
    return np.stack([image[channel] for channel in RGBA], axis=-1), nuke


def test_the_parser_follows_nukes_stack_convention():
    """A hand-written script: B is the node pushed last (input 0), A the one beneath;
    ``push 0`` is an empty input."""
    a = {channel: np.full((1, 1), 1.0, np.float32) for channel in RGBA}
    b = {channel: np.full((1, 1), 4.0, np.float32) for channel in RGBA}
    nuke = Nuke(Path("/nowhere.nk"))
    nuke.named = {"Na": (Node("A"), a), "Nb": (Node("B"), b)}
    script = "push $Na\npush $Nb\nMerge2 {\n inputs 2\n operation from\n}\npush 0\npush $Nb\nMerge2 {\n inputs 2\n operation minus\n}\n"
    assert nuke.run(parse(script))["rgba.red"][0, 0] == -4.0  # A empty: 0 − B
    assert nuke.stack[0][1]["rgba.red"][0, 0] == 3.0  # B − A


# --- the composite rule ----------------------------------------------------------------------


def composite_rule(beauty: np.ndarray, layers: dict[str, np.ndarray], grades: dict[str, LayerGrade],
                   exposure: float, masks: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """The inspector's rule (view/composite.py), in float64: (h, w, 3). masks: layer name →
    its mask m (h, w); a layer's weight is then 1 + m · (gain − 1)."""
    def gain(grade: LayerGrade, name: str) -> np.ndarray:
        g = 0.0 if grade.mute else 2.0 ** grade.stops * np.array(grade.tint, np.float64)
        if masks and name in masks:
            return 1.0 + masks[name].astype(np.float64)[..., None] * (g - 1.0)
        return g

    graded = {name: grades.get(name, LayerGrade()) for name in layers}
    if any(grade.solo for grade in graded.values()):
        out = sum(gain(graded[name], name) * layer.astype(np.float64) for name, layer in layers.items()
                  if graded[name].solo)
    else:
        out = beauty[..., :3].astype(np.float64) + sum(
            (gain(graded[name], name) - 1) * layer.astype(np.float64) for name, layer in layers.items())
    return out * 2.0 ** exposure


def bound(beauty: np.ndarray, layers: dict[str, np.ndarray], grades: dict[str, LayerGrade],
          exposure: float) -> np.ndarray:
    """What float32 may be off by: each of the script's ~3 operations per layer (a gain cast,
    a product, a sum) and the rest's subtraction rounds once, by at most the unit roundoff of
    magnitudes up to |beauty| + Σ (1 + |gain|)·|layer|."""
    gains = [2.0 ** grades.get(name, LayerGrade()).stops * max(grades.get(name, LayerGrade()).tint)
             for name in layers]
    magnitude = np.abs(beauty[..., :3]) + sum((1 + g) * np.abs(layer) for g, layer in zip(gains, layers.values()))
    return (3 * len(layers) + 4) * UNIT_ROUNDOFF * magnitude * 2.0 ** exposure


@pytest.fixture
def stack(tmp_path, rng):
    """A multipart EXR of three random layers: (folder, beauty (h, w, 4), layers, partition)
    for a partition (beauty = Σ layers) and a beauty with more light than its layers."""
    def make(partition: bool, name: str = "look"):
        height, width = 6, 5
        layers = {name: rng.uniform(0, 4, (height, width, 3)).astype(np.float32) for name in ("key", "fill", "rim")}
        rgb = layers["key"] + layers["fill"] + layers["rim"]
        if not partition:
            rgb = rgb + rng.uniform(0.5, 2, rgb.shape).astype(np.float32)  # light no layer holds
        beauty = np.concatenate([rgb, rng.uniform(0, 1, (height, width, 1)).astype(np.float32)], axis=2)
        write_multipart(tmp_path / f"{name}.exr", beauty, layers)
        return beauty, layers
    return make


def script_result(folder: Path, layers, grades, *, partition: bool, exposure: float = 0.0) -> tuple[np.ndarray, Nuke]:
    path = write_nuke_script(folder / "look.nk", folder / "look.exr", list(layers), grades, resolution=(5, 6),
                             partition=partition, exposure=exposure)
    return evaluate(path.read_text(), path)


@pytest.mark.parametrize("partition", [True, False], ids=["partition", "with rest"])
def test_unit_gains_give_the_beauty(stack, tmp_path, partition):
    beauty, layers = stack(partition)
    out, nuke = script_result(tmp_path, layers, {}, partition=partition)
    # Within float32 rounding: the rest (beauty − Σ layers) plus the layers again.
    assert np.all(np.abs(out[..., :3] - beauty[..., :3]) <= bound(beauty, layers, {}, 0.0))
    if partition:  # Σ layers in the beauty's own order: the same float32 sums, bit for bit
        np.testing.assert_array_equal(out[..., :3], beauty[..., :3])
    np.testing.assert_array_equal(out[..., 3], beauty[..., 3])  # the beauty's alpha
    assert ("Rest_of_beauty" in nuke.nodes) == (not partition)


GRADES = {
    "gains": ({"key": LayerGrade(stops=1.5, tint=(1, 0.8, 0.5)), "rim": LayerGrade(stops=-2)}, 0.0),
    "mute": ({"key": LayerGrade(stops=0.5), "fill": LayerGrade(stops=3, mute=True)}, 0.0),
    "solo": ({"key": LayerGrade(stops=1, solo=True), "fill": LayerGrade(tint=(0, 1, 2), solo=True),
              "rim": LayerGrade(stops=4)}, 0.0),
    "solo and mute": ({"key": LayerGrade(solo=True, mute=True), "fill": LayerGrade(solo=True, stops=-1)}, 0.0),
    "exposure": ({"fill": LayerGrade(stops=0.25, tint=(0.9, 1, 1.1))}, -1.75),
}


@pytest.mark.parametrize("partition", [True, False], ids=["partition", "with rest"])
@pytest.mark.parametrize("case", GRADES)
def test_grades_give_the_composite_rule(stack, tmp_path, partition, case):
    grades, exposure = GRADES[case]
    beauty, layers = stack(partition)
    out, nuke = script_result(tmp_path, layers, grades, partition=partition, exposure=exposure)
    expected = composite_rule(beauty, layers, grades, exposure)
    assert np.all(np.abs(out[..., :3] - expected) <= bound(beauty, layers, grades, exposure))
    np.testing.assert_array_equal(out[..., 3], beauty[..., 3])
    # What is off is a disabled Merge; each Grade keeps the artist's gain.
    soloing = any(grade.solo for grade in grades.values())
    for name in layers:
        grade = grades.get(name, LayerGrade())
        assert (nuke.nodes[f"Merge_{name}"].knob("disable") == "true") == (grade.mute or soloing and not grade.solo)
        multiply = numbers(nuke.nodes[f"Grade_{name}"].knob("multiply"), 4)
        np.testing.assert_allclose(multiply[:3], 2.0 ** grade.stops * np.array(grade.tint), rtol=1e-15)
    if not partition:
        assert (nuke.nodes["Rest"].knob("disable") == "true") == soloing


def test_the_script_reads_the_exr_beside_it_wherever_the_folder_goes(stack, tmp_path):
    beauty, layers = stack(False)
    grades = {"key": LayerGrade(stops=1)}
    path = write_nuke_script(tmp_path / "look.nk", tmp_path / "look.exr", list(layers), grades,
                             resolution=(5, 6), partition=False)
    assert r'file "\[file dirname \[value root.name]]/look.exr"' in path.read_text()
    moved = shutil.copytree(tmp_path, tmp_path.parent / (tmp_path.name + " moved"))
    here, _ = evaluate(path.read_text(), path)
    there, _ = evaluate((moved / "look.nk").read_text(), moved / "look.nk")
    np.testing.assert_array_equal(here, there)
    elsewhere = write_nuke_script(tmp_path / "scripts" / "look.nk", tmp_path / "look.exr", list(layers), grades,
                                  resolution=(5, 6), partition=False)
    assert f'file "{(tmp_path / "look.exr").as_posix()}"' in elsewhere.read_text()
    np.testing.assert_array_equal(evaluate(elsewhere.read_text(), elsewhere)[0], here)


def test_a_beauty_in_a_named_part_is_shuffled_out(tmp_path, rng):
    layers = {name: rng.uniform(0, 1, (4, 3, 3)).astype(np.float32) for name in ("a", "b")}
    beauty = np.concatenate([layers["a"] + layers["b"] + 0.25, np.full((4, 3, 1), 0.5, np.float32)], axis=2)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    parts = [OpenEXR.Part(dict(header), {"R": np.zeros((4, 3), np.float32), "G": np.zeros((4, 3), np.float32),
                                   "B": np.zeros((4, 3), np.float32)}, "rgba"),
             OpenEXR.Part(dict(header), {f"beauty.{c}": np.ascontiguousarray(beauty[..., i]) for i, c in enumerate("RGBA")},
                          "beauty"),
             *(OpenEXR.Part(dict(header), {f"{name}.{c}": np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")},
                            name) for name, image in layers.items())]
    OpenEXR.File(parts).write(str(tmp_path / "named.exr"))
    grades = {"a": LayerGrade(stops=1)}
    text = nuke_script("named.exr", ["a", "b"], grades, resolution=(3, 4), partition=False, beauty_part="beauty")
    out, _ = evaluate(text, tmp_path / "named.nk")
    expected = composite_rule(beauty, layers, grades, 0.0)
    assert np.all(np.abs(out[..., :3] - expected) <= bound(beauty, layers, grades, 0.0))
    np.testing.assert_array_equal(out[..., 3], beauty[..., 3])


def test_the_passes_of_a_real_extract_rebuild_its_beauty(tmp_path):
    """A tiny render of the shipped Cornell box, its standard passes cut by `pxr-layers
    extract`: float32 parts named as the inspector's products are."""
    assert main(["render", str(ROOT / "render" / "cornell.usda"), "-o", str(tmp_path), "--spp", "2",
                 "--resolution", "12", "10", "--max-depth", "3", "--quiet", "--no-previews"]) == 0
    exr = tmp_path / "passes.exr"
    assert main(["extract", str(tmp_path / "cornell.pxlidx"), "--passes", "-o", str(exr), "--no-previews",
                 "--quiet"]) == 0
    file = OpenEXR.File(str(exr))
    names = [part.name() for part in file.parts]
    beauty = file.parts[0].channels["RGBA"].pixels
    layers = {name: part.channels[name].pixels for name, part in zip(names[1:], file.parts[1:], strict=True)}
    grades = {"diffuse_direct": LayerGrade(stops=2), "emission": LayerGrade(mute=True)}
    expected = composite_rule(beauty, layers, grades, 0.0)
    # The passes sum to the beauty within 1e-4 of its pixels (what "partition" means); the
    # rest branch makes up for even that.
    residual = np.abs(sum(layer.astype(np.float64) for layer in layers.values()) - beauty[..., :3])
    assert np.all(residual <= 1e-4 * np.maximum(beauty[..., :3], 1e-3 * beauty.max()))
    for partition, slack in ((True, residual), (False, 0)):
        path = write_nuke_script(tmp_path / "passes.nk", exr, names[1:], grades, resolution=(12, 10),
                                 partition=partition)
        out, _ = evaluate(path.read_text(), path)
        assert np.all(np.abs(out[..., :3] - expected) <= bound(beauty, layers, grades, 0.0) + slack)
        np.testing.assert_array_equal(out[..., 3], beauty[..., 3])
    assert layers["diffuse_direct"].max() > 0 and layers["emission"].max() > 0


@pytest.mark.parametrize("parts, grades, message", [
    (["key", "main"], {}, "'main'"),
    (["key", "Ci"], {}, "'Ci'"),
    (["depth"], {}, "'depth'"),
    (["key", "key"], {}, "given twice"),
    (["rgba"], {}, "'rgba'"),
    (["2key"], {}, "not a name Nuke keeps"),
    (["key"], {"key": LayerGrade(stops=math.inf)}, "finite"),
    (["key"], {"key": LayerGrade(tint=(1, -1, 1))}, "finite"),
])
def test_what_nuke_would_read_otherwise_is_refused(parts, grades, message):
    with pytest.raises(OutputError, match=message):
        nuke_script("x.exr", parts, grades, resolution=(4, 4), partition=True)


def test_a_cryptomatte_deeper_than_the_gizmo_keys_is_refused():
    from pxr_layers.recipe.model import MAX_CRYPTOMATTE_DEPTH

    text = nuke_script("x.exr", [], {}, resolution=(4, 4), partition=True,
                       cryptomattes={"CryptoObject": MAX_CRYPTOMATTE_DEPTH})
    assert " in11 CryptoObject11\n" in text and " in12 " not in text
    for depth in (0, MAX_CRYPTOMATTE_DEPTH + 1):
        with pytest.raises(OutputError, match=f"1 to {MAX_CRYPTOMATTE_DEPTH} ranks: 12 parts"):
            nuke_script("x.exr", [], {}, resolution=(4, 4), partition=True, cryptomattes={"CryptoObject": depth})


def test_a_grade_of_a_layer_not_in_the_stack_is_a_mistake():
    with pytest.raises(ValueError, match="glossy"):
        nuke_script("x.exr", ["key"], {"glossy": LayerGrade()}, resolution=(4, 4), partition=True)


def test_the_script_uses_nuke_12_nodes_and_knobs(stack, tmp_path):
    _, layers = stack(False)
    text = write_nuke_script(tmp_path / "look.nk", tmp_path / "look.exr", list(layers), {}, resolution=(5, 6),
                             partition=False).read_text()
    kinds = {item.kind for item in parse(text) if isinstance(item, Node)}
    assert kinds == {"Root", "Read", "Shuffle", "Grade", "Merge2"}
    assert text.splitlines()[1] == "version 12.0 v1"
    assert 'format "5 6 0 0 5 6 1 pxrLayers_5x6"' in text
    assert "add_layer {key key.red key.green key.blue}" in text
    assert text.isascii()


def test_the_nuke_command_rebuilds_a_product_and_wires_its_cryptomattes(tmp_path, monkeypatch):
    """`pxr-layers nuke` on a render with passes and Cryptomattes: a Shuffle, Grade and Merge
    per colour layer whose sum is part 0, and a Cryptomatte gizmo per type on the Read whose
    matte of a picked name is that name's coverage in the EXR."""
    from test_cryptomatte import matte, read_cryptomattes

    import pxr_layers.cli.main as cli

    if "nuke" not in cli.SUBCOMMAND_NAMES:
        monkeypatch.setattr(cli, "SUBCOMMAND_NAMES", (*cli.SUBCOMMAND_NAMES, "nuke"))
    assert main(["render", str(ROOT / "render" / "cornell.usda"), "-o", str(tmp_path), "--spp", "4",
                 "--resolution", "16", "12", "--quiet", "--no-previews", "--cryptomatte", "object,material"]) == 0
    exr = tmp_path / "passes.exr"
    assert main(["extract", str(tmp_path / "cornell.pxlidx"), "--passes", "--cryptomatte", "object,material",
                 "-o", str(exr), "--no-previews", "--quiet"]) == 0
    script = tmp_path / "comp" / "passes.nk"
    script.parent.mkdir()
    assert main(["nuke", str(exr), "-o", str(script), "--quiet"]) == 0
    text = script.read_text()
    items = parse(text)
    nodes = [item for item in items if isinstance(item, Node)]
    file = OpenEXR.File(str(exr))
    layers = [part.name() for part in file.parts[1:] if not part.name().startswith("Crypto")]
    assert len(layers) == 8
    for layer in layers:
        assert {f"Shuffle_{layer}", f"Grade_{layer}", f"Merge_{layer}"} <= {node.knob("name") for node in nodes}
    gizmos = [node for node in nodes if node.kind == "Cryptomatte"]
    assert [node.knob("cryptoLayer") for node in gizmos] == ["CryptoObject", "CryptoMaterial"]
    assert [gizmos[0].knob(f"in0{n}") for n in range(3)] == [f"CryptoObject0{n}" for n in range(3)]
    for gizmo in gizmos:  # on the Read
        position = items.index(gizmo)
        assert items[position - 1].words == ["push", "$N_Read_layers"]

    out, nuke = evaluate(text, script)
    beauty = file.parts[0].channels["RGBA"].pixels
    np.testing.assert_allclose(out[..., :3], beauty[..., :3], rtol=1e-5, atol=1e-6)  # the parts sum to part 0
    np.testing.assert_array_equal(out[..., 3], beauty[..., 3])

    picked = "/World/Geometry/tallBox"
    keyed = text.replace(' cryptoLayer CryptoObject\n cryptoLayerLock true\n matteList ""',
                         f' cryptoLayer CryptoObject\n cryptoLayerLock true\n matteList "{picked}, /World/Geometry/floor"')
    assert keyed != text
    nuke = Nuke(script)
    nuke.run(parse(keyed))
    gizmo_alpha = next(image for node, image in (entry for entry in nuke.stack if entry)
                       if node.kind == "Cryptomatte" and node.knob("cryptoLayer") == "CryptoObject")["rgba.alpha"]
    expected = matte(read_cryptomattes(exr)[0]["CryptoObject"], [picked, "/World/Geometry/floor"])
    np.testing.assert_allclose(gizmo_alpha, expected, atol=1e-7)
    assert expected.max() == 1.0 and expected.min() == 0.0


def test_render_and_extract_write_the_nuke_command_s_script_beside_every_product(tmp_path, capsys):
    """--nuke-script: PRODUCT.nk beside each EXR, the very text `pxr-layers nuke PRODUCT.exr` writes
    (from the images in memory instead of the file read back), printed after its EXR."""
    rendered = tmp_path / "render"
    assert main(["render", str(ROOT / "render" / "cornell.usda"), "-o", str(rendered), "--spp", "4",
                 "--resolution", "16", "12", "--no-previews", "--cryptomatte", "object", "--nuke-script"]) == 0
    printed = capsys.readouterr().out.split()
    exrs = sorted(rendered.glob("*.exr"))
    assert exrs and sorted(rendered.glob("*.nk")) == [exr.with_suffix(".nk") for exr in exrs]
    assert printed == [str(path) for exr in exrs for path in (exr, exr.with_suffix(".nk"))]
    extracted = tmp_path / "passes.exr"
    assert main(["extract", str(rendered / "cornell.pxlidx"), "--passes", "-o", str(extracted), "--no-previews",
                 "--quiet", "--nuke-script"]) == 0
    for exr in [*exrs, extracted]:
        again = write_product_script(exr, exr.with_name(f"{exr.stem}.again.nk"))  # beside it: the same file knob
        assert exr.with_suffix(".nk").read_text() == again.read_text()


def test_a_look_saved_in_the_inspector_reads_its_exr_from_any_working_directory(tmp_path, monkeypatch):
    """The inspector's save writes NAME.nk beside NAME.exr: its file knob is relative to the
    script's folder, whatever folder the server was started from, and the script rebuilds
    the look from another one (issue 33: it named the EXR relative to the server's cwd)."""
    from pxr_layers.view.session import Session

    folder = tmp_path / "shot"
    assert main(["render", str(ROOT / "render" / "cornell.usda"), "-o", str(folder), "--spp", "2",
                 "--resolution", "12", "10", "--max-depth", "3", "--quiet", "--no-previews"]) == 0
    (tmp_path / "server").mkdir()
    monkeypatch.chdir(tmp_path / "server")
    session = Session.open(folder)
    diffuse, _ = session.add_layer("diffuse", "C<RD>.*")
    saved = session.save("look", [{"id": diffuse.id, "stops": 1.0}])
    script = folder / saved["nuke"]
    text = script.read_text()
    assert r'file "\[file dirname \[value root.name]]/look.exr"' in text
    (tmp_path / "artist").mkdir()
    monkeypatch.chdir(tmp_path / "artist")
    out, _ = evaluate(text, script)
    file = OpenEXR.File(str(folder / "look.exr"))
    beauty, layer = file.parts[0].channels["RGBA"].pixels, file.parts[1].channels["diffuse"].pixels
    expected = composite_rule(beauty, {"diffuse": layer}, {"diffuse": LayerGrade(stops=1.0)}, 0.0)
    assert np.all(np.abs(out[..., :3] - expected) <= bound(beauty, {"diffuse": layer},
                                                           {"diffuse": LayerGrade(stops=1.0)}, 0.0))


@pytest.mark.parametrize("script, exr", [("look.nk", "look.exr"), ("comp/look.nk", "look.exr"),
                                         ("look.nk", "./sub/../look.exr"), ("sub/look.nk", "sub/../look.exr")])
def test_the_nuke_command_s_script_opens_from_any_working_directory(stack, tmp_path, monkeypatch, script, exr):
    """`pxr-layers nuke` given names relative to one folder: the script, read from another
    folder, finds the EXR and rebuilds the beauty."""
    beauty, _ = stack(True)
    for folder in ("comp", "sub", "elsewhere"):
        (tmp_path / folder).mkdir()
    monkeypatch.chdir(tmp_path)
    assert main(["nuke", exr, "-o", script, "--quiet"]) == 0
    monkeypatch.chdir(tmp_path / "elsewhere")
    out, _ = evaluate((tmp_path / script).read_text(), tmp_path / script)
    np.testing.assert_array_equal(out[..., :3], beauty[..., :3])


@pytest.mark.parametrize("name", ["look.txt", "look", "look.nk.bak"])
def test_a_nuke_script_is_written_only_under_a_nk_name(stack, tmp_path, name):
    _, layers = stack(True)
    with pytest.raises(OutputError, match=f"{name}: not a Nuke script's name: a Nuke script ends in .nk"):
        write_nuke_script(tmp_path / name, tmp_path / "look.exr", list(layers), {}, resolution=(5, 6),
                          partition=True)
    assert not (tmp_path / name).exists()


# --- masks -----------------------------------------------------------------------------------

MASK_NAMES = ("/World/a", "/World/b", "/World/c")


@pytest.fixture
def masked_stack(tmp_path, rng):
    """look.exr: three random layers (a beauty with light no layer holds) and a CryptoObject
    of MASK_NAMES with random, fractional coverages (some pixels background, some covered by
    all three): (beauty (h, w, 4), layers)."""
    from pxr_layers.layers.cryptomatte import rank
    from pxr_layers.recipe.model import CRYPTOMATTE_DATA_TYPE, Layer, Product

    height, width = 6, 5
    layers = {name: rng.uniform(0, 4, (height, width, 3)).astype(np.float32) for name in ("key", "fill", "rim")}
    rgb = layers["key"] + layers["fill"] + layers["rim"] + rng.uniform(0.5, 2, (height, width, 3)).astype(np.float32)
    beauty = np.concatenate([rgb, np.ones((height, width, 1), np.float32)], axis=2)
    shares = rng.dirichlet(np.ones(4), height * width).astype(np.float32)  # three names and the background
    shares[rng.uniform(size=height * width) < 0.3] = [1, 0, 0, 0]  # whole pixels of /World/a
    pixel, name = np.nonzero(shares[:, :3] > 0)
    matte = rank(MASK_NAMES, pixel, name, shares[pixel, name], (width, height), 6, "CryptoObject")
    product = Product("look", "look.exr", "/camera", (width, height),
                      (Layer("beauty", "raw", "color"), *(Layer(name, "lpe", "C.*") for name in layers),
                       Layer("CryptoObject", "raw", "CryptoObject", data_type=CRYPTOMATTE_DATA_TYPE, preview=False)))
    write_multipart(tmp_path / "look.exr", beauty, {**layers, "CryptoObject": matte}, product)
    return beauty, layers


def mask(*names: str):
    from pxr_layers.layers.nuke import LayerMask

    return LayerMask("object", names)


MASKED = {
    "masked gain": ({"key": LayerGrade(stops=2, tint=(1, 0.5, 0.25), mask=mask("/World/a")),
                     "rim": LayerGrade(stops=-1)}, 0.0),
    "masked mute": ({"fill": LayerGrade(stops=1, mute=True, mask=mask("/World/b", "/World/c")),
                     "key": LayerGrade(stops=1, mute=True)}, 0.5),
    "masked solo": ({"key": LayerGrade(stops=1, solo=True, mask=mask("/World/a")),
                     "fill": LayerGrade(solo=True, mute=True, mask=mask("/World/b")),
                     "rim": LayerGrade(stops=3, mask=mask("/World/c"))}, 0.0),
    "mask of every name": ({"rim": LayerGrade(stops=-3, tint=(2, 1, 0), mask=mask(*MASK_NAMES))}, -1.0),
}


@pytest.mark.parametrize("case", MASKED)
def test_masked_grades_give_the_masked_composite_rule(masked_stack, tmp_path, case):
    """A masked layer's Grade takes the matte of a Cryptomatte gizmo keyed on its names: the
    script is the rule with w = 1 + m·(gain − 1), m the names' matte decoded here from the
    EXR (test_cryptomatte.matte), and the inspector's composite (view/composite.py) with the
    masks of layers.cryptomatte.coverage agrees."""
    from test_cryptomatte import matte, read_cryptomattes

    from pxr_layers.layers.cryptomatte import coverage
    from pxr_layers.layers.multipart import read_multipart
    from pxr_layers.view.composite import composite

    grades, exposure = MASKED[case]
    beauty, layers = masked_stack
    path = write_nuke_script(tmp_path / "look.nk", tmp_path / "look.exr", list(layers), grades, resolution=(5, 6),
                             partition=False, exposure=exposure, cryptomattes={"CryptoObject": 6})
    out, nuke = evaluate(path.read_text(), path)
    entry = read_cryptomattes(tmp_path / "look.exr")[0]["CryptoObject"]
    masks = {name: matte(entry, list(grade.mask.names)) for name, grade in grades.items() if grade.mask}
    assert all(0.0 < m.mean() < 1.0 for m in masks.values())  # fractional somewhere, not everywhere
    expected = composite_rule(beauty, layers, grades, exposure, masks)
    tolerance = 2 * bound(beauty, layers, grades, exposure) + 1e-6  # the mask's blend rounds thrice more
    assert np.all(np.abs(out[..., :3] - expected) <= tolerance)
    np.testing.assert_array_equal(out[..., 3], beauty[..., 3])
    soloing = any(grade.solo for grade in grades.values())
    for name in layers:
        grade = grades.get(name, LayerGrade())
        node = nuke.nodes[f"Grade_{name}"]
        assert (node.knob("inputs") == "1+1") == (grade.mask is not None)
        if grade.mask is not None:
            keyer = nuke.nodes[f"Mask_{name}"]
            assert keyer.kind == "Cryptomatte" and keyer.knob("cryptoLayer") == "CryptoObject"
            assert keyer.knob("matteList") == ", ".join(grade.mask.names)
        off = (grade.mute and grade.mask is None) or (soloing and not grade.solo)
        assert (nuke.nodes[f"Merge_{name}"].knob("disable") == "true") == off

    read = read_multipart(tmp_path / "look.exr")
    ours = {name: coverage(read.cryptomattes["CryptoObject"], grade.mask.names) for name, grade in grades.items()
            if grade.mask}
    for name, m in ours.items():
        np.testing.assert_allclose(m, masks[name], atol=1e-6)
    inspector = composite(beauty[..., :3], list(layers.values()), [grades.get(n, LayerGrade()) for n in layers],
                          exposure, [ours.get(n) for n in layers])
    assert np.all(np.abs(inspector - expected) <= tolerance)


def test_a_mask_needs_its_cryptomatte_and_names_the_gizmo_can_list(masked_stack, tmp_path):
    _, layers = masked_stack
    grades = {"key": LayerGrade(mask=mask("/World/a"))}
    with pytest.raises(OutputError, match="the mask of 'key' keys the object Cryptomatte 'CryptoObject', which the "
                                          "EXR does not hold"):
        nuke_script("look.exr", list(layers), grades, resolution=(5, 6), partition=False)
    # another layer name for the kind: the product's own Cryptomatte layer
    text = nuke_script("look.exr", list(layers), grades, resolution=(5, 6), partition=False,
                       cryptomattes={"Objects": 4}, mask_layers={"object": "Objects"})
    assert " cryptoLayer Objects\n" in text and " in01 Objects01\n" in text
    with pytest.raises(OutputError, match=r"the mask name '/World/a\*' holds \*"):
        nuke_script("look.exr", list(layers), {"key": LayerGrade(mask=mask("/World/a*"))}, resolution=(5, 6),
                    partition=False, cryptomattes={"CryptoObject": 6})
    spaced = nuke_script("look.exr", list(layers), {"key": LayerGrade(mask=mask("/World/a b", "/World/c,d"))},
                         resolution=(5, 6), partition=False, cryptomattes={"CryptoObject": 6})
    assert r' matteList "\"/World/a b\", \"/World/c,d\""' in spaced
