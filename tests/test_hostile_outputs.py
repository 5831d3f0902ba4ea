"""Hostile conditions around a render's outputs (issue 18, items 1, 7, 8 and the umask):
two renders into one folder, a full disk, SIGTERM and SIGKILL, a folder that cannot be
written, Ctrl-C during start-up. The real console script in a subprocess, as a farm runs it."""

from __future__ import annotations

import fcntl
import os
import resource
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from pxr_layers.layers.exr import METADATA_PREFIX
from pxr_layers.paths.reader import PathIndex

from test_cli import RENDER_DIR, SCRIPT, run

CORNELL = str(RENDER_DIR / "cornell.usda")
TINY = ["--spp", "2", "--resolution", "24", "24", "--max-depth", "3", "--quiet"]
LONG = ["--spp", "4096", "--resolution", "64", "64", "--quiet"]  # minutes: only ever interrupted


def start(*args: str, preexec=None) -> subprocess.Popen:
    return subprocess.Popen([SCRIPT, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "CI": "1"}, preexec_fn=preexec)


def visible_files(folder: Path) -> list[str]:
    return sorted(path.name for path in folder.iterdir() if not path.name.startswith("."))


def temporaries(folder: Path) -> list[str]:
    return sorted(path.name for path in folder.iterdir() if path.name.startswith(".") and ".tmp" in path.name)


def render_id(exr: Path) -> str:
    return OpenEXR.File(str(exr)).header()[METADATA_PREFIX + "renderId"]


def wait_for_temporary_index(folder: Path, process: subprocess.Popen, timeout: float = 240.0) -> None:
    """Until the render has begun writing its index (it is tracing)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process.poll() is None:
        if folder.is_dir() and any(name.endswith(".tmp.pxlidx") for name in temporaries(folder)):
            return
        time.sleep(0.05)
    raise AssertionError(f"the render did not start tracing: {process.communicate()}")


# -- 1. two renders, one folder -------------------------------------------------------------

def test_the_index_and_the_exr_carry_one_render_id(tmp_path):
    assert run("render", CORNELL, "-o", str(tmp_path), *TINY).returncode == 0
    identifier = PathIndex(tmp_path / "cornell.pxlidx").manifest["render_id"]
    assert len(identifier) == 32 and render_id(tmp_path / "cornell.exr") == identifier
    again = tmp_path / "again"
    assert run("render", CORNELL, "-o", str(again), *TINY).returncode == 0
    assert render_id(again / "cornell.exr") == identifier, "the same render again is the same render"


def test_extract_refuses_an_exr_of_another_render_beside_the_index(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    assert run("render", CORNELL, "-o", str(first), *TINY).returncode == 0
    assert run("render", CORNELL, "-o", str(second), *TINY, "--seed", "7").returncode == 0
    os.replace(first / "cornell.exr", second / "cornell.exr")  # what an interleaved pair of renders left
    result = run("extract", str(second / "cornell.pxlidx"), "--layer", "diffuse=C<RD>.*", "--quiet")
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1 and "cornell.exr" in result.stderr and "another render" in result.stderr
    assert not (second / "cornell.layers.exr").exists()


def test_a_commit_waits_for_the_folder_lock_of_another(tmp_path):
    """While another process holds the folder's lock (committing its set), a render's files do
    not appear; they all appear once it is released."""
    tmp_path.mkdir(exist_ok=True)
    handle = os.open(tmp_path, os.O_RDONLY)
    fcntl.flock(handle, fcntl.LOCK_EX)
    try:
        process = start("render", CORNELL, "-o", str(tmp_path), *TINY)
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not any(name.endswith(".tmp.pxlidx") for name in temporaries(tmp_path)):
            time.sleep(0.05)
        time.sleep(3.0)  # long past the tiny render's tracing: it is waiting to commit
        assert process.poll() is None and visible_files(tmp_path) == []
    finally:
        os.close(handle)
    assert process.wait(timeout=240) == 0, process.stderr.read()
    assert visible_files(tmp_path) == ["cornell.exr", "cornell.pxlidx", "cornell.rgba.png"]


def test_two_concurrent_renders_leave_one_consistent_pair(tmp_path):
    processes = [start("render", CORNELL, "-o", str(tmp_path), *TINY, "--seed", str(seed)) for seed in (1, 2)]
    assert [process.wait(timeout=300) for process in processes] == [0, 0]
    assert render_id(tmp_path / "cornell.exr") == PathIndex(tmp_path / "cornell.pxlidx").manifest["render_id"]
    assert temporaries(tmp_path) == []
    assert run("extract", str(tmp_path / "cornell.pxlidx"), "--passes", "--no-previews", "--quiet").returncode == 0
    layers = OpenEXR.File(str(tmp_path / "cornell.layers.exr"))
    beauty = layers.parts[0].channels["RGBA"].pixels[..., :3]
    summed = np.zeros_like(beauty)
    for part in layers.parts[1:]:
        summed += part.channels[part.name()].pixels  # the binding groups NAME.R, .G, .B as one (h, w, 3)
    np.testing.assert_allclose(summed, beauty, rtol=1e-4, atol=1e-5)


# -- 7. a full disk ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def warm_kernels(tmp_path_factory):
    """The tracer's compiled kernels in numba's cache before a render runs under a file size
    limit (saving them is a write like any other)."""
    assert run("render", CORNELL, "-o", str(tmp_path_factory.mktemp("warm")), *TINY).returncode == 0


def _file_size_limit(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


@pytest.mark.parametrize("limit, outcome", [(600, "fails"), (3000, None), (12000, None), (10_000_000, "succeeds")])
def test_a_disk_that_fills_up_leaves_all_the_outputs_or_none(tmp_path, limit, outcome, warm_kernels):
    """RLIMIT_FSIZE fails every write past `limit` bytes in a file, as a full disk does: the
    render either writes everything or, with one line naming the file, nothing at all."""
    process = start("render", CORNELL, "-o", str(tmp_path), "--spp", "8", "--resolution", "40", "40", "--quiet",
                    preexec=_file_size_limit(limit))
    _, stderr = process.communicate(timeout=300)
    assert "Traceback" not in stderr and "internal error" not in stderr
    assert outcome is None or process.returncode == {"fails": 1, "succeeds": 0}[outcome], stderr
    files = visible_files(tmp_path) if tmp_path.exists() else []
    if process.returncode == 0:
        assert files == ["cornell.exr", "cornell.pxlidx", "cornell.rgba.png"]
        assert all((tmp_path / name).stat().st_size > 0 for name in files)
    else:
        assert process.returncode == 1 and stderr.count("\n") == 1 and "cannot write" in stderr, stderr
        assert files == [], f"a failed render left {files}"
    assert not tmp_path.exists() or temporaries(tmp_path) == []


# -- 8. SIGTERM, SIGKILL, Ctrl-C --------------------------------------------------------------

def test_sigterm_is_handled_like_ctrl_c(tmp_path):
    process = start("render", CORNELL, "-o", str(tmp_path), *LONG)
    wait_for_temporary_index(tmp_path, process)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGTERM
    assert stderr == "pxr-layers: terminated; nothing was written\n"
    assert os.listdir(tmp_path) == []


def test_a_later_render_removes_the_temporaries_of_a_killed_one(tmp_path):
    process = start("render", CORNELL, "-o", str(tmp_path), *LONG)
    wait_for_temporary_index(tmp_path, process)
    process.kill()
    process.wait(timeout=60)
    left = temporaries(tmp_path)
    assert left and all(f"-{process.pid}." in name for name in left)
    assert run("render", CORNELL, "-o", str(tmp_path), *TINY).returncode == 0
    assert temporaries(tmp_path) == []
    assert visible_files(tmp_path) == ["cornell.exr", "cornell.pxlidx", "cornell.rgba.png"]


def test_ctrl_c_during_start_up_is_one_line(tmp_path):
    process = start("render", CORNELL, "-o", str(tmp_path), *TINY)
    time.sleep(0.4)  # inside the imports (numpy, USD, Embree take seconds)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert stderr == "pxr-layers: interrupted; nothing was written\n"


# -- folders that cannot be written, the umask ------------------------------------------------

@pytest.mark.parametrize("output", ["a_file/out", "a_file", "/proc/self/out"])
def test_an_output_folder_that_cannot_be_written_is_one_line(tmp_path, output):
    (tmp_path / "a_file").write_text("not a folder")
    target = output if output.startswith("/") else str(tmp_path / output)
    result = run("render", CORNELL, "-o", target, *TINY)
    assert result.returncode == 1 and result.stderr.count("\n") == 1, result.stderr
    assert target in result.stderr


def test_outputs_have_the_mode_the_umask_gives(tmp_path):
    def umask_027() -> None:
        os.umask(0o027)

    process = start("render", CORNELL, "-o", str(tmp_path), *TINY, preexec=umask_027)
    assert process.wait(timeout=300) == 0
    modes = {name: (tmp_path / name).stat().st_mode & 0o777 for name in visible_files(tmp_path)}
    assert set(modes.values()) == {0o640}, modes


def test_ctrl_c_during_the_renames_is_raised_after_them():
    """The process's other threads (Embree's, numba's) do not take the signal in the middle
    of a commit either: it is recorded, then raised once the block is done."""
    import threading

    from pxr_layers.interrupts import raise_recorded, recorded

    other = threading.Thread(target=time.sleep, args=(0.5,))
    other.start()
    reached = False
    with pytest.raises(KeyboardInterrupt):
        with recorded() as received:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)  # Python runs handlers between bytecodes: here, without the recording
            reached = True
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        raise_recorded(received)
    other.join()
    assert reached


# -- issue 33: what an output may be ---------------------------------------------------------
#
# Every command that writes refuses, in one line naming the file and before its work: a name
# that is (or links to) a FIFO, a device, a folder; a name of the wrong kind for what it
# writes; one of its own inputs (the index, the render's EXR, the stage), however spelt; and
# a recipe's productName that leaves the output folder. Such a name is never replaced.

import shutil  # noqa: E402 (the section's own imports)
import stat  # noqa: E402

from test_hostile_jobs import one_error_line  # noqa: E402

from pxr_layers.cli.main import main  # noqa: E402
from pxr_layers.errors import OutputError, RecipeError  # noqa: E402
from pxr_layers.outputs import OutputSet, check_output, output_problem, reading, write_atomically  # noqa: E402
from pxr_layers.recipe.model import Layer, Product  # noqa: E402

SMALL = ["--spp", "2", "--resolution", "16", "16", "--max-depth", "3", "--quiet", "--no-previews"]


def cli(capsys, *args: str) -> tuple[int, str, str]:
    """`pxr-layers ARGS` in this process: (exit code, stdout, stderr)."""
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def refused(capsys, name, *args: str) -> str:
    """Run the command; it must exit 1 with one error line naming ``name``. Returns the line."""
    code, out, err = cli(capsys, *args)
    line = one_error_line(err)
    assert code == 1 and str(name) in line and "internal error" not in line, (code, err)
    return line


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    """A tiny render of the Cornell box (cornell.exr, cornell.pxlidx) and its passes cut by
    extract (passes.exr), made once; tests work on a copy (:func:`shot`)."""
    folder = tmp_path_factory.mktemp("rendered") / "out"
    assert main(["render", CORNELL, "-o", str(folder), *SMALL]) == 0
    assert main(["extract", str(folder / "cornell.pxlidx"), "--passes", "-o", str(folder / "passes.exr"),
                 "--quiet", "--no-previews"]) == 0
    return folder


@pytest.fixture
def shot(rendered, tmp_path) -> Path:
    """A copy of the rendered folder, the test's own (tmp_path/out)."""
    return Path(shutil.copytree(rendered, tmp_path / "out"))


def contents(folder: Path) -> dict[str, bytes]:
    """Every regular file under ``folder`` (names relative to it) and its bytes."""
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*")) if path.is_file()}


# --- its own inputs ----------------------------------------------------------------------------

OWN_INPUTS = {
    # suggest names its EXRs after its recipe: shot.usda beside shot.pxlidx would write shot.exr
    "suggest recipe named after the render": (
        ["suggest", "{out}/cornell.pxlidx", "-k", "2", "-o", "{out}/cornell.usda"], "{out}/cornell.exr"),
    "suggest -o the render's EXR": (
        ["suggest", "{out}/cornell.pxlidx", "-o", "{out}/cornell.exr"], "{out}/cornell.exr"),
    "suggest -o the index": (["suggest", "{out}/cornell.pxlidx", "-o", "{out}/cornell.pxlidx"], "{out}/cornell.pxlidx"),
    "extract -o the render's EXR": (["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{out}/cornell.exr"],
                                    "{out}/cornell.exr"),
    "extract -o the render's EXR, spelt with ..": (
        ["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{out}/../out/cornell.exr"], "{out}/../out/cornell.exr"),
    "extract -o a link to the render's EXR": (["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{out}/link.exr"],
                                             "{out}/link.exr"),
    "extract -o the index": (["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{out}/cornell.pxlidx"],
                             "{out}/cornell.pxlidx"),
    "nuke -o its product": (["nuke", "{out}/passes.exr", "-o", "{out}/passes.exr"], "{out}/passes.exr"),
    "nuke -o a link to its product": (["nuke", "{out}/passes.exr", "-o", "{out}/passes_link.nk"],
                                      "{out}/passes_link.nk"),
    "render -o its stage": (["render", "{out}/stage.usda", "-o", "{out}/stage.usda", *SMALL], "{out}/stage.usda"),
}


@pytest.mark.parametrize("case", list(OWN_INPUTS))
def test_a_command_never_replaces_its_own_inputs(shot, capsys, case):
    (shot / "link.exr").symlink_to("cornell.exr")
    (shot / "passes_link.nk").symlink_to("passes.exr")
    shutil.copy(CORNELL, shot / "stage.usda")
    before = contents(shot)
    args, name = OWN_INPUTS[case]
    refused(capsys, name.format(out=shot), *(arg.format(out=shot) for arg in args))
    assert contents(shot) == before
    assert (shot / "link.exr").is_symlink() and (shot / "passes_link.nk").is_symlink()


def test_an_input_is_known_as_a_file_whatever_its_name(tmp_path):
    """The rule itself: device and inode, so a link, a relative or a `..` spelling is the input."""
    source = tmp_path / "in.exr"
    source.write_bytes(b"x")
    (tmp_path / "alias.exr").symlink_to(source)
    (tmp_path / "hard.exr").hardlink_to(source)
    spellings = [source, tmp_path / "alias.exr", tmp_path / "hard.exr", tmp_path / ".." / tmp_path.name / "in.exr"]
    with reading(source, tmp_path / "missing.usda", None):  # one missing, one None: skipped
        for path in spellings:
            assert "this command reads" in output_problem(path), path
            with pytest.raises(OutputError, match="this command reads"):
                write_atomically(path, lambda temporary: temporary.write_bytes(b"y"))
    assert [output_problem(path) for path in spellings] == [None] * 4  # the block is over
    assert source.read_bytes() == b"x" and not [p for p in tmp_path.iterdir() if ".tmp" in p.name]


def test_a_look_saved_under_the_render_s_name_does_not_replace_its_exr(shot):
    """The inspector's save with overwrite: true writes NAME.exr, NAME.usda, NAME.nk; a look
    named after the render would replace the EXR (and index) it reads."""
    from pxr_layers.view.session import Session

    session = Session.open(shot)
    layer, _ = session.add_layer("diffuse", "C<RD>.*")
    before = contents(shot)
    with pytest.raises(OutputError, match="cornell.exr: is a file this command reads"):
        session.save("cornell", [{"id": layer.id}], overwrite=True)
    assert contents(shot) == before
    assert session.save("look", [{"id": layer.id}])["exr"] == "look.exr"


# --- the kind of file a command writes ---------------------------------------------------------

WRONG_SUFFIXES = {
    "extract -o cut.png": (["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{out}/cut.png"], "{out}/cut.png",
                           "names a .png file, not a folder"),
    "extract -o cut.nk": (["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{out}/cut.nk"], "{out}/cut.nk",
                          "names a .nk file, not a folder"),
    "render -o shot.png": (["render", CORNELL, "-o", "{out}/shot.png", *SMALL], "{out}/shot.png",
                           "names a .png file, not a folder"),
    "suggest -o x.exr": (["suggest", "{out}/cornell.pxlidx", "-o", "{out}/x.exr"], "{out}/x.exr",
                         "a recipe ends in .usda or .usd or .usdc"),
    "suggest -o x.nk": (["suggest", "{out}/cornell.pxlidx", "-o", "{out}/x.nk"], "{out}/x.nk",
                        "a recipe ends in .usda or .usd or .usdc"),
    "suggest -o x": (["suggest", "{out}/cornell.pxlidx", "-o", "{out}/x"], "{out}/x",
                     "a recipe ends in .usda or .usd or .usdc"),
    "nuke -o comp.txt": (["nuke", "{out}/passes.exr", "-o", "{out}/comp.txt"], "{out}/comp.txt",
                         "a Nuke script ends in .nk"),
    "nuke -o comp": (["nuke", "{out}/passes.exr", "-o", "{out}/comp"], "{out}/comp", "a Nuke script ends in .nk"),
}


@pytest.mark.parametrize("case", list(WRONG_SUFFIXES))
def test_a_wrong_extension_is_one_line_and_writes_nothing(shot, capsys, case):
    before = contents(shot)
    args, name, said = WRONG_SUFFIXES[case]
    line = refused(capsys, name.format(out=shot), *(arg.format(out=shot) for arg in args))
    assert said in line
    assert contents(shot) == before and sorted(path.name for path in shot.iterdir() if path.is_dir()) == []


def test_a_folder_with_a_dot_stays_a_folder(shot, capsys):
    """Only the suffixes of files (outputs.FILE_SUFFIXES) are refused: `v1.2` is a folder."""
    code, out, _ = cli(capsys, "extract", str(shot / "cornell.pxlidx"), "--passes", "-o", str(shot / "v1.2"),
                       "--quiet", "--no-previews")
    assert code == 0 and (shot / "v1.2" / "cornell.layers.exr").is_file()


# --- devices, FIFOs, folders, and links to them ------------------------------------------------

def _fifo(path: Path) -> None:
    os.mkfifo(path)


def _folder(path: Path) -> None:
    path.mkdir()


def _device(path: Path) -> None:
    """A character device of its own (the null device's numbers): replacing it would be
    harmless, unlike /dev/null's. Only root may make one."""
    try:
        os.mknod(path, 0o644 | stat.S_IFCHR, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")


SPECIAL = {"FIFO": (_fifo, stat.S_ISFIFO), "folder": (_folder, stat.S_ISDIR), "device": (_device, stat.S_ISCHR)}
WRITERS = {
    "nuke": (["nuke", "{out}/passes.exr", "-o", "{name}"], ".nk"),
    "extract": (["extract", "{out}/cornell.pxlidx", "--passes", "-o", "{name}"], ".exr"),
    "suggest": (["suggest", "{out}/cornell.pxlidx", "-k", "2", "-o", "{name}"], ".usda"),
    "render": (["render", CORNELL, "-o", "{name}", *SMALL], ".exr"),
}


@pytest.mark.parametrize("linked", [False, True], ids=["itself", "a link to it"])
@pytest.mark.parametrize("kind", list(SPECIAL))
@pytest.mark.parametrize("command", list(WRITERS))
def test_an_output_that_is_not_a_regular_file_is_refused_and_left_alone(shot, capsys, command, kind, linked):
    make, is_kind = SPECIAL[kind]
    args, suffix = WRITERS[command]
    node = shot / f"node{suffix}"
    make(node)
    name = node
    if linked:
        name = shot / f"link{suffix}"
        name.symlink_to(node.name)
    before = os.lstat(node)
    line = refused(capsys, name, *(arg.format(out=shot, name=name) for arg in args))
    assert "an output replaces only a regular file" in line and ("symbolic link" in line) == linked, line
    after = os.lstat(node)
    assert is_kind(after.st_mode) and (after.st_ino, after.st_rdev) == (before.st_ino, before.st_rdev)
    assert not linked or name.is_symlink()
    assert not [path for path in shot.iterdir() if ".tmp" in path.name]


def test_dev_null_is_not_a_file_to_write():
    """Checked without writing: were the rule broken, a write would make /dev/null a regular file."""
    assert "is a character device" in output_problem("/dev/null", "Nuke script")
    with pytest.raises(OutputError, match="^/dev/null: is a character device"):
        check_output("/dev/null")


def test_a_fifo_that_appears_while_the_files_are_written_is_not_replaced(tmp_path):
    """The names are checked again under the folder's lock, just before the renames: nothing
    of the set is put in place and the FIFO stays."""
    final = tmp_path / "late.exr"
    with pytest.raises(OutputError, match="late.exr: is a FIFO"):
        with OutputSet():
            write_atomically(tmp_path / "other.png", lambda temporary: temporary.write_bytes(b"png"))
            write_atomically(final, lambda temporary: temporary.write_bytes(b"exr"))
            os.mkfifo(final)
    assert stat.S_ISFIFO(os.lstat(final).st_mode) and sorted(os.listdir(tmp_path)) == ["late.exr"]


# --- productName ---------------------------------------------------------------------------------

def recipe_layer(product_name: str) -> str:
    return f'''#usda 1.0
(
    renderSettingsPrimPath = "/Render/Out/Settings"
)
def Scope "Render"
{{
    def Scope "Out"
    {{
        def RenderSettings "Settings"
        {{
            rel products = </Render/Out/escape>
        }}
        def RenderProduct "escape"
        {{
            rel orderedVars = </Render/Out/diffuse>
            token productName = "{product_name}"
        }}
        def RenderVar "diffuse"
        {{
            uniform token sourceType = "lpe"
            uniform string sourceName = "C<RD>.*"
            uniform token dataType = "color3f"
        }}
    }}
}}
'''


ESCAPING = ["../../escaped.exr", "sub/../../escaped.exr", "..\\\\escaped.exr", "/tmp/pxr-layers-escaped.exr"]


@pytest.mark.parametrize("product_name", ESCAPING)
@pytest.mark.parametrize("command", ["render", "extract"])
def test_a_product_name_that_leaves_the_output_folder_is_refused(shot, capsys, command, product_name):
    recipe = shot / "escape.usda"
    recipe.write_text(recipe_layer(product_name))
    before = contents(shot.parent)
    source = [CORNELL] if command == "render" else [str(shot / "cornell.pxlidx")]
    # named as every recipe error is: the composed stage's file, the prim, the attribute
    line = refused(capsys, "/Render/Out/escape.productName", command, *source, "--recipe", str(recipe), "-o",
                   str(shot / "deep" / "er"), *(SMALL if command == "render" else ["--quiet"]))
    assert "output folder" in line and "escaped.exr" in line
    assert contents(shot.parent) == before
    assert not Path("/tmp/pxr-layers-escaped.exr").exists()


def test_a_product_name_may_name_a_subfolder():
    layers = (Layer("diffuse", "lpe", "C<RD>.*"),)
    product = Product("p", "beauty/shot.####.exr", "/World/Camera", (4, 4), layers)
    assert product.output_path(12, "out") == Path("out/beauty/shot.0012.exr")
    with pytest.raises(RecipeError, match=r"product 'p'\.productName: productName must stay inside the output folder"):
        Product("p", "beauty/../../shot.exr", "/World/Camera", (4, 4), layers)


# --- an EXR cut short ----------------------------------------------------------------------------

@pytest.mark.parametrize("cut", [1, 100, 1000, "header"])
def test_nuke_on_an_exr_cut_short_is_one_line_and_writes_nothing(shot, cut):
    """Its last bytes cut off (an interrupted copy): OpenEXR's binding would drop the parts it
    cannot read, printing to stdout and stderr; the real console script says one line."""
    data = (shot / "passes.exr").read_bytes()
    cut = len(data) - 200 if cut == "header" else cut  # into the headers
    damaged = shot / "damaged.exr"
    damaged.write_bytes(data[:-cut])
    result = run("nuke", str(damaged), "--quiet")
    assert result.returncode == 1 and result.stdout == "", result
    line = one_error_line(result.stderr)
    assert line.startswith(f"pxr-layers: error: {damaged}: ")
    assert "cut short or damaged" in line or "cannot open it" in line, line
    assert not (shot / "damaged.nk").exists()


def test_an_exr_cut_short_is_refused_wherever_it_is_read(shot, capsys):
    """extract and suggest read the render's EXR beside the index (its beauty), the inspector
    its products: each refuses the file, naming it, instead of reading what is left."""
    from pxr_layers.errors import PxrLayersError
    from pxr_layers.view.session import Session

    exr = shot / "cornell.exr"
    exr.write_bytes(exr.read_bytes()[:-20])
    for args in (["extract", str(shot / "cornell.pxlidx"), "--passes", "-o", str(shot / "cut.exr")],
                 ["suggest", str(shot / "cornell.pxlidx"), "-k", "2", "-o", str(shot / "suggested.usda")]):
        line = refused(capsys, exr, *args, "--quiet")
        assert "cut short or damaged" in line
    with pytest.raises(PxrLayersError, match="cut short or damaged"):
        Session.open(exr)
    assert not (shot / "cut.exr").exists() and not (shot / "suggested.usda").exists()


def test_a_file_that_is_not_an_exr_is_named_as_such(shot, capsys):
    line = refused(capsys, shot / "cornell.pxlidx", "nuke", str(shot / "cornell.pxlidx"), "-o", str(shot / "x.nk"))
    assert "not an OpenEXR file" in line


def test_suggest_for_two_indexes_of_one_time_refuses_to_write_one_exr_twice(shot, capsys):
    """Each index gets `<recipe stem>[.FFFF].exr`: two renders at the same time (or both at
    the default one) would give one name, the second EXR silently replacing the first."""
    other = shot / "retake"
    other.mkdir()
    shutil.copy(shot / "cornell.pxlidx", other / "cornell.pxlidx")
    line = refused(capsys, shot / "look.exr", "suggest", str(shot / "cornell.pxlidx"), str(other / "cornell.pxlidx"),
                   "-k", "2", "-o", str(shot / "look.usda"))
    assert "would write it" in line and not (shot / "look.usda").exists()


@pytest.mark.parametrize("delay", [0.3, 0.5, 0.6, 0.7])
def test_ctrl_c_while_native_libraries_load_is_one_line(tmp_path, delay):
    """USD's module loader swallows a KeyboardInterrupt (a printed warning) and pybind11's
    turns it into "ImportError: initialization failed" (OpenColorIO): either way the command
    ends as interrupted, in one line, whenever the signal lands in the start-up."""
    process = start("render", CORNELL, "-o", str(tmp_path), "--resolution", "64", "64", "--spp", "256", "--quiet")
    time.sleep(delay)  # within the start-up's imports, or the first moments of the render
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130 and stderr == "pxr-layers: interrupted; nothing was written\n", stderr
