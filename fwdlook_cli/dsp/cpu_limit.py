"""The CPU bandwidth limit of this process's control group: how many cores' worth of time it may use.

A container started with ``docker --cpus 2`` or a Kubernetes CPU limit keeps every core of the machine
in its CPU affinity and is throttled by the kernel instead: each period (100 ms by default) its
threads may run ``quota`` microseconds in all, then wait for the next period.  Threads beyond the
quota only add their switching and synchronisation to the same budget.  So the stages' thread pools
and ``scipy.fft``'s workers (:func:`dsp.blas.available_cores`) count the smaller of the affinity and
this limit, rounded up.  Measured on this project's 2-core VM with a 64-core machine faked (a
preloaded ``get_nprocs``, ``sysconf`` and ``sched_getaffinity``) in a cgroup limited to 2 CPUs, the
paper cube's ``decimation`` chain took 175.5 ms with the machine's counts and 152 ms with the limit's
(medians of ten alternated pairs of processes; faster in eight), and limited to 1 CPU 287 against
226 ms (six pairs, faster in six) (README, Speed).

Read once per process (the limit of a running process seldom changes; :func:`cached_cpu_limit`):

* cgroup v2: ``cpu.max`` (``"max 100000"``: none; ``"200000 100000"``: 2 CPUs) of the process's cgroup
  (the ``0::PATH`` line of ``/proc/self/cgroup``) and of each cgroup above it;
* cgroup v1: ``cpu.cfs_quota_us`` (-1: none) over ``cpu.cfs_period_us`` in the hierarchy whose
  controllers include ``cpu``.

The smallest limit on the path applies (a parent's limit binds its children).  Where the path does not
exist under the mount (a container that sees its own cgroup at the mount's root while
``/proc/self/cgroup`` names the host's path), the directories that do exist on the way up are read,
the mount's root last.  Nothing readable: no limit (None).
"""
from __future__ import annotations

import functools
import os
from pathlib import Path

PROC_CGROUP = "/proc/self/cgroup"
CGROUP_ROOT = "/sys/fs/cgroup"


def _read(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None


def _v2_limit(folder: Path) -> float | None:
    """CPUs allowed by ``folder/cpu.max`` ("QUOTA PERIOD" or "max PERIOD"); None for none or unreadable."""
    text = _read(folder / "cpu.max")
    parts = text.split() if text else []
    if len(parts) != 2 or parts[0] == "max":
        return None
    try:
        quota, period = int(parts[0]), int(parts[1])
    except ValueError:
        return None
    return quota / period if quota > 0 and period > 0 else None


def _v1_limit(folder: Path) -> float | None:
    """CPUs allowed by ``folder/cpu.cfs_quota_us`` over ``cpu.cfs_period_us``; None for -1 or unreadable."""
    quota, period = _read(folder / "cpu.cfs_quota_us"), _read(folder / "cpu.cfs_period_us")
    try:
        quota_us, period_us = int(quota), int(period)
    except (TypeError, ValueError):
        return None
    return quota_us / period_us if quota_us > 0 and period_us > 0 else None


def _up_to(base: Path, cgroup_path: str) -> list:
    """``base/cgroup_path`` and every folder above it up to ``base``, those that exist."""
    parts = [p for p in cgroup_path.split("/") if p and p not in (".", "..")]
    folders = [base.joinpath(*parts[:k]) for k in range(len(parts), -1, -1)]
    return [f for f in folders if f.is_dir()]


def cgroup_cpu_limit(proc_cgroup: str = PROC_CGROUP, root: str = CGROUP_ROOT) -> float | None:
    """The CPU bandwidth limit on this process, in CPUs (may be fractional), from ``proc_cgroup``
    (``/proc/self/cgroup``) and the cgroup file systems mounted under ``root``; None where none is set
    or nothing can be read (not Linux, no cgroup file system)."""
    text = _read(Path(proc_cgroup))
    if not text:
        return None
    root_path = Path(root)
    limits = []
    for line in text.splitlines():
        hierarchy, _, rest = line.partition(":")
        controllers, _, path = rest.partition(":")
        if hierarchy == "0" and controllers == "":              # cgroup v2 (alone, or beside v1)
            mounts, read, marker = (root_path, root_path / "unified"), _v2_limit, "cgroup.controllers"
        elif "cpu" in controllers.split(","):                    # cgroup v1's cpu controller
            mounts = (root_path / controllers, root_path / "cpu", root_path / "cpu,cpuacct")
            read, marker = _v1_limit, "cpu.cfs_quota_us"
        else:
            continue
        base = next((m for m in mounts if (m / marker).is_file()), None)   # where that hierarchy is mounted
        if base is None:
            continue
        limits += [x for x in map(read, _up_to(base, path)) if x is not None]
    return min(limits) if limits else None


@functools.lru_cache(maxsize=1)
def _cached(pid: int) -> float | None:
    return cgroup_cpu_limit()


def cached_cpu_limit() -> float | None:
    """:func:`cgroup_cpu_limit` read once per process (a forked child reads its own)."""
    return _cached(os.getpid())
