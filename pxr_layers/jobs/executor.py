"""Run a shot job on Dask: frames × pixel tiles as tasks, each frame assembled in order.

The work of a frame is cut into **tiles**: ranges of whole pixels with every one of their
samples, starting on the tracer's batch boundaries (:func:`pxr_layers.trace.render.batch_pixels`).
A tile therefore holds exactly the batches `pxr-layers render` would trace for those
pixels, with the same seeds (every random stream derives from seed, frame, pixel, sample),
and the frame is assembled from its tiles in pixel order: the EXRs and the index are
byte-identical whatever the tile size, the worker count or the order tasks finish in.
(Splitting a pixel's samples across tasks would change the order its samples are summed
in, and with it the last bits of the beauty.)

Tasks (run on workers):

* ``render_tile``: trace pixels [first, stop) of a frame and commit the batches to
  ``<frame scratch>/tile.<first>-<stop>.pkl`` (temporary name, then rename). The Embree
  scene of a frame is built once per worker process (a small cache of prepared frames).
* ``render_frame_data``: the frame's data AOVs and its event vocabulary, likewise (done
  by the frame's first tile task, or on its own when every tile is already committed).

* ``assemble_frame`` (after the frame's tiles): the frame made by
  :func:`~pxr_layers.jobs.frame.render_frame` from the tiles in order (film + path index,
  then the recipe's products), then
  ``<stem>.done.json``, the frame's commit record, written last; then the scratch folder
  is removed.

The client only plans the frames and submits their tasks, a window of frames at a time
(``FRAMES_IN_FLIGHT_PER_THREAD`` per worker thread: however many frames a job has, the
client and the scheduler hold a few frames' worth), and waits. Workers share the output
directory (a local disk for a LocalCluster, the studio's shared storage on a farm). A frame with a commit record whose files exist is complete and is
skipped on the next run; an interrupted frame keeps its committed tiles, and the next run
renders only the missing ones. A killed worker loses at most its running tile (its
temporary file is never renamed), which Dask runs again elsewhere; a task that raises is
retried ``job.retries`` times.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import math
import os
import pickle
import shutil
import tempfile
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from .. import interrupts
from ..errors import JobError, OutputError, PxrLayersError
from ..outputs import write_atomically
from ..paths.format import stored_norms
from .definition import DONE_SUFFIX, Job
from .frame import (
    FramePlan,
    file_sha256,
    frame_data,
    plan_frame,
    prepare_frame,
    render_frame,
    resolve_recipe,
)

log = logging.getLogger(__name__)

PLAN_FILE = "plan.json"
DATA_FILE = "data.pkl"


@dataclass
class JobReport:
    """What a run did: frames rendered and skipped, tiles rendered and reused, seconds."""

    rendered: list[float] = field(default_factory=list)
    skipped: list[float] = field(default_factory=list)
    tiles_rendered: int = 0
    tiles_reused: int = 0
    seconds: float = 0.0


# -- the frames and their tiles ---------------------------------------------------------------


def frame_plan(job: Job, frame: float, recipe=None, stage_sha256: str | None = None, shot=None) -> FramePlan:
    """The plan of one frame; ``recipe`` None reads it at the frame from ``shot`` (an open
    Shot of the job's request, else the stage is opened)."""
    return plan_frame(
        job.request, frame, directory=job.output_directory, index_path=job.index_path(frame),
        product_path=lambda product: job.product_path(product.output_name, frame), recipe=recipe,
        stage_sha256=stage_sha256, shot=shot,
    )


def tiles(plan: FramePlan, batch_pixels_wanted: int) -> list[tuple[int, int]]:
    """(first, stop) pixel ranges: the fewest tiles of at most about ``batch_pixels_wanted``
    pixels, as equal as the tracer's batch boundaries allow (equal tasks keep workers busy
    alike to the end)."""
    from ..trace.render import batch_pixels

    step = batch_pixels(plan.trace.spp)
    count = math.ceil(plan.pixels / max(step, batch_pixels_wanted))
    size = math.ceil(plan.pixels / count / step) * step
    return [(first, min(first + size, plan.pixels)) for first in range(0, plan.pixels, size)]


def done_record(job: Job, frame: float) -> Path:
    return job.output_directory / f"{job.output_stem(frame)}{DONE_SUFFIX}"


def is_done(job: Job, frame: float) -> bool:
    """A frame is done when its commit record exists and every file it lists is there."""
    record = done_record(job, frame)
    if not record.exists():
        return False
    try:
        files = json.loads(record.read_text())["files"]
    except (OSError, ValueError, KeyError):
        return False
    return all((record.parent / name).exists() for name in files)


def _fingerprint(plan: FramePlan) -> str:
    """What a tile's content depends on: a scratch folder of another plan is discarded."""
    trace = plan.trace
    return json.dumps({
        "stage": str(plan.stage), "sha256": plan.manifest.get("stage_sha256"), "frame": plan.frame,
        "camera": plan.camera, "resolution": list(plan.resolution), "settings": plan.recipe.settings_path,
        # The layers' contents, not only their names: a recipe layer may override any opinion.
        "recipe_layers": [(str(layer), file_sha256(layer)) for layer in plan.request.recipe_layers],
        "recipe": plan.recipe.to_json(), "data_aovs": list(plan.data_aovs),
        "variants": [str(selection) for selection in plan.request.variants],
        "subdiv_level": plan.request.subdiv_level, "default_lights": plan.request.default_lights,
        "auto_camera": plan.request.auto_camera,
        "spp": trace.spp, "max_depth": trace.max_depth, "seed": trace.seed, "norm_bounces": trace.norm_bounces,
        "record": trace.record_paths, "merge": trace.merge_records, "sigma": trace.record_sigma,
        "first_bounce_norms": trace.first_bounce_norms,
        "clamp_indirect": trace.clamp_indirect, "guides": trace.guides,
    }, sort_keys=True)


def _scratch(job: Job, plan: FramePlan, tile_list: list[tuple[int, int]]) -> Path:
    """The frame's scratch folder, emptied if it holds tiles of another plan."""
    folder = job.frame_directory(plan.frame)
    stamp = folder / PLAN_FILE
    fingerprint = _fingerprint(plan)
    if folder.exists():
        try:
            same = json.loads(stamp.read_text())["fingerprint"] == fingerprint
        except (OSError, ValueError, KeyError):
            same = False
        if not same:
            shutil.rmtree(folder)
    if not folder.exists():
        folder.mkdir(parents=True)
        _write_atomically(stamp, json.dumps({"fingerprint": fingerprint, "tiles": len(tile_list)}).encode())
    return folder


def tile_file(folder: Path, first: int, stop: int) -> Path:
    return folder / f"tile.{first:09d}-{stop:09d}.pkl"


# -- tasks (run on workers) -------------------------------------------------------------------


_PREPARED: OrderedDict = OrderedDict()
_PREPARED_LOCK = threading.Lock()
PREPARED_FRAMES = 2
"""Frames a worker process keeps prepared (a frame's tiles usually reach it together)."""


def _prepared(plan: FramePlan):
    """The frame's Integrator (Embree scene built), once per worker process and frame."""
    key = _fingerprint(plan)
    with _PREPARED_LOCK:  # a worker started with several threads runs tasks side by side
        if key not in _PREPARED:
            _PREPARED[key] = prepare_frame(plan)
            while len(_PREPARED) > PREPARED_FRAMES:
                _PREPARED.popitem(last=False)
        _PREPARED.move_to_end(key)
        return _PREPARED[key]


TASK_THREADS = 1
"""Threads a task traces with. A Dask worker runs as many tasks at once as it has threads,
so each task is one core's worth of work (workers: one process per core, --nthreads 1)."""


def render_tile(plan: FramePlan, first: int, stop: int, path: str, data_path: str | None = None) -> dict:
    """Trace pixels [first, stop) of the frame; commit their batches to ``path``. With
    ``data_path``, the frame's data (:func:`render_frame_data`) is committed first, saving
    a task (and maybe a worker preparing the frame for it alone)."""
    start = time.perf_counter()
    if data_path is not None:
        render_frame_data(plan, data_path)
    integrator = _prepared(plan)
    from ..trace import trace_pixels
    from ..trace.recorder import Contributions

    batches: list = []

    def keep(batch) -> None:
        if isinstance(batch.records, Contributions):  # norms as the index stores them: a quarter of the bytes to move
            norms = stored_norms(batch.records.norms)
            batch = dataclasses.replace(batch, records=dataclasses.replace(batch.records, norms=norms))
        batches.append(batch)

    trace_pixels(integrator, first, stop, keep, threads=TASK_THREADS)
    _pickle_atomically(Path(path), batches)
    return {"rays": sum(batch.rays for batch in batches), "seconds": time.perf_counter() - start}


def render_frame_data(plan: FramePlan, path: str) -> None:
    """The frame's data AOVs and Cryptomatte names (:func:`frame_data`; the tiles bring the
    first hits they rank), event vocabulary and object paths, committed to ``path``."""
    integrator = _prepared(plan)
    data = frame_data(plan, integrator, TASK_THREADS)
    payload = (data, integrator.vocabulary, tuple(integrator.world.object_paths))
    _pickle_atomically(Path(path), payload)


def _write_atomically(path: Path, content: bytes) -> None:
    write_atomically(path, lambda temporary: temporary.write_bytes(content))


def _pickle_atomically(path: Path, content) -> None:
    """Pickled straight to the file (tiles are tens of MB: no copy of them in memory first)."""

    def dump(temporary: Path) -> None:
        with open(temporary, "wb") as file:
            pickle.dump(content, file, protocol=pickle.HIGHEST_PROTOCOL)

    write_atomically(path, dump)


# -- the client -------------------------------------------------------------------------------


def run_job(job: Job, *, client=None, on_frame: Callable[[float, str], None] | None = None) -> JobReport:
    """Render every frame of ``job`` not done yet; returns what was done.

    client : a ``distributed.Client``; None starts one as the job says (its scheduler, or
             a LocalCluster of ``job.workers`` single-threaded worker processes,
             :func:`~pxr_layers.jobs.workers.local_cluster`) and stops
             it at the end.
    on_frame(frame, status) : called as frames are skipped, started and finished.

    Raises OutputError when the output directory cannot be created or written. Ctrl-C
    raises KeyboardInterrupt (within INTERRUPT_POLL_SECONDS once frames are under way);
    the frames committed until then stay, and a run again resumes from them.
    """
    started = time.perf_counter()
    report = JobReport()
    check_output_directory(job, create=True)
    todo = []
    for frame in job.frames:
        if is_done(job, frame):
            report.skipped.append(frame)
            if on_frame:
                on_frame(frame, "skipped (done)")
        else:
            todo.append(frame)
    if not todo:
        report.seconds = time.perf_counter() - started
        return report
    # Worked out once for every frame: the recipe (a stage's own is not animated), unless it
    # has per-light layers, whose lights are listed at each frame as `render --frame` lists
    # them (a light may be invisible at some frames); and the stage file's hash (the
    # fingerprint of each frame's tiles).
    from ..stage import open_request

    shot = open_request(job.request)  # the client composes the stage once for every frame's plan
    recipe = resolve_recipe(job.request, job.frames[0], shot)
    if any(product.per_light != "none" for product in recipe.products):
        recipe = None
    stage_sha256 = file_sha256(job.request.stage)
    # Planned as they are submitted: the client holds the plans of the frames in flight only.
    plans = (frame_plan(job, frame, recipe, stage_sha256, shot) for frame in todo)
    first = next(plans)  # before a cluster starts: a mistake in the recipe stops the job at once
    with _client(job, client) as dask:
        _run_frames(job, dask, itertools.chain([first], plans), len(todo), report, on_frame)
    report.seconds = time.perf_counter() - started
    return report


def check_output_directory(job: Job, *, create: bool) -> None:
    """Raise OutputError, naming the job's output directory, when it cannot be used.

    It must be a directory, or one that can be created (no file on its way). create True
    (a run): it is created if missing, then a file is created in it and removed, the one
    sure test of writing (permissions, ACLs, read-only mounts, a farm's root squash alike).
    create False (status): if it exists, it must be readable.
    """
    directory = job.output_directory
    try:
        existing = next(folder for folder in (directory, *directory.parents) if folder.exists())
    except OSError as error:  # a folder on the way that may not be searched
        raise OutputError(f"output directory {directory}: cannot be reached ({error.strerror})") from None
    if not existing.is_dir():
        where = "is a file" if existing == directory else f"cannot be created: {existing} is a file"
        raise OutputError(f"output directory {directory}: {where}, not a directory")
    if not create:
        if existing == directory and not os.access(directory, os.R_OK | os.X_OK):
            raise OutputError(f"output directory {directory}: cannot be read (permission denied)")
        return
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"output directory {directory}: cannot be created ({error.strerror})") from None
    try:
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".pxr-layers-write-test."):
            pass
    except OSError as error:
        raise OutputError(f"output directory {directory}: cannot be written ({error.strerror})") from None


INTERRUPT_POLL_SECONDS = 0.2
"""How often the client, waiting for its frames, looks whether Ctrl-C or SIGTERM came."""


@contextmanager
def _file_errors(what: str):
    """An OSError about a file (it carries the file's name: a full disk, a permission, a
    read-only mount) as one OutputError line; others (a lost connection) are left as they are."""
    try:
        yield
    except OSError as error:
        if error.filename is None:
            raise
        raise OutputError(f"{what}: {error.filename}: {error.strerror or error}") from None


class _client:
    """The given client, or a cluster started (and stopped) for the job."""

    def __init__(self, job: Job, client):
        self.job, self.given, self.started = job, client, []

    def __enter__(self):
        if self.given is not None:
            return self.given
        from distributed import Client

        if self.job.scheduler:
            try:
                client = Client(self.job.scheduler, timeout="30s")
            except OSError as error:
                raise JobError(f"cannot reach the Dask scheduler ({error})", file=str(self.job.file),
                               key="dask.scheduler") from None
            self.started = [client]
            return client
        from .workers import local_cluster

        cluster = local_cluster(self.job.workers, dashboard_address=None)
        client = Client(cluster)
        self.started = [client, cluster]
        log.info("started a local Dask cluster of %d workers", self.job.workers)
        return client

    def __exit__(self, *exc) -> None:
        for thing in self.started:
            thing.close()


@dataclass(frozen=True)
class UserErrorResult:
    """A task's PxrLayersError, returned instead of raised: Dask would retry it (running it
    again cannot mend the user's input) and print its traceback per try."""

    text: str


def _user_errors_returned(task: Callable) -> Callable:
    """``task`` returning UserErrorResult for a PxrLayersError (its own, or one of the input
    tasks handed to it in a list) instead of raising it; other errors are still raised and
    retried (a killed worker, a full disk)."""
    def run(*args):
        for value in args:
            if isinstance(value, list):
                failed = next((item for item in value if isinstance(item, UserErrorResult)), None)
                if failed is not None:
                    return failed
        try:
            return task(*args)
        except PxrLayersError as error:
            return UserErrorResult(str(error))

    run.__name__ = task.__name__  # Dask names the task after it
    return run


FRAMES_IN_FLIGHT_PER_THREAD = 2
"""Frames submitted to Dask at a time, per worker thread of the cluster (counted again as
frames finish, so workers that join are used). Enough that every worker has tiles while
earlier frames are assembled; few enough that the client plans, and the scheduler holds,
a bounded number of frames however long the job (up to MAX_FRAMES)."""


def _run_frames(job: Job, client, plans: Iterator[FramePlan], count: int, report: JobReport, on_frame) -> None:
    """Submit the frames' tiles and assemblies (which wait for them), a window of frames at
    a time, the next as one is done; wait for all. ``count``: how many ``plans`` yields.
    Ctrl-C raises KeyboardInterrupt, SIGTERM Terminated, within INTERRUPT_POLL_SECONDS."""
    from distributed import wait

    from .workers import WorkerTuning

    client.register_plugin(WorkerTuning())
    assemblies: dict = {}  # future → frame, of the frames in flight
    positions = itertools.count()

    def submit_more() -> None:
        window = FRAMES_IN_FLIGHT_PER_THREAD * max(1, sum(client.nthreads().values()))
        while len(assemblies) < window:
            plan = next(plans, None)
            if plan is None:
                return
            assemblies[_submit_frame(job, client, plan, next(positions), report, on_frame)] = plan.frame

    with interrupts.recorded() as received:  # Python's handlers raise where Dask's callbacks swallow it
        submit_more()
        while assemblies:
            try:
                done, _ = wait(list(assemblies), timeout=INTERRUPT_POLL_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:
                done = set()
            interrupts.raise_recorded(received)
            for future in sorted(done, key=assemblies.get):
                frame = assemblies.pop(future)
                with _file_errors(f"frame {frame:g}"):
                    result = future.result()  # raises the task's error once its retries are spent
                if isinstance(result, UserErrorResult):
                    raise PxrLayersError(result.text)
                report.rendered.append(frame)
                if on_frame:
                    on_frame(frame, f"done ({len(report.rendered)} of {count} frames)")
            submit_more()
        interrupts.raise_recorded(received)  # one that came while the last frames were counted
    report.rendered.sort()


def _submit_frame(job: Job, client, plan: FramePlan, position: int, report: JobReport, on_frame):
    """Submit the frame's tiles not committed yet and its assembly; returns the assembly's future."""
    # Frame k's tiles come before the assembly of frame k - 1: workers run ahead on tiles,
    # and the last two assemblies run side by side instead of one alone at the end (the
    # scratch of about two frames is on disk at a time). Higher priority runs first.
    tile_priority, assembly_priority = -2 * position, -(2 * position + 3)
    tile_list = tiles(plan, job.batch_pixels)
    with _file_errors(f"frame {plan.frame:g}"):
        folder = _scratch(job, plan, tile_list)
    inputs = []
    data_path = None if (folder / DATA_FILE).exists() else str(folder / DATA_FILE)
    for first, stop in tile_list:
        path = tile_file(folder, first, stop)
        if path.exists():
            report.tiles_reused += 1
            continue
        inputs.append(client.submit(_user_errors_returned(render_tile), plan, first, stop, str(path), data_path,
                                    retries=job.retries, pure=False, priority=tile_priority))
        data_path = None  # the frame's first tile to render brings the data
        report.tiles_rendered += 1
    if data_path is not None:  # every tile was committed by an earlier run, not the data
        inputs.append(client.submit(_user_errors_returned(render_frame_data), plan, data_path,
                                    retries=job.retries, pure=False, priority=tile_priority))
    # Assembling runs on a worker too: frames are assembled in parallel, next to the
    # tiles of later frames, and the client only waits.
    future = client.submit(_user_errors_returned(assemble_frame), job, plan, inputs, retries=job.retries,
                           pure=False, priority=assembly_priority)
    if on_frame:
        on_frame(plan.frame, f"submitted {len(inputs)} tasks ({len(tile_list)} tiles) and the assembly")
    return future


def assemble_frame(job: Job, plan: FramePlan, inputs=()) -> None:
    """The frame made from its committed tiles by :func:`render_frame` (film + index in
    pixel order, then the products); then its commit record.

    inputs: the frame's tile and data tasks (Dask passes their results once they are done).
    """
    folder = job.frame_directory(plan.frame)
    result = render_frame(plan.request, plan.frame, plan=plan,
                          source=CommittedTiles(folder, tiles(plan, job.batch_pixels)))
    files = [os.path.relpath(path, job.output_directory) for path in plan.files]
    files += [os.path.relpath(path, job.output_directory) for item in result.delivered
              for path in item.previews.values()]
    record = {"frame": plan.frame, "files": sorted(files), "recipe": plan.recipe.settings_path}
    _write_atomically(done_record(job, plan.frame), json.dumps(record, indent=1).encode())
    shutil.rmtree(folder, ignore_errors=True)


@dataclass(frozen=True)
class CommittedTiles:
    """A frame's batches and data as its tasks committed them to its scratch ``folder``
    (a :class:`~pxr_layers.jobs.frame.FrameSource`): the tiles read in pixel order."""

    folder: Path
    tile_list: list[tuple[int, int]]

    def trace(self, add: Callable) -> None:
        for first, stop in self.tile_list:
            with open(tile_file(self.folder, first, stop), "rb") as file:
                for batch in pickle.load(file):
                    add(batch)

    def frame_data(self):
        with open(self.folder / DATA_FILE, "rb") as file:
            return pickle.load(file)


# -- status -----------------------------------------------------------------------------------


def frame_status(job: Job, frame: float) -> str:
    """'done', 'k/n tiles' for a frame under way (or interrupted), or 'pending'."""
    if is_done(job, frame):
        return "done"
    folder = job.frame_directory(frame)
    try:
        total = json.loads((folder / PLAN_FILE).read_text())["tiles"]
    except (OSError, ValueError, KeyError):
        return "pending"
    committed = len(list(folder.glob("tile.*.pkl")))
    return f"{committed}/{total} tiles"


def frame_statuses(job: Job) -> Iterator[tuple[float, str, str]]:
    """(frame, its file stem, its :func:`frame_status`) of every frame of the job, in order.

    The output folders are listed once: a frame with neither a commit record nor a scratch
    folder is pending without a file-system call of its own, so the status of a job of
    MAX_FRAMES frames takes about a second.
    """
    listings: dict[str, set[str]] = {}  # folder of the stems (relative to the output directory) → its names
    for frame in job.frames:
        stem = job.output_stem(frame)
        folder, name = os.path.split(stem)  # a stem may name a subfolder, "beauty/shot.$F4"
        if folder not in listings:
            try:
                listings[folder] = set(os.listdir(job.output_directory / folder))
            except OSError:  # not there (yet): nothing of these frames was written
                listings[folder] = set()
        names = listings[folder]
        started = name in names or name + DONE_SUFFIX in names
        yield frame, stem, frame_status(job, frame) if started else "pending"
