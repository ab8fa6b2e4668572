"""The CPU bandwidth limit of the process's control group (dsp/cpu_limit.py) and the cores the stages and
scipy.fft then use (dsp.blas.available_cores): file trees laid out as the kernel's cgroup file systems
(Documentation/admin-guide/cgroup-v2.rst, "cpu.max"; cgroup-v1 "cpu.cfs_quota_us" / "cpu.cfs_period_us"),
and, where this test runs as root on a cgroup v1 cpu hierarchy, a real cgroup with a quota."""
from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from fwdlook_cli.dsp import blas, cpu_limit
from fwdlook_cli.dsp.cpu_limit import cgroup_cpu_limit


def _tree(tmp_path, proc_lines, files):
    """/proc/self/cgroup with ``proc_lines`` and the cgroup mount under tmp_path/cg with ``files``."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    proc = tmp_path / "cgroup"
    proc.write_text("\n".join(proc_lines) + "\n")
    root = tmp_path / "cg"
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text + "\n")
    return str(proc), str(root)


def test_v2_the_smallest_limit_on_the_way_up_applies(tmp_path):
    proc, root = _tree(tmp_path, ["0::/kubepods/pod1/ctr"], {
        "cgroup.controllers": "cpu memory",                     # the root: no cpu.max of its own
        "kubepods/cgroup.controllers": "cpu", "kubepods/cpu.max": "max 100000",
        "kubepods/pod1/cgroup.controllers": "cpu", "kubepods/pod1/cpu.max": "150000 100000",
        "kubepods/pod1/ctr/cgroup.controllers": "cpu", "kubepods/pod1/ctr/cpu.max": "400000 100000"})
    assert cgroup_cpu_limit(proc, root) == 1.5


def test_v2_without_a_limit_is_none(tmp_path):
    proc, root = _tree(tmp_path, ["0::/user.slice/session"], {
        "cgroup.controllers": "cpu", "user.slice/cpu.max": "max 100000",
        "user.slice/session/cpu.max": "max 100000"})
    assert cgroup_cpu_limit(proc, root) is None


def test_v2_a_container_that_sees_its_own_cgroup_at_the_mount(tmp_path):
    """With a cgroup namespace the path is '/' and the mount's root is the container's cgroup."""
    proc, root = _tree(tmp_path, ["0::/"], {"cgroup.controllers": "cpu", "cpu.max": "50000 100000"})
    assert cgroup_cpu_limit(proc, root) == 0.5


def test_v1_host_path_missing_under_the_containers_mount(tmp_path):
    """Docker on cgroup v1 without a namespace: /proc/self/cgroup names the host's path, which the
    container's mount does not have; its root is the container's cgroup, and is read."""
    proc, root = _tree(tmp_path, ["4:cpu,cpuacct:/docker/0123abcd", "3:cpuset:/docker/0123abcd", "0::/"], {
        "cpu,cpuacct/cpu.cfs_quota_us": "200000", "cpu,cpuacct/cpu.cfs_period_us": "100000",
        "cpuset/cpuset.cpus": "0-63"})
    assert cgroup_cpu_limit(proc, root) == 2.0


def test_v1_no_quota_and_unreadable_files_are_none(tmp_path):
    proc, root = _tree(tmp_path, ["1:cpu:/"], {"cpu/cpu.cfs_quota_us": "-1", "cpu/cpu.cfs_period_us": "100000"})
    assert cgroup_cpu_limit(proc, root) is None
    proc, root = _tree(tmp_path / "b", ["1:cpu:/x"], {"cpu/cpu.cfs_quota_us": "junk", "cpu/cpu.cfs_period_us": "100000"})
    assert cgroup_cpu_limit(proc, root) is None
    assert cgroup_cpu_limit(str(tmp_path / "none"), root) is None          # no /proc/self/cgroup


def test_the_cores_used_are_the_affinitys_within_the_limit_rounded_up(monkeypatch):
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    monkeypatch.setattr(cpu_limit, "cached_cpu_limit", lambda: None)
    assert blas.available_cores() == affinity
    monkeypatch.setattr(cpu_limit, "cached_cpu_limit", lambda: 0.3)
    assert blas.available_cores() == 1
    monkeypatch.setattr(cpu_limit, "cached_cpu_limit", lambda: 1.2)
    assert blas.available_cores() == min(affinity, 2)
    monkeypatch.setattr(cpu_limit, "cached_cpu_limit", lambda: 1000.0)
    assert blas.available_cores() == affinity


_IN_CGROUP = """
import sys
from scipy.fft._pocketfft import helper
from fwdlook_cli.cli import main
from fwdlook_cli.dsp.blas import available_cores, worker_threads
try:
    main(["validate", sys.argv[1]])
except SystemExit as exc:
    assert not exc.code, exc.code
print(available_cores(), worker_threads(), helper._workers(-1))
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
