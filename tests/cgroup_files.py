"""/proc files and cgroup folders laid out as the kernel's, for the tests of the cgroup readers
(tests/test_cgroups.py: the CPU limit; tests/test_out_of_core.py: the memory room)."""
from __future__ import annotations


def fake_proc(tmp_path, cgroup_lines, mount_lines, meminfo_kib=None) -> str:
    """A /proc with ``self/cgroup`` and ``self/mountinfo`` of these lines (and ``meminfo`` where given)."""
    proc = tmp_path / "proc"
    (proc / "self").mkdir(parents=True)
    (proc / "self" / "cgroup").write_text("".join(line + "\n" for line in cgroup_lines))
    (proc / "self" / "mountinfo").write_text("".join(line + "\n" for line in mount_lines))
    if meminfo_kib is not None:
        (proc / "meminfo").write_text(f"MemTotal: {4 * meminfo_kib} kB\nMemAvailable: {meminfo_kib} kB\n")
    return str(proc)


def cgroup_files(folder, **files) -> None:
    """``folder`` with one file per keyword, its first ``_`` read as ``.`` (``cpu_max`` is ``cpu.max``)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (folder / name.replace("_", ".", 1)).write_text(str(text) + "\n")
