"""A plain-text listing of any HDF5 file: groups, datasets with shape, dtype and units, attributes."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from ..limits import shown


def _plain(value):
    if isinstance(value, bytes):
        return value.decode()
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
