"""No file name can inject Tcl into a Nuke script (issue 33): every string in a .nk is one
Tcl word reading back as itself, checked against a real Tcl (tkinter's) in a safe
interpreter where the only commands are recorders: a substitution or an extra top-level
command is an error there, or a value that differs.

Nuke runs a .nk as a Tcl script (a node block ``Read { ... }`` is one braced word whose
lines are ``knob value``), then substitutes a file knob's value as Tcl again when it opens
the file (``[...]``, ``$``, backslashes); both levels are checked.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pxr_layers.errors import OutputError
from pxr_layers.layers.multipart import write_multipart
from pxr_layers.layers.nuke import nuke_script, tcl_escaped, tcl_word, write_nuke_script
from pxr_layers.recipe.model import Layer, layer_problems

tkinter = pytest.importorskip("tkinter")

HOSTILE = [
    'x\npython {import os; os.system("touch /tmp/pwned")}\n',
    "[exec rm -rf /]",
    "\\[exec rm -rf /]",
    "$env(HOME)",
    "${HOME}",
    "a; python {print(1)}",
    "open{ brace",
    "close} brace",
    "}\nRead {\n",
    'quote"d',
    "back\\slash\\",
    "\\\n",
    "tab\tcr\rform\fvertical\vnul\x00del\x7f",
    "\u2028line\u2029sep\x85next",
    " leading and trailing ",
    "#not a comment",
    "ünïcødé 映像 🎞",
    "",
]
NODE_KINDS = ("Root", "Read", "Shuffle", "Grade", "Merge2", "Cryptomatte")
SCRIPT = Path("/comp/look.nk")


class SafeTcl:
    """A real Tcl: a safe child interpreter ``nk`` whose only visible commands are ``set``
    and recorders (``record`` in the master appends each call to ``::recorded``), and a
    child ``fn`` where Nuke's file-knob substitution runs with ``value`` and ``file``."""

    def __init__(self, commands=(*NODE_KINDS, "version", "add_layer", "push", "stack", "knob")):
        self.tcl = tkinter.Tcl()
        self.tcl.eval("""
            set ::recorded {}
            proc record {args} {
                lappend ::recorded $args
                if {[lindex $args 0] eq "stack"} { return stack0 }
            }
            proc root_name {knob} {
                if {$knob ne "root.name"} { error "value $knob" }
                return %s
            }
            proc file_dirname {subcommand path} {
                if {$subcommand ne "dirname"} { error "file $subcommand" }
                return [file dirname $path]
            }""" % tcl_word(SCRIPT.as_posix()))
        for name in ("nk", "fn"):
            self.tcl.eval(f"interp create -safe {name}")
            for command in self.tcl.splitlist(self.tcl.eval(f"{name} eval {{info commands}}")):
                if not (name == "nk" and command == "set"):
                    self.tcl.call("interp", "hide", name, command)
        for command in commands:
            self.tcl.call("interp", "alias", "nk", command, "", "record", command)
        self.tcl.call("interp", "alias", "fn", "value", "", "root_name")
        self.tcl.call("interp", "alias", "fn", "file", "", "file_dirname")

    def string(self, expression: str) -> str:
        """The master's Tcl ``expression`` as a Python str (NULs and all)."""
        self.tcl.eval("set ::out {}; append ::out " + expression)
        return self.tcl.getvar("::out")

    def run(self, script: str) -> list[list[str]]:
        """Every command ``script`` ran in ``nk``, as words (``set`` not recorded)."""
        self.tcl.eval("set ::recorded {}")
        self.tcl.call("interp", "eval", "nk", script)
        count = int(self.tcl.eval("llength $::recorded"))
        return [[self.string(f"[lindex $::recorded {i} {j}]")
                 for j in range(int(self.tcl.eval(f"llength [lindex $::recorded {i}]")))] for i in range(count)]

    def word(self, word: str) -> str:
        """What Tcl reads ``word`` as, as a command's argument."""
        self.tcl.call("interp", "eval", "nk", "set x " + word)
        return self.string("[interp eval nk {set x}]")

    def subst(self, text: str) -> str:
        """Nuke's substitution of a file knob's value."""
        self.tcl.setvar("::in", text)
        return self.string("[interp invokehidden fn subst $::in]")


@pytest.fixture(scope="module")
def tcl() -> SafeTcl:
    try:
        return SafeTcl()
    except tkinter.TclError as error:  # tkinter without its Tcl library
        pytest.skip(f"no Tcl: {error}")


def knobs(tcl: SafeTcl, body: str) -> dict[str, str]:
    """A node block's knobs read as Tcl does both ways, which must agree: the body as a
    list, and each line as a command ``knob NAME VALUE``."""
    words = tcl.tcl.splitlist(body)
    as_list = dict(zip(words[::2], words[1::2], strict=True))
    lines = [line for line in body.split("\n") if line.strip()]
    as_commands = {}
    for line in lines:
        (_, name, value), = tcl.run("knob " + line)
        as_commands[name] = value
    assert as_list == as_commands and len(lines) == len(as_list)
    return as_list


def assert_reads_back(tcl: SafeTcl, text: str) -> None:
    word = tcl_word(text)
    assert "\n" not in word and "\r" not in word
    assert tcl.word(word) == text  # as a command's argument
    assert tcl.tcl.splitlist(word) == (text,)  # as a list's element
    (kind, body), = tcl.run("Read {\n file " + word + "\n}")  # inside a node block's braces
    assert kind == "Read" and knobs(tcl, body) == {"file": text}
    assert tcl.subst(tcl_escaped(text)) == text  # substituted again, as Nuke does to a file knob


@pytest.mark.parametrize("text", HOSTILE)
def test_a_hostile_string_is_one_word_that_reads_back_as_itself(tcl, text):
    assert_reads_back(tcl, text)


@settings(max_examples=200, deadline=None)
@given(st.text())
def test_any_string_is_one_word_that_reads_back_as_itself(tcl, text):
    assert_reads_back(tcl, text)


def test_ordinary_words_stay_as_they_were():
    assert [tcl_word(text) for text in ("linear", "-150", "1e-05", "nuke-default", "a b", "", "/x/look.exr")] == [
        "linear", "-150", "1e-05", "nuke-default", '"a b"', '""', '"/x/look.exr"']
    assert tcl_word("[file dirname [value root.name]]/look.exr") == '"\\[file dirname \\[value root.name]]/look.exr"'


def script_of(exr_path: str) -> str:
    return nuke_script(exr_path, ["key", "fill"], {}, resolution=(4, 3), partition=False,
                       cryptomattes={"CryptoObject": 2})


@pytest.mark.parametrize("absolute", [True, False], ids=["absolute", "relative"])
@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_exr_path_adds_no_command_and_is_the_file_read(tcl, name, absolute):
    from test_nuke_script import Command, Node, parse, tcl_value

    path = ("/shots/" if absolute else "") + name + ".exr"
    expected = Path(path).as_posix() if absolute else f"{SCRIPT.parent.as_posix()}/{Path(path).as_posix()}"
    clean, script = script_of("/shots/look.exr" if absolute else "look.exr"), script_of(path)
    assert len(script.splitlines()) == len(clean.splitlines()) and script.startswith("# ")

    ran, ran_clean = tcl.run(script), tcl.run(clean)
    assert [command[0] for command in ran] == [command[0] for command in ran_clean]  # no command more
    reads = [command for command in ran if command[0] == "Read"]
    assert len(reads) == 1
    file = knobs(tcl, reads[0][1])["file"]
    assert tcl.subst(file) == expected
    for command, clean_command in zip(ran, ran_clean, strict=True):  # nothing else differs
        if command[0] != "Read":
            assert command == clean_command
            if command[0] in NODE_KINDS:
                knobs(tcl, command[1])

    # The independent parser of test_nuke_script reads the same script alike.
    items, clean_items = parse(script), parse(clean)
    assert [(type(item), item.kind if isinstance(item, Node) else item.words) for item in items] == [
        (type(item), item.kind if isinstance(item, Node) else item.words) for item in clean_items]
    read, = (item for item in items if isinstance(item, Node) and item.kind == "Read")
    assert read.knob("file") == file and tcl_value(file, SCRIPT) == expected
    assert all(isinstance(item, Command) or item.kind != "Read" or item is read for item in items)


def test_a_script_beside_a_hostile_exr_rebuilds_it(tcl, tmp_path):
    """A real file whose name holds every hostile character (but ``/``): the script beside it
    and one elsewhere both read it (the small Nuke of test_nuke_script) and give the beauty."""
    from test_nuke_script import evaluate

    rng = np.random.default_rng(33)
    layers = {name: rng.uniform(0, 1, (3, 4, 3)).astype(np.float32) for name in ("key", "fill")}
    beauty = np.concatenate([layers["key"] + layers["fill"], np.full((3, 4, 1), 0.5, np.float32)], axis=2)
    exr = (tmp_path / 'x\npython {import os; os.system("touch pwned")}\n[exec rm -rf ]$env(HOME);{"\\ é\t}'
           / "\\\n} [exec touch pwned] {.exr")
    exr.parent.mkdir()
    write_multipart(exr, beauty, layers)
    for script in (tmp_path / "look.nk", tmp_path / "elsewhere" / "look.nk"):
        script.parent.mkdir(exist_ok=True)
        path = write_nuke_script(script, exr, list(layers), {}, resolution=(4, 3), partition=True)
        text = path.read_text(encoding="utf-8")
        out, nuke = evaluate(text, path)
        np.testing.assert_array_equal(out, beauty)
        (read,) = (command for command in tcl.run(text) if command[0] == "Read")
        file = knobs(tcl, read[1])["file"]
        if script.parent == tmp_path:
            assert file.startswith("[file dirname [value root.name]]/")
            assert tcl.subst(file) == SCRIPT.parent.as_posix() + "/" + exr.relative_to(tmp_path).as_posix()
        else:
            assert tcl.subst(file) == exr.as_posix()
    assert not list(tmp_path.rglob("pwned"))


@pytest.mark.parametrize("name", ["key\n", "key\nx", "key ", "ke;y", "key}"])
def test_a_part_name_with_a_trailing_newline_is_refused(name):
    """Names are checked whole (fullmatch): ``^...$`` with ``match`` lets ``key\\n`` through."""
    with pytest.raises(OutputError, match="not a name Nuke keeps"):
        nuke_script("x.exr", [name], {}, resolution=(4, 4), partition=True)
    with pytest.raises(OutputError, match="not a name Nuke keeps"):
        nuke_script("x.exr", ["key"], {}, resolution=(4, 4), partition=True, beauty_part=name)
    with pytest.raises(OutputError, match="not a name Nuke keeps|is not one the gizmo keys"):
        nuke_script("x.exr", [], {}, resolution=(4, 4), partition=True, cryptomattes={name: 1})
    with pytest.raises(Exception, match="not an identifier"):
        Layer(name, "lpe", "C<RD>.*")
    assert layer_problems(Layer("key", "lpe", "C<RD>.*")) == []


@pytest.mark.parametrize("where", ["beside", "below", "elsewhere"])
def test_the_file_knob_names_the_exr_from_any_working_directory(tcl, tmp_path, monkeypatch, where):
    """Written from one working directory with relative names, the script's file knob,
    substituted by a real, unrestricted Tcl (``file dirname``, ``value root.name`` = the
    script as opened) run from another folder, is an existing file: the EXR (issue 33)."""
    rng = np.random.default_rng(7)
    layers = {"key": rng.uniform(0, 1, (3, 4, 3)).astype(np.float32)}
    beauty = np.concatenate([layers["key"], np.ones((3, 4, 1), np.float32)], axis=2)
    shots = tmp_path / "shots [v1] $x"
    exr = shots / ("sub" if where == "below" else "") / "a {b} ;c.exr"
    exr.parent.mkdir(parents=True)
    write_multipart(exr, beauty, layers)
    script = (tmp_path / "comp" if where == "elsewhere" else shots) / "look.nk"
    monkeypatch.chdir(shots)
    written = write_nuke_script(os.path.relpath(script), os.path.relpath(exr), ["key"], {}, resolution=(4, 3),
                                partition=True)
    (read,) = (command for command in tcl.run(written.read_text(encoding="utf-8")) if command[0] == "Read")
    file = knobs(tcl, read[1])["file"]
    assert file.startswith("[file dirname [value root.name]]/") == (where != "elsewhere")
    real = tkinter.Tcl()
    real.eval(f"proc value {{knob}} {{ return {tcl_word(script.as_posix())} }}")
    real.eval(f"cd {tcl_word(tmp_path.parent.as_posix())}")
    real.setvar("knob", file)
    assert os.path.realpath(real.eval("subst $knob")) == os.path.realpath(exr)
    assert real.eval("file isfile [subst $knob]") == "1"
