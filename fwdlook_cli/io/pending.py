"""A run's outputs written under staged names and put in place together, once all are written.

The run directory's outputs of an earlier run stay whole until the new ones are all written: a rerun
refused or failing on the way (a refusal after the simulation, a full disk at image.png or scenario.yaml)
leaves them as they were, and never new outputs beside old ones.  Each output is written as
``.fwdlook-new.<name>`` (``run``'s simulated cube too, before the chain, which releases the cube's
echoes after its first stage), and :func:`commit` removes the earlier ``scenario.yaml`` (the folder then reads as
unfinished), renames each staged file over its name in the order image.h5, metrics.json, image.png
(a PNG is taken for fwdlook's only with a metrics.json beside it), removes an earlier output this run
did not write, and puts ``scenario.yaml`` last: the run is complete.  A failure removes the staged files
(:func:`discard`); a killed command leaves them, and the next run writes over them.  (Fifty-second
round: an ISAR rerun refused after its simulation had left its new cube beside the earlier run's
outputs, the earlier cube lost; a full disk at image.png had left a new metrics.json and image.h5
beside no scenario.yaml, the earlier run's PNG and scenario.yaml removed.)
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

OUTPUTS = ("raw.h5", "image.h5", "metrics.json", "image.png", "scenario.yaml")   # the order of commit


STAGED_PREFIX = ".fwdlook-new."      # fwdlook's own names, hidden, as its ``.fwdlook.lock``


def staged(run_dir, name: str) -> Path:
    """Where output ``name`` is written before :func:`commit`: ``.fwdlook-new.<name>`` (hidden and
    fwdlook's own, so never a user's file; the suffix kept: matplotlib and h5py read the format from it)."""
    return Path(run_dir) / f"{STAGED_PREFIX}{name}"


def discard(run_dir, *, raw: bool) -> None:
    """Remove the staged outputs (``raw``: the staged cube too), and the partial files of their writes
    that a killed command left (``.fwdlook-new.image.partial.png``: Ctrl-C while the quick look was
    drawn, found by an independent review; the next run had written around it and left it for good).
    Their names are fwdlook's own; regular files only, never a link."""
    run_dir = Path(run_dir)
    for name in OUTPUTS if raw else OUTPUTS[1:]:
        staged(run_dir, name).unlink(missing_ok=True)
        stem, suffix = os.path.splitext(staged(run_dir, name).name)
        for leftover in run_dir.glob(f"{stem}.partial*{suffix}"):
            if leftover.is_file() and not leftover.is_symlink():
                leftover.unlink(missing_ok=True)


def commit(run_dir, *, raw: bool) -> None:
    """Put the staged outputs in place (module docstring); ``raw``: the staged cube too (``run`` only:
    a cube another command left staged is not this run's)."""
    run_dir = Path(run_dir)
    (run_dir / "scenario.yaml").unlink(missing_ok=True)
    for name in OUTPUTS if raw else OUTPUTS[1:]:
        new = staged(run_dir, name)
        if new.exists():
            os.replace(new, run_dir / name)
        elif name != "raw.h5":
            (run_dir / name).unlink(missing_ok=True)


@contextlib.contextmanager
def discarded_on_failure(run_dir, *, raw: bool):
    """Runs the body; where it raises (a refusal, a failure, an interrupt), :func:`discard`."""
    try:
        yield
    except BaseException:
        discard(run_dir, raw=raw)
        raise
