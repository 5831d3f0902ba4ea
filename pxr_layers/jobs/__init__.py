"""Shot jobs: frames × sample batches of one shot, spread over Dask.

``definition`` reads a TOML job file (and the show-level files it extends) into a frozen
:class:`Job`; see pipelines/README.md for the keys; ``frames`` reads its frame ranges and
output templates. Neither imports pxr nor Dask.

    from pxr_layers.jobs import load_job

    job = load_job("pipelines/shows/demo/shot010.toml")
    job.frames                  # (1.0, 2.0, ..., 24.0)
    job.index_path(1)           # .../shot010.0001.pxlidx
    job.request.recipe_layers           # what load_recipe(recipe_layers=...) takes
"""

from .definition import KEYS, TABLES, Job, default_workers, load_job
from .frames import check_template, expand_template, has_frame_token, parse_frames

__all__ = [
    "KEYS",
    "TABLES",
    "Job",
    "check_template",
    "default_workers",
    "expand_template",
    "has_frame_token",
    "load_job",
    "parse_frames",
]
