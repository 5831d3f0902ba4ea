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
