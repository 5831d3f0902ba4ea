"""`pxr-layers job run|status JOB`: render a shot's frames on Dask; show where a job is."""

from __future__ import annotations

import argparse
import logging
import sys

from ..request import OPTIONS
from . import logging_flags
from .render import add_request_flags, nonempty_path

HELP = "run a shot job (frames × tiles on Dask), show its progress, or suggest layers for its frames"
DESCRIPTION = (
    "A job file (TOML, pipelines/README.md) names a stage, frames, recipe layers, render settings, "
    "output templates and a Dask scheduler. `job run` renders every frame not done yet on a "
    "LocalCluster (or the job's scheduler) and resumes where an interrupted run stopped; "
    "`job status` lists each frame as done, under way (tiles committed) or pending; `job suggest` runs "
    "`pxr-layers suggest` (the same search) on the indexes of the frames done, one layer set for the shot."
)
SUGGESTED_RECIPE = "$JOB.suggested.usda"
"""`job suggest`'s recipe in the job's output directory when -o is not given ($JOB: the job's name)."""
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    run = actions.add_parser("run", help="render the frames not done yet", parents=[logging_flags(nested=True)],
                             description="Render every frame of JOB that has no commit record yet.")
    run.add_argument("job", type=nonempty_path, metavar="JOB", help="the job file (.toml)")
    run.add_argument("--frames", metavar="RANGE", help="only these frames, e.g. 1-4 or 1-24x4 (default: the job's)")
    run.add_argument("--scheduler", metavar="ADDRESS",
                     help="a Dask scheduler, tcp://host:8786 (default: the job's, else a LocalCluster)")
    run.add_argument("--workers", type=int, metavar="N", help="LocalCluster worker processes (default: the job's)")
    run.add_argument("--batch-pixels", type=int, metavar="N", help="pixels per task (default: the job's)")
    # Every option of `pxr-layers render`, overriding the job file's key of the same option.
    add_request_flags(run, unset_defaults=True)
    status = actions.add_parser("status", help="show each frame's progress", parents=[logging_flags(nested=True)],
                                description="Each frame of JOB: done, k/n tiles committed, or pending.")
    status.add_argument("job", type=nonempty_path, metavar="JOB", help="the job file (.toml)")
    for sub in (run, status):
        sub.add_argument("-o", "--output", type=nonempty_path, metavar="DIR", help="output directory (default: the job's)")
    from . import suggest as suggest_command

    suggest = actions.add_parser("suggest", help="suggest layers for the frames done (pxr-layers suggest)",
                                 parents=[logging_flags(nested=True)],
                                 description="Suggest one set of layers for every frame of JOB that is done: "
                                 "`pxr-layers suggest` on their indexes (docs/suggest.md).")
    suggest.add_argument("job", type=nonempty_path, metavar="JOB", help="the job file (.toml)")
    suggest.add_argument("--directory", type=nonempty_path, metavar="DIR",
                         help="the job's output directory (default: the job's)")
    suggest_command.add_search_options(suggest, default_recipe=f"{SUGGESTED_RECIPE} in the job's output directory")


def run(args: argparse.Namespace) -> int:
    from ..jobs import load_job

    if args.action == "suggest":
        return _suggest(args)
    overrides = {"output.directory": args.output} if args.output else {}
    if args.action == "run":
        for flag, key in (("frames", "frames"), ("scheduler", "dask.scheduler"),
                          ("workers", "dask.workers"), ("batch_pixels", "dask.batch_pixels")):
            if getattr(args, flag) is not None:
                overrides[key] = getattr(args, flag)
        for spec in OPTIONS:
            if getattr(args, spec.name) is not None:
                overrides[spec.job_key] = as_toml(getattr(args, spec.name))
    job = load_job(args.job, overrides)
    if args.action == "status":
        return _status(job)
    from ..jobs.executor import run_job

    try:
        report = run_job(job, on_frame=lambda frame, status: log.info("frame %g: %s", frame, status))
    except KeyboardInterrupt as interrupt:  # Ctrl-C, or SIGTERM (Terminated)
        # Frames are committed one by one (by the workers, which the client does not see
        # write), so what is on disk is read back: the honest account of an interrupted run.
        from .main import EXIT_INTERRUPTED, interruption

        print(f"pxr-layers: {interruption(interrupt)}: {_committed(job)}; the same command again resumes",
              file=sys.stderr)
        return getattr(interrupt, "exit_code", EXIT_INTERRUPTED)
    print(f"{job.name}: {len(report.rendered)} frames rendered, {len(report.skipped)} already done "
          f"({report.tiles_rendered} tiles rendered, {report.tiles_reused} reused) in {report.seconds:.1f}s")
    return 0


def as_toml(value):
    """A flag's parsed value as a job file would write it (lists, strings), for load_job."""
    if isinstance(value, tuple):
        return [as_toml(item) for item in value]
    return value if isinstance(value, (bool, int, float, str)) else str(value)


def _committed(job) -> str:
    """'16 of 24 frames committed in DIR (2 more under way: their committed tiles are kept)'."""
    from ..jobs.executor import frame_statuses

    statuses = [status for _, _, status in frame_statuses(job)]
    done = statuses.count("done")
    under_way = sum(status.endswith(" tiles") and not status.startswith("0/") for status in statuses)
    text = f"{done} of {len(statuses)} frames committed in {job.output_directory}"
    if under_way:
        text += f" ({under_way} more under way: their committed tiles are kept)"
    return text


def _suggest(args: argparse.Namespace) -> int:
    """`pxr-layers suggest` on the indexes of the job's frames that are done."""
    from ..errors import JobError
    from ..jobs import expand_template, load_job
    from ..jobs.executor import is_done
    from . import suggest as suggest_command

    job = load_job(args.job, {"output.directory": args.directory} if args.directory else {})
    done = [frame for frame in job.frames if is_done(job, frame)]
    if not done:
        raise JobError(f"no frame is done in {job.output_directory} yet: `pxr-layers job run` first",
                       file=str(job.file))
    args.indexes = [str(job.index_path(frame)) for frame in done]
    if not args.output:
        args.output = str(job.output_directory / expand_template(SUGGESTED_RECIPE, done[0], job.name))
    return suggest_command.run(args)


def _status(job) -> int:
    from ..jobs.executor import check_output_directory, frame_statuses

    check_output_directory(job, create=False)
    done = 0
    for _, stem, status in frame_statuses(job):
        print(f"{stem}  {status}")
        done += status == "done"
    print(f"{job.name}: {done}/{len(job.frames)} frames done")
    return 0
