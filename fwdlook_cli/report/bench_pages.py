"""What memory costs the machine a bench runs on: ``page_cost`` in every bench's JSON.

The chain writes each stage's output into memory it has not used before and each stage file into
the page cache, so its time depends on what a new page costs the machine as well as on its code.
On the virtual machine these figures were measured on, a large write into a new file is many times
dearer than the same bytes written in pieces (docs/SPEED.md: "What a new page costs here").  Its
kernel also reports freed memory to its host at once (free page reporting,
``/sys/module/page_reporting``: ``page_reporting_order`` 9, ``min_free_ms`` 0), which the probe
records; that this is what makes the large writes dear was not shown.

Every figure is in ms per MiB, timed once each (a probe of the machine's state, not a benchmark):
- ``anon_first_touch``: one byte written in every 4 KiB page of a new anonymous mapping (the page
  faults and the kernel's zeroing);
- ``new_file_one_write``: a new file written from memory already touched, in one ``write(2)``;
- ``new_file``: a second new file, after the first is unlinked, written in ``io.outputs.FailSafeSink``'s
  pieces (``WRITE_PIECE_BYTES``), as a stage file is written;
- ``overwrite``: the same bytes written again over the second (pages already in the cache: the copy
  alone).
"""
from __future__ import annotations

import mmap
import stat
import tempfile
import time
from pathlib import Path

import numpy as np

from ..io.outputs import FailSafeSink

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


def file_write_ms_per_mib(mib: int = PROBE_MIB, directory=None) -> dict:
    """``new_file_one_write``, ``new_file`` and ``overwrite`` (module docstring), in that order, ms per
    MiB, in a temporary folder under ``directory`` (the system's temporary folder where None)."""
    data = np.ones(int(mib) << 20, dtype=np.uint8)            # touched: only the file's pages are new
    out = {}
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        with open(Path(tmp) / "one_write", "xb", buffering=0) as f:
            t0 = time.perf_counter()
            done = f.write(data)
            out["new_file_one_write"] = 1e3 * (time.perf_counter() - t0) / mib
        if done != data.nbytes:                                 # pragma: no cover (a short write)
            raise OSError(f"bench_pages: wrote {done} of {data.nbytes} bytes")
        (Path(tmp) / "one_write").unlink()
        sink = FailSafeSink(Path(tmp) / "pieces")            # as a stage file is written (io/outputs.py)
        try:
            t0 = time.perf_counter()
            sink.write(data)
            out["new_file"] = 1e3 * (time.perf_counter() - t0) / mib
            sink.seek(0)
            t0 = time.perf_counter()
            sink.write(data)
            out["overwrite"] = 1e3 * (time.perf_counter() - t0) / mib
        finally:
            sink.close()
        if sink.error is not None:
            raise sink.error
        (Path(tmp) / "pieces").unlink()
    return out


def page_cost(mib: int = PROBE_MIB, directory=None) -> dict:
    """The probe (module docstring): ``{anon_first_touch, new_file_one_write, new_file, overwrite}``
    in ms per MiB, ``probe_mib``, and the kernel's ``page_reporting`` settings."""
    out = {"anon_first_touch": anon_first_touch_ms_per_mib(mib)}
    out.update(file_write_ms_per_mib(mib, directory))
    out["probe_mib"] = int(mib)
    out["page_reporting"] = page_reporting_settings()
    return out
