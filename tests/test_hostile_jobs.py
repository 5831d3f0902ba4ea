"""Hostile job files (issue 18): frame sets past the limit, stems that climb out of the
output directory, impossible sample counts, output directories that cannot be written,
and a run interrupted by Ctrl-C. Each is one line naming the file and key (or the
directory), in bounded time and memory, or an honest account of what is on disk."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import tempfile
import time
import tracemalloc
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_cli import SCRIPT
from test_job_definition import job_file, stage, write  # noqa: F401 (stage: a fixture)
from test_jobs import SHOT

from pxr_layers.cli.main import main
from pxr_layers.errors import JobError, OutputError
from pxr_layers.jobs import load_job, parse_frames
from pxr_layers.jobs.definition import OVERRIDES
from pxr_layers.jobs.frames import MAX_FRAME_NUMBER, MAX_FRAMES
from pxr_layers.jobs.executor import FRAMES_IN_FLIGHT_PER_THREAD, _file_errors, is_done
from pxr_layers.request import MAX_PIXELS, MAX_SEED, MAX_SPP


def cli(capsys, *args: str) -> tuple[int, str, str]:
    """`pxr-layers ARGS` in this process: (exit code, stdout, stderr)."""
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_error_line(stderr: str) -> str:
    (line,) = stderr.strip().splitlines()
    assert line.startswith("pxr-layers: error: ") and "Traceback" not in stderr
    return line


SLOW_MACHINE_SECONDS = 5.0
"""A wall-clock bound that tells linear work from work the size of a range or quadratic in
the frames, with room for a CI machine several times slower than this one (where each takes
at most 0.15 s): a guard against blow-ups, not a performance target."""


def frames_job(tmp_path: Path, frames: str) -> Path:
    return job_file(tmp_path, head=f'stage = "assets/shot.usda"\nframes = {frames}\n')


# --- frames: counted before they are expanded, at most MAX_FRAMES -------------------------


def test_a_range_of_10_to_the_14_frames_is_one_line_at_once(tmp_path, stage, capsys):
    path = frames_job(tmp_path, '"1-24, 25-99999999999999"')
    tracemalloc.start()
    started = time.perf_counter()
    with pytest.raises(JobError) as caught:
        load_job(path)
    seconds = time.perf_counter() - started
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert seconds < SLOW_MACHINE_SECONDS and peak < 4 << 20  # bytes: nothing the size of the range was built
    error = caught.value
    assert (error.file, error.key, error.position) == (str(path), "frames", 6)
    assert f"more than the {MAX_FRAMES} a job may have (MAX_FRAMES" in str(error)
    assert "at character 7" in str(error)
    code, _, stderr = cli(capsys, "job", "status", str(path))
    assert code == 1 and "frames: bad frame range" in one_error_line(stderr)
    code, _, stderr = cli(capsys, "job", "run", str(frames_job(tmp_path, "1")), "--frames", "1-99999999999999")
    assert code == 1 and f"{OVERRIDES}: frames: bad frame range" in one_error_line(stderr)


def test_the_limit_counts_steps_and_every_item(stage, tmp_path):
    assert len(parse_frames(f"1-{2 * MAX_FRAMES}x2")) == MAX_FRAMES
    with pytest.raises(JobError, match=f"{MAX_FRAMES + 1} frames up to here") as caught:
        parse_frames(f"1-{MAX_FRAMES // 2}, {MAX_FRAMES}-{MAX_FRAMES + MAX_FRAMES // 2}")
    assert caught.value.position == len(f"1-{MAX_FRAMES // 2}, ")
    with pytest.raises(JobError, match="1000000 frames, more than"):
        parse_frames("1-1000000")
    with pytest.raises(JobError, match=f"{MAX_FRAMES + 1} frames listed, more than") as caught:
        parse_frames(list(range(MAX_FRAMES + 1)))
    assert caught.value.key == "frames"


def test_a_job_of_max_frames_loads_and_answers_its_status_quickly(tmp_path, stage, capsys):
    path = frames_job(tmp_path, f'"1-{MAX_FRAMES}"')
    started = time.perf_counter()
    job = load_job(path)
    assert time.perf_counter() - started < SLOW_MACHINE_SECONDS and len(job.frames) == MAX_FRAMES
    started = time.perf_counter()
    code, stdout, _ = cli(capsys, "job", "status", str(path))
    assert time.perf_counter() - started < 2 * SLOW_MACHINE_SECONDS  # about 1.3 s here
    assert code == 0 and stdout.count("pending") == MAX_FRAMES and f"0/{MAX_FRAMES} frames done" in stdout


def test_duplicates_are_found_in_linear_time():
    started = time.perf_counter()
    with pytest.raises(JobError, match=f"frame {MAX_FRAMES - 2} is listed twice") as caught:
        parse_frames([*range(MAX_FRAMES - 1), MAX_FRAMES - 2])
    assert caught.value.key == f"frames[{MAX_FRAMES - 1}]"
    with pytest.raises(JobError, match="frame 75000 is listed twice"):
        parse_frames(f"1-{MAX_FRAMES // 2}, 75000-{MAX_FRAMES // 2 + 25000}x1, 75000")
    assert time.perf_counter() - started < SLOW_MACHINE_SECONDS  # 0.14 s here; quadratic would take hours


@pytest.mark.parametrize(("value", "words"), [
    ("1" * 5000, "a frame number beyond"),  # int() of it would raise ValueError (4300 digits)
    (f"-{MAX_FRAME_NUMBER + 1}", "a frame number beyond"),
    (f"1-{MAX_FRAME_NUMBER + 1}", "the last frame of the range beyond"),
    (f"1-10x{'9' * 30}", "a step beyond"),
    ([1e300], "beyond"),
    ([-(1 << 60)], "beyond"),
])
def test_frame_numbers_stay_exact_time_codes(value, words):
    with pytest.raises(JobError, match=words) as caught:
        parse_frames(value, file="shot.toml")
    message = str(caught.value)
    assert "\n" not in message and len(message) < 300  # a long text is shortened in the message
    assert parse_frames(f"{MAX_FRAME_NUMBER - 1}-{MAX_FRAME_NUMBER}") == (MAX_FRAME_NUMBER - 1.0, float(MAX_FRAME_NUMBER))


ranges = st.tuples(st.integers(-1000, 1000), st.integers(0, MAX_FRAMES * 3 // 2), st.integers(1, 4))


@settings(max_examples=40, deadline=None)
@given(st.lists(ranges, min_size=1, max_size=3))
def test_counting_agrees_with_expanding(items):
    """A text is refused for its size exactly when its expansion would pass MAX_FRAMES; else
    it is every range expanded, or a duplicate found."""
    text = ", ".join(f"{start}-{start + length}x{step}" for start, length, step in items)
    expanded = [frame for start, length, step in items for frame in range(start, start + length + 1, step)]
    if len(expanded) > MAX_FRAMES:
        with pytest.raises(JobError, match="more than the"):
            parse_frames(text)
    elif len(set(expanded)) < len(expanded):
        with pytest.raises(JobError, match="listed twice"):
            parse_frames(text)
    else:
        assert parse_frames(text) == tuple(map(float, expanded))


# --- output.stem stays inside output.directory --------------------------------------------


@pytest.mark.parametrize(("stem", "words"), [
    ("../../escape.$F4", "climbs out of it with '..'"),
    ("shots/../../escape.$F4", "climbs out of it with '..'"),
    ("..\\\\escape.$F4", "climbs out of it with '..'"),
    ("/tmp/escape.$F4", "not absolute"),
    ("\\\\server\\\\escape.$F4", "not absolute"),
    ("beauty/", "must end with a file name"),
])
def test_a_stem_that_leaves_the_output_directory_is_refused(tmp_path, stage, capsys, stem, words):
    path = job_file(tmp_path, f'[output]\nstem = "{stem}"\n')
    with pytest.raises(JobError, match=words) as caught:
        load_job(path)
    assert (caught.value.file, caught.value.key) == (str(path), "output.stem")
    code, _, stderr = cli(capsys, "job", "run", str(path))
    assert code == 1 and f"{path}: output.stem: " in one_error_line(stderr)
    assert not list(tmp_path.parent.glob("escape.*")) and not (tmp_path / "out").exists()


@pytest.mark.parametrize("stem", ["beauty/shot.$F4", "..shot.$F4", "shot..$F4"])
def test_a_stem_may_name_a_subfolder_or_hold_dots(tmp_path, stage, stem):
    job = load_job(job_file(tmp_path, f'[output]\nstem = "{stem}"\n'))
    assert job.beauty_path(1).resolve().is_relative_to(job.output_directory)


# --- render.spp (and the other limits of request.check_work) ------------------------------


@pytest.mark.parametrize(("body", "key", "words"), [
    ("[render]\nspp = 9223372036854775807\n", "render.spp", f"at most {MAX_SPP}"),
    ("[render]\nresolution = [65536, 65536]\n", "render.resolution", f"more than the {MAX_PIXELS} pixels"),
    (f"[render]\nseed = {MAX_SEED + 1}\n", "render.seed", f"at most {MAX_SEED}"),
])
def test_work_past_the_limits_names_the_file_and_key(tmp_path, stage, capsys, body, key, words):
    path = job_file(tmp_path, body)
    with pytest.raises(JobError, match=words) as caught:
        load_job(path)
    assert (caught.value.file, caught.value.key) == (str(path), key)
    code, _, stderr = cli(capsys, "job", "status", str(path))
    assert code == 1 and f"{path}: {key}: " in one_error_line(stderr)


def test_a_huge_spp_flag_names_the_override(tmp_path, stage, capsys):
    code, _, stderr = cli(capsys, "job", "run", str(job_file(tmp_path)), "--spp", str((1 << 63) - 1))
    assert code == 1 and f"{OVERRIDES}: render.spp: " in one_error_line(stderr)
    assert not (tmp_path / "out").exists()


# --- output directories that cannot be used -----------------------------------------------


def writable(folder: Path) -> bool:
    try:
        with tempfile.NamedTemporaryFile(dir=folder):
            return True
    except OSError:
        return False


@pytest.fixture
def read_only_directory(tmp_path):
    """A directory this process cannot write into: mode 0555, or, for root (who writes
    there all the same), a sysfs folder, where no one can create a file."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    found = next((candidate for candidate in (folder, Path("/sys/kernel"))
                  if candidate.is_dir() and not writable(candidate)), None)
    if found is None:
        pytest.skip("no directory here is read-only for this user")
    yield found
    folder.chmod(0o755)


def directory_job(tmp_path: Path, directory: Path) -> Path:
    return job_file(tmp_path, f'[output]\ndirectory = "{directory}"\n')


def test_a_read_only_output_directory_is_one_line(tmp_path, stage, capsys, read_only_directory):
    path = directory_job(tmp_path, read_only_directory)
    code, _, stderr = cli(capsys, "job", "run", str(path))
    assert code == 1
    assert f"output directory {read_only_directory}: cannot be written" in one_error_line(stderr)
    code, stdout, _ = cli(capsys, "job", "status", str(path))  # status only reads: it answers
    assert code == 0 and "0/3 frames done" in stdout


@pytest.mark.parametrize("below", ["", "out"])
def test_an_output_directory_that_cannot_be_created_is_one_line(tmp_path, stage, capsys, below):
    blocker = write(tmp_path / "a_file", "not a folder\n")
    directory = blocker / below if below else blocker
    path = directory_job(tmp_path, directory)
    for action in ("run", "status"):
        code, _, stderr = cli(capsys, "job", action, str(path))
        line = one_error_line(stderr)
        assert code == 1 and f"output directory {directory}: " in line and "is a file, not a directory" in line


def test_an_unreadable_output_directory_is_one_line_for_status(tmp_path, stage, capsys):
    folder = tmp_path / "hidden"
    folder.mkdir(mode=0o000)
    try:
        code, _, stderr = cli(capsys, "job", "status", str(directory_job(tmp_path, folder)))
        if os.access(folder, os.R_OK):  # root reads any directory: status answers as for any other
            assert code == 0, stderr
        else:
            assert code == 1 and "cannot be read" in one_error_line(stderr)
    finally:
        folder.chmod(0o755)


def test_a_file_system_error_in_a_run_is_an_output_error(tmp_path):
    with pytest.raises(OutputError, match=r"^frame 7: .*missing/tile\.pkl: No such file or directory$"):
        with _file_errors("frame 7"):
            open(tmp_path / "missing" / "tile.pkl", "rb")
    with pytest.raises(ConnectionError):  # no file: not the output's fault, left as it is
        with _file_errors("frame 7"):
            raise ConnectionRefusedError("scheduler gone")


# --- Ctrl-C -------------------------------------------------------------------------------


@pytest.mark.parametrize("signal_number, said", [(signal.SIGINT, "interrupted"), (signal.SIGTERM, "terminated")])
def test_ctrl_c_or_sigterm_says_what_was_committed(tmp_path, signal_number, said):
    """A real Ctrl-C (SIGINT to the whole process group, workers too), or a farm manager's
    SIGTERM, once a frame is committed: exit 128 + the signal and one last line counting the
    frames on disk, not "nothing was written". The frames are submitted a window at a time,
    not all 40 at once."""
    frames = 40
    command = [SCRIPT, "job", "run", str(SHOT), "--frames", f"1-{frames}", "--spp", "4", "--resolution", "16", "12",
               "--workers", "1", "-o", str(tmp_path)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True, env={**os.environ, "CI": "1"})
    deadline = time.monotonic() + 600  # seconds: the first render of a fresh checkout compiles the tracer
    while not list(tmp_path.glob("*.done.json")) and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.05)
    os.killpg(process.pid, signal_number)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 128 + signal_number, stderr
    committed = sum(is_done(load_job(SHOT, {"output.directory": str(tmp_path)}), frame) for frame in range(1, frames + 1))
    assert 1 <= committed < frames
    last = stderr.strip().splitlines()[-1]
    assert re.fullmatch(rf"pxr-layers: {said}: {committed} of {frames} frames committed in {re.escape(str(tmp_path))}"
                        r"( \(\d+ more under way: their committed tiles are kept\))?; the same command again resumes", last)
    assert "nothing was written" not in stderr and "Traceback" not in stderr, stderr
    submitted = len(re.findall(r"frame \d+: submitted", stderr))
    assert submitted <= FRAMES_IN_FLIGHT_PER_THREAD + committed


# --- issue 33, nothing unbounded: job files and names ----------------------------------------


def test_a_job_file_nested_thousands_deep_is_one_error(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(JobError, match="nested thousands deep"):
        load_job(path)


def test_a_hundred_thousand_local_workers_are_refused(tmp_path, stage):
    with pytest.raises(JobError, match="at most 256") as caught:
        load_job(job_file(tmp_path, "[dask]\nworkers = 100000\n"))
    assert caught.value.key == "dask.workers"


def test_a_stem_too_long_for_a_file_name_is_refused_naming_the_key(tmp_path, stage):
    with pytest.raises(JobError, match="too long for a file name") as caught:
        load_job(job_file(tmp_path, f'[output]\nstem = "{"s" * 300}.$F4"\n'))
    assert caught.value.key == "output.stem"
    load_job(job_file(tmp_path, f'[output]\nstem = "{"s" * 200}.$F4"\n'))  # long, and fits


def test_an_output_folder_name_too_long_is_a_user_error(tmp_path):
    out = tmp_path / ("o" * 300)
    result = subprocess.run([SCRIPT, "render", str(Path(__file__).resolve().parents[1] / "render" / "cornell.usda"),
                             "--spp", "1", "--resolution", "8", "8", "-q", "-o", str(out)],
                            capture_output=True, text=True, check=False, timeout=600)
    assert result.returncode == 1 and "File name too long" in result.stderr, result.stderr
    assert result.stderr.count("\n") == 1
