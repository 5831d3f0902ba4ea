"""How many CPU cores this process may use: the one rule for "all cores".

``os.cpu_count()`` counts the machine's cores, not this process's. A render pinned with
``taskset``, a Dask worker pinned by its scheduler, or a container given two CPUs of a
64-core host must not start 64 threads: they would share two cores and each thread's
buffers would still be allocated. So the count is the smaller of

* the CPU affinity mask (``sched_getaffinity``: taskset, cpusets, a scheduler's pinning);
* the cgroup CPU quota, rounded up (``cpu.max`` in cgroup v2, ``cpu.cfs_quota_us`` /
  ``cpu.cfs_period_us`` in v1: Docker's ``--cpus``, Kubernetes limits), of this process's
  cgroup and of every cgroup above it.

Every thread pool of the package (the tracer, the data AOVs, OpenEXR's compression) and the
job's local workers default to :func:`available_cores`.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

CGROUP_ROOT = Path("/sys/fs/cgroup")


@functools.cache
def available_cores() -> int:
    """The cores this process may use (at least 1): affinity, then any cgroup CPU quota."""
    if hasattr(os, "sched_getaffinity"):
        cores = len(os.sched_getaffinity(0))
    else:  # macOS, Windows: no affinity API in the standard library
        cores = os.cpu_count() or 1
    quota = cgroup_cpu_quota()
    if quota is not None:
        cores = min(cores, max(1, math.ceil(quota)))
    return max(1, cores)


def cgroup_cpu_quota(root: Path = CGROUP_ROOT, membership: Path = Path("/proc/self/cgroup")) -> float | None:
    """The tightest CPU quota, in cores (1.5 = one and a half), of this process's cgroup and
    its ancestors; None when there is none (or no cgroup file system, as outside Linux).

    root : where the cgroup file system is mounted; membership : /proc/self/cgroup's text.
    """
    try:
        lines = membership.read_text().splitlines()
    except OSError:
        return None
    quotas: list[float] = []
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":  # cgroup v2: one unified hierarchy (beside v1's under "unified" in hybrid mode)
            mount = root if (root / "cgroup.controllers").exists() else root / "unified"
            quotas += _quotas_up(mount, path, _v2_quota)
        elif "cpu" in controllers.split(","):  # cgroup v1: the cpu controller's hierarchy
            mount = next((root / name for name in ("cpu,cpuacct", "cpu") if (root / name).is_dir()), None)
            if mount is not None:
                quotas += _quotas_up(mount, path, _v1_quota)
    return min(quotas) if quotas else None


def _quotas_up(mount: Path, path: str, read) -> list[float]:
    """The quotas ``read`` finds in the cgroup at ``path`` and every folder above it (a
    container's limit may sit on a parent of the process's own cgroup)."""
    folder = mount / path.lstrip("/")
    quotas = []
    for candidate in (folder, *folder.parents):
        if not candidate.is_relative_to(mount):
            break
        quota = read(candidate)
        if quota is not None:
            quotas.append(quota)
    return quotas


def _v2_quota(folder: Path) -> float | None:
    """``cpu.max``: "QUOTA PERIOD" in microseconds, or "max PERIOD" for no limit."""
    try:
        quota, period = (folder / "cpu.max").read_text().split()[:2]
    except (OSError, ValueError):
        return None
    return None if quota == "max" or int(period) <= 0 else int(quota) / int(period)


def _v1_quota(folder: Path) -> float | None:
    """``cpu.cfs_quota_us`` (-1 for no limit) over ``cpu.cfs_period_us``."""
    try:
        quota = int((folder / "cpu.cfs_quota_us").read_text())
        period = int((folder / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return None if quota <= 0 or period <= 0 else quota / period
