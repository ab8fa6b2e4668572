"""Outputs beside the run, report and sweep folders of :mod:`io.outputs`: the scaling series' plot of
``fwdlook bench`` (checked before the series runs, marked by its PNG's Software text) and the pruning of
a run's stage files (a sweep keeps each point's outputs only)."""
from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

from ..errors import BadInput
from .outputs import OVERWRITE_HINT, _iter_quiet, _unlink_quietly, h5_format, make_parent, output_path, probe_writable

BENCH_PNG_SOFTWARE = "fwdlook bench --scaling"     # the PNG's Software text: what marks the plot as fwdlook's


def png_software(path) -> str | None:
    """The ``Software`` text chunk of a PNG file (read up to its first image data), or None."""
    try:
        if not Path(path).is_file():
            return None
        with open(path, "rb") as fh:
            if fh.read(8) != b"\x89PNG\r\n\x1a\n":
                return None
            while True:
                head = fh.read(8)
                if len(head) < 8:
                    return None
                size, kind = int.from_bytes(head[:4], "big"), head[4:]
                if kind in (b"IDAT", b"IEND") or size > 1 << 20:
                    return None
                body = fh.read(size + 4)[:size]
                if kind == b"tEXt" and body.split(b"\0", 1)[0] == b"Software":
                    return body.split(b"\0", 1)[1].decode("latin-1")
    except OSError:
        return None


def bench_png_path(path, *, overwrite: bool = False) -> Path:
    """Where ``fwdlook bench --scaling`` draws its plot, checked before the series runs (minutes): absent,
    the plot of an earlier series (its PNG's Software text), or ``overwrite``; its folder made and
    probed (a user's PNG there had been overwritten, a regular file on its path ended in a traceback)."""
    if str(path).endswith(("/", os.sep)):
        raise BadInput(f"--plot {path}: a folder's path (it ends in '/'); expected the path of a PNG file")
    target = output_path(path)
    if target.is_dir():
        raise BadInput(f"--plot {target}: is a directory; expected the path of a PNG file")
    if (target.exists() or target.is_symlink()) and not overwrite and png_software(target) != BENCH_PNG_SOFTWARE:
        raise BadInput(f"--plot {target}: exists and is not a plot of fwdlook bench --scaling; refusing to "
                       f"overwrite it; {OVERWRITE_HINT}")
    make_parent(target)
    probe_writable(target.parent, target)
    return target


def remove_stage_files(run_dir) -> None:
    """Delete a run's stage files (a sweep keeps only each point's outputs): fwdlook's own stage files and
    their partial files only, then ``stages/`` where nothing else is left in it (anything else there is
    not fwdlook's and stays: a sweep removed the whole folder, a user's files with it)."""
    stages = Path(run_dir) / "stages"
    for q in _iter_quiet(stages) if stages.is_dir() else []:
        if q.is_file() and not q.is_symlink() and (
                h5_format(q) == "fwdlook-stage" or re.fullmatch(r"\d\d_\w+\.h5\.partial(-[0-9a-f]{8})?", q.name)):
            _unlink_quietly(q)
    with contextlib.suppress(OSError):
        stages.rmdir()
