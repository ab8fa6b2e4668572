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


def test_the_file_probe_writes_one_file_at_a_time_as_the_stage_files_are_written_and_leaves_nothing(
        tmp_path, monkeypatch):
    """``new_file_one_write`` first (its file unlinked before the next), then ``new_file`` through
    ``FailSafeSink`` into an empty file and ``overwrite`` over that file's full length (every page
    already cached); the folder is left as it was."""
    from fwdlook_cli.io.outputs import FailSafeSink

    seen = []

    class Spy(FailSafeSink):
        def write(self, buffer):
            seen.append((os.fstat(self._f.fileno()).st_size, self.tell(), sorted(os.listdir(self.path.parent))))
            return super().write(buffer)

    monkeypatch.setattr(bench_pages, "FailSafeSink", Spy)
    got = bench_pages.file_write_ms_per_mib(mib=1, directory=tmp_path)
    assert set(got) == {"new_file_one_write", "new_file", "overwrite"}
    assert all(np.isfinite(v) and v > 0 for v in got.values())
    assert seen == [(0, 0, ["pieces"]), (1 << 20, 0, ["pieces"])]
    assert list(tmp_path.iterdir()) == []


def test_the_bench_prints_the_page_probe_in_ms_per_mib(monkeypatch, capsys):
    import fwdlook_cli.report.bench as bench

    probe = {"anon_first_touch": 0.7, "new_file_one_write": 2.5, "new_file": 0.25, "overwrite": 0.1,
             "probe_mib": 32, "page_reporting": "min_free_ms=0, page_reporting_order=9"}
    monkeypatch.setattr(bench, "run_bench", lambda chain_repeats=3: {"fft2_s": 0.003, "page_cost": probe})
    bench.print_bench()
    lines = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert ["page_cost[anon_first_touch]", "0.70", "ms/MiB"] in lines
    assert ["page_cost[new_file_one_write]", "2.50", "ms/MiB"] in lines
    assert ["page_cost[page_reporting]", "min_free_ms=0,", "page_reporting_order=9"] in lines
    assert ["page_cost[probe_mib]", "32"] in lines
