"""``fwdlook report`` writes one self-contained index.html (issue 13, item 1): every figure embedded as
a base64 PNG, forward and ISAR runs, a ground-plane figure, a sweep's stability map on a fixed
logarithmic colour norm in metres; opened in headless Chromium where Chromium is installed."""
from __future__ import annotations

import base64
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from fwdlook_cli.cli import main

ROOT = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def cli(*argv):
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv])
    assert exc.value.code == 0


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    base = tmp_path_factory.mktemp("html")
    cli("-q", "run", ROOT / "scenarios" / "tiny.yaml", "-o", base / "fwd", "-c", ROOT / "configs" / "tracking.yaml")
    cli("-q", "run", ROOT / "scenarios" / "isar_theta3.yaml", "-o", base / "isar", "--set", "radar.n_pulses=600")
    spec = {"name": "s", "scenarios": [str(ROOT / "scenarios" / "tiny.yaml")], "set": ["noise.snr_db=null"],
            "grid": {"processing.method": ["tracking", "beam"], "processing.t_ref": ["centre"]}}
    (base / "s.yaml").write_text(yaml.safe_dump(spec))
    cli("-q", "sweep", base / "s.yaml", "-o", base / "sweep")
    cli("-q", "report", base / "fwd", base / "isar", base / "sweep", "-o", base / "report")
    return base / "report" / "index.html"


def images(text):
    return re.findall(r'<img alt="([^"]+)" src="([^"]+)"', text)


def test_index_html_is_self_contained(report):
    text = report.read_text(encoding="utf-8")
    imgs = images(text)
    names = [n for n, _ in imgs]
    for src in (s for _, s in imgs):
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == PNG_MAGIC
    # nothing fetched from elsewhere: no external URL, no file reference, links only to anchors
    assert not re.search(r'(src|href)="(?!data:|#)', text)
    assert "http://" not in text and "https://" not in text
    assert {"images.png", "real_beam.png", "range_profiles.png", "errors.png", "ground_fwd.png",
            "isar_isar_echo_before.png", "isar_isar_echo_after.png", "isar_isar_image.png",
            "sweep_sweep_stability.png", "sweep_sweep_speed_accuracy.png"} <= set(names)
    # the glance table's numbers are the runs' metrics.json numbers
    import json

    for run in ("fwd", "isar"):
        m = json.loads((report.parent.parent / run / "metrics.json").read_text())
        row = re.search(rf"<tr><td><code>{run}</code></td>(.*?)</tr>", text).group(1)
        cells = re.findall(r"<td>(.*?)</td>", row)
        assert cells[3] == f"{m['summary']['detected']}/{m['summary']['n_targets']}"
        assert float(cells[4]) == pytest.approx(m["summary"]["max_abs_range_error_m"], abs=0.005)
        if run == "isar":
            assert float(cells[7]) == pytest.approx(m["summary"]["migration_span_cells"], abs=0.005)
    assert report.stat().st_size < 5e6


def test_error_maps_share_one_fixed_log_colour_scale():
    """The same error in metres gets the same colour on two maps whose data ranges differ."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from fwdlook_cli.report.plots import ERROR_NORM_M, error_map

    fig, (a1, a2) = plt.subplots(1, 2)
    m1 = error_map(a1, [[1.0, 0.05]], ["a", "b"], ["x"], xlabel="x", ylabel="y", title="1")
    m2 = error_map(a2, [[1.0, 12.0]], ["a", "b"], ["x"], xlabel="x", ylabel="y", title="2")
    for m in (m1, m2):
        assert isinstance(m.norm, LogNorm) and (m.norm.vmin, m.norm.vmax) == ERROR_NORM_M
    np.testing.assert_array_equal(m1.to_rgba(np.array([1.0])), m2.to_rgba(np.array([1.0])))
    # logarithmic: the colour position of 0.1 m is log(0.1 / vmin) / log(vmax / vmin)
    assert float(m1.norm(0.1)) == pytest.approx(np.log10(0.1 / ERROR_NORM_M[0]) / np.log10(ERROR_NORM_M[1] / ERROR_NORM_M[0]))
    plt.close(fig)


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.skipif(_chromium() is None, reason="no Chromium on this machine (apt-get install chromium)")
def test_headless_chromium_decodes_every_figure(report, tmp_path):
    exe = _chromium()
    common = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
              f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=15000"]
    dom = subprocess.run([*common, "--dump-dom", report.as_uri()], capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0, dom.stderr[-2000:]
    n = len(images(report.read_text(encoding="utf-8")))
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert f'data-images="{n}"' in body
    assert f'data-images-decoded="{n}"' in body                # every embedded PNG decoded by the browser
    shot = tmp_path / "first_screen.png"
    run = subprocess.run([*common, "--window-size=1280,900", f"--screenshot={shot}", report.as_uri()],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and shot.exists(), run.stderr[-2000:]
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[:2] == (900, 1280)
    assert pixels[..., :3].std() > 0.1                         # a page, not a blank screen
