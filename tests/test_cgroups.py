"""The CPU bandwidth limit of the process's control group (dsp/cgroups.py) and the cores the stages and
scipy.fft then use (dsp.blas.available_cores): /proc files and cgroup folders laid out as the kernel's
(Documentation/admin-guide/cgroup-v2.rst, "cpu.max"; cgroup-v1 "cpu.cfs_quota_us" / "cpu.cfs_period_us";
proc(5), mountinfo), and, where this test runs as root on a cgroup v1 cpu hierarchy, a real cgroup with
a quota.  The memory room through the same folders: tests/test_out_of_core.py."""
from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from cgroup_files import cgroup_files, fake_proc
from fwdlook_cli.dsp import blas, cgroups
from fwdlook_cli.dsp.cgroups import cgroup_cpu_limit, own_cgroup_folders


def test_v2_the_smallest_limit_on_the_way_up_applies(tmp_path):
    """A Kubernetes pod's layout: the container's own limit, its pod's (smaller, binding) and an
    unlimited parent; the mount's root (the host's root cgroup) has no cpu.max of its own."""
    mnt = tmp_path / "cg"
    cgroup_files(mnt / "kubepods" / "pod1" / "ctr", cpu_max="400000 100000")
    cgroup_files(mnt / "kubepods" / "pod1", cpu_max="150000 100000")
    cgroup_files(mnt / "kubepods", cpu_max="max 100000")
    proc = fake_proc(tmp_path, ["0::/kubepods/pod1/ctr"], [f"30 23 0:27 / {mnt} rw,nosuid - cgroup2 cgroup2 rw"])
    assert [f for f, _ in own_cgroup_folders("cpu", proc)] == [
        mnt / "kubepods" / "pod1" / "ctr", mnt / "kubepods" / "pod1", mnt / "kubepods", mnt]
    assert cgroup_cpu_limit(proc) == 1.5
    cgroup_files(mnt / "kubepods" / "pod1", cpu_max="max 100000")
    cgroup_files(mnt / "kubepods" / "pod1" / "ctr", cpu_max="max 100000")
    assert cgroup_cpu_limit(proc) is None                              # "max": no limit anywhere


def test_v2_a_container_whose_mount_root_is_its_own_cgroup(tmp_path):
    """With a cgroup namespace the process's path is '/' and the mount is the container's cgroup."""
    mnt = tmp_path / "cg"
    cgroup_files(mnt, cpu_max="50000 100000")
    proc = fake_proc(tmp_path, ["0::/"], [f"30 23 0:27 / {mnt} rw - cgroup2 cgroup2 rw"])
    assert cgroup_cpu_limit(proc) == 0.5


def test_v1_docker_mount_of_its_own_cgroup_and_other_controllers_left_out(tmp_path):
    """Docker on cgroup v1: the cpu hierarchy mounted with the container's cgroup as its root, which
    /proc/self/cgroup names by the host's path; the memory and cpuset mounts hold no CPU limit, and a
    cpuset controller is not the cpu controller."""
    cpu, mem, cpuset = tmp_path / "cpu,cpuacct", tmp_path / "memory", tmp_path / "cpuset"
    cgroup_files(cpu, cpu_cfs_quota_us=200000, cpu_cfs_period_us=100000)
    cgroup_files(mem, cpu_cfs_quota_us=10000, cpu_cfs_period_us=100000)
    cgroup_files(cpuset, cpu_cfs_quota_us=10000, cpu_cfs_period_us=100000)
    proc = fake_proc(tmp_path, ["5:cpu,cpuacct:/docker/abc", "4:memory:/docker/abc", "3:cpuset:/docker/abc", "0::/"],
                 [f"40 31 0:30 /docker/abc {cpu} rw - cgroup cgroup rw,cpu,cpuacct",
                  f"41 31 0:31 /docker/abc {mem} rw - cgroup cgroup rw,memory",
                  f"42 31 0:32 /docker/abc {cpuset} rw - cgroup cgroup rw,cpuset"])
    assert cgroup_cpu_limit(proc) == 2.0
    cgroup_files(cpu, cpu_cfs_quota_us=-1)
    assert cgroup_cpu_limit(proc) is None                              # -1: no quota


def test_unreadable_or_missing_files_are_no_limit(tmp_path):
    mnt = tmp_path / "cg"
    cgroup_files(mnt / "job", cpu_max="junk 100000")
    proc = fake_proc(tmp_path, ["0::/job"], [f"30 23 0:27 / {mnt} rw - cgroup2 cgroup2 rw"])
    assert cgroup_cpu_limit(proc) is None
    assert cgroup_cpu_limit(str(tmp_path / "no-proc")) is None
    assert own_cgroup_folders("cpu", str(tmp_path / "no-proc")) == []


def test_the_cores_used_are_the_affinitys_within_the_limit_rounded_up(monkeypatch):
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    monkeypatch.setattr(cgroups, "cached_cpu_limit", lambda: None)
    assert blas.available_cores() == affinity
    monkeypatch.setattr(cgroups, "cached_cpu_limit", lambda: 0.3)
    assert blas.available_cores() == 1
    monkeypatch.setattr(cgroups, "cached_cpu_limit", lambda: 1.2)
    assert blas.available_cores() == min(affinity, 2)
    monkeypatch.setattr(cgroups, "cached_cpu_limit", lambda: 1000.0)
    assert blas.available_cores() == affinity


_IN_CGROUP = """
import sys
from fwdlook_cli.cli import main
from fwdlook_cli.dsp.blas import available_cores, fft_workers, worker_threads
try:
    main(["validate", sys.argv[1]])
except SystemExit as exc:
    assert not exc.code, exc.code
print(available_cores(), worker_threads(), fft_workers())
"""


def _v1_cpu_mount():
    mount = Path("/sys/fs/cgroup/cpu")
    ok = (os.geteuid() == 0 and (mount / "cpu.cfs_quota_us").is_file() and os.access(mount, os.W_OK)
          and len(os.sched_getaffinity(0)) >= 2)
    return mount if ok else None


@pytest.mark.skipif(_v1_cpu_mount() is None, reason="needs root, a cgroup v1 cpu hierarchy and two cores")
def test_a_command_in_a_cgroup_with_a_one_cpu_quota_runs_one_thread(tmp_path):
    """A real cgroup (made and removed here) with a quota of one CPU: the command sees one core, its
    stages' pools and its FFTs run one thread, though its affinity has more."""
    group = _v1_cpu_mount() / f"fwdlook-test-{uuid.uuid4().hex[:8]}"
    try:
        group.mkdir()
    except OSError as exc:
        pytest.skip(f"cannot make a cgroup here: {exc}")
    try:
        try:
            (group / "cpu.cfs_period_us").write_text("100000")
            (group / "cpu.cfs_quota_us").write_text("100000")
        except OSError as exc:
            pytest.skip(f"cannot set a cgroup's quota here: {exc}")
        tiny = Path(__file__).resolve().parents[1] / "scenarios" / "tiny.yaml"
        enter = f"(echo $$ > {group / 'cgroup.procs'}) 2>/dev/null || exit 77; exec \"$0\" -c \"$1\" \"$2\""
        res = subprocess.run(["sh", "-c", enter, sys.executable, _IN_CGROUP, str(tiny)], capture_output=True,
                             text=True, timeout=120, env=dict(os.environ, FWDLOOK_THREADS="", OMP_NUM_THREADS=""))
        if res.returncode == 77:
            pytest.skip("cannot move a process into a cgroup here")
        assert res.returncode == 0, res.stderr
        assert res.stdout.split()[-3:] == ["1", "1", "1"]
    finally:
        group.rmdir()
