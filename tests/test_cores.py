"""The one rule for "all cores": CPU affinity, then any cgroup CPU quota (v1 and v2)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from test_cli import SCRIPT

from pxr_layers.cores import available_cores, cgroup_cpu_quota

REPO = Path(__file__).resolve().parents[1]


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_a_cgroup_v2_quota_counts_and_the_tightest_ancestor_wins(tmp_path):
    membership = tmp_path / "proc-cgroup"
    write(membership, "0::/farm/job7\n")
    write(tmp_path / "fs" / "cgroup.controllers", "cpu memory\n")
    write(tmp_path / "fs" / "farm" / "cpu.max", "150000 100000\n")  # the farm's slot: 1.5 cores
    write(tmp_path / "fs" / "farm" / "job7" / "cpu.max", "max 100000\n")  # the job's own: no limit
    assert cgroup_cpu_quota(tmp_path / "fs", membership) == 1.5
    write(tmp_path / "fs" / "farm" / "cpu.max", "max 100000\n")
    assert cgroup_cpu_quota(tmp_path / "fs", membership) is None


def test_a_cgroup_v1_quota_counts(tmp_path):
    membership = tmp_path / "proc-cgroup"
    write(membership, "4:memory:/docker/abc\n3:cpu,cpuacct:/docker/abc\n")
    write(tmp_path / "fs" / "cpu,cpuacct" / "docker" / "abc" / "cpu.cfs_quota_us", "200000\n")
    write(tmp_path / "fs" / "cpu,cpuacct" / "docker" / "abc" / "cpu.cfs_period_us", "100000\n")
    assert cgroup_cpu_quota(tmp_path / "fs", membership) == 2.0
    write(tmp_path / "fs" / "cpu,cpuacct" / "docker" / "abc" / "cpu.cfs_quota_us", "-1\n")
    assert cgroup_cpu_quota(tmp_path / "fs", membership) is None


def test_no_cgroup_file_system_is_no_quota(tmp_path):
    assert cgroup_cpu_quota(tmp_path / "nothing", tmp_path / "no-such-file") is None
    assert 1 <= available_cores() <= (os.cpu_count() or 1)


def render_log(cpus: set[int], tmp_path: Path) -> str:
    """The render command's log when the process may run on ``cpus`` only (as taskset -c)."""
    result = subprocess.run([SCRIPT, "render", str(REPO / "render" / "cornell.usda"), "--spp", "1",
                             "--resolution", "8", "8", "--max-depth", "1", "--no-index", "--no-previews",
                             "-o", str(tmp_path / "out.exr")], capture_output=True, text=True, check=False,
                            preexec_fn=lambda: os.sched_setaffinity(0, cpus), timeout=600)
    assert result.returncode == 0, result.stderr
    return result.stderr


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this OS")
def test_the_render_uses_the_cores_its_affinity_gives(tmp_path):
    assert "on 1 thread\n" in render_log({0}, tmp_path)
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) >= 2 and (cgroup_cpu_quota() or 2) >= 2:
        assert "on 2 threads\n" in render_log(set(allowed[:2]), tmp_path)
