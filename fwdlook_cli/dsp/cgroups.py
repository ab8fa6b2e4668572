"""This process's control groups: the folders that hold its limits, and the CPU bandwidth limit.

The folders (:func:`own_cgroup_folders`) serve the memory room (``io.backing.cgroup_room_bytes``: a
container's or a batch job's memory limit) and the CPU limit below.  They come from
``/proc/self/cgroup`` (the process's cgroup per hierarchy) and ``/proc/self/mountinfo`` (where each
hierarchy is mounted, and which of its cgroups is the mount's root), so a container whose mount root is
its own cgroup reads its own limits, and a cgroup's ancestors visible in the mount are read as well
(a parent's limit binds its children).  cgroup v2 and v1 alike.

**The CPU limit** (:func:`cgroup_cpu_limit`).  A container started with ``docker --cpus 2`` or a
Kubernetes CPU limit keeps every core of the machine in its CPU affinity and is throttled by the kernel
instead: each period (100 ms by default) its threads may run ``quota`` microseconds in all, then wait.
Threads beyond the quota only add their switching and synchronisation to the same budget, so the
stages' thread pools and ``scipy.fft``'s workers (:func:`dsp.blas.available_cores`) count the smaller
of the affinity and this limit, rounded up.  Measured on this project's 2-core VM with a 64-core
machine faked (a preloaded ``get_nprocs``, ``sysconf`` and ``sched_getaffinity``) in a cgroup limited
to 2 CPUs, the paper cube's ``decimation`` chain took 175.5 ms with the machine's counts and 152 ms with
the limit's (medians of ten alternated pairs of processes; faster in eight), and limited to 1 CPU 287
against 226 ms (six pairs, faster in six) (docs/SPEED.md, its last section).  cgroup v2: ``cpu.max``
("max PERIOD": none; "200000 100000": 2 CPUs); v1: ``cpu.cfs_quota_us`` (-1: none) over ``cpu.cfs_period_us``.  Read once per
process (:func:`cached_cpu_limit`): the limit of a running process seldom changes.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path


def own_cgroup_folders(controller: str, proc: str = "/proc") -> list:
    """[(folder, is_v2)]: this process's cgroup folder for ``controller`` (``"memory"``, ``"cpu"``) and
    each ancestor's, own first, in every mount of a hierarchy that may hold it (a v1 hierarchy with that
    controller, or cgroup v2); [] where nothing can be read."""
    try:
        cgroups = Path(proc, "self", "cgroup").read_text(encoding="ascii").splitlines()
        mounts = Path(proc, "self", "mountinfo").read_text(encoding="ascii").splitlines()
    except (OSError, UnicodeDecodeError):
        return []
    own = {}
    for line in cgroups:
        hierarchy, controllers, path = (line.split(":", 2) + ["", ""])[:3]
        if hierarchy == "0" and not controllers:
            own["cgroup2"] = path
        elif controller in controllers.split(","):
            own["cgroup"] = path
    folders = []
    for line in mounts:
        left, _, right = line.partition(" - ")
        fields, kind = left.split(), right.split()
        if len(fields) < 5 or len(kind) < 3 or kind[0] not in own:
            continue
        if kind[0] == "cgroup" and controller not in kind[2].split(","):
            continue
        root, mount, path = fields[3], fields[4], own[kind[0]]
        inside = root == "/" or path == root or path.startswith(root.rstrip("/") + "/")
        rel = path[len(root):] if inside else ""           # the own cgroup below the mount's root
        parts = [p for p in rel.split("/") if p]
        folders += [(Path(mount, *parts[:k]), kind[0] == "cgroup2") for k in range(len(parts), -1, -1)]
    return folders


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None


def _cpus(quota: str | None, period: str | None) -> float | None:
    """quota / period in CPUs; None for no limit ("max", -1) or anything unreadable."""
    try:
        quota_us, period_us = int(quota), int(period)
    except (TypeError, ValueError):
        return None
    return quota_us / period_us if quota_us > 0 and period_us > 0 else None


def cgroup_cpu_limit(proc: str = "/proc") -> float | None:
    """The CPU bandwidth limit on this process, in CPUs (may be fractional): the smallest over its cpu
    cgroup and the ancestors visible in the mounts; None where none is set or nothing can be read (not
    Linux, no cgroup file system)."""
    limits = []
    for folder, v2 in own_cgroup_folders("cpu", proc):
        if v2:
            parts = (_read(folder / "cpu.max") or "").split()
            limit = _cpus(*parts) if len(parts) == 2 else None
        else:
            limit = _cpus(_read(folder / "cpu.cfs_quota_us"), _read(folder / "cpu.cfs_period_us"))
        if limit is not None:
            limits.append(limit)
    return min(limits) if limits else None


@functools.lru_cache(maxsize=1)
def _cached(pid: int) -> float | None:
    return cgroup_cpu_limit()


def cached_cpu_limit() -> float | None:
    """:func:`cgroup_cpu_limit` read once per process (a forked child reads its own)."""
    return _cached(os.getpid())
