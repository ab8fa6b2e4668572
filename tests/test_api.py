"""The Python API (issue 13, item 3): the README's notebook-style example runs as written (extracted
from README.md here, so it cannot go stale), the in-memory chain gives the same image and metrics as
the stage-file chain of ``fwdlook run``, and ``import fwdlook_cli`` imports nothing heavy."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Python API"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_example_runs(monkeypatch, capsys):
    pytest.importorskip("xarray")
    monkeypatch.chdir(ROOT)                      # the example names scenarios/tiny.yaml, as a reader would
    code = readme_example()
    assert "import fwdlook_cli as fw" in code
    exec(compile(code, "README.md (Python API)", "exec"), {"__name__": "__readme__"})
    assert capsys.readouterr().out.strip()        # it prints what it shows


def test_in_memory_chain_equals_the_run_directory_chain(tmp_path):
    import fwdlook_cli as fw

    scn = fw.load_scenario(ROOT / "scenarios" / "tiny.yaml", ["processing.method=tracking"])
    cube = fw.simulate_cube(scn)
    final = fw.run_chain(cube, scn["processing"])
    mem = fw.measure(cube, final, scn["processing"])
    disk = fw.process_cube(cube, scn, tmp_path, png=False)
    import h5py

    with h5py.File(tmp_path / "image.h5", "r") as f:
        np.testing.assert_array_equal(f["image"][()], final["image"])
    for a, b in zip(mem["targets"], disk["targets"]):
        for key in ("true_range_m", "meas_range_m", "range_error_m", "meas_azimuth_deg", "detected"):
            assert a[key] == b[key], key
    assert mem["summary"]["max_abs_range_error_m"] == disk["summary"]["max_abs_range_error_m"]
    assert json.loads((tmp_path / "metrics.json").read_text())["scenario_sha256"] == fw.scenario_hash(scn)


def test_every_exported_name_resolves():
    import fwdlook_cli as fw
    from fwdlook_cli.api import EXPORTS

    import pkgutil

    # a submodule of the same name would shadow the export once imported (import binds it on the package)
    assert not set(EXPORTS) & {m.name for m in pkgutil.iter_modules(fw.__path__)}
    for name in EXPORTS:
        assert callable(getattr(fw, name)), name
    assert set(EXPORTS) <= set(dir(fw))
    with pytest.raises(AttributeError):
        fw.no_such_name  # noqa: B018


def test_import_and_cli_help_stay_light():
    probe = ("import sys, fwdlook_cli; from fwdlook_cli.cli import cli; "
             "print(sorted(m for m in ('numpy', 'scipy', 'h5py', 'matplotlib', 'xarray') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"
