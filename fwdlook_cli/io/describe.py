"""A plain-text listing of any HDF5 file: groups, datasets with shape, dtype and units, attributes; the
checks that ``info`` and ``report`` make of what they read (axes, grids, JSON files)."""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np

from ..errors import BadInput
from ..limits import shown


def _plain(value):
    """An attribute's value as Python: text decoded (bytes that are not UTF-8 shown with U+FFFD, never an
    exception: a value the caller then checks), numpy scalars as Python numbers."""
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def describe_h5(path: str | Path) -> str:
    """A plain listing of any HDF5 file (stage files, images): groups, datasets, shapes, units."""
    lines = []
    with h5py.File(path, "r") as f:
        for key in ("format", "stage", "software_version", "config_sha256", "input_sha256"):
            if key in f.attrs:
                value = _plain(f.attrs[key])
                text = value if isinstance(value, str) else shown(value, 200)
                lines.append(f"{key}: {text if len(text) <= 200 else text[:197] + '...'}")

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                units = _plain(obj.attrs.get("units", ""))
                lines.append(f"  /{name}  {obj.dtype}  {list(obj.shape)}  [{units}]")

        f.visititems(visit)
    return "\n".join(lines)


def checked_axis(f, path, name: str) -> np.ndarray:
    """An axis of an image file (image.h5): 1-D, finite, strictly increasing (what the report's cuts and
    meshes need); else BadInput naming the dataset."""
    a = np.asarray(f[name][()])
    if (a.ndim != 1 or a.dtype.kind not in "fiu" or a.size == 0 or not np.all(np.isfinite(a))
            or np.any(np.diff(a) <= 0)):
        raise BadInput(f"{path}: /{name}: {a.dtype} {list(a.shape)}; expected a strictly increasing 1-D axis "
                       f"of finite numbers")
    return a.astype(np.float64, copy=False)


def checked_grid(f, path, name: str, rows: str, cols: str) -> np.ndarray:
    """A 2-D image of an image file over its axes ``rows`` x ``cols`` (each checked by
    :func:`checked_axis` first): real numbers of that shape; else BadInput naming the dataset."""
    g = np.asarray(f[name][()])
    n_rows, n_cols = len(f[rows]), len(f[cols])          # (checked by checked_axis first: 1-D)
    if g.dtype.kind not in "fiu":
        raise BadInput(f"{path}: /{name}: dtype {g.dtype} not allowed; allowed: real numbers (power)")
    if g.ndim != 2 or g.shape != (n_rows, n_cols):
        raise BadInput(f"{path}: /{name}: shape {list(g.shape)}, expected [{rows}, {cols}] = [{n_rows}, {n_cols}]")
    return g


def read_json_text(path: Path):
    """The JSON value of the text file ``path``; BadInput in one line naming the file when it cannot be
    read (a folder, no permission, a dangling link), is not UTF-8 text or not JSON."""
    try:
        if not path.is_file() and path.exists():
            raise IsADirectoryError(0, "not a regular file")     # (a FIFO would block the read)
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise BadInput(f"{path}: not a UTF-8 text file; expected JSON written by fwdlook") from None
    except OSError as exc:
        raise BadInput(f"{path}: cannot read it ({exc.strerror or exc}); expected JSON written by "
                       f"fwdlook") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise BadInput(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
