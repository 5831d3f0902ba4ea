"""For tests of a frame's internals. A test of what a render gives goes through the entry
users use, :func:`pxr_layers.jobs.frame.render_frame`.

* :func:`trace_image`: the tracer's stages only (trace.prepare → trace_pixels → Film), for
  batch-size invariance (``batch_paths``), a SceneData edited in memory (what no USD file
  says), the records of each batch.
* :func:`index_writer`: render_frame's path index written with other writer options (small
  chunks: a small render's index holds as many as a large one's).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from collections.abc import Iterator

import numpy as np
import pytest

from pxr_layers.jobs import frame
from pxr_layers.paths.writer import PathIndexWriter
from pxr_layers.scene import RenderSpec, SceneData
from pxr_layers.trace import DEFAULT_BATCH_PATHS, Film, TraceSettings, prepare, trace_pixels
from pxr_layers.trace.integrator import BatchResult, Integrator


@dataclasses.dataclass(frozen=True)
class Traced:
    """rgba (h, w, 4) float32 and first_bounce_norms (h, w, 3) or None, as the Film sums
    them; every BatchResult in path order (with its records when settings.record_paths);
    the Integrator (its vocabulary names the records' events)."""

    rgba: np.ndarray
    first_bounce_norms: np.ndarray | None
    batches: list[BatchResult]
    integrator: Integrator

    @property
    def vocabulary(self):
        return self.integrator.vocabulary


def trace_image(scene: SceneData, spec: RenderSpec, settings: TraceSettings, *,
                resolution: tuple[int, int] | None = None, threads: int | None = None,
                batch_paths: int = DEFAULT_BATCH_PATHS) -> Traced:
    """Trace every pixel of ``spec`` (at ``resolution`` if given) with ``settings``: the
    tracer's stages only, no index, no products."""
    if resolution is not None:
        spec = dataclasses.replace(spec, resolution=tuple(resolution))
    integrator = prepare(scene, spec, settings)
    width, height = spec.resolution
    film = Film(width * height, settings.spp, settings.first_bounce_norms)
    batches: list[BatchResult] = []

    def add(batch: BatchResult) -> None:
        film.add(batch)
        batches.append(batch)

    trace_pixels(integrator, 0, width * height, add, threads=threads, batch_paths=batch_paths)
    rgba, norms = film.images(width, height)
    return Traced(rgba, norms, batches, integrator)


@contextlib.contextmanager
def index_writer(writer: type[PathIndexWriter] = PathIndexWriter, **options) -> Iterator[None]:
    """Within, render_frame writes its path index with ``writer(path, ..., **options)``
    (``chunk_records``, ``buffer_records``; ``writer`` a PathIndexWriter subclass).
    Tests that rely on the chunks check they got them (a render's index otherwise has one
    chunk per 65,536 records)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(frame, "PathIndexWriter", functools.partial(writer, **options))
        yield
