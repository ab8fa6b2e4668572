"""The bad-input corpus: every way a user can hand fwdlook a broken scenario or cube.

CONTRACT.md section 1: bad input exits 2 with ONE plain line on stderr naming the file, the key path
or dataset, the bad value and what is allowed, no traceback; and a failed command never leaves a file
that looks complete (no output, no ``*.partial``).  Each case builds its bad input in tmp_path and
runs ``fwdlook_cli.cli.main`` in-process.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from fwdlook_cli.errors import BadInput
from fwdlook_cli.scenario.loader import load_scenario, scenario_hash
from fwdlook_cli.io.raw import write_raw
from fwdlook_cli.forward.simulate import simulate_scenario
from cli_runner import run_cli

TINY = Path(__file__).resolve().parents[1] / "scenarios" / "tiny.yaml"
TINY_TEXT = TINY.read_text(encoding="utf-8")


def assert_bad_input(code, out, err, path, fragments):
    """Exit 2, one 'fwdlook: error:' line on stderr naming the file and every fragment."""
    assert code == 2, f"exit {code}, stderr: {err!r}"
    assert "Traceback" not in err and "Traceback" not in out
    lines = err.splitlines()
    assert len(lines) == 1, f"expected one stderr line, got {lines!r}"
    line = lines[0]
    assert line.strip(), "empty error line"
    assert line.startswith("fwdlook: error:"), line
    assert str(path) in line, f"file {path} not named in: {line}"
    for fragment in fragments:
        assert fragment in line, f"{fragment!r} not named in: {line}"
    assert out == "", f"unexpected stdout on failure: {out!r}"


def assert_nothing_written(tmp_path, output):
    assert not Path(output).exists(), f"{output} was written by a failing command"
    assert list(tmp_path.rglob("*.partial")) == []


# ----------------------------------------------------------------------------------------------
# Scenario cases: each builds a scenario file from tiny.yaml (text edit or dict edit)
# ----------------------------------------------------------------------------------------------
def _text_edit(old, new):
    def build(tmp_path):
        assert TINY_TEXT.count(old) == 1, old  # the edit must hit tiny.yaml exactly once
        path = tmp_path / "scenario.yaml"
        path.write_text(TINY_TEXT.replace(old, new), encoding="utf-8")
        return path

    return build


def _dict_edit(fn):
    def build(tmp_path):
        raw = yaml.safe_load(TINY_TEXT)
        fn(raw)
        path = tmp_path / "scenario.yaml"
        path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
        return path

    return build


def _set(dotted, value):
    def fn(raw):
        *parents, leaf = dotted.split(".")
        node = raw
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value

    return _dict_edit(fn)


def _delete(dotted):
    def fn(raw):
        *parents, leaf = dotted.split(".")
        node = raw
        for part in parents:
            node = node[part]
        del node[leaf]

    return _dict_edit(fn)


def _copy_tiny(tmp_path):
    path = tmp_path / "scenario.yaml"
    path.write_text(TINY_TEXT, encoding="utf-8")
    return path


def _missing_file(tmp_path):
    return tmp_path / "no_such_scenario.yaml"


def _raw(text):
    def build(tmp_path):
        path = tmp_path / "scenario.yaml"
        path.write_text(text, encoding="utf-8")
        return path

    return build


# (id, builder, extra argv, fragments the message must contain besides the file path)
SCENARIO_CASES = [
    ("malformed-yaml-unclosed-bracket",
     _text_edit("points_m: [[-150.0, 1000.0], [0.0, 1030.0], [120.0, 990.0]]",
                "points_m: [[-150.0, 1000.0], [0.0, 1030.0], [120.0, 990.0]"),
     [], ["invalid YAML", "line "]),
    ("duplicate-key",
     _text_edit("  prf_hz: 2000\n", "  prf_hz: 2000\n  prf_hz: 3000\n"),
     [], ["radar.prf_hz", "duplicate"]),
    ("unknown-top-level-key", _set("colour", "red"), [], ["colour", "unknown key", "radar", "processing"]),
    ("unknown-nested-key", _set("radar.prf", 2000), [],
     ["radar.prf", "unknown key", "allowed:", "prf_hz", "fc_hz", "fs_hz"]),
    ("section-not-a-mapping", _set("radar", 5), [], ["radar", "expected a mapping"]),
    ("top-level-not-a-mapping", _raw("- 1\n- 2\n"), [], ["top level", "mapping"]),
    ("wrong-type-string-for-prf", _set("radar.prf_hz", "fast"), [],
     ["radar.prf_hz", "'fast'", "expected a number"]),
    ("bool-for-number", _set("radar.prf_hz", True), [], ["radar.prf_hz", "true", "expected a number"]),
    ("yaml11-yes-for-number", _text_edit("speed_mps: 150.0", "speed_mps: yes"), [],
     ["platform.speed_mps", "expected a number"]),
    ("float-for-integer", _set("noise.seed", 1.5), [], ["noise.seed", "1.5", "integer"]),
    ("negative-prf", _set("radar.prf_hz", -2000), [], ["radar.prf_hz", "-2000", ">= 1"]),
    ("zero-prf", _set("radar.prf_hz", 0), [], ["radar.prf_hz", "= 0", ">= 1"]),
    ("nan-value", _text_edit("snr_db: 30.0", "snr_db: .nan"), [], ["noise.snr_db", "finite"]),
    ("fs-below-bandwidth", _set("radar.fs_hz", 10.0e6), [],
     ["radar.fs_hz", "1e+07", "radar.bandwidth_hz", "2e+07"]),
    ("q-does-not-divide-pulses", _set("processing.q", 7), [], ["processing.q", "7", "400"]),
    ("bad-choice-method", _set("processing.method", "foo"), [],
     ["processing.method", "'foo'", "allowed:", "decimation", "tracking", "auto"]),
    ("bad-choice-keystone", _set("processing.keystone", "fft"), [],
     ["processing.keystone", "'fft'", "czt", "dft", "sinc"]),
    ("bad-n-doppler", _set("processing.n_doppler", "many"), [],
     ["processing.n_doppler", "'many'", "integer", "'auto'"]),
    ("n-doppler-too-few", _set("processing.n_doppler", 2), [], ["processing.n_doppler", "2", ">= 4", "'auto'"]),
    ("points-without-points_m", _delete("scene.points_m"), [], ["scene.points_m", "points"]),
    ("amplitude-list-wrong-length", _set("scene.amplitude", [1.0, 2.0]), [],
     ["scene.amplitude", "2", "3"]),
    ("amplitude-non-positive", _set("scene.amplitude", [1.0, 0.0, 1.0]), [], ["scene.amplitude", "> 0"]),
    ("range-window-misses-targets", _set("radar.range_window_m", [1100.0, 1200.0]), [],
     ["radar.range_window_m", "1100", "1200", "auto"]),
    ("range-window-reversed", _set("radar.range_window_m", [1200.0, 1100.0]), [],
     ["radar.range_window_m", "far > near"]),
    ("scan-stop-equals-start", _set("antenna.scan_stop_deg", -10.0), [],
     ["antenna.scan_stop_deg", "antenna.scan_start_deg"]),
    ("scan-stop-below-start", _set("antenna.scan_stop_deg", -20.0), [],
     ["antenna.scan_stop_deg", "-20", "antenna.scan_start_deg"]),
    ("squint-too-large", _set("antenna.squint_deg", 3.0), [], ["antenna.squint_deg", "3", "allowed"]),
    ("accel-wrong-length", _set("platform.accel_mps2", [0.0, 10.0]), [],
     ["platform.accel_mps2", "list of 3"]),
    ("missing-scenario-file", _missing_file, [], ["not found"]),
    ("set-unknown-key", _copy_tiny, ["--set", "radar.foo=1"], ["radar.foo", "unknown key", "prf_hz"]),
    ("set-without-equals", _copy_tiny, ["--set", "processing.q"], ["--set", "processing.q", "KEY.PATH=VALUE"]),
    ("set-bad-value", _copy_tiny, ["--set", "processing.q=7"], ["processing.q", "7", "400"]),
    ("set-invalid-yaml-value", _copy_tiny, ["--set", "platform.accel_mps2=[0, 30"],
     ["platform.accel_mps2", "invalid YAML"]),
    ("set-through-a-leaf", _copy_tiny, ["--set", "radar.prf_hz.x=1"], ["radar.prf_hz", "not a mapping"]),
    ("set-with-an-empty-key", _copy_tiny, ["--set", "processing..q=1"], ["processing..q=1", "an empty key"]),
    # an independent review (fifty-first round): a whole section replaced, its other keys back to their
    # defaults (noise=null: 20 dB and seed 1, not "no noise"), and YAML 1.1's octal and base-60 numbers
    ("set-a-section-to-null", _copy_tiny, ["--set", "noise=null"], ["--set noise = null", "is a section",
                                                                      "noise.snr_db=null"]),
    ("set-a-section-to-a-number", _copy_tiny, ["--set", "radar=5"], ["--set radar = 5", "a mapping of its keys"]),
    ("set-an-octal-number", _copy_tiny, ["--set", "noise.seed=010"], ["noise.seed", "010", "octal: 8"]),
    ("set-a-base-60-number", _copy_tiny, ["--set", "noise.seed=1:0"], ["noise.seed", "1:0", "base 60: 60"]),
    # values the chain cannot process (each ran before, with a traceback, an overflow or 24 GB)
    ("carrier-below-half-fs", _set("radar.fc_hz", 1.0e7), [],
     ["radar.fc_hz", "1e+07", "radar.fs_hz / 2 = 1.2e+07"]),
    ("time-bandwidth-below-1", _set("radar.bandwidth_hz", 1.0), [],
     ["radar.bandwidth_hz", "= 1:", "1 / radar.pulse_width_s", "time-bandwidth"]),
    ("amplitude-overflows", _set("scene.amplitude", 1.0e300), [], ["scene.amplitude", "<= 10000"]),
    ("name-climbs-out-of-runs", _set("name", ".."), [], ["name", "'..'", "one folder"]),
    ("name-with-a-slash", _set("name", "../mine"), [], ["name", "one folder", "no '/'"]),
    ("pulse-longer-than-its-interval", _set("radar.pulse_width_s", 1.0e-3), [],
     ["radar.pulse_width_s", "0.001", "duty cycle", "1 / radar.prf_hz = 0.0005"]),
    # a fuzz of the command line (fifty-eighth round): a window from 0 m passed validate and ended the chain
    # in a ZeroDivisionError (exit 1); a lone surrogate in a name was a UnicodeEncodeError in every command;
    # a PRF of 1e-300 Hz printed numpy's overflow warnings and a NaN extent under the error
    ("range-window-from-0-m", _set("radar.range_window_m", [0.0, 1100.0]), [],
     ["radar.range_window_m", "[0.0, 1100.0]", "> 0"]),
    ("name-a-lone-surrogate", _text_edit("name: tiny", 'name: "\\ud800"'), [],
     ["name", "UTF-8", "lone surrogate"]),
    ("pattern-file-a-lone-surrogate", _text_edit("  beamwidth_3db_deg: 6.0\n", '  beamwidth_3db_deg: 6.0\n'
                                                 '  pattern: table\n  pattern_file: "a\\udc80.csv"\n'), [],
     ["antenna.pattern_file", "UTF-8"]),
    ("prf-1e-300-hz", _set("radar.prf_hz", 1.0e-300), [], ["radar.prf_hz", "1e-300", ">= 1"]),
]


@pytest.mark.parametrize("case_id, build, extra, fragments",
                         [pytest.param(*c, id=c[0]) for c in SCENARIO_CASES])
def test_bad_scenario_simulate(tmp_path, capsys, case_id, build, extra, fragments):
    scenario = build(tmp_path)
    output = tmp_path / "out" / "raw.h5"
    code, out, err = run_cli(["simulate", scenario, "-o", output, *extra], capsys)
    assert_bad_input(code, out, err, scenario, fragments)
    assert_nothing_written(tmp_path, output)


@pytest.mark.parametrize("case_id, build, extra, fragments",
                         [pytest.param(*c, id=c[0]) for c in SCENARIO_CASES])
def test_bad_scenario_validate(tmp_path, capsys, case_id, build, extra, fragments):
    scenario = build(tmp_path)
    code, out, err = run_cli(["validate", scenario, *extra], capsys)
    assert_bad_input(code, out, err, scenario, fragments)
    assert list(tmp_path.rglob("*.partial")) == []


# ----------------------------------------------------------------------------------------------
# Cube cases: each starts from a valid simulated tiny cube and breaks one thing
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def good_cube(tmp_path_factory):
    cube, _ = simulate_scenario(load_scenario(TINY))
    path = tmp_path_factory.mktemp("good") / "good.h5"
    write_raw(path, cube)
    return path


def _h5_edit(fn):
    def build(good, tmp_path):
        path = tmp_path / "cube.h5"
        shutil.copyfile(good, path)
        with h5py.File(path, "r+") as f:
            fn(f)
        return path

    return build


def _drop_diff(f):
    del f["echo/diff"]


def _float32_echo(f):
    data = np.abs(f["echo/sum"][()]).astype(np.float32)
    del f["echo/sum"]
    f.create_dataset("echo/sum", data=data)


def _diff_shape(f):
    data = f["echo/diff"][:, :-1]
    del f["echo/diff"]
    f.create_dataset("echo/diff", data=data)


def _nan_sum(f):
    f["echo/sum"][3, 4] = np.complex64(complex(np.nan, 0.0))


def _inf_position(f):
    f["platform/position_m"][5, 1] = np.inf


def _drop_prf(f):
    del f["radar"].attrs["prf_hz"]


def _bad_prf_attr(f):
    f["radar"].attrs["prf_hz"] = "fast"


def _wrong_format(f):
    f.attrs["format"] = "netcdf-radar"


def _bad_format_version(f):
    f.attrs["format_version"] = "one"


def _drop_position(f):
    del f["platform/position_m"]


def _attr(group, key, value):
    def fn(f):
        f[group].attrs[key] = value

    return fn


def _truncated(good, tmp_path):
    path = tmp_path / "cube.h5"
    shutil.copyfile(good, path)
    size = os.path.getsize(path)
    os.truncate(path, size // 2)
    return path


def _text_file(good, tmp_path):
    path = tmp_path / "cube.h5"
    path.write_text("this is not an HDF5 file\n", encoding="utf-8")
    return path


def _missing_cube(good, tmp_path):
    return tmp_path / "absent.h5"


CUBE_CASES = [
    ("missing-echo-diff", _h5_edit(_drop_diff), ["/echo/diff", "missing"]),
    ("float32-echo", _h5_edit(_float32_echo), ["/echo/sum", "float32", "complex64"]),
    ("diff-shape-differs", _h5_edit(_diff_shape), ["/echo/diff", "[400, 76]", "[400, 77]"]),
    ("nan-in-echo-sum", _h5_edit(_nan_sum), ["/echo/sum", "NaN"]),
    ("inf-in-position", _h5_edit(_inf_position), ["/platform/position_m", "Inf"]),
    ("missing-position", _h5_edit(_drop_position), ["/platform/position_m", "missing"]),
    ("missing-radar-prf", _h5_edit(_drop_prf), ["/radar", "prf_hz", "missing"]),
    ("non-numeric-radar-prf", _h5_edit(_bad_prf_attr), ["/radar", "prf_hz", "'fast'"]),
    ("wrong-format-attr", _h5_edit(_wrong_format), ["format", "'netcdf-radar'", "'fwdlook-raw'"]),
    ("bad-format-version", _h5_edit(_bad_format_version), ["format_version", "'one'"]),
    # each of these once ended in a traceback (the attribute's kind unchecked) or a 191 GiB allocation
    ("format-an-array", _h5_edit(_attr("/", "format", np.array([1.0, 2.0]))), ["format", "'fwdlook-raw'"]),
    ("format-version-inf", _h5_edit(_attr("/", "format_version", np.inf)), ["format_version", "inf"]),
    ("antenna-pattern-an-array", _h5_edit(_attr("antenna", "pattern", np.array([1.0, 2.0]))),
     ["/antenna", "pattern", "expected a name"]),
    ("antenna-beta-text", _h5_edit(_attr("antenna", "beta_per_deg2", "abc")), ["/antenna", "beta_per_deg2", "number"]),
    ("antenna-slope-inf", _h5_edit(_attr("antenna", "monopulse_slope_per_deg", np.inf)),
     ["/antenna", "monopulse_slope_per_deg", "positive"]),
    ("antenna-gain-nan", _h5_edit(_attr("antenna", "diff_gain_db", np.nan)), ["/antenna", "diff_gain_db", "finite"]),
    ("bandwidth-3-hz", _h5_edit(_attr("radar", "bandwidth_hz", 3.0)),
     ["/radar", "bandwidth_hz", "time-bandwidth"]),
    ("resolution-over-the-window", _h5_edit(lambda f: (f["radar"].attrs.__setitem__("bandwidth_hz", 1.0e5),
                                                       f["radar"].attrs.__setitem__("pulse_width_s", 1.0e-5))),
     ["/radar", "bandwidth_hz", "longer than the range window", "77 samples"]),
    ("sampled-below-the-band", _h5_edit(_attr("radar", "bandwidth_hz", 30.0e6)), ["/radar", "fs_hz", "bandwidth_hz"]),
    ("pulse-width-zero", _h5_edit(_attr("radar", "pulse_width_s", 0.0)), ["/radar", "pulse_width_s", "positive"]),
    ("pulse-longer-than-its-interval", _h5_edit(_attr("radar", "pulse_width_s", 1.0e-3)),
     ["/radar", "pulse_width_s", "duty cycle", "1 / prf_hz"]),
    ("range-weighting-a-number", _h5_edit(_attr("radar", "range_weighting", 3.0)),
     ["/radar", "range_weighting", "3.0", "expected a name", "hamming"]),
    # an independent review (forty-ninth round): each of these was a traceback, or processed with exit 0
    ("non-utf8-format", _h5_edit(_attr("/", "format", np.bytes_(b"\xff"))), ["format", "'fwdlook-raw'"]),
    ("null-dataspace-echo", _h5_edit(lambda f: (f.__delitem__("echo/sum"),
                                                f.create_dataset("echo/sum", data=h5py.Empty("c8")))),
     ["/echo/sum", "null"]),
    ("complex-carrier", _h5_edit(_attr("radar", "fc_hz", np.complex128(1e10 + 5e9j))),
     ["/radar", "fc_hz", "real number"]),
    ("boolean-slope", _h5_edit(_attr("antenna", "monopulse_slope_per_deg", True)),
     ["/antenna", "monopulse_slope_per_deg", "real number"]),
    ("range-axis-in-km", _h5_edit(lambda f: f["axes/range_m"].attrs.__setitem__("units", "km")),
     ["/axes/range_m", "units", "'km'", "allowed: m"]),
    ("speed-1e12", _h5_edit(lambda f: f["platform/velocity_mps"].__setitem__(slice(None), 1e12)),
     ["/platform/velocity_mps", "speed", "10000 m/s"]),
    ("position-jump", _h5_edit(lambda f: f["platform/position_m"].__setitem__(
        (slice(200, None), 0), f["platform/position_m"][200:, 0] + 500.0)),
     ["/platform/position_m", "between pulses 199 and 200", "500"]),
    ("echo-scaled-1e18", _h5_edit(lambda f: [f["echo/" + c].__setitem__(slice(None), f["echo/" + c][()] * 1e18)
                                             for c in ("sum", "diff")]),
     ["/echo/sum", "largest |sample|", "1e+18"]),
    ("one-sample-3e38", _h5_edit(lambda f: f["echo/sum"].__setitem__((5, 5), np.complex64(3e38 + 3e38j))),
     ["/echo/sum", "largest |sample|"]),
    ("truth-1e300", _h5_edit(lambda f: f["truth/targets/x_m"].__setitem__(slice(None), 1e300)),
     ["/truth/targets/x_m", "1e+300", "1e+07 m"]),
    # an independent review of recorded cubes (fifty-first round): tracebacks (a dead receiver: the data's
    # zero slope divided by, the noise level's zero sigma), and a velocity record processed into an empty image
    ("diff-all-zero", _h5_edit(lambda f: f["echo/diff"].__setitem__(slice(None), 0)),
     ["/echo/diff", "every sample is zero", "difference channel"]),
    ("sum-all-zero", _h5_edit(lambda f: [f["echo/" + c].__setitem__(slice(None), 0) for c in ("sum", "diff")]),
     ["/echo/sum", "every sample is zero"]),
    ("velocity-y-flipped", _h5_edit(lambda f: f["platform/velocity_mps"].__setitem__(
        (slice(None), 1), -f["platform/velocity_mps"][:, 1])),
     ["/platform/velocity_mps", "contradicts /platform/position_m", "allowed: within 0.1 of the speed"]),
    ("range-axis-jittered", _h5_edit(lambda f: f["axes/range_m"].__setitem__(3, f["axes/range_m"][3] + 1e-3)),
     ["/axes/range_m", "not uniformly increasing", "float64"]),
    # the scenario's own ranges (fifty-eighth round's fuzz: a carrier of 1e300 Hz and an imbalance of 1e5 dB
    # passed validate and stopped process with a ZeroDivisionError and an OverflowError, exit 1; a slope of
    # 1e300 per degree ran, every angle NaN)
    ("carrier-1e300-hz", _h5_edit(_attr("radar", "fc_hz", 1e300)), ["/radar", "fc_hz", "1e+300", "1e+12"]),
    ("carrier-1e13-hz", _h5_edit(_attr("radar", "fc_hz", 1e13)), ["/radar", "fc_hz", "1e+13", "1e+06 to 1e+12"]),
    ("prf-half-a-hz", _h5_edit(_attr("radar", "prf_hz", 0.5)), ["/radar", "prf_hz", "0.5", "at least 1 Hz"]),
    ("imbalance-1e5-db", _h5_edit(_attr("antenna", "diff_gain_db", 1e5)),
     ["/antenna", "diff_gain_db", "100000.0", "-40 to 40 dB"]),
    ("imbalance-phase-1e6-deg", _h5_edit(_attr("antenna", "diff_phase_deg", -1e6)),
     ["/antenna", "diff_phase_deg", "-360 to 360 deg"]),
    ("slope-1e6-per-degree", _h5_edit(_attr("antenna", "monopulse_slope_per_deg", 1e6)),
     ["/antenna", "monopulse_slope_per_deg", "0 to 100 per degree"]),
    ("truncated-file", _truncated, ["truncated"]),
    ("text-file-named-h5", _text_file, ["HDF5"]),
    ("missing-cube-file", _missing_cube, ["not found"]),
]


# `info` lists ANY HDF5 file (stage files, images), so a foreign `format` attribute is not an
# error there (see test_info_lists_foreign_hdf5); every other broken cube fails both commands.
CUBE_PARAMS = [pytest.param(command, *case, id=f"{case[0]}-{command}")
               for case in CUBE_CASES for command in ("validate", "info")
               if not (command == "info" and case[0] in ("wrong-format-attr", "format-an-array", "non-utf8-format"))]


@pytest.mark.parametrize("command, case_id, build, fragments", CUBE_PARAMS)
def test_bad_cube(good_cube, tmp_path, capsys, command, case_id, build, fragments):
    path = build(good_cube, tmp_path)
    code, out, err = run_cli([command, path], capsys)
    assert_bad_input(code, out, err, path, fragments)
    assert list(tmp_path.rglob("*.partial")) == []


def test_a_mapping_set_on_a_section_is_merged_into_it(tmp_path):
    """`--set 'processing={q: 4}'` had replaced the whole section, tiny's CPI of 16 back to the default 32
    (an independent review); CONTRACT.md's --set takes any key path with a YAML value, so a mapping on a
    section is merged into it: q 4, every other key as the file and the earlier --set have it."""
    scn = load_scenario(_copy_tiny(tmp_path), ["processing.threshold_db=14", "processing={q: 4}",
                                                "scene={amplitude: 2.0}"])
    tiny = load_scenario(TINY)
    assert scn["processing"]["q"] == 4 and scn["processing"]["threshold_db"] == 14
    assert {k: v for k, v in scn["processing"].items() if k not in ("q", "threshold_db")} == {
        k: v for k, v in tiny["processing"].items() if k not in ("q", "threshold_db")}
    assert scn["scene"]["points_m"] == tiny["scene"]["points_m"] and scn["scene"]["amplitude"] == 2.0


def test_a_scene_key_of_another_kind_is_said_once(tmp_path, capsys):
    """scene.lattice or center_m set under kind: points are not read: said in one warning, once per
    process (they had been recorded in the cube's /scenario and ignored without a word); a written
    scenario.yaml, which holds every section (here the lattice of the run's --set), says nothing: only a
    --set names what the user meant to change."""
    from fwdlook_cli.scenario import forward

    forward._SAID.clear()
    scenario = _copy_tiny(tmp_path)
    said = f"{scenario}: scene.lattice is not read: scene.kind is points"
    code, out, err = run_cli(["validate", scenario, "--set", "scene.lattice.nx=5"], capsys)
    assert code == 0 and err.splitlines() == [said], err
    code, out, err = run_cli(["validate", scenario, "--set", "scene.lattice.nx=5"], capsys)
    assert code == 0 and said not in err, err                          # once per process (a sweep's points)
    forward._SAID.clear()
    code, out, err = run_cli(["validate", scenario, "--set", "scene={lattice: {nx: 5}}"], capsys)   # a mapping
    assert code == 0 and err.splitlines() == [said], err
    forward._SAID.clear()
    code, out, err = run_cli(["run", scenario, "-o", tmp_path / "run", "--set", "scene.lattice.nx=5"], capsys)
    assert code == 0 and said in err, err
    forward._SAID.clear()                   # its scenario.yaml holds the lattice of nx 5 beside kind: points
    code, out, err = run_cli(["validate", tmp_path / "run" / "scenario.yaml"], capsys)
    assert code == 0 and "is not read" not in err, err


def test_a_float32_range_axis_is_read_as_its_uniform_float64_axis(good_cube, tmp_path, capsys):
    """CONTRACT.md asks float64 axes; a recorder's float32 range axis (1.5 km held to 1e-4 m) had been
    refused as "not uniformly increasing" (an independent review): it is read as the least-squares uniform
    axis within float32's rounding, and the cube processes as its float64 twin does."""
    from fwdlook_cli.io.raw import read_raw

    def to_float32(f):
        r = f["axes/range_m"][()]
        units = f["axes/range_m"].attrs.get("units")
        del f["axes/range_m"]
        f.create_dataset("axes/range_m", data=r.astype(np.float32))
        if units is not None:
            f["axes/range_m"].attrs["units"] = units

    path = _h5_edit(to_float32)(good_cube, tmp_path)
    r64, r32 = read_raw(good_cube).range_m, read_raw(path).range_m
    assert r32.dtype == np.float64 and np.ptp(np.diff(r32)) < 1e-9 * np.diff(r32)[0]
    assert np.max(np.abs(r32 - r64)) < 4 * np.finfo(np.float32).eps * r64.max()
    for cube, run in ((good_cube, "r64"), (path, "r32")):
        code, out, err = run_cli(["process", cube, "-o", tmp_path / run, "-q"], capsys)
        assert code == 0, err
    import json
    a, b = (json.loads((tmp_path / run / "metrics.json").read_text())["targets"] for run in ("r64", "r32"))
    for ta, tb in zip(a, b):
        assert abs(ta["range_error_m"] - tb["range_error_m"]) < 1e-3 and ta["detected"] == tb["detected"]


def test_info_lists_a_file_whose_format_is_an_array(good_cube, tmp_path, capsys):
    """`info` lists any HDF5 file; a root `format` that is an array (no fwdlook file's) once ended in
    "truth value of an array is ambiguous": it is another file, listed generically, exit 0."""
    path = _h5_edit(_attr("/", "format", np.array([1.0, 2.0])))(good_cube, tmp_path)
    code, out, err = run_cli(["info", path], capsys)
    assert code == 0, err
    assert "/echo/sum" in out and "fwdlook raw cube" not in out


def test_info_lists_foreign_hdf5(good_cube, tmp_path, capsys):
    """A non-fwdlook-raw HDF5 file is described generically by `info` (exit 0), rejected by `validate`."""
    path = _h5_edit(_wrong_format)(good_cube, tmp_path)
    code, out, err = run_cli(["info", path], capsys)
    assert code == 0, err
    assert "format: netcdf-radar" in out and "/echo/sum" in out
    assert "fwdlook raw cube" not in out


def test_a_point_beneath_the_platform_leaves_a_cube_its_own_reader_takes(tmp_path, capsys):
    """A target within the pulse's reach of the antenna (here beneath it, 50 m down; behind the scan, so it
    returns nothing): the automatic range axis begins one range step out, as no echo comes from a slant
    range at or below 0 m, and still holds the far targets' whole kernels.  It had begun at -150 m: the
    cube was written, then refused by its own reader, and processing the scenario divided by its 0 m sample
    (numpy's RuntimeWarning on the user's terminal)."""
    import warnings

    from fwdlook_cli.dsp.geometry import C_MPS

    raw = yaml.safe_load(TINY_TEXT)
    raw["scene"]["points_m"] = [[0.0, 0.0], [0.0, 1030.0], [120.0, 990.0]]
    scenario = tmp_path / "beneath.yaml"
    scenario.write_text(yaml.safe_dump(raw), encoding="utf-8")
    cube = tmp_path / "beneath.h5"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, _, err = run_cli(["simulate", scenario, "-o", cube, "-q"], capsys)
        assert code == 0, err
        code, out, err = run_cli(["validate", cube], capsys)
        assert code == 0, err
        code, _, err = run_cli(["process", scenario, "-o", tmp_path / "run", "-q"], capsys)
        assert code == 0, err
    assert [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)] == []
    radar = load_scenario(scenario)["radar"]
    step_m = C_MPS / (2.0 * radar["fs_hz"])
    with h5py.File(cube, "r") as f:
        range_m = f["axes/range_m"][()]
    assert range_m[0] == pytest.approx(step_m, rel=1e-12)
    reach_m = C_MPS * radar["pulse_width_s"] / 2.0
    farthest_m = float(np.hypot(1030.0, raw["platform"]["height_m"]))   # at the first pulse, before it closes in
    assert range_m[-1] >= farthest_m + reach_m              # the farthest target's whole kernel


# ----------------------------------------------------------------------------------------------
# Positive controls
# ----------------------------------------------------------------------------------------------
def test_tiny_scenario_validates(tmp_path, capsys):
    scenario = _copy_tiny(tmp_path)
    code, out, err = run_cli(["validate", scenario], capsys)
    assert code == 0, err
    assert "valid" in out and "tiny" in out


def test_tiny_scenario_simulates(tmp_path, capsys):
    scenario = _copy_tiny(tmp_path)
    output = tmp_path / "out" / "raw.h5"
    code, _out, err = run_cli(["simulate", scenario, "-o", output, "-q"], capsys)
    assert code == 0, err
    assert output.exists()
    assert list(tmp_path.rglob("*.partial")) == []
    code, out, err = run_cli(["validate", output], capsys)
    assert code == 0, err
    assert "400 pulses" in out


def test_good_cube_validates_and_describes(good_cube, capsys):
    for command in ("validate", "info"):
        code, out, err = run_cli([command, good_cube], capsys)
        assert code == 0, err
        assert str(good_cube) in out


def test_yaml11_exponent_string_is_a_number(tmp_path, capsys):
    """PyYAML reads '18e9' (no dot) as a string; the schema must still take it as 18 GHz."""
    assert yaml.safe_load("fc_hz: 18e9")["fc_hz"] == "18e9"  # the YAML 1.1 premise
    scenario = _text_edit("fc_hz: 10.0e9", "fc_hz: 18e9")(tmp_path)
    scn = load_scenario(scenario)
    assert isinstance(scn["radar"]["fc_hz"], float)
    assert scn["radar"]["fc_hz"] == 18.0e9
    code, out, err = run_cli(["validate", scenario], capsys)
    assert code == 0, err


def test_set_overrides_resolved_value(tmp_path, capsys):
    base = load_scenario(TINY)
    assert base["processing"]["q"] == 8
    changed = load_scenario(TINY, overrides=["processing.q=20"])
    assert changed["processing"]["q"] == 20
    assert scenario_hash(changed) != scenario_hash(base)
    # same through the command line: validate prints the hash prefix of the resolved scenario
    scenario = _copy_tiny(tmp_path)
    code, out_base, err = run_cli(["validate", scenario], capsys)
    assert code == 0, err
    code, out_set, err = run_cli(["validate", scenario, "--set", "processing.q=20"], capsys)
    assert code == 0, err
    assert scenario_hash(changed)[:16] in out_set
    assert scenario_hash(base)[:16] in out_base


# ----------------------------------------------------------------------------------------------
# Every key of a resolved scenario (every default filled in) given a value of the wrong kind
# ----------------------------------------------------------------------------------------------
SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def _leaves(node, path=()):
    for key, value in node.items():
        if isinstance(value, dict):
            yield from _leaves(value, path + (key,))
        else:
            yield path + (key,)


@pytest.mark.parametrize("name", ["tiny", "paper_fig8_a50", "isar_theta3"])
def test_every_key_refuses_a_mapping_in_one_line(tmp_path, capsys, name):
    """No key of any scenario kind (points, extended image, ISAR) takes a mapping where a value goes:
    each is refused with exit 2 and one line naming the file and the key's whole path, never a
    traceback (the top-level ``kind`` once raised TypeError: a mapping is unhashable)."""
    from fwdlook_cli.scenario.loader import dump_scenario

    resolved_text = dump_scenario(load_scenario(SCENARIOS / f"{name}.yaml"))
    leaves = list(_leaves(yaml.safe_load(resolved_text)))
    assert len(leaves) > 20                      # the whole schema, defaults included
    for i, path in enumerate(leaves):
        raw = yaml.safe_load(resolved_text)
        node = raw
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = {"a": 1}
        scenario = tmp_path / f"{i}.yaml"
        scenario.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
        code, out, err = run_cli(["validate", scenario], capsys)
        assert_bad_input(code, out, err, scenario, [".".join(path)])


def test_a_far_isar_object_is_refused_by_its_window_size_before_simulation(tmp_path, capsys):
    """The auto window holds the object's range minimum on its straight track; for an object 1e12 m out
    that minimum lies 1e11 m nearer than its dwell, and the window's size was once checked over the
    dwell alone, so the simulator tried to allocate 24 GiB.  Now the check sizes the window the
    simulator builds (``scenario.isar.auto_range_extent_m``)."""
    raw = yaml.safe_load((SCENARIOS / "isar_theta3.yaml").read_text(encoding="utf-8"))
    raw["target"]["range_m"] = 1.0e12
    scenario = tmp_path / "far.yaml"
    scenario.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    output = tmp_path / "out" / "raw.h5"
    code, out, err = run_cli(["simulate", scenario, "-o", output], capsys)
    assert_bad_input(code, out, err, scenario, ["radar.range_window_m = auto", "GiB"])
    assert_nothing_written(tmp_path, output)


def test_isar_settings_refused_or_said_before_the_cube_is_simulated(tmp_path, capsys):
    """An independent review of the ISAR chain (fifty-first round): `run --keep-stages none|last` had been
    refused after the cube was simulated and written (over an earlier run's raw.h5); now before any work.
    `processing.n0_pulses` under another correction, which does not read it, is said in one warning; and a
    two-channel cube marked `scenario_kind = isar` says its difference channel is not read."""
    for keep in ("none", "last"):
        code, out, err = run_cli(["run", SCENARIOS / "isar_theta3.yaml", "-o", tmp_path / keep,
                                  "--keep-stages", keep], capsys)
        assert_bad_input(code, out, err, SCENARIOS / "isar_theta3.yaml", [f"--keep-stages {keep}", "allowed: all"])
        assert not (tmp_path / keep).exists()
    code, out, err = run_cli(["validate", SCENARIOS / "isar_theta3.yaml", "--set", "processing.correction=keystone1",
                              "--set", "processing.n0_pulses=100"], capsys)
    assert code == 0 and "processing.n0_pulses = 100 is not read: processing.correction is keystone1" in err, err
    cube, _ = simulate_scenario(load_scenario(SCENARIOS / "tiny.yaml"))
    cube.attrs["scenario_kind"] = "isar"
    write_raw(tmp_path / "both.h5", cube)
    with h5py.File(tmp_path / "both.h5", "a") as f:
        f.attrs["scenario_kind"] = "isar"
    code, out, err = run_cli(["process", tmp_path / "both.h5", "-o", tmp_path / "both"], capsys)
    assert "processed as ISAR (/ attribute scenario_kind = isar): /echo/diff is not read" in err, err


def test_a_pattern_file_under_another_pattern_is_said_to_be_unread(tmp_path, capsys):
    """``antenna.pattern_file`` is only read with ``antenna.pattern: table``; set beside gaussian2 it
    would be ignored silently, and the cube simulated with the Gaussian beams.  It is valid, and said."""
    scenario = _set("antenna.pattern_file", "measured.csv")(tmp_path)
    code, out, err = run_cli(["validate", scenario], capsys)
    assert code == 0, err
    assert "antenna.pattern_file = 'measured.csv' is not read" in err and "gaussian2" in err


def test_a_noise_record_of_the_wrong_kind_is_said_and_left_out(good_cube, tmp_path, capsys):
    """/echo's ``noise_*`` attributes only record what the simulator drew; one that is no number (a
    text here; it once stopped `info` with a TypeError) is said once and left out, and the cube is read."""
    path = _h5_edit(_attr("echo", "noise_snr_db", "abc"))(good_cube, tmp_path)
    for command in ("validate", "info"):
        code, out, err = run_cli([command, path], capsys)
        assert code == 0, err
        assert "noise_snr_db = 'abc' is not a number; ignored" in err
    assert "SNR             unknown" in out         # no SNR on record


def test_a_zero_amplitude_target_has_no_peak_loss(good_cube, tmp_path, capsys):
    """A truth target of amplitude 0 (a recorded cube's surveyed point of unknown strength) has no
    ideal peak to lose against: its peak loss is null in metrics.json (it once made the file invalid
    JSON: Infinity), and the run finishes."""
    import json

    path = _h5_edit(lambda f: f["truth/targets/amplitude"].__setitem__(slice(None), 0.0))(good_cube, tmp_path)
    code, out, err = run_cli(["process", path, "-o", tmp_path / "run", "-q"], capsys)
    assert code == 0, err
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert all(t.get("peak_loss_db") is None for t in metrics["targets"])


def test_the_chains_own_largest_arrays_are_sized_before_they_are_allocated(good_cube, tmp_path, capsys,
                                                                            monkeypatch):
    """Settings the schema allows can ask for arrays far beyond the cube: an angle step of 1e-4 deg with
    x16 range oversampling makes the tiny cube's dwell image a grid of 319 501 x 1 232 cells, which
    once took the process past 23 GB until the kernel ended it; 4096 Doppler cells in CPIs of 2 pulses
    make its spectra 1 GB.  Both are sized from the settings before the chain starts (limits.py::
    check_processing_sizes, the cube's size limit), one line each, nothing written."""
    sets = ["--set", "processing.imaging=dwell", "--set", "processing.range_oversample=16",
            "--set", "processing.angle_step_deg=0.0001"]
    code, out, err = run_cli(["process", good_cube, "-o", tmp_path / "fine", *sets], capsys)
    assert_bad_input(code, out, err, good_cube, ["processing.angle_step_deg = 0.0001", "319,501 angles",
                                                 "1,232 ranges", "11.7 GiB", "over the default limit"])
    assert not (tmp_path / "fine" / "metrics.json").exists()
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", str(512 * 2**20))
    sets = ["--set", "processing.n_doppler=4096", "--set", "processing.cpi=2", "--set", "processing.q=1"]
    code, out, err = run_cli(["process", good_cube, "-o", tmp_path / "cells", *sets], capsys)
    assert_bad_input(code, out, err, good_cube, ["processing.n_doppler = 4096", "200 CPIs", "$FWDLOOK_MAX_CUBE_BYTES"])


def test_spectra_on_disk_are_not_held_to_the_memory_limit():
    """With ``--out-of-core`` the Doppler spectra are file-backed, so their size is the disk's business:
    the same settings refused in memory pass the check; the image grid is held to it either way."""
    from fwdlook_cli.limits import check_processing_sizes

    sizes = dict(n_range=77, range_oversample=2, n_angle=520, angle_step_deg=0.05, imaging="cpi", n_cpi=200,
                 n_doppler=4096, limit=512 * 2**20)
    with pytest.raises(BadInput, match="processing.n_doppler = 4096"):
        check_processing_sizes(**sizes)
    check_processing_sizes(**sizes, spectra_in_memory=False)
    with pytest.raises(BadInput, match="processing.angle_step_deg"):
        check_processing_sizes(**dict(sizes, n_angle=10**6), spectra_in_memory=False)


# ----------------------------------------------------------------------------------------------
# what an independent review (forty-ninth round) found beyond the corpus above
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("group, key", [("radar", "range_weighting"), ("antenna", "pattern"),
                                        ("echo", "noise_snr_db"), ("/", "software")])
def test_attributes_that_are_not_utf8_never_end_in_a_traceback(good_cube, tmp_path, capsys, group, key):
    """Bytes that are not UTF-8 are text with U+FFFD in it (io.describe._plain), then checked as any
    value of that attribute: a name kept, a noise record said and left out.  They had been a
    UnicodeDecodeError traceback (exit 1) in validate, info and process."""
    path = _h5_edit(_attr(group, key, np.bytes_(b"\xff\xfe")))(good_cube, tmp_path)
    for argv in (["validate", path], ["info", path], ["process", path, "-o", tmp_path / "run", "-q"]):
        code, out, err = run_cli(argv, capsys)
        assert code in (0, 2) and "Traceback" not in err, (argv[0], code, err)


def test_a_cube_whose_antenna_does_not_give_its_slope_processes(good_cube, tmp_path, capsys):
    """/antenna with its ratio table but no monopulse_slope_per_deg (a recorder's): processed, the
    slope calibrated from the table or the data (a KeyError traceback before)."""
    path = _h5_edit(lambda f: f["antenna"].attrs.__delitem__("monopulse_slope_per_deg"))(good_cube, tmp_path)
    code, out, err = run_cli(["process", path, "-o", tmp_path / "run", "-q",
                              "--set", "processing.imaging=cpi"], capsys)
    assert code == 0, err
    assert (tmp_path / "run" / "metrics.json").is_file()


def test_validate_checks_a_cubes_settings_as_process_does(good_cube, capsys):
    """``validate CUBE --set`` had ignored the --set (a malformed one, an unknown key, q = 7 against 400
    pulses: exit 0, where process refused them)."""
    for item, fragments in (("noequals", ["--set", "KEY.PATH=VALUE"]),
                            ("bogus.key=1", ["bogus.key", "allowed with a cube"]),
                            ("processing.q=7", ["processing.q = 7", "400"]),
                            ("processing.cpi=100000", ["processing.cpi = 100000", "400 pulses"])):
        code, out, err = run_cli(["validate", good_cube, "--set", item], capsys)
        assert code == 2 and len(err.splitlines()) == 1 and all(f in err for f in fragments), (item, err)
    code, out, err = run_cli(["validate", good_cube, "--set", "processing.q=8"], capsys)
    assert code == 0, err


def test_a_target_the_beam_never_reaches_is_said(tmp_path, capsys):
    """A point behind the platform or outside the scanned sector leaves no echo: one warning names it
    (it had run to "detected 0/1" with nothing said); the run still completes."""
    scenario = _copy_tiny(tmp_path)
    code, out, err = run_cli(["run", scenario, "-o", tmp_path / "r", "--set",
                              "scene.points_m=[[0, -1000], [5000, 100], [0, 1000]]"], capsys)
    assert code == 0, err
    lines = [ln for ln in err.splitlines() if "never in the beam" in ln]
    assert len(lines) == 1 and "2 of 3 targets" in lines[0] and "azimuth 180.0 deg" in lines[0], err
    code, out, err = run_cli(["simulate", TINY, "-o", tmp_path / "tiny.h5"], capsys)
    assert code == 0 and "never in the beam" not in err


def test_integer_keys_take_yaml11_exponents_and_numbers_are_shown_as_numbers(tmp_path, capsys):
    """YAML 1.1 reads 4e2 as text: an integer key takes it when it is whole (as 8.0 was taken), and a
    refused number written so is echoed as a number, not a quoted string."""
    code, out, err = run_cli(["validate", TINY, "--set", "noise.seed=1e3"], capsys)
    assert code == 0, err
    code, out, err = run_cli(["validate", TINY, "--set", "noise.seed=1.5e0"], capsys)
    assert code == 2 and "expected an integer" in err
    code, out, err = run_cli(["validate", TINY, "--set", "radar.fc_hz=-1e9"], capsys)
    assert code == 2 and "radar.fc_hz = -1e9:" in err and "'-1e9'" not in err


def test_a_folder_named_like_a_cube_is_said_to_be_a_folder(tmp_path, capsys):
    (tmp_path / "x.h5").mkdir()
    for command in ("validate", "info"):
        code, out, err = run_cli([command, tmp_path / "x.h5"], capsys)
        assert_bad_input(code, out, err, tmp_path / "x.h5", ["is a directory"])


def test_a_gpu_that_is_not_there_is_refused_before_the_cube_is_simulated(tmp_path, capsys, monkeypatch):
    """``run`` with processing.backend = gpu and no CuPy had simulated and written raw.h5, then refused."""
    import importlib.util

    monkeypatch.delenv("FWDLOOK_XP", raising=False)
    if importlib.util.find_spec("cupy") is not None:
        pytest.skip("CuPy is installed here")
    code, out, err = run_cli(["run", TINY, "-o", tmp_path / "r", "--set", "processing.backend=gpu"], capsys)
    assert_bad_input(code, out, err, TINY, ["processing.backend = gpu", "CuPy"])
    assert not (tmp_path / "r").exists()


def test_a_sweep_grid_over_a_whole_section_is_refused(tmp_path, capsys):
    """grid: {processing: [{q: 8}, {q: 4}]} had replaced the whole section, method, cpi and t_ref lost."""
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(f"name: s\nscenarios: [{TINY}]\ngrid:\n  processing: [{{q: 8}}, {{q: 4}}]\n", encoding="utf-8")
    code, out, err = run_cli(["sweep", sweep, "-o", tmp_path / "out"], capsys)
    assert_bad_input(code, out, err, sweep, ["grid key 'processing'", "processing.KEY"])
    assert not (tmp_path / "out").exists()


def test_info_on_a_run_folder_points_to_its_files(tmp_path, capsys):
    """`fwdlook info RUN_DIR` is refused (info reads one file) with the folder's own image.h5 named."""
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "image.h5").write_bytes(b"")
    code, out, err = run_cli(["info", tmp_path / "run"], capsys)
    assert_bad_input(code, out, err, tmp_path / "run", ["is a directory", str(tmp_path / "run" / "image.h5")])
    code, out, err = run_cli(["info", tmp_path], capsys)               # a folder of nothing of ours: no hint
    assert code == 2 and "is a directory" in err and "allowed" not in err


@pytest.mark.parametrize("text, fragment", [
    ("", "holds nothing"),                                # empty: had run with no preset, exit 0
    ("# only a comment\n", "holds nothing"),
    ("processing: null\n", "processing = None: expected a mapping"),
    ("[1, 2]\n", "holds a list"),
    ("processing: {metod: beam}\n", "processing.metod: unknown key"),   # had named the scenario file
])
def test_a_bad_processing_preset_is_one_line_naming_the_preset(tmp_path, capsys, text, fragment):
    preset = tmp_path / "preset.yaml"
    preset.write_text(text)
    code, out, err = run_cli(["run", str(TINY), "-c", str(preset), "-o", str(tmp_path / "out")], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith(f"fwdlook: error: {preset}:"), err
    assert fragment in lines[0] and not (tmp_path / "out" / "metrics.json").exists()


def test_a_refused_set_value_names_the_setting_and_a_yaml_boolean_says_so(tmp_path, capsys):
    """A value given by --set had read as the scenario file's own (`tiny.yaml: processing.q = 7: ...`); and
    an unquoted off/no/yes arrives as a boolean, which the message now says (an independent review)."""
    code, out, err = run_cli(["validate", str(TINY), "--set", "processing.q=7"], capsys)
    assert code == 2 and err.strip().endswith("(set by --set processing.q=7)"), err
    code, out, err = run_cli(["validate", str(TINY), "--set", "processing.keystone=off"], capsys)
    assert code == 2 and "allowed: czt, dft, sinc (YAML reads off, on, no and yes as true/false" in err, err
    assert len(err.strip().splitlines()) == 1


def test_a_sub_swath_keystone_over_the_size_limit_is_refused_before_the_chain(tmp_path, monkeypatch):
    """Steep depression corrects the window in range sub-swaths, each padded by the range walk
    (forward/subswath.py); a scene whose walk outruns its window (tiny at a PRF of 1 Hz: 1060 km in a 400 s
    scan) had run for minutes to 7.8 GiB of RSS.  One sub-swath's keystone, ``SUBSWATH_WORK_FACTOR`` x its
    padded rows (both channels, complex64), is now held to the size limit when the stages are built, in one
    line naming the setting and its alternatives; at the limit exactly it is built, and out of core (the rows
    file-backed) it is not held to it."""
    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.io import backing
    from fwdlook_cli.limits import SUBSWATH_WORK_FACTOR
    from fwdlook_cli.testing import tiny_scenario

    base = tiny_scenario()
    scn = tiny_scenario(antenna=dict(base["antenna"], scan_rate_dps=25.0),
                        platform=dict(base["platform"], height_m=3000.0),
                        scene={"kind": "points", "points_m": [[300.0, 2000.0], [0.0, 2800.0]], "amplitude": 1.0})
    cube, _ = simulate_scenario(scn)
    proc = dict(scn["processing"], method="tracking", q=1, imaging="cpi", cpi=32, n_doppler=32)   # (spectra: 4 MB)
    _, stages, geo = build_forward_stages(cube, proc)
    subswaths = next(st for st in stages if st.name == "keystone").params["subswaths"]
    assert geo["subswaths"] == len(subswaths) > 1
    need = SUBSWATH_WORK_FACTOR * 2 * 8 * cube.n_pulses * max(sw["hi"] - sw["lo"] for sw in subswaths)
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", str(need))
    build_forward_stages(cube, proc)
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", str(need - 1))
    with pytest.raises(BadInput) as exc:
        build_forward_stages(cube, proc)
    line = str(exc.value)
    assert "\n" not in line and f"in {len(subswaths)} sub-swaths" in line and "range walk" in line
    for fragment in ("processing.subswaths = auto", "$FWDLOOK_MAX_CUBE_BYTES", "processing.subswaths: none",
                     "--out-of-core"):
        assert fragment in line, line
    with backing.file_backed(tmp_path):
        build_forward_stages(cube, proc)


@pytest.mark.parametrize("slope_per_deg, accepted", [(50.0, True), (150.0, False)])
def test_a_table_antenna_the_scenario_takes_makes_a_cube_its_reader_takes(tmp_path, capsys, slope_per_deg, accepted):
    """A measured pattern (``antenna.pattern: table``) of a 0.1 deg beam whose ratio is tanh(k d): its slope
    through boresight k is held to the bound a cube's /antenna is held to (up to 100 per degree, as
    ``processing.monopulse_calibration``), so what the scenario takes, its cube's reader takes (an
    independent review: k = 150 was simulated, exit 0, and the cube then refused by ``validate``)."""
    d = np.linspace(-0.5, 0.5, 2001)
    sum_v = np.exp(-2.0 * np.log(2.0) * (d / 0.1) ** 2)          # one-way 3 dB width 0.1 deg
    np.savetxt(tmp_path / "pat.csv", np.column_stack([d, sum_v, sum_v * np.tanh(slope_per_deg * d)]),
               delimiter=",", header="offset_deg,sum,diff", comments="")
    raw = yaml.safe_load(TINY_TEXT)
    raw["antenna"].update(beamwidth_3db_deg=0.1, pattern="table", pattern_file="pat.csv")
    raw["antenna"].pop("squint_deg", None)
    scenario = tmp_path / "table.yaml"
    scenario.write_text(yaml.safe_dump(raw), encoding="utf-8")
    cube = tmp_path / "table.h5"
    code, out, err = run_cli(["simulate", scenario, "-o", cube, "-q"], capsys)
    if not accepted:
        assert_bad_input(code, out, err, scenario, ["antenna.pattern_file", "slope through boresight", "up to 100"])
        assert not cube.exists()
        return
    assert code == 0, err
    code, out, err = run_cli(["validate", cube], capsys)
    assert code == 0, err
    with h5py.File(cube, "r") as f:
        assert f["antenna"].attrs["monopulse_slope_per_deg"] == pytest.approx(slope_per_deg, rel=1e-3)


def test_a_path_under_a_folder_whose_name_is_not_utf8_is_refused_in_one_line(tmp_path, capsys):
    """A relative ``antenna.pattern_file`` resolved against the scenario's folder, whose name holds a byte
    that is not UTF-8 (Python keeps it as a lone surrogate): the resolved path cannot be written into the
    outputs, so it is refused by ``validate`` and ``simulate`` alike, in one line (an independent review: it
    passed ``validate`` and ended ``simulate`` in a UnicodeEncodeError, exit 1)."""
    folder = Path(os.fsdecode(os.path.join(os.fsencode(tmp_path), b"d\xff")))
    folder.mkdir()
    d = np.linspace(-20.0, 20.0, 2001)
    sum_v = np.exp(-2.0 * np.log(2.0) * (d / 6.0) ** 2)
    np.savetxt(folder / "pat.csv", np.column_stack([d, sum_v, sum_v * np.tanh(0.3 * d)]), delimiter=",",
               header="offset_deg,sum,diff", comments="")
    raw = yaml.safe_load(TINY_TEXT)
    raw["antenna"].update(pattern="table", pattern_file="pat.csv")
    raw["antenna"].pop("squint_deg", None)
    scenario = folder / "table.yaml"
    scenario.write_text(yaml.safe_dump(raw), encoding="utf-8")
    for command in (["validate", scenario], ["simulate", scenario, "-o", tmp_path / "raw.h5"]):
        code, out, err = run_cli(command, capsys)
        assert code == 2 and "Traceback" not in err, err
        lines = err.splitlines()
        assert len(lines) == 1 and lines[0].startswith("fwdlook: error:"), lines
        assert "antenna.pattern_file" in lines[0] and "not UTF-8" in lines[0], lines[0]
    assert not (tmp_path / "raw.h5").exists() and list(tmp_path.rglob("*.partial")) == []


def test_a_recorded_phase_imbalance_in_0_to_360_deg_is_the_same_as_in_plus_minus_180(good_cube, tmp_path, capsys):
    """A recorder's channel phase imbalance in the 0-360 deg convention (270 deg) is one turn from the
    scenario's +-180 deg (-90 deg): with the difference channel rotated by it, both process to the metrics of
    the cube without the imbalance (exp(j phi) is all the chain takes of it); beyond one turn either way it is
    refused (the fifty-eighth round's bound, which had first refused 270 deg)."""
    import json

    def metrics_of(name, phase_deg):
        path = tmp_path / f"{name}.h5"
        shutil.copyfile(good_cube, path)
        if phase_deg is not None:
            with h5py.File(path, "r+") as f:
                f["echo/diff"][...] = (f["echo/diff"][()] * np.exp(1j * np.radians(phase_deg))).astype(np.complex64)
                f["antenna"].attrs["diff_phase_deg"] = phase_deg
        code, _, err = run_cli(["process", path, "-o", tmp_path / name, "-q"], capsys)
        assert code == 0, err
        return json.loads((tmp_path / name / "metrics.json").read_text())["targets"]

    plain = metrics_of("plain", None)
    for phase_deg in (270.0, -90.0):
        rotated = metrics_of(f"phase{phase_deg:g}", phase_deg)
        for a, b in zip(plain, rotated):
            assert (a["meas_range_m"] is None) == (b["meas_range_m"] is None)
            if a["meas_range_m"] is not None:
                assert b["meas_range_m"] == pytest.approx(a["meas_range_m"], abs=1e-6)
                assert b["meas_azimuth_deg"] == pytest.approx(a["meas_azimuth_deg"], abs=1e-6)
    path = _h5_edit(_attr("antenna", "diff_phase_deg", 361.0))(good_cube, tmp_path)
    assert_bad_input(*run_cli(["validate", path], capsys), path, ["/antenna", "diff_phase_deg", "-360 to 360 deg"])
