"""The one place that sets up numba: the decorators of every compiled kernel and their cache.

Kernels are ``njit(nogil=True, cache=True)``: they release the GIL, so the render's thread
pool runs them (and Embree) in parallel, and their machine code is cached on disk, so only
the first run on a machine pays the compile. ``error_model="numpy"``: a division by zero
gives inf or NaN as in numpy instead of raising (the kernels guard their divisions; the
check would cost a branch per division). No fastmath: results must not depend on how LLVM
reassociates, so that renders are byte-identical across machines with the same build.

Kernels run without numba's reference counting (``_nrt=False``): with it, every array
handed to a helper costs an atomic increment and decrement per lane wherever LLVM cannot
prove them redundant (measured: 80 ns per lane for a helper of seven arrays, against 2 ns
without). The price is that a kernel cannot allocate: its callers pass every array it
writes, scratch space included (:func:`scratch`).

The cache lives in ``$PXR_LAYERS_CACHE_DIR`` if set, else numba's own ``$NUMBA_CACHE_DIR``,
else ``$XDG_CACHE_HOME/pxr-layers/numba`` (``~/.cache/pxr-layers/numba``): never beside the
installed sources, so a read-only install works. An unwritable cache folder falls back to
one under the system's temporary directory. Inside it, each version of the tracer's
sources gets its own subfolder (a hash of them): numba checks only a kernel's own file,
so a kernel whose inlined helpers changed in another file would otherwise load stale.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

import numba
import numpy

log = logging.getLogger(__name__)

CACHE_ENV = "PXR_LAYERS_CACHE_DIR"


def cache_dir() -> Path:
    """Where compiled kernels are cached (see the module docstring)."""
    chosen = os.environ.get(CACHE_ENV) or os.environ.get("NUMBA_CACHE_DIR")
    if not chosen:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
        chosen = Path(base) / "pxr-layers" / "numba"
    path = Path(chosen) / _sources_digest()
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=path, prefix=".probe")
        probe.close()
    except OSError:
        fallback = Path(tempfile.gettempdir()) / f"pxr-layers-numba-{os.getuid()}"
        log.debug("kernel cache %s is not writable: using %s", path, fallback)
        fallback.mkdir(parents=True, exist_ok=True)
        path = fallback
    return path


def _sources_digest() -> str:
    """A short hash of the compiled code's sources: trace/, paths/, shader_nodes.py and this
    module."""
    package = Path(__file__).resolve().parent
    digest = hashlib.blake2b(digest_size=8)
    for source in sorted([*(package / "trace").rglob("*.py"), *(package / "paths").glob("*.py"),
                          package / "shader_nodes.py", Path(__file__)]):
        digest.update(source.read_bytes())
    digest.update(numba.__version__.encode())
    return digest.hexdigest()


# numba reads the folder when a cached function is declared: set it before any kernel is.
numba.config.CACHE_DIR = str(cache_dir())

_OPTIONS = dict(nogil=True, cache=True, error_model="numpy", _nrt=False)

kernel = numba.njit(**_OPTIONS)
"""A compiled loop over lanes, called from Python once per queue; or a large per-lane
routine that several kernels call instead of inlining (the material interpreter): without
reference counting a call costs nanoseconds, and the routine is compiled once."""

inline = numba.njit(**_OPTIONS, inline="always")
"""A per-lane helper of kernels, inlined into them (no call, no reference counting)."""


def scratch(*shape: int) -> "numpy.ndarray":
    """Zeroed float64 working space for one kernel call (kernels cannot allocate)."""
    return numpy.zeros(shape)
