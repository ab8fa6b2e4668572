"""What memory costs the machine a bench runs on: ``page_cost`` in every bench's JSON.

The chain writes each stage's output into memory it has not used before and each stage file into
the page cache, so its time depends on what a new page costs the machine as well as on its code.
On a virtual machine that cost can be many times a bare-metal Linux's: the machine these figures
were measured on is a Firecracker guest whose kernel reports each freed 2 MiB block back to its host
at once (free page reporting, ``/sys/module/page_reporting``: ``page_reporting_order`` 9,
``min_free_ms`` 0), so a page the guest takes next may be one the host must fault in again.  The
probe measures it, so that a bench's ratios can be read against the machine they came from
(README, Speed: "What a new page costs here").

Every figure is in ms per MiB, timed once each (a probe of the machine's state, not a benchmark):
- ``anon_first_touch``: one byte written in every 4 KiB page of a new anonymous mapping (the page
  faults and the kernel's zeroing, and whatever the host adds);
- ``new_file``: a new file written from memory already touched (page-cache pages the kernel takes
  from its free memory);
- ``new_file_after_unlink``: the same into a second new file, right after the first was unlinked
  (pages the kernel has just had back);
- ``overwrite``: the same bytes written again over the second file (pages already in the cache: the
  copy alone).
"""
from __future__ import annotations

import mmap
import os
import stat
import tempfile
import time
from pathlib import Path

import numpy as np

PAGE_REPORTING_DIR = Path("/sys/module/page_reporting/parameters")
PROBE_MIB = 32
PAGE_BYTES = 4096


def page_reporting_settings(params_dir: Path = PAGE_REPORTING_DIR) -> str:
    """The kernel's free page reporting settings, ``"name=value, ..."`` (its writable parameters: the
    read-only ones are counters), or ``"none"`` where the kernel does not report free pages."""
    try:
        entries = sorted(Path(params_dir).iterdir())
    except OSError:
        return "none"
    settings = []
    for entry in entries:
        try:
            if not entry.stat().st_mode & stat.S_IWUSR:
                continue
            settings.append(f"{entry.name}={entry.read_text(encoding='utf-8').strip()}")
        except OSError:
            continue
    return ", ".join(settings) or "none"


def anon_first_touch_ms_per_mib(mib: int = PROBE_MIB) -> float:
    """ms per MiB to write one byte in every page of a new anonymous mapping of ``mib`` MiB."""
    size = int(mib) << 20
    region = mmap.mmap(-1, size)
    try:
        pages = np.frombuffer(region, dtype=np.uint8)
        t0 = time.perf_counter()
        pages[::PAGE_BYTES] = 1
        seconds = time.perf_counter() - t0
        del pages
    finally:
        region.close()
    return 1e3 * seconds / mib


def _write_all(fd: int, data, offset: int = 0) -> None:
    """``data`` written at ``offset``, however many calls the kernel takes."""
    view = memoryview(data).cast("B")
    while view:
        done = os.pwrite(fd, view, offset)
        view, offset = view[done:], offset + done


def file_write_ms_per_mib(mib: int = PROBE_MIB, directory=None) -> dict:
    """``new_file``, ``new_file_after_unlink`` and ``overwrite`` (module docstring), ms per MiB, in a
    temporary folder under ``directory`` (the system's temporary folder where None)."""
    data = np.ones(int(mib) << 20, dtype=np.uint8)            # touched: only the file's pages are new
    out = {}
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        for name, path in (("new_file", Path(tmp) / "a"), ("new_file_after_unlink", Path(tmp) / "b")):
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            try:
                t0 = time.perf_counter()
                _write_all(fd, data)
                out[name] = 1e3 * (time.perf_counter() - t0) / mib
                if name == "new_file_after_unlink":
                    t0 = time.perf_counter()
                    _write_all(fd, data)
                    out["overwrite"] = 1e3 * (time.perf_counter() - t0) / mib
            finally:
                os.close(fd)
            if name == "new_file":
                path.unlink()
    return out


def page_cost(mib: int = PROBE_MIB, directory=None) -> dict:
    """The probe (module docstring): ``{anon_first_touch, new_file, new_file_after_unlink, overwrite}``
    in ms per MiB, ``probe_mib``, and the kernel's ``page_reporting`` settings."""
    out = {"anon_first_touch": anon_first_touch_ms_per_mib(mib)}
    out.update(file_write_ms_per_mib(mib, directory))
    out["probe_mib"] = int(mib)
    out["page_reporting"] = page_reporting_settings()
    return out
