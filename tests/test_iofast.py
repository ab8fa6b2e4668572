"""Issue 11, the I/O share: stage files of format 2 (one root declaration, byte-only digests, views
declaring their source's digest, no bytes hashed twice), the fast attribute writer, image.h5's sparse
gzip chunks, the memory-mapped stage reader, the fail-safe sink's piece writes, the cube hash and the
libyaml scenario dump.  Each fast path is compared with the straightforward one (h5py's own attribute
writes, HDF5's own deflate filter, a plain read, the pure-Python YAML emitter)."""
from __future__ import annotations

import glob
import json
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from fwdlook_cli.cli import main
from fwdlook_cli.io import integrity
from fwdlook_cli.io.h5 import GzipChunks, atomic_h5, deflate_rle, put_sparse_gzip, set_attrs
from fwdlook_cli.io.stagefile import load_verified, read_stage

ROOT = Path(__file__).resolve().parents[1]


def _run(argv):
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    assert info.value.code == 0


@pytest.fixture(scope="module")
def tiny_run(tiny_raw, tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("iofast") / "run"
    _run(["process", tiny_raw, "-o", run_dir, "-q"])
    return run_dir


# ----------------------------------------------------------------------------------------------
# attributes
# ----------------------------------------------------------------------------------------------
def test_fast_attributes_are_those_h5py_writes(tmp_path):
    values = {"text": "métre ünits", "empty": "", "f": 1.5, "f64": np.float64(2.25), "i": -3, "big": 2**62,
              "flag": True, "f32": np.float32(0.5), "list": [1, 2, 3], "bytes": b"raw"}
    with h5py.File(tmp_path / "a.h5", "w") as f:
        fast, slow = f.create_group("fast"), f.create_group("slow")
        set_attrs(fast, values)
        for k, v in values.items():
            slow.attrs[k] = v
        set_attrs(fast, {"text": "replaced"})            # an existing name is replaced, as by h5py
        slow.attrs["text"] = "replaced"
    with h5py.File(tmp_path / "a.h5", "r") as f:
        for k in values:
            a, b = f["fast"].attrs[k], f["slow"].attrs[k]
            assert type(a) is type(b) and np.array_equal(a, b), k
            ta, tb = f["fast"].attrs.get_id(k).get_type(), f["slow"].attrs.get_id(k).get_type()
            assert ta.equal(tb), k                       # the same HDF5 type (vlen UTF-8, float64, int64)


# ----------------------------------------------------------------------------------------------
# image.h5: sparse gzip chunks
# ----------------------------------------------------------------------------------------------
def _sparse(shape, fraction, seed):
    rng = np.random.default_rng(seed)
    a = rng.random(shape).astype(np.float32)
    a[rng.random(shape) > fraction] = 0.0
    return a


@pytest.mark.parametrize("shape, fraction, rows", [((1120, 834), 0.075, 16), ((37, 5), 0.3, 16),
                                                   ((40, 9), 0.0, 16), ((3, 7), 1.0, 1), ((33, 4), 0.5, 8)])
def test_sparse_gzip_reads_back_what_the_deflate_filter_stores(tmp_path, shape, fraction, rows):
    a = _sparse(shape, fraction, 1)
    if a.size > 10:
        a.reshape(-1)[5] = -0.0                             # a sign bit alone makes a chunk non-zero
        a.reshape(-1)[7] = np.nan
    with h5py.File(tmp_path / "a.h5", "w") as f:
        put_sparse_gzip(f, "sparse", a, "1", "x", rows_per_chunk=rows)
        put_sparse_gzip(f, "packed", GzipChunks(a, rows), "1", "x")
        f.create_dataset("filter", data=a, chunks=(min(rows, shape[0]), shape[1]), compression="gzip",
                         compression_opts=1)
    with h5py.File(tmp_path / "a.h5", "r") as f:
        for name in ("sparse", "packed"):
            b = f[name][()]
            assert b.dtype == a.dtype and b.shape == a.shape and b.tobytes() == a.tobytes(), name
            assert f[name].compression == "gzip" and f[name].compression_opts == 1
        assert f["sparse"][()].tobytes() == f["filter"][()].tobytes()
        n_chunks = f["sparse"].id.get_num_chunks()
    non_zero_chunks = sum(a.view(np.uint8).reshape(shape[0], -1)[i:i + rows].any() for i in range(0, shape[0], rows))
    assert n_chunks == non_zero_chunks


@pytest.mark.parametrize("fraction", [0.0, 0.075, 1.0])
def test_run_length_deflate_is_a_zlib_stream_of_the_same_bytes(fraction):
    """The run-length strategy's stream, read by zlib's own decoder (the one HDF5's deflate filter
    calls), gives back the chunk byte for byte; its header says zlib's 32 KiB window, as the default
    strategy's does."""
    block = _sparse((16, 834), fraction, 3).view(np.uint8).reshape(-1)
    for level in (1, 6):
        stream = deflate_rle(memoryview(block), level)
        assert zlib.decompress(stream) == block.tobytes()
        assert stream[:1] == zlib.compress(block.tobytes(), level)[:1]        # CMF: deflate, 32 KiB window


def test_image_h5_opens_in_xarray_with_named_axes(tiny_run):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    with xr.open_dataset(tiny_run / "image.h5", engine="h5netcdf") as img, \
            h5py.File(tiny_run / "stages" / "07_monopulse_image.h5", "r") as st:
        assert img["image"].dims == ("range_m", "angle_deg")
        np.testing.assert_array_equal(img["image"].values, st["image"][()])
        assert img["image"].attrs["units"] == "1"


# ----------------------------------------------------------------------------------------------
# stage files, format 2
# ----------------------------------------------------------------------------------------------
def _declaration(path):
    with h5py.File(path, "r") as f:
        return json.loads(f.attrs["stage_datasets"]), int(f.attrs["format_version"])


def test_every_dataset_is_declared_once_on_the_root_with_its_true_digest(tiny_run):
    for path in sorted((tiny_run / "stages").glob("*.h5")):
        decl, version = _declaration(path)
        assert version == integrity.STAGE_FORMAT_VERSION
        with h5py.File(path, "r") as f:
            assert sorted(decl) == sorted(k for k in f if isinstance(f[k], h5py.Dataset))
            for name, d in decl.items():
                data = f[name][()]
                assert d["dtype"] == data.dtype.str and d["shape"] == list(data.shape)
                assert d[integrity.DIGEST_ATTR] == integrity.digest(data), (path.name, name)
                assert not {integrity.DIGEST_ATTR, "shape", "dtype"} & set(f[name].attrs)   # nothing per dataset


def test_a_view_declares_its_source_digest(tiny_run):
    st = tiny_run / "stages"
    for view, source in (("02_decimate.h5", "01_range_fft.h5"), ("04_regroup.h5", "03_keystone.h5")):
        v, s = _declaration(st / view)[0], _declaration(st / source)[0]
        for ch in ("sum_f", "diff_f"):
            assert v[ch][integrity.DIGEST_ATTR] == s[ch][integrity.DIGEST_ATTR] and v[ch]["shape"] != s[ch]["shape"]


def test_a_view_over_a_damaged_source_is_not_reused(tiny_run, tiny_raw, tmp_path, capsys):
    import shutil

    run_dir = tmp_path / "run"
    shutil.copytree(tiny_run, run_dir)
    with h5py.File(run_dir / "stages" / "01_range_fft.h5", "r+") as f:
        a = f["sum_f"][()]
        a.view(np.uint8).reshape(-1)[a.nbytes // 3] ^= 0x01
        f["sum_f"][...] = a
    key = json.loads((run_dir / "metrics.json").read_text())["stage_sha256"]["decimate"]
    loaded, damage = load_verified(run_dir / "stages" / "02_decimate.h5", key)
    assert loaded is None and integrity.DIGEST_ATTR in damage   # the bytes read through the view fail too
    capsys.readouterr()
    _run(["process", tiny_raw, "-o", run_dir])
    err = capsys.readouterr().err
    assert "01_range_fft.h5 is damaged" in err and "[1/7] range_fft" in err
    assert (json.loads((run_dir / "metrics.json").read_text())["targets"]
            == json.loads((tiny_run / "metrics.json").read_text())["targets"])


def test_an_undeclared_dataset_makes_a_stage_damaged(tiny_run, tmp_path):
    import shutil

    path = tmp_path / "03.h5"
    shutil.copyfile(tiny_run / "stages" / "03_keystone.h5", path)
    key = json.loads((tiny_run / "metrics.json").read_text())["stage_sha256"]["keystone"]
    assert load_verified(path, key)[1] is None
    with h5py.File(path, "r+") as f:
        f["intruder"] = np.zeros(3)
    assert "not declared" in load_verified(path, key)[1]


def test_a_stage_file_of_format_1_is_never_trusted(tiny_run, tmp_path, monkeypatch):
    import shutil

    from fwdlook_cli import runner

    path = tmp_path / "03.h5"
    shutil.copyfile(tiny_run / "stages" / "03_keystone.h5", path)
    key = json.loads((tiny_run / "metrics.json").read_text())["stage_sha256"]["keystone"]
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = 1
    assert "format_version" in load_verified(path, key)[1]
    # and the key itself names the format: old files are stale, not reused
    new = runner.stage_key("keystone", {"a": 1}, "0" * 64)
    monkeypatch.setattr(runner, "STAGE_FORMAT_VERSION", 1)
    assert runner.stage_key("keystone", {"a": 1}, "0" * 64) != new


def test_no_bytes_are_hashed_twice_in_a_run(tiny_raw, tmp_path, monkeypatch):
    """Every digest of one fresh run is of a different (address, size, digest): unchanged context
    arrays keep their digest from stage to stage and the views' arrays are not hashed at all."""
    seen = []
    real = integrity.digest

    def counting(data):
        a = np.asarray(data)
        out = real(a)
        seen.append((a.__array_interface__["data"][0], a.nbytes, out))
        return out

    monkeypatch.setattr(integrity, "digest", counting)
    _run(["process", tiny_raw, "-o", tmp_path / "run", "-q"])
    assert len(seen) > 20
    assert len(set(seen)) == len(seen)
    n_declared = sum(len(_declaration(p)[0]) for p in (tmp_path / "run" / "stages").glob("*.h5"))
    assert len(seen) < 0.6 * n_declared                 # most datasets are passed on or viewed


def test_mapped_reader_gives_the_arrays_of_the_plain_reader(tiny_run):
    from fwdlook_cli.io.stageview import read_stage_mapped

    path = tiny_run / "stages" / "06_doppler_spectra.h5"
    a, b = read_stage(path), read_stage_mapped(path, min_bytes=1)
    assert a.attrs == b.attrs and sorted(a.vars) == sorted(b.vars)
    for name, var in a.vars.items():
        other = b.vars[name]
        assert (var.dims, var.units, var.long_name) == (other.dims, other.units, other.long_name)
        assert np.asarray(other.data).tobytes() == var.data.tobytes() and other.data.dtype == var.data.dtype
    assert isinstance(b["sum_z"], np.memmap)


# ----------------------------------------------------------------------------------------------
# fail-safe sink, cube hash, scenario YAML
# ----------------------------------------------------------------------------------------------
def test_sink_finishes_short_writes_in_pieces(tmp_path, monkeypatch):
    from fwdlook_cli.io import outputs

    calls = []

    class Short:
        def __init__(self, f):
            self.f = f

        def write(self, view):
            calls.append(len(view))
            return self.f.write(view[:100_000])           # the OS takes at most 100 kB per call

        def __getattr__(self, name):
            return getattr(self.f, name)

    real_init = outputs.FailSafeSink.__init__

    def init(self, path):
        real_init(self, path)
        self._f = Short(self._f)

    monkeypatch.setattr(outputs.FailSafeSink, "__init__", init)
    data = np.random.default_rng(0).standard_normal(600_000)   # 4.8 MB
    with atomic_h5(tmp_path / "a.h5") as f:
        f["x"] = data
    with h5py.File(tmp_path / "a.h5", "r") as f:
        assert f["x"][()].tobytes() == data.tobytes()
    assert max(calls) <= outputs.WRITE_PIECE_BYTES


def test_a_closed_sink_drops_what_hdf5_still_sends(tmp_path):
    """A file an interrupted command left open is closed by HDF5 at the interpreter's exit, through its
    sink closed long before (its partial file removed): nothing is written, nothing is raised."""
    from fwdlook_cli.io import outputs

    sink = outputs.FailSafeSink(tmp_path / "a.partial")
    sink.write(b"12345")
    sink.close()
    assert (sink.write(b"6789"), sink.seek(96), sink.tell(), sink.truncate(4096)) == (4, 96, 0, 4096)
    assert sink.readinto(bytearray(8)) == 0 and sink.error is None
    assert (tmp_path / "a.partial").read_bytes() == b"12345"


def test_cube_hash_sees_every_element_of_the_antenna_table(tiny_raw):
    from fwdlook_cli.io.cube import cube_hash
    from fwdlook_cli.io.raw import read_raw

    cube = read_raw(tiny_raw)
    cube.antenna = dict(cube.antenna, ratio=np.linspace(-1, 1, 4001), ratio_offset_deg=np.linspace(-3, 3, 4001))
    before = cube_hash(cube)
    table = cube.antenna["ratio"].copy()
    table[2000] += 1e-12                                   # the middle: str() of the array elides it
    cube.antenna = dict(cube.antenna, ratio=table)
    assert cube_hash(cube) != before
    assert cube_hash(cube) == cube_hash(cube)


def test_libyaml_dump_is_the_pure_python_dump():
    from fwdlook_cli.scenario.loader import dump_scenario, load_scenario

    paths = sorted(glob.glob(str(ROOT / "scenarios" / "*.yaml")))
    assert len(paths) >= 5
    for p in paths:
        scn = load_scenario(p)
        assert dump_scenario(scn) == yaml.safe_dump(scn, sort_keys=False, default_flow_style=None, width=100), p


# ----------------------------------------------------------------------------------------------
# the ground image's tail percentiles
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["normal", "ties", "sorted", "half-zero", "constant-bulk", "nan", "inf", "small"])
def test_tail_percentiles_are_numpys_bit_for_bit(kind):
    from fwdlook_cli.forward.process import tail_percentiles

    rng = np.random.default_rng(7)
    for trial in range(40):
        n = int(rng.integers(10, 300)) if kind == "small" else int(rng.integers(4096, 200_000))
        x = rng.standard_normal(n) * 300
        if kind == "ties":
            x = np.round(x / 50) * 50
        elif kind == "sorted":
            x = np.sort(x)
        elif kind == "half-zero":
            x[rng.random(n) < 0.5] = 0.0
        elif kind == "constant-bulk":
            x[n // 50:] = 1700.0
        elif kind in ("nan", "inf"):
            x[int(rng.integers(n))] = np.nan if kind == "nan" else -np.inf
        x32 = x.astype(np.float32)          # float32 (the cells' positions): its float64 values' percentiles
        for q in ((0.1, 99.9), (0.0, 100.0), (2.5, 97.5)):
            with np.errstate(invalid="ignore"):           # numpy's own lerp of -inf
                want, got = np.percentile(x, list(q)), tail_percentiles(x, *q)
                want32, got32 = np.percentile(x32.astype(np.float64), list(q)), tail_percentiles(x32, *q)
            assert got.tobytes() == want.tobytes(), (kind, n, q)
            assert got32.dtype == np.float64 and got32.tobytes() == want32.tobytes(), (kind, n, q, "float32")


def test_worker_pool_works_in_a_forked_child(tmp_path):
    import os

    from fwdlook_cli.io.h5 import worker_pool

    assert worker_pool().submit(lambda: 1).result(timeout=10) == 1     # the parent's pool exists
    pid = os.fork()
    if pid == 0:                                                       # child: a pool of its own
        try:
            ok = worker_pool().submit(lambda: 2).result(timeout=10) == 2
        except Exception:  # noqa: BLE001
            ok = False
        os._exit(0 if ok else 1)
    _, status = os.waitpid(pid, 0)
    assert os.WEXITSTATUS(status) == 0


def test_metrics_json_text_is_the_indented_dump_read_back_one_target_a_line(tiny_run):
    """``io.h5.json_text`` (metrics.json through the C encoder): ``json.loads`` gives the object back;
    each target record is one line; NaN is refused as before."""
    from fwdlook_cli.io.h5 import json_text

    text = (tiny_run / "metrics.json").read_text()
    metrics = json.loads(text)
    assert json.loads(json_text(metrics)) == metrics
    target_lines = [ln for ln in text.splitlines() if ln.lstrip().startswith('{"id":')]
    assert len(target_lines) == len(metrics["targets"]) > 0
    assert json.loads(target_lines[0].strip().rstrip(",")) == metrics["targets"][0]
    nested = {"a": {"b": [1, {"c": None}]}, "rows": [{"x": 1.5}, {"x": -2}], "empty": {}, "none": []}
    assert json.loads(json_text(nested)) == nested
    with pytest.raises(ValueError):
        json_text({"targets": [{"x": float("nan")}]})
