"""The bench's page probe (report/bench_pages.py): what it writes where, that it leaves nothing behind,
and the kernel settings it reports."""
from __future__ import annotations

import os

import numpy as np

from fwdlook_cli.report import bench_pages


def test_the_page_reporting_settings_are_the_writable_parameters_and_none_without_the_module(tmp_path):
    params = tmp_path / "parameters"
    params.mkdir()
    for name, text, mode in (("page_reporting_order", "9\n", 0o644), ("min_free_ms", "0\n", 0o644),
                             ("reported_kib", "123456\n", 0o444)):         # read-only: a counter
        (params / name).write_text(text)
        os.chmod(params / name, mode)
    assert bench_pages.page_reporting_settings(params) == "min_free_ms=0, page_reporting_order=9"
    assert bench_pages.page_reporting_settings(tmp_path / "absent") == "none"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert bench_pages.page_reporting_settings(empty) == "none"


def test_write_all_completes_a_write_the_kernel_takes_in_pieces(tmp_path, monkeypatch):
    real = os.pwrite
    calls = []

    def short(fd, data, offset):               # at most 1000 bytes a call, as a kernel may do
        calls.append(offset)
        return real(fd, bytes(memoryview(data)[:1000]), offset)

    monkeypatch.setattr(bench_pages.os, "pwrite", short)
    data = np.arange(5000, dtype=np.uint8)
    fd = os.open(tmp_path / "f", os.O_WRONLY | os.O_CREAT)
    try:
        bench_pages._write_all(fd, data)
    finally:
        os.close(fd)
    assert calls == [0, 1000, 2000, 3000, 4000]
    assert (tmp_path / "f").read_bytes() == data.tobytes()


def test_the_file_probe_writes_two_new_files_and_one_overwrite_and_leaves_nothing(tmp_path, monkeypatch):
    """``new_file`` and ``new_file_after_unlink`` write into empty files (every page new to the page
    cache), the first unlinked before the second; ``overwrite`` writes over the second's full length
    (every page already cached); the folder is left as it was."""
    real = bench_pages._write_all
    sizes_before = []

    def spy(fd, data, offset=0):
        sizes_before.append(os.fstat(fd).st_size)
        assert len(os.listdir(next(tmp_path.iterdir()))) == 1      # one file at a time
        real(fd, data, offset)

    monkeypatch.setattr(bench_pages, "_write_all", spy)
    got = bench_pages.file_write_ms_per_mib(mib=1, directory=tmp_path)
    assert set(got) == {"new_file", "new_file_after_unlink", "overwrite"}
    assert all(np.isfinite(v) and v > 0 for v in got.values())
    assert sizes_before == [0, 0, 1 << 20]
    assert list(tmp_path.iterdir()) == []


def test_the_bench_prints_the_page_probe_in_ms_per_mib(monkeypatch, capsys):
    import fwdlook_cli.report.bench as bench

    probe = {"anon_first_touch": 0.7, "new_file": 2.5, "new_file_after_unlink": 0.2, "overwrite": 0.1,
             "probe_mib": 32, "page_reporting": "min_free_ms=0, page_reporting_order=9"}
    monkeypatch.setattr(bench, "run_bench", lambda chain_repeats=3: {"fft2_s": 0.003, "page_cost": probe})
    bench.print_bench()
    lines = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert ["page_cost[anon_first_touch]", "0.70", "ms/MiB"] in lines
    assert ["page_cost[new_file]", "2.50", "ms/MiB"] in lines
    assert ["page_cost[page_reporting]", "min_free_ms=0,", "page_reporting_order=9"] in lines
    assert ["page_cost[probe_mib]", "32"] in lines
