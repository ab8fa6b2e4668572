"""The chain's floor, measured: the transforms every stage must do and the bytes the stage files must
hold, timed alone in the bench's process on arrays of the chain's own shapes (``fwdlook bench``,
keys ``floor_<method>_*``).

What the chain cannot avoid, for the paper cube (both channels, complex64), stage by stage:

* ``range_fft``: one FFT over range of every pulse (eq. 6).
* ``keystone``: the CZT (Bluestein) keystone per column and channel: one slow-time FFT of length P and an
  FFT and inverse FFT of length L = next_fast_len(2P - 1), plus the filter spectrum of the plan (one
  length-L FFT per distinct alpha).  ``decimation``: P = M/Q for Q x n_r columns; ``tracking``:
  P = M for n_r columns.
* ``range_curvature``: the inverse FFT over range back to range time.
* ``doppler_spectra``: the zoom DFT, one (n_doppler x cpi) by (cpi x n_r) product per CPI and channel, the
  two channels side by side as the stage runs them (``dsp.blas.batched_matmul_each``).
* ``monopulse_image``: band-limited range oversampling of both channels, one FFT of n_r and one inverse
  FFT of n_r x range_oversample per Doppler row, fused row by row as the stage runs them
  (``dsp.peaks.oversample_range``; at 20 dB SNR nearly every row can hold a cell: ``dsp.imaging``).
* stage files: each written stage's bytes copied to the page cache once, into a new file as a run
  writes them (``io.outputs.FailSafeSink``), and hashed once (XXH3-128, the integrity digest: ``io.integrity``); the outputs the resume guarantee needs.

Nothing here is a model: each figure is a median of repeated timings of exactly these calls.  The
ratio ``chain / floor`` says how far the chain is from what its algorithm and its guarantees cost.
"""
from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.fft

from ..dsp.blas import batched_matmul_each
from ..dsp.peaks import oversample_range
from ..io.integrity import digest
from ..io.outputs import FailSafeSink
from .benchtools import median_time as _median_s


def _noise(shape, rng):
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)


def _bluestein_s(x, n_alpha, rng, repeats):
    """The three FFTs of the CZT on every column of x [P, cols], and the plan's filter FFT (one column
    per distinct alpha)."""
    p, cols = x.shape
    L = scipy.fft.next_fast_len(2 * p - 1)
    buf = np.zeros((L, cols), np.complex64)
    filt = _noise((L, n_alpha), rng)

    def run():
        scipy.fft.fft(x, axis=0, workers=-1)
        b = scipy.fft.fft(buf, axis=0, workers=-1)
        scipy.fft.ifft(b, axis=0, workers=-1, overwrite_x=True)

    return _median_s(run, repeats), _median_s(lambda: scipy.fft.fft(filt, axis=0, workers=-1), repeats)


def _stage_bytes_s(n_bytes: int, repeats: int) -> float:
    """Write n_bytes to a new file in the system temporary directory as the stage files are written (a
    file of its own each time, in ``FailSafeSink``'s pieces: io/outputs.py) and digest them once
    (io.integrity); each file is removed after its timing.  (Rewriting one path, as this did until the
    twenty-third round, times ext4's truncation of the file before it: 7.5-8.6 against 2.3-2.5 ms for
    11 MB here, three times what a run's new stage file costs.)"""
    buf = np.zeros(n_bytes // 8, np.complex64)
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(max(1, repeats)):
            path = Path(tmp) / f"floor{i}.bin"
            t0 = time.perf_counter()
            sink = FailSafeSink(path)
            sink.write(buf)
            sink.close()
            digest(buf)
            times.append(time.perf_counter() - t0)
            if sink.error is not None:
                raise sink.error
            path.unlink()
    return statistics.median(times)


def chain_floor(n_pulses: int, n_range: int, *, method: str, q: int = 1, cpi: int = 32, n_doppler: int = 64,
                range_oversample: int = 4, repeats: int = 7, seed: int = 0) -> dict:
    """Seconds per floor item for one chain (both channels), and their total (``total_s``)."""
    rng = np.random.default_rng(seed)
    cube = _noise((n_pulses, n_range), rng)
    out = {}
    out["range_fft_s"] = 2 * _median_s(lambda: scipy.fft.fft(cube, axis=1, workers=-1), repeats)
    cols_q = q if method == "decimation" else 1
    p = n_pulses // cols_q
    ks, filt = _bluestein_s(np.ascontiguousarray(cube[: p * cols_q].reshape(p, cols_q * n_range)), n_range,
                            rng, repeats)
    out["keystone_s"] = 2 * ks + filt
    out["range_curvature_s"] = 2 * _median_s(lambda: scipy.fft.ifft(cube, axis=1, workers=-1), repeats)
    n_cpi = n_pulses // cpi
    e = _noise((n_cpi, n_doppler, cpi), rng)
    x = cube[: n_cpi * cpi].reshape(n_cpi, cpi, n_range)
    out["doppler_spectra_s"] = _median_s(lambda: batched_matmul_each(e, (x, x)), repeats)
    rows = _noise((n_cpi * n_doppler, n_range), rng)
    # the range oversampling as the image stage runs it (fused: dsp.peaks.oversample_range)
    out["monopulse_image_s"] = 2 * _median_s(lambda: oversample_range(rows, range_oversample), repeats)
    cube_bytes = 2 * cube.nbytes
    spectra_bytes = 2 * n_cpi * n_doppler * n_range * 8
    # written stages: range_fft, keystone, range_curvature (cubes), doppler_spectra (spectra);
    # decimate and regroup are views (io.stageview)
    out["stage_files_s"] = 3 * _stage_bytes_s(cube_bytes, repeats) + _stage_bytes_s(spectra_bytes, repeats)
    out["total_s"] = float(sum(out.values()))
    return out
