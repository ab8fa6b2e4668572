"""Every fwdlook file opens in xarray with named dimensions and coordinates (issue 13, item 2).

The raw cube's dimension scales sit at the root and are hard-linked into /echo and /axes, so that a
netCDF reader finds them from /echo, while the CONTRACT.md section 3 paths stay readable by h5py and
by fwdlook's own reader (the same datasets, not copies).
"""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from fwdlook_cli.cli import main
from fwdlook_cli.io.raw import read_raw

xr = pytest.importorskip("xarray")
pytest.importorskip("h5netcdf")

TINY = "scenarios/tiny.yaml"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    run_dir = tmp_path_factory.mktemp("xr") / "tiny"
    with pytest.raises(SystemExit) as exc:
        main(["run", str(repo / TINY), "-o", str(run_dir), "-q"])
    assert exc.value.code == 0
    return run_dir


@pytest.mark.filterwarnings("error:.*phony_dims:UserWarning")     # a dataset without named dimensions
def test_raw_cube_opens_in_xarray_with_named_dims(tiny_run):
    raw = tiny_run / "raw.h5"
    cube = read_raw(raw)
    ds = xr.open_dataset(raw, group="echo", engine="h5netcdf")
    assert ds["sum"].dims == ("slow_time_s", "range_m")
    assert ds["diff"].dims == ("slow_time_s", "range_m")
    assert ds["sum"].dtype == np.complex64
    np.testing.assert_array_equal(ds["slow_time_s"].values, cube.slow_time_s)
    np.testing.assert_array_equal(ds["range_m"].values, cube.range_m)
    np.testing.assert_array_equal(ds["sum"].values, cube.sum)
    # selecting by coordinate: the pulse at t = 0.1 s is pulse round(0.1 * PRF)
    i = int(round(0.1 * cube.radar["prf_hz"]))
    np.testing.assert_array_equal(ds["sum"].sel(slow_time_s=0.1, method="nearest").values, cube.sum[i])
    assert ds["range_m"].attrs["units"] == "m"
    tree = xr.open_datatree(raw, engine="h5netcdf")
    assert tree["platform"]["position_m"].dims == ("slow_time_s", "xyz")
    assert tree["axes"]["scan_angle_deg"].dims == ("slow_time_s",)
    assert tree["truth/targets"]["x_m"].dims == ("target",)
    # the antenna's ratio table: the ratio against its offsets, no dimension without a name
    assert tree["antenna"]["ratio"].dims == ("ratio_offset_deg",)
    np.testing.assert_array_equal(tree["antenna"]["ratio_offset_deg"].values, cube.antenna["ratio_offset_deg"])
    np.testing.assert_array_equal(tree["platform"]["position_m"].values, cube.position_m)


def test_contract_paths_are_hard_links_to_the_scales(tiny_run):
    with h5py.File(tiny_run / "raw.h5", "r") as f:
        for name in ("slow_time_s", "range_m"):
            a, e, root = f[f"axes/{name}"], f[f"echo/{name}"], f[name]
            assert a.id == e.id == root.id          # one dataset under three names
            assert a.is_scale and a.dtype == np.float64
            assert a.attrs["units"] in ("s", "m")
        assert f["echo/sum"].dims[0][0] == f["axes/slow_time_s"]


def test_stage_file_and_image_open_in_xarray(tiny_run):
    stage = xr.open_dataset(tiny_run / "stages" / "01_range_fft.h5", engine="h5netcdf")
    assert stage["sum_f"].dims == ("slow_time_s", "fr_hz")
    fs = float(json.loads(stage.attrs["settings"])["fs_hz"])
    n = stage.sizes["fr_hz"]
    # the range-frequency axis is the FFT grid of the sampling rate: spacing fs / n
    np.testing.assert_allclose(np.sort(stage["fr_hz"].values), (np.arange(n) - n // 2) * fs / n, rtol=0, atol=1e-6 * fs)
    img = xr.open_dataset(tiny_run / "image.h5", engine="h5netcdf")
    assert img["image"].dims == ("range_m", "angle_deg")
    assert img["ground_image"].dims == ("ground_y_m", "ground_x_m")
    assert img["real_beam"].dims == ("range_native_m", "angle_deg")
    assert img["angle_deg"].attrs["units"] == "deg"


def test_cube_to_xarray_matches_the_file_view(tiny_run):
    cube = read_raw(tiny_run / "raw.h5")
    mem = cube.to_xarray()
    disk = xr.open_dataset(tiny_run / "raw.h5", group="echo", engine="h5netcdf")
    xr.testing.assert_equal(mem["sum"].reset_coords(drop=True), disk["sum"].reset_coords(drop=True).load())
    assert mem["position_m"].dims == ("slow_time_s", "xyz")
    assert mem.attrs["radar_prf_hz"] == cube.radar["prf_hz"]
    # every variable and coordinate with the units the file gives it (the truth had none in memory)
    truth = xr.open_dataset(tiny_run / "raw.h5", group="truth/targets", engine="h5netcdf")
    for key in ("x_m", "y_m", "z_m", "amplitude"):
        assert mem[f"truth_{key}"].attrs["units"] == truth[key].attrs["units"], key
    assert mem["target"].attrs["units"] == truth["target"].attrs["units"] == "1"
    assert all("units" in mem[name].attrs for name in list(mem.variables)), [
        name for name in mem.variables if "units" not in mem[name].attrs]
