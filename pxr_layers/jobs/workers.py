"""What job tasks need of the worker processes they run in (a Dask worker plugin)."""

from __future__ import annotations

import ctypes
import logging
import sys

from distributed.diagnostics.plugin import WorkerPlugin

log = logging.getLogger(__name__)


class ThroughputAllocator(WorkerPlugin):
    """A Dask worker plugin: glibc's malloc tuned for tasks that free and allocate large arrays.

    Dask starts worker processes with ``MALLOC_TRIM_THRESHOLD_=65536`` (to hand memory back
    to the OS quickly). Setting it pins glibc's mmap threshold at 128 KiB, so every array
    of a tile or of an extraction chunk is mapped afresh and page-faulted in, then unmapped:
    tiles and assemblies ran about 1.5x slower in workers than in a plain process. Arrays
    under ``MMAP_THRESHOLD`` are kept in the heap instead, and up to ``TRIM_THRESHOLD`` of
    free heap is kept for the next task. Linux/glibc only; elsewhere it does nothing.
    """

    name = "pxr-layers-allocator"
    MMAP_THRESHOLD = 32 << 20  # glibc's upper limit for this setting on 64-bit
    TRIM_THRESHOLD = 128 << 20

    def setup(self, worker=None) -> None:
        if not sys.platform.startswith("linux"):
            return
        try:
            libc = ctypes.CDLL("libc.so.6")
        except OSError:  # not glibc (musl, ...): leave its allocator alone
            return
        m_trim_threshold, m_mmap_threshold = -1, -3  # from <malloc.h>
        if not (libc.mallopt(m_mmap_threshold, self.MMAP_THRESHOLD) and libc.mallopt(m_trim_threshold,
                                                                                      self.TRIM_THRESHOLD)):
            log.debug("mallopt refused the worker's allocator settings")
