"""scene.kind: image: a one-pixel map is a one-point scene; bad maps are one-line BadInput (exit 2)."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from fwdlook_cli.scenario.loader import resolve_scenario
from fwdlook_cli.scenario.forward import scene_points
from fwdlook_cli.scenario.scene_image import SPECKLE_STREAM, make_road_scene
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.testing import TINY, _merge
from cli_runner import run_cli


def _tiny(scene, **extra):
    return resolve_scenario(_merge(_merge(TINY, {"noise": {"snr_db": None}}), {"scene": scene, **extra}), "<t>")


def _one_pixel(tmp_path, ny=5, nx=7, i=0, j=3, value=2.0):
    arr = np.zeros((ny, nx), np.float32)
    arr[i, j] = value
    path = tmp_path / "one.npy"
    np.save(path, arr)
    return path


def test_one_bright_pixel_is_a_one_point_scene(tmp_path):
    """Orientation 90 deg turns the map's up towards +x: the top-centre pixel of a 5 x 7 map of 4 m
    pixels lies 2 pixels (8 m) from the centre along +x.  Its echo is the point's times exp(j phase)."""
    path = _one_pixel(tmp_path)
    img = _tiny({"kind": "image", "center_m": [20.0, 1000.0], "amplitude": 1.5,
                 "image": {"file": str(path), "pixel_spacing_m": 4.0, "orientation_deg": 90.0}})
    pts, amps = scene_points(img)
    assert np.allclose(pts, [[28.0, 1000.0]], atol=1e-9)
    phase = np.random.default_rng([img["noise"]["seed"], SPECKLE_STREAM]).uniform(0, 2 * np.pi, (5, 7))[0, 3]
    assert amps[0] == pytest.approx(1.5 * np.exp(1j * phase))
    pt = _tiny({"kind": "points", "points_m": [[28.0, 1000.0]], "amplitude": 1.5})
    ci, _ = simulate_scenario(img)
    cp, _ = simulate_scenario(pt)
    assert ci.sum.shape == cp.sum.shape and np.allclose(ci.range_m, cp.range_m)
    for a, b in ((ci.sum, cp.sum), (ci.diff, cp.diff)):
        err = np.sum(np.abs(a - np.exp(1j * phase) * b) ** 2) / np.sum(np.abs(b) ** 2)
        assert 10 * np.log10(err) < -100.0
    assert ci.truth is None                       # an image's truth is its map


def test_a_one_row_map_is_a_map_and_a_map_outside_the_beam_is_said(tmp_path, caplog, capsys):
    """A 1 x 7 map (squeezed to 1-D, it had been refused as "image of shape (7,)", which is not the
    file's shape) is read as a map: its one bright pixel at the map's centre row is a point at the
    centre; and a map the beam never reaches, which had run to "detected 0/0" without a word, is said in
    one warning (an independent review)."""
    import logging

    row = np.zeros((1, 7), np.float32)
    row[0, 3] = 2.0
    np.save(tmp_path / "row.npy", row)
    one = _tiny({"kind": "image", "center_m": [20.0, 1000.0],
                 "image": {"file": str(tmp_path / "row.npy"), "pixel_spacing_m": 4.0, "speckle": False}})
    pts, amps = scene_points(one)
    assert np.allclose(pts, [[20.0, 1000.0]], atol=1e-9) and np.allclose(amps, [1.0])
    behind = _tiny({"kind": "image", "center_m": [0.0, -1000.0],
                    "image": {"file": str(tmp_path / "row.npy"), "pixel_spacing_m": 4.0}})
    with caplog.at_level(logging.WARNING):
        _, stats = simulate_scenario(behind)
    assert stats.n_pairs_kept == 0
    said = [r.getMessage() for r in caplog.records
            if "no pixel of the image scene is ever in the beam" in r.getMessage()]
    assert len(said) == 1 and "zeros (no noise), which process refuses" in said[0], said   # (noise off here)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        simulate_scenario(one)
    assert not any("never in the beam" in r.getMessage() for r in caplog.records)
    np.save(tmp_path / "stack.npy", np.ones((2, 5, 5)))
    bad = _merge(TINY, {"scene": {"kind": "image", "image": {"file": str(tmp_path / "stack.npy")}}})
    path = tmp_path / "scn.yaml"
    path.write_text(yaml.safe_dump(bad), encoding="utf-8")
    code, out, err = run_cli(["validate", path], capsys)       # a stack of two maps: refused, its own shape
    assert code == 2 and "image of shape (2, 5, 5)" in err, err


def test_power_intensity_threshold_and_png(tmp_path):
    from PIL import Image

    arr = np.zeros((4, 4), np.uint8)
    arr[1, 1], arr[2, 3], arr[3, 0] = 255, 64, 16
    Image.fromarray(arr, mode="L").save(tmp_path / "m.png")
    scn = _tiny({"kind": "image", "image": {"file": str(tmp_path / "m.png"), "intensity": "power",
                                             "threshold": 0.4, "speckle": False}})
    pts, amps = scene_points(scn)
    # power 255 -> amplitude 1; 64 -> sqrt(64/255) = 0.501 (kept); 16 -> 0.25 (dropped)
    assert np.allclose(np.sort(np.abs(amps)), [np.sqrt(64 / 255), 1.0])


def test_procedural_edges_lie_on_their_lines():
    """Each edge ridge's power centroid across the edge is on its true line (sub-pixel)."""
    amp, edges = make_road_scene(60, 200, 3.0, 0)
    ny = amp.shape[0]
    v = ((ny - 1) / 2.0 - np.arange(ny)) * 3.0
    col = amp[:, 30] ** 2                        # u = +1.5 m: road_a flat, road_b tilted
    for name, v0, ang in edges:
        v_line = v0 + 1.5 * np.tan(np.radians(ang))
        near = np.abs(v - v_line) < 3.0
        centroid = np.sum(v[near] * col[near]) / np.sum(col[near])
        assert abs(centroid - v_line) < 0.75, name   # quarter pixel: the field on one side biases it


def _scenario_file(tmp_path, image):
    raw = _merge(TINY, {"scene": {"kind": "image", "image": image}})
    path = tmp_path / "scn.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


@pytest.mark.parametrize("case", ["missing", "unreadable", "zero_size", "all_zero", "spacing", "spacing_zero",
                                  "extent", "h5_no_dataset", "no_file"])
def test_bad_image_exits_2_with_one_line(tmp_path, capsys, case):
    image, fragments = {"file": str(tmp_path / "m.npy")}, ["scene.image"]
    if case == "missing":
        fragments += ["not found", "m.npy"]
    elif case == "unreadable":
        (tmp_path / "m.png").write_bytes(b"not a png at all")
        image["file"], fragments = str(tmp_path / "m.png"), ["scene.image.file", "unreadable", "m.png"]
    elif case == "zero_size":
        np.save(tmp_path / "m.npy", np.zeros((0, 5)))
        fragments += ["shape (0, 5)", "non-empty 2-D"]
    elif case == "all_zero":
        np.save(tmp_path / "m.npy", np.zeros((3, 5)))
        fragments += ["every pixel is zero"]
    elif case in ("spacing", "spacing_zero"):
        np.save(tmp_path / "m.npy", np.ones((3, 5)))
        image["pixel_spacing_m"] = 1e6 if case == "spacing" else 0
        fragments = ["scene.image.pixel_spacing_m", "must be"]
    elif case == "extent":
        np.save(tmp_path / "m.npy", np.ones((3, 500)))
        image["pixel_spacing_m"] = 900.0
        fragments = ["scene.image.pixel_spacing_m", "450 km", "100 km"]
    elif case == "h5_no_dataset":
        import h5py

        with h5py.File(tmp_path / "m.h5", "w") as f:
            f["img"] = np.ones((3, 3))
        image["file"], fragments = f"{tmp_path / 'm.h5'}:/nope", ["scene.image.file", "no dataset", "nope"]
    elif case == "no_file":
        image = {}
        fragments = ["scene.image.file", "required"]
    path = _scenario_file(tmp_path, image)
    code, out, err = run_cli(["validate", path], capsys)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert str(path) in lines[0]
    for frag in fragments:
        assert frag in lines[0], (frag, lines[0])


def test_hdf5_and_tiff_read(tmp_path):
    import h5py
    from PIL import Image

    arr = np.arange(12, dtype=np.float32).reshape(3, 4)
    with h5py.File(tmp_path / "m.h5", "w") as f:
        f["g/refl"] = arr
    Image.fromarray(arr, mode="F").save(tmp_path / "m.tif")
    for spec in (f"{tmp_path / 'm.h5'}:/g/refl", str(tmp_path / "m.tif")):
        scn = _tiny({"kind": "image", "image": {"file": spec, "speckle": False}})
        pts, amps = scene_points(scn)
        assert len(pts) == 11 and np.isclose(np.max(np.abs(amps)), 1.0)
        assert np.allclose(np.sort(np.abs(amps)), np.arange(1, 12) / 11.0)


def test_the_road_scene_script_writes_the_procedural_map(tmp_path):
    """``scripts/make_road_scene.py`` (README, Extended scenes) writes the map ``procedural:roads``
    makes inside fwdlook: the .npy bit for bit, the PNG its 8-bit quantisation, the edges' lines as
    ``make_road_scene`` returns them.  Run as a user runs it, in a fresh interpreter."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from PIL import Image

    script = Path(__file__).resolve().parent.parent / "scripts" / "make_road_scene.py"
    done = subprocess.run([sys.executable, str(script), str(tmp_path), "--nx", "40", "--ny", "30",
                           "--spacing", "2.5", "--seed", "3"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    amp, edges = make_road_scene(40, 30, 2.5, 3)
    written = np.load(tmp_path / "road_scene.npy")
    assert written.dtype == amp.dtype and np.array_equal(written, amp)
    png = np.asarray(Image.open(tmp_path / "road_scene.png"))
    assert png.shape == (30, 40)
    assert np.array_equal(png, np.round(255 * amp / amp.max()).astype(np.uint8))
    truth = json.loads((tmp_path / "road_edges.json").read_text())
    assert truth["size_px"] == [40, 30] and truth["pixel_spacing_m"] == 2.5
    assert [(e["name"], e["v0_m"], e["angle_deg"]) for e in truth["edges"]] == [tuple(e) for e in edges]
