"""Tests for fwdlook_cli.io (raw.py, h5.py): raw-cube round trip, on-disk layout, foreign writers, atomic writes.

Facts checked here come from CONTRACT.md section 3 (the raw cube layout) and section 1 (outputs are
written to a temporary name and renamed into place).  Everything runs on scenarios/tiny.yaml
(400 pulses x 77 range samples, about 10 ms to simulate).
"""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from fwdlook_cli.scenario.loader import load_scenario, resolve_scenario, scenario_hash
from fwdlook_cli.io.h5 import atomic_h5
from fwdlook_cli.io.raw import read_raw, write_raw
from fwdlook_cli.forward.simulate import simulate_scenario
from cli_runner import run_cli

TINY = Path(__file__).resolve().parents[1] / "scenarios" / "tiny.yaml"
RADAR_KEYS = ("fc_hz", "bandwidth_hz", "fs_hz", "prf_hz", "beamwidth_3db_deg")


def _same(a, b) -> bool:
    """Equality that treats NaN as equal to NaN (noise.snr_db = null is stored as NaN)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


# ----------------------------------------------------------------------------------------------
# Round trip: simulate -> write_raw -> read_raw
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module", params=[(), ("noise.snr_db=null",)], ids=["noisy", "noiseless"])
def simulated(request, tmp_path_factory):
    """(resolved scenario, simulated cube, path of the written file, its directory)."""
    scn = load_scenario(TINY, overrides=list(request.param))
    cube, _stats = simulate_scenario(scn)
    out_dir = tmp_path_factory.mktemp("raw")
    path = out_dir / "raw.h5"
    write_raw(path, cube)
    return scn, cube, path, out_dir


def test_round_trip_arrays_bit_identical(simulated):
    _scn, cube, path, _ = simulated
    back = read_raw(path)
    assert back.sum.dtype == np.complex64 and back.diff.dtype == np.complex64
    assert back.sum.shape == (400, 77) == back.diff.shape
    # write_raw stores complex64; the simulator's arrays (whatever their dtype) round to exactly that.
    np.testing.assert_array_equal(back.sum, cube.sum.astype(np.complex64))
    np.testing.assert_array_equal(back.diff, cube.diff.astype(np.complex64))
    assert back.sum.tobytes() == cube.sum.astype(np.complex64).tobytes()
    for name in ("slow_time_s", "range_m", "scan_angle_deg", "position_m", "velocity_mps"):
        got, want = getattr(back, name), np.asarray(getattr(cube, name), dtype=np.float64)
        assert got.dtype == np.float64, name
        assert got.tobytes() == want.tobytes(), name
    assert back.position_m.shape == (400, 3) and back.velocity_mps.shape == (400, 3)


def test_round_trip_radar_antenna_noise_truth(simulated):
    _scn, cube, path, _ = simulated
    back = read_raw(path)
    assert back.radar == cube.radar
    assert set(RADAR_KEYS) <= set(back.radar)
    assert back.antenna.keys() == cube.antenna.keys()
    for key, value in cube.antenna.items():   # scalars as attrs, the ratio table as datasets
        np.testing.assert_array_equal(back.antenna[key], value)
    assert set(back.noise) == set(cube.noise)
    for key in cube.noise:
        assert _same(float(back.noise[key]), float(cube.noise[key])), key
    assert back.truth is not None
    assert set(back.truth) == {"x_m", "y_m", "z_m", "amplitude"}
    for key in back.truth:
        np.testing.assert_array_equal(back.truth[key], np.asarray(cube.truth[key], dtype=np.float64))
    assert len(back.truth["x_m"]) == 3  # tiny.yaml has three points


def test_round_trip_scenario_text_reloads_to_same_hash(simulated):
    scn, cube, path, _ = simulated
    back = read_raw(path)
    assert isinstance(back.scenario_yaml, str)
    reloaded = resolve_scenario(yaml.safe_load(back.scenario_yaml), source=str(path))
    assert reloaded == scn
    assert scenario_hash(reloaded) == scenario_hash(scn)
    assert back.attrs["scenario_sha256"] == scenario_hash(scn)


def test_file_layout_root_attrs(simulated):
    scn, _cube, path, _ = simulated
    with h5py.File(path, "r") as f:
        fmt = f.attrs["format"]
        assert (fmt.decode() if isinstance(fmt, bytes) else fmt) == "fwdlook-raw"
        assert int(f.attrs["format_version"]) == 1
        assert "software_version" in f.attrs
        from fwdlook_cli import __version__

        assert str(f.attrs["software_version"]) == __version__
        assert str(f.attrs["scenario_sha256"]) == scenario_hash(scn)
        assert "scenario" in f.attrs or "scenario" in f


def test_file_layout_every_dataset_has_units_and_long_name(simulated):
    _scn, _cube, path, _ = simulated
    seen = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            seen.append(name)
            assert "units" in obj.attrs, f"/{name} has no units"
            assert "long_name" in obj.attrs, f"/{name} has no long_name"

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    for required in ("echo/sum", "echo/diff", "axes/slow_time_s", "axes/range_m",
                     "axes/scan_angle_deg", "platform/position_m", "platform/velocity_mps",
                     "truth/targets/x_m", "truth/targets/y_m", "truth/targets/z_m",
                     "truth/targets/amplitude"):
        assert required in seen


def test_file_layout_dtypes_shapes_and_units(simulated):
    _scn, _cube, path, _ = simulated
    with h5py.File(path, "r") as f:
        n_p, n_r = f["echo/sum"].shape
        assert f["echo/sum"].dtype == np.complex64 and f["echo/diff"].dtype == np.complex64
        assert f["echo/diff"].shape == (n_p, n_r)
        assert f["axes/slow_time_s"].dtype == np.float64 and f["axes/slow_time_s"].shape == (n_p,)
        assert f["axes/range_m"].dtype == np.float64 and f["axes/range_m"].shape == (n_r,)
        assert f["axes/scan_angle_deg"].shape == (n_p,)
        assert f["platform/position_m"].shape == (n_p, 3)
        assert f["platform/velocity_mps"].shape == (n_p, 3)
        assert f["axes/slow_time_s"][0] == 0.0  # t = 0 at the first pulse
        units = {name: f[name].attrs["units"] for name in
                 ("axes/slow_time_s", "axes/range_m", "axes/scan_angle_deg", "platform/position_m",
                  "platform/velocity_mps")}
        units = {k: v.decode() if isinstance(v, bytes) else str(v) for k, v in units.items()}
        assert units == {"axes/slow_time_s": "s", "axes/range_m": "m", "axes/scan_angle_deg": "deg",
                         "platform/position_m": "m", "platform/velocity_mps": "m/s"}
        for key in RADAR_KEYS:
            assert key in f["radar"].attrs


def test_file_layout_dimension_scales_on_echo(simulated):
    _scn, _cube, path, _ = simulated
    with h5py.File(path, "r") as f:
        for name in ("echo/sum", "echo/diff"):
            ds = f[name]
            assert len(ds.dims[0]) >= 1 and len(ds.dims[1]) >= 1, name
            assert ds.dims[0][0].name.endswith("slow_time_s"), ds.dims[0][0].name
            assert ds.dims[1][0].name.endswith("range_m"), ds.dims[1][0].name


def test_no_partial_file_left(simulated):
    _scn, _cube, path, out_dir = simulated
    assert path.exists()
    assert list(out_dir.glob("*.partial")) == []
    assert not path.with_name(path.name + ".partial").exists()


# ----------------------------------------------------------------------------------------------
# A cube written by plain h5py, not by fwdlook's writer (CONTRACT.md 3: "whoever wrote it")
# ----------------------------------------------------------------------------------------------
N_P, N_R, PRF = 64, 32, 1000.0


def _plain_cube_arrays(echo_dtype=np.complex64):
    rng = np.random.default_rng(3)
    t = np.arange(N_P) / PRF
    echo_sum = (rng.standard_normal((N_P, N_R)) + 1j * rng.standard_normal((N_P, N_R))).astype(echo_dtype)
    echo_diff = (rng.standard_normal((N_P, N_R)) + 1j * rng.standard_normal((N_P, N_R))).astype(echo_dtype)
    return {
        "echo/sum": echo_sum,
        "echo/diff": echo_diff,
        "axes/slow_time_s": t,
        "axes/range_m": 1000.0 + 6.25 * np.arange(N_R),
        "axes/scan_angle_deg": np.linspace(-5.0, 5.0, N_P),
        "platform/position_m": np.column_stack([np.zeros(N_P), 100.0 * t, np.full(N_P, 50.0)]),
        "platform/velocity_mps": np.tile([0.0, 100.0, 0.0], (N_P, 1)),
    }


PLAIN_RADAR = {"fc_hz": 10.0e9, "bandwidth_hz": 20.0e6, "fs_hz": 24.0e6, "prf_hz": PRF,
               "beamwidth_3db_deg": 6.0}


def write_plain_cube(path: Path, *, echo_dtype=np.complex64, bytes_attrs=False, scenario=None):
    """The minimal CONTRACT layout with plain h5py: no units, no /truth, no dimension scales."""
    arrays = _plain_cube_arrays(echo_dtype)
    with h5py.File(path, "w") as f:
        if bytes_attrs:  # fixed-length byte strings, as e.g. MATLAB or C writers store them
            f.attrs["format"] = np.bytes_(b"fwdlook-raw")
            f.attrs["format_version"] = np.int32(1)
        else:
            f.attrs["format"] = "fwdlook-raw"
            f.attrs["format_version"] = 1
        for name, data in arrays.items():
            f.create_dataset(name, data=data)
        radar = f.create_group("radar")
        for key, value in PLAIN_RADAR.items():
            radar.attrs[key] = value
        if scenario is not None:
            f.create_dataset("scenario", data=scenario)
    return arrays


@pytest.mark.parametrize("bytes_attrs", [False, True], ids=["str-attrs", "bytes-attrs"])
def test_plain_h5py_cube_is_read_with_correct_values(tmp_path, bytes_attrs):
    path = tmp_path / "foreign.h5"
    arrays = write_plain_cube(path, bytes_attrs=bytes_attrs)
    cube = read_raw(path)
    assert cube.n_pulses == N_P and cube.n_range == N_R
    np.testing.assert_array_equal(cube.sum, arrays["echo/sum"])
    np.testing.assert_array_equal(cube.diff, arrays["echo/diff"])
    np.testing.assert_array_equal(cube.slow_time_s, arrays["axes/slow_time_s"])
    np.testing.assert_array_equal(cube.range_m, arrays["axes/range_m"])
    np.testing.assert_array_equal(cube.scan_angle_deg, arrays["axes/scan_angle_deg"])
    np.testing.assert_array_equal(cube.position_m, arrays["platform/position_m"])
    np.testing.assert_array_equal(cube.velocity_mps, arrays["platform/velocity_mps"])
    assert cube.sum.dtype == np.complex64 and cube.diff.dtype == np.complex64
    for key, value in PLAIN_RADAR.items():
        assert cube.radar[key] == value
    assert not cube.truth
    assert cube.scenario_yaml is None
    assert cube.range_spacing_m == pytest.approx(6.25)


def test_plain_h5py_cube_passes_info_and_validate(tmp_path, capsys):
    path = tmp_path / "foreign.h5"
    write_plain_cube(path)
    code, out, err = run_cli(["info", path], capsys)
    assert code == 0, err
    assert "Traceback" not in err
    assert str(N_P) in out and str(N_R) in out
    assert "truth" in out
    code, out, err = run_cli(["validate", path], capsys)
    assert code == 0, err
    assert "valid" in out and f"{N_P} pulses" in out


def test_plain_h5py_cube_complex128_is_converted_to_complex64(tmp_path, capsys):
    path = tmp_path / "foreign128.h5"
    arrays = write_plain_cube(path, echo_dtype=np.complex128)
    with h5py.File(path, "r") as f:
        assert f["echo/sum"].dtype == np.complex128  # the file really holds complex128
    cube = read_raw(path)
    assert cube.sum.dtype == np.complex64 and cube.diff.dtype == np.complex64
    np.testing.assert_array_equal(cube.sum, arrays["echo/sum"].astype(np.complex64))
    np.testing.assert_array_equal(cube.diff, arrays["echo/diff"].astype(np.complex64))
    code, _out, err = run_cli(["validate", path], capsys)
    assert code == 0, err


def test_plain_h5py_cube_scenario_as_dataset(tmp_path):
    """CONTRACT.md 3: /scenario may be a string dataset instead of a root attribute."""
    path = tmp_path / "foreign_scn.h5"
    text = TINY.read_text()
    write_plain_cube(path, scenario=text)
    cube = read_raw(path)
    assert cube.scenario_yaml == text


def _mutate(path, name, fn):
    with h5py.File(path, "r+") as f:
        if name.startswith("radar."):
            key = name.split(".", 1)[1]
            f["radar"].attrs[key] = fn(f["radar"].attrs[key])
        else:
            data = fn(f[name][()])
            del f[name]
            f.create_dataset(name, data=data)


def _drop_pulses(path, lo=20, hi=25):
    """Five pulses cut out of every per-pulse dataset: a gap of six intervals in the pulse train."""
    with h5py.File(path, "r+") as f:
        for name in ("echo/sum", "echo/diff", "axes/slow_time_s", "axes/scan_angle_deg",
                     "platform/position_m", "platform/velocity_mps"):
            data = np.delete(f[name][()], np.s_[lo:hi], axis=0)
            del f[name]
            f.create_dataset(name, data=data)


# (dataset or radar.attr, change, fragments the one-line message must hold)
PHYSICS_REFUSALS = {
    "carrier-below-band": ("radar.fc_hz", lambda v: 1.0e7, ("fc_hz = 1e+07", "fs_hz / 2 = 1.2e+07")),
    "negative-range": ("axes/range_m", lambda r: r - 2000.0, ("/axes/range_m", "allowed: > 0 m")),
    "scan-behind": ("axes/scan_angle_deg", lambda a: a + 400.0, ("/axes/scan_angle_deg", "below 90 deg")),
    "beam-400-deg": ("radar.beamwidth_3db_deg", lambda v: 400.0, ("beamwidth_3db_deg = 400", "up to 90")),
    "fs-against-range-step": ("radar.fs_hz", lambda v: 1.0e6, ("fs_hz = 1000000", "c / (2 fs_hz)", "0.001")),
    "prf-off": ("radar.prf_hz", lambda v: v * 1.001, ("prf_hz = 1001", "sampled at 1000 Hz", "within 0.0001")),
    "jittered-pulses": ("axes/slow_time_s", lambda t: t + 0.03 / PRF * np.cos(np.arange(len(t))),
                        ("/axes/slow_time_s", "pulse intervals off a uniform pulse train", "at most 0.01")),
}


@pytest.mark.parametrize("case", sorted(PHYSICS_REFUSALS))
def test_plain_cube_the_chain_cannot_process_is_refused(tmp_path, capsys, case):
    """Values the chain's physics cannot use are exit 2, one line naming the file, the dataset or
    attribute, the value and what is allowed (each of them processed with exit 0 and wrong results, or a
    traceback, before)."""
    path = tmp_path / "foreign.h5"
    write_plain_cube(path)
    name, change, fragments = PHYSICS_REFUSALS[case]
    _mutate(path, name, change)
    code, out, err = run_cli(["validate", path], capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for fragment in (str(path),) + fragments:
        assert fragment in err, (fragment, err)


def test_plain_cube_with_dropped_pulses_is_refused(tmp_path, capsys):
    path = tmp_path / "gap.h5"
    write_plain_cube(path)
    _drop_pulses(path)
    code, _out, err = run_cli(["validate", path], capsys)
    assert code == 2 and "no gaps or dropped pulses" in err, err


@pytest.mark.parametrize("case", ["float32-times", "jitter-0.5%", "late-start", "uniform-jitter-0.95%"])
def test_plain_cube_timing_within_tolerance_is_accepted(tmp_path, case):
    """float32 pulse times (rounding 1e-5 of an interval here), jitter under 1 % of an interval and a
    clock that does not start at 0 are a uniform pulse train for the chain."""
    path = tmp_path / "timing.h5"
    write_plain_cube(path)
    change = {"float32-times": lambda t: (t + 100.0).astype(np.float32),
              "jitter-0.5%": lambda t: t + 0.005 / PRF * np.cos(np.arange(len(t))),
              "late-start": lambda t: t + 5.0,
              # every pulse within 0.95 % of the exact train, the first unjittered: the least-squares
              # train's offset put pulses 1.02 % off it (an exploratory pass)
              "uniform-jitter-0.95%": lambda t: t + np.r_[0.0, np.random.default_rng(7).uniform(
                  -0.0095, 0.0095, len(t) - 1)] / PRF}[case]
    _mutate(path, "axes/slow_time_s", change)
    assert read_raw(path).n_pulses == N_P


def test_plain_cube_scenario_not_utf8_is_ignored(tmp_path, caplog):
    """/scenario only records what made the file: undecodable bytes are said and left out."""
    path = tmp_path / "latin1.h5"
    write_plain_cube(path)
    with h5py.File(path, "r+") as f:
        f.attrs["scenario"] = np.bytes_(b"\xffname: caf\xe9")
    with caplog.at_level("WARNING"):
        cube = read_raw(path)
    assert cube.scenario_yaml is None and "not UTF-8" in caplog.text


# ----------------------------------------------------------------------------------------------
# Atomic writes
# ----------------------------------------------------------------------------------------------
class _Boom(RuntimeError):
    pass


def test_atomic_h5_exception_leaves_nothing(tmp_path):
    path = tmp_path / "out.h5"
    with pytest.raises(_Boom):
        with atomic_h5(path) as f:
            f.create_dataset("x", data=np.arange(10))
            assert path.with_name("out.h5.partial").exists()  # written under the temporary name
            assert not path.exists()
            raise _Boom("interrupted")
    assert not path.exists()
    assert not path.with_name("out.h5.partial").exists()
    assert list(tmp_path.iterdir()) == []


def test_atomic_h5_exception_keeps_previous_file(tmp_path):
    path = tmp_path / "out.h5"
    with atomic_h5(path) as f:
        f.create_dataset("x", data=np.arange(3))
    before = path.read_bytes()
    with pytest.raises(_Boom):
        with atomic_h5(path) as f:
            f.create_dataset("y", data=np.arange(5))
            raise _Boom("interrupted")
    assert path.read_bytes() == before
    assert not path.with_name("out.h5.partial").exists()


def test_atomic_h5_success_renames_into_place(tmp_path):
    path = tmp_path / "sub" / "out.h5"
    with atomic_h5(path) as f:
        f.create_dataset("x", data=np.arange(4))
    assert path.exists()
    assert not path.with_name("out.h5.partial").exists()
    with h5py.File(path, "r") as f:
        np.testing.assert_array_equal(f["x"][()], np.arange(4))


def test_an_error_while_reading_a_cube_leaves_hdf5_free_for_other_threads(tmp_path, monkeypatch):
    """h5py's ``items()`` holds its global lock while a loop's body runs; an exception raised in the body
    (here: in the comprehension over the /antenna attributes, whose iterator is a local of its own frame
    before Python 3.12) with its traceback still held (pytest's report, a notebook's last error) kept the lock, and the next chain's stage writer thread waited on it for
    ever (an independent review's run of the bad-input tests hung).  The reader reads every HDF5 object's
    items into a list first: another thread opens a file at once."""
    import threading

    import h5py

    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.io import raw as raw_mod
    from fwdlook_cli.scenario.loader import load_scenario

    cube, _ = simulate_scenario(load_scenario(TINY))
    path = tmp_path / "c.h5"
    raw_mod.write_raw(path, cube)
    calls = []

    class Raised(Exception):
        pass

    def plain(value):                   # raised inside the comprehension over /antenna's attributes
        calls.append(value)
        if value in ("gaussian2", b"gaussian2"):
            raise Raised("raised in the loop's body")
        return value.decode() if isinstance(value, bytes) else value

    monkeypatch.setattr(raw_mod, "_plain", plain)
    with pytest.raises(Raised) as held:
        raw_mod.read_raw(path)
    assert held.value.__traceback__ is not None            # kept alive, as a caller may keep it
    opened = []
    worker = threading.Thread(target=lambda: opened.append(h5py.File(path, "r").close()), daemon=True)
    worker.start()
    worker.join(timeout=20)
    assert not worker.is_alive() and opened, "HDF5's lock still held by the failed read"
