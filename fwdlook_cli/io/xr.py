"""xarray views of fwdlook's arrays (optional dependency: ``pip install -e .[xarray]``).

On disk, every fwdlook file already opens in xarray with named dimensions (``engine="h5netcdf"``):
the raw cube with ``xarray.open_dataset(path, group="echo", engine="h5netcdf")`` or
``xarray.open_datatree(path, engine="h5netcdf")``, a stage file or ``image.h5`` with
``xarray.open_dataset(path, engine="h5netcdf")``.  This module builds the same views in memory.
"""
from __future__ import annotations

import numpy as np


def _xarray():
    try:
        import xarray
    except ImportError as exc:  # pragma: no cover - the extra is installed by make install
        raise ImportError("to_xarray() needs xarray: pip install -e '.[xarray]'") from exc
    return xarray


UNIT_SUFFIXES = (("_mps", "m/s"), ("_deg", "deg"), ("_m", "m"), ("_s", "s"))


def units_of_name(key: str) -> str:
    """Units of a dataset from its name's suffix (``vx_mps`` -> m/s, ``x_m`` -> m); else "1"."""
    return next((units for suffix, units in UNIT_SUFFIXES if key.endswith(suffix)), "1")


def cube_to_xarray(cube):
    """A :class:`~fwdlook_cli.cube.RawCube` as an ``xarray.Dataset`` (arrays shared, not copied)."""
    xr = _xarray()
    coords = {
        "slow_time_s": ("slow_time_s", cube.slow_time_s, {"units": "s", "long_name": "slow time, t = 0 at the first pulse"}),
        "range_m": ("range_m", cube.range_m, {"units": "m", "long_name": "slant range"}),
        "xyz": ("xyz", np.arange(3), {"units": "1", "long_name": "axis: 0 = x cross-range, 1 = y forward, 2 = z up"}),
    }
    data = {"sum": (("slow_time_s", "range_m"), cube.sum,
                    {"units": "1", "long_name": "range-compressed baseband echo, sum channel"})}
    if cube.diff is not None:
        data["diff"] = (("slow_time_s", "range_m"), cube.diff,
                        {"units": "1", "long_name": "range-compressed baseband echo, difference channel"})
    data["scan_angle_deg"] = ("slow_time_s", cube.scan_angle_deg, {"units": "deg", "long_name": "beam pointing azimuth"})
    data["position_m"] = (("slow_time_s", "xyz"), cube.position_m, {"units": "m", "long_name": "antenna phase centre (INS)"})
    data["velocity_mps"] = (("slow_time_s", "xyz"), cube.velocity_mps, {"units": "m/s", "long_name": "antenna velocity (INS)"})
    if cube.truth:            # the units raw.h5 gives each (m, m/s, 1): the file view's
        coords["target"] = ("target", np.arange(len(cube.truth["x_m"])), {"units": "1", "long_name": "target index"})
        for key, value in cube.truth.items():
            data[f"truth_{key}"] = ("target", np.asarray(value), {"units": units_of_name(key),
                                                                  "long_name": f"target {key}"})
    attrs = {f"radar_{k}": v for k, v in cube.radar.items()}
    attrs.update({f"antenna_{k}": v for k, v in cube.antenna.items()})
    attrs.update({f"noise_{k}": v for k, v in cube.noise.items()})
    return xr.Dataset(data, coords=coords, attrs=attrs)


def stage_to_xarray(data):
    """A :class:`~fwdlook_cli.pipeline.StageData` (a stage's output in memory) as an ``xarray.Dataset``."""
    xr = _xarray()
    coords, variables = {}, {}
    for name, var in data.vars.items():
        entry = (var.dims, var.data, {"units": var.units, "long_name": var.long_name})
        (coords if var.dims == (name,) else variables)[name] = entry
    attrs = {k: v for k, v in data.attrs.items() if isinstance(v, (str, int, float, bool, np.generic))}
    return xr.Dataset(variables, coords=coords, attrs=attrs)
