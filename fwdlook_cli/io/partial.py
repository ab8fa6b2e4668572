"""The partial file an output is written to before its rename into place: never through a link, never
over a file that fwdlook did not make there.

Every writer writes ``NAME`` to ``NAME.partial`` (``NAME.partial.SUFFIX`` for matplotlib, which takes
the format from the suffix) and renames it.  :func:`claim_partial` creates that name empty with
``O_CREAT | O_EXCL``, which neither follows a symbolic link nor opens what is already there.  Where the
name is taken (a user's file of that name, a symbolic link to anywhere, a folder, or the partial file
of a fwdlook command killed mid-write), the output is written through a fresh name beside it
(``NAME.partial-XXXXXXXX``, before the suffix where there is one) and what was there is left as it is,
with a warning naming both.  Only in fwdlook's own ``stages/`` folder, whose stage names are its own
(``io.extra_outputs.remove_stage_files``), is a regular file at ``NN_stage.h5.partial`` a killed
write's leftover, replaced; a link there is left alone too.
"""
from __future__ import annotations

import logging
import os
import secrets
from pathlib import Path

log = logging.getLogger(__name__)

_CREATE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)


def _create(path: Path) -> bool:
    """Create ``path`` empty (mode 0666 less the umask, as ``open`` gives); False where the name is taken."""
    try:
        fd = os.open(path, _CREATE, 0o666)
    except FileExistsError:
        return False
    os.close(fd)
    return True


def claim_partial(tmp, *, replace_regular: bool = False) -> Path:
    """``tmp`` created empty, or where that name is taken, a fresh name beside it (created empty); returns
    the one to write.  ``replace_regular``: a regular file at ``tmp`` (not a link) is a leftover of
    fwdlook's own, removed first (``stages/``).  OSErrors other than the name being taken propagate
    (the caller's ``cannot write PATH: ...``)."""
    tmp = Path(tmp)
    if _create(tmp):
        return tmp
    if replace_regular and tmp.is_file() and not tmp.is_symlink():
        tmp.unlink()
        if _create(tmp):
            return tmp
    name = tmp.name
    stem, suffix = (name, "") if name.endswith(".partial") else (name[:-len(Path(name).suffix)], Path(name).suffix)
    for _ in range(100):
        other = tmp.with_name(f"{stem}-{secrets.token_hex(4)}{suffix}")
        if _create(other):
            log.warning(f"{tmp} is in the way (not a partial file fwdlook may replace: a file of yours, a link, "
                        f"or one a killed run left): left as it is; writing through {other.name} instead")
            return other
    raise FileExistsError(f"no free partial name beside {tmp}")


def claim_partial_into(claimed: list, tmp, *, replace_regular: bool = False) -> Path:
    """:func:`claim_partial`, its result appended to ``claimed`` before it returns: called through
    ``signals.call_held``, a Ctrl-C or SIGTERM arriving meanwhile is raised only once the caller can see
    the name it must remove (a SIGTERM just after the file was created had left ``NAME.partial`` behind
    the command: ``tests/test_reliability.py``, under load)."""
    claimed.append(claim_partial(tmp, replace_regular=replace_regular))
    return claimed[-1]
