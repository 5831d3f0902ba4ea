"""What job tasks need of the worker processes they run in: a Dask worker plugin, and
the settings of the LocalCluster a job starts."""

from __future__ import annotations

import ctypes
import logging
import signal
import sys
import threading

from distributed.diagnostics.plugin import WorkerPlugin

log = logging.getLogger(__name__)

LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.memory.monitor-interval": "500ms",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.tick.interval": "100ms",
    "distributed.worker.preload": [__name__],  # dask_setup, below
}
"""Dask's housekeeping, at a pace for tasks of seconds. With the defaults (memory checked
every 100 ms by each nanny and worker, system figures every 500 ms, event-loop ticks every
20 ms) the scheduler, nannies and workers spend about 8 % of a core on it, which the
workers' tasks lose when there is one worker per core. And each worker process runs this
module's :func:`dask_setup` as it starts (a Dask preload)."""


def local_cluster(workers: int, **options):
    """A ``distributed.LocalCluster`` of ``workers`` single-threaded worker processes (one
    task per core: a task traces with one thread), with ``LOCAL_CLUSTER_CONFIG``.
    ``options`` go to LocalCluster (``dashboard_address``, ...)."""
    import copy

    import dask
    from distributed import LocalCluster

    with dask.config.set(LOCAL_CLUSTER_CONFIG):  # read as the scheduler and nannies start
        # Each nanny starts (and restarts) its worker with the config it was given: a copy,
        # as the settings are undone in the shared one when this block ends.
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            config=copy.deepcopy(dask.config.config), **options)


def dask_setup(worker) -> None:
    """Run by each worker process of a job's LocalCluster as it starts (and restarts): the
    worker ignores SIGINT. Ctrl-C in a terminal reaches the whole process group; a worker
    killed by it printed its KeyboardInterrupt traceback and its nanny another. The job's
    own process takes the Ctrl-C, says what was committed and closes the cluster. (Only
    local workers: a farm's `dask worker` keeps its own Ctrl-C.)"""
    if threading.current_thread() is threading.main_thread():  # where Python handles signals
        signal.signal(signal.SIGINT, signal.SIG_IGN)


class WorkerTuning(WorkerPlugin):
    """Two Dask worker defaults that cost render tasks much of their time, undone.

    * **The allocator.** Dask starts worker processes with ``MALLOC_TRIM_THRESHOLD_=65536``
      (to hand memory back to the OS quickly). Setting it pins glibc's mmap threshold at
      128 KiB, so every array of a tile or of an extraction chunk is mapped afresh,
      page-faulted in, then unmapped: tiles and assemblies ran about 1.5x slower in workers
      than in a plain process. Arrays under ``MMAP_THRESHOLD`` are now kept in the heap,
      and up to ``TRIM_THRESHOLD`` of free heap is kept for the next task (Linux/glibc
      only; elsewhere the allocator is left alone).
    * **The statistical profiler.** Every 10 ms a worker walks the stack of its running
      task, under the GIL: with one worker per core, that is taken from the tasks (about
      10 % here). Its callbacks are stopped; the dashboard's profile page stays empty.

    Registered by every job on its client, so it reaches a farm's workers too.
    """

    name = "pxr-layers-worker-tuning"
    MMAP_THRESHOLD = 32 << 20  # glibc's upper limit for this setting on 64-bit
    TRIM_THRESHOLD = 128 << 20
    PROFILER_CALLBACKS = ("profile", "profile-cycle")

    def setup(self, worker) -> None:
        tune_allocator(self.MMAP_THRESHOLD, self.TRIM_THRESHOLD)
        for name in self.PROFILER_CALLBACKS:
            callback = getattr(worker, "periodic_callbacks", {}).pop(name, None)
            if callback is not None:
                callback.stop()


def tune_allocator(mmap_threshold: int, trim_threshold: int) -> None:
    """Set glibc's M_MMAP_THRESHOLD and M_TRIM_THRESHOLD for this process (bytes)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # not glibc (musl, ...): leave its allocator alone
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # from <malloc.h>
    if not (libc.mallopt(m_mmap_threshold, mmap_threshold) and libc.mallopt(m_trim_threshold, trim_threshold)):
        log.debug("mallopt refused the allocator settings")
