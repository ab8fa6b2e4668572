"""The joint fit's fast path (forward/dwell_fit.py): the axis-relative phases in float32 against the
float64 paths, the incremental Gram matrices against A^H A, the decimation filter's passband and its
equality with scipy.signal's, the fit on decimated slow time against the fit at the PRF and the truth,
the extended-scene guard, the fit's resolution flags, and its clusters on worker threads or forked
processes (dsp/forked.py: the same results as in one process, the fallbacks, errors and cancel)."""
import os

import numpy as np
import pytest
from scipy.signal import freqz

from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.forward import dwell_fit as F
from fwdlook_cli.forward import dwell_fit_plan as FP
from fwdlook_cli.forward.dwell_resolution import fit_resolved_flags

FC_HZ, PRF_HZ, SPEED_MPS, HEIGHT_M = 18e9, 2500.0, 240.0, 50.0
SLOPE, BETA = 0.147, 0.049           # the paper antenna's calibrated slope (1/deg) and pattern beta (1/deg^2)


def _flight(accel_mps2=0.0, scan_deg=(-10.0, 10.0), rate_dps=30.0):
    """Straight flight along +y from y = 0, uniformly accelerated, the beam scanning at ``rate_dps``."""
    n = int(round((scan_deg[1] - scan_deg[0]) / rate_dps * PRF_HZ))
    t = np.arange(n) / PRF_HZ
    y = SPEED_MPS * t + 0.5 * accel_mps2 * t**2
    pos = np.stack([np.zeros(n), y, np.full(n, HEIGHT_M)], axis=1)
    beam = scan_deg[0] + rate_dps * t
    return pos, beam, pos[n // 2]


def _model(pos, beam, p_ref, **kw):
    return F.FitModel(position_m=pos, scan_angle_deg=beam, fc_hz=FC_HZ, slope_per_deg=SLOPE, beta_per_deg2=BETA,
                      position_ref_m=p_ref, **kw)


def test_baseband_phases_in_float32_match_the_float64_paths():
    """exp(-j 4 pi (R(theta) - R(axis)) / lambda) from the float32 difference formula against the two
    float64 path lengths subtracted: within 1e-3 rad over +-11 deg, 1700 m."""
    pos, beam, p_ref = _flight(accel_mps2=50.0)
    base = _model(pos, beam, p_ref, axis_relative_deg=0.0)
    plain = _model(pos, beam, p_ref)
    theta = np.array([[-11.2, -1.1, 0.0], [0.4, 1.1, 11.2]])
    ranges = np.array([[1650.0, 1700.0], [1703.0, 1760.0]])
    got = base.paired_phases(theta, ranges)                                     # [M, N, J, P]
    lam = C_MPS / FC_HZ
    for m in range(2):
        for j in range(2):
            d_path = plain.path(theta[j], [ranges[m, j]])[0] - plain.path([0.0], [ranges[m, j]])[0]   # [N, P]
            want = np.exp(-1j * 4 * np.pi * d_path / lam)
            err = np.angle(got[m, :, j, :] * np.conj(want))
            assert np.max(np.abs(err)) < 1e-3
    # the plain phases keep the slant range r_b: exp(-j 4 pi (R - r_b) / lambda)
    ph = plain.phases([1.1], [1700.0])[:, :, 0]
    want = np.exp(-4j * np.pi * (plain.path([1.1], [1700.0])[0, :, 0] - 1700.0) / lam)
    assert np.max(np.abs(np.angle(ph[0] * np.conj(want)))) < 1e-3


def test_active_set_gram_updates_equal_a_h_a():
    """Atoms added and then replaced one column block at a time: the Gram matrices and right-hand sides
    equal A^H A and A^H y formed directly, and the amplitudes equal numpy's least squares."""
    rng = np.random.default_rng(3)
    n_b, n_2, k = 3, 200, 20                  # past the first allocation (16 atoms): the storage grows

    def rand(*shape):
        return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)

    y = rand(n_b, n_2)
    act = F._ActiveSet(y, max_atoms=40)
    atoms = rand(n_b, n_2, k)
    for i in range(k):
        act.set([i], atoms[:, :, i:i + 1])
    atoms[:, :, [1, 3]] = rand(n_b, n_2, 2)
    act.set([1, 3], atoms[:, :, [1, 3]])
    a = atoms.astype(np.complex128)
    gram = np.conj(np.swapaxes(a, 1, 2)) @ a
    assert np.allclose(act.gram[:, :k, :k], gram, rtol=1e-5, atol=1e-3)
    assert np.allclose(act.rhs[:, :k], np.einsum("bnk,bn->bk", np.conj(a), y), rtol=1e-5, atol=1e-3)
    c = act.solve()
    for b in range(n_b):
        want = np.linalg.lstsq(a[b], y[b].astype(np.complex128), rcond=None)[0]
        assert np.allclose(c[b], want, rtol=1e-4, atol=1e-5)
    assert np.allclose(act.model(), np.einsum("bnk,bk->bn", a, c), atol=1e-4)


def test_decimation_filter_passes_the_regions_atoms_and_stops_the_rest():
    """The plan fit_region makes: the band of the region's directions (4.8 deg + BAND_GUARD_DEG, 0 to
    about -200 Hz relative to the axis at a = 50) decimates by 10.  Its filter is within 2e-4 of 1 over
    the passband the region's atoms occupy (DECIMATION_PASSBAND of the decimated Nyquist band) and
    under 1e-3 (-60 dB) from where the next band's images would fold onto it; a direction whose
    baseband offsets all lie beyond the stop edge (9.6 deg: -390 to -510 Hz) is suppressed by 60 dB
    over the whole window, so the dictionary need not hold it (the paper's +-11.2 deg dictionary at
    the PRF's rate would allow only Q = 3)."""
    pos, beam, p_ref = _flight(50.0)
    win = np.flatnonzero(np.abs(beam) <= 8.0)
    model = _model(pos[win], beam[win], p_ref)
    grid = np.arange(-11.2, 11.25, 0.05)
    assert F.decimation_plan(model, grid, 1700.0, 0.0, PRF_HZ)[0] == 3
    band = grid[np.abs(grid) <= 4.8 + F.BAND_GUARD_DEG]
    q, shift_hz, taps = F.decimation_plan(model, band, 1700.0, 0.0, PRF_HZ)
    assert q == 10 and -110.0 < shift_hz < -70.0
    cut = PRF_HZ / (2 * q)
    f_pass = np.linspace(0.0, FP.DECIMATION_PASSBAND * cut, 400)
    f_stop = np.linspace((2.0 - FP.DECIMATION_PASSBAND) * cut, PRF_HZ / 2, 800)
    _, h_pass = freqz(taps, worN=f_pass, fs=PRF_HZ)
    _, h_stop = freqz(taps, worN=f_stop, fs=PRF_HZ)
    assert np.max(np.abs(np.abs(h_pass) - 1.0)) < 2e-4
    assert np.max(np.abs(h_stop)) < 1e-3
    lam = C_MPS / FC_HZ
    f_far = -2.0 / lam * np.diff(model.path([9.6], [1700.0])[0, :, 0] - model.path([0.0], [1700.0])[0, :, 0]) * PRF_HZ
    _, h_far = freqz(taps, worN=np.abs(f_far - shift_hz), fs=PRF_HZ)
    assert np.max(np.abs(h_far)) < 1e-3


def _cluster_data(pos, beam, p_ref, targets, n_r=40, r0=1650.0, dr=3.0, amp=10.0, seed=0):
    """Sum and difference channels [N, n_r] of point scatterers (cell, theta) from the fit's own model
    at the PRF, plus unit complex noise in both channels."""
    rng = np.random.default_rng(seed)
    range_m = r0 + dr * np.arange(n_r)
    gen = _model(pos, beam, p_ref)
    n = len(beam)
    s = (rng.standard_normal((n, n_r)) + 1j * rng.standard_normal((n, n_r))) / np.sqrt(2)
    d = (rng.standard_normal((n, n_r)) + 1j * rng.standard_normal((n, n_r))) / np.sqrt(2)
    for cell, theta in targets:
        a = gen.atoms([theta], [range_m[cell]])[0, :, 0]
        s[:, cell] += amp * a[:n]
        d[:, cell] += amp * a[n:]
    return s.astype(np.complex64), d.astype(np.complex64), range_m


def _angle_crb_deg(pos, beam, p_ref, thetas, range_m, amp, half_deg=8.0, h_deg=1e-4):
    """Deterministic CRB of the angles of point scatterers sharing one range cell, unit complex noise per
    sample and channel: (1/2) Re(D^H P_A^perp D)^-1, D = [c_k da/dtheta_k] over the window's pulses."""
    win = np.flatnonzero(np.abs(beam) <= half_deg)
    model = _model(pos[win], beam[win], p_ref)
    th = np.asarray(thetas, dtype=np.float64)
    a = model.atoms(th, [range_m])[0].astype(np.complex128)
    d = amp * (model.atoms(th + h_deg, [range_m])[0] - model.atoms(th - h_deg, [range_m])[0]).astype(np.complex128)
    d /= 2 * h_deg
    q, _ = np.linalg.qr(a)
    d_perp = d - q @ (q.conj().T @ d)
    return np.sqrt(np.diag(np.linalg.inv(2.0 * np.real(d_perp.conj().T @ d_perp))))


@pytest.mark.parametrize("accel_mps2", [0.0, 50.0])
def test_fit_on_decimated_slow_time_matches_the_prf_fit_and_the_crb(accel_mps2):
    """A mirror pair +-1.1 deg in one range cell, a point on the axis and one at 2.5 deg: fitted on the
    decimated baseband (Q = 10-11) and at the PRF, every point within 4 standard deviations of its angle
    CRB (0.0004-0.012 deg: the point on the axis has only the pattern to place it, its phase history
    being even in theta) and the two fits within 1 (the filter removes only noise the atoms are
    orthogonal to); amplitudes within 5 %; no spurious atom in the region."""
    pos, beam, p_ref = _flight(accel_mps2)
    truth = [(18, -1.1), (18, 1.1), (20, 0.0), (22, 2.5)]
    s, d, range_m = _cluster_data(pos, beam, p_ref, truth)
    crb = {}
    for cell in {c for c, _ in truth}:
        angles = [t for c, t in truth if c == cell]
        crb.update(zip(angles, _angle_crb_deg(pos, beam, p_ref, angles, range_m[cell], 10.0)))
    profile = np.max(np.abs(s) ** 2, axis=0)
    kw = dict(scan_angle_deg=beam, position_m=pos, range_m=range_m, profile=profile, level=30.0, axis_deg=0.0,
              half_width_deg=4.8, dwell_half_width_deg=3.2, angle_step_deg=0.05, fc_hz=FC_HZ, prf_hz=PRF_HZ,
              slope_per_deg=SLOPE, beta_per_deg2=BETA, position_ref_m=p_ref)
    fits = []
    for decimate in (True, False):
        theta, prof, covered = F.fit_region(s, d, decimate=decimate, **kw)
        assert covered[[18, 20, 22]].all()
        assert len(theta) == len(truth)
        fits.append((theta, prof))
    for cell, theta_true in truth:
        got = []
        for theta, prof in fits:
            i = int(np.argmin(np.abs(theta - theta_true) + 1e3 * (np.abs(prof[:, cell]) < 1.0)))
            assert abs(theta[i] - theta_true) <= 4.0 * crb[theta_true]
            assert abs(abs(prof[i, cell]) - 10.0) <= 0.5
            got.append(theta[i])
        assert abs(got[0] - got[1]) <= crb[theta_true]


def test_an_extended_cluster_is_left_to_the_dwell_image():
    """More than MAX_CLUSTER_CELLS contiguous hot range cells: not point-like, not fitted (nothing
    returned, no cell marked fitted), and at no cost."""
    pos, beam, p_ref = _flight()
    n_r = F.MAX_CLUSTER_CELLS + 20
    s, d, range_m = _cluster_data(pos, beam, p_ref, [], n_r=n_r)
    profile = np.ones(n_r)
    profile[5:5 + F.MAX_CLUSTER_CELLS + 5] = 100.0
    theta, prof, covered = F.fit_region(
        s, d, scan_angle_deg=beam, position_m=pos, range_m=range_m, profile=profile, level=10.0, axis_deg=0.0,
        half_width_deg=4.8, dwell_half_width_deg=3.2, angle_step_deg=0.05, fc_hz=FC_HZ, prf_hz=PRF_HZ,
        slope_per_deg=SLOPE, beta_per_deg2=BETA, position_ref_m=p_ref)
    assert len(theta) == 0 and prof.shape == (0, n_r) and not covered.any()


def test_fit_resolution_flags_follow_the_atoms_correlation():
    """Mirror twins +-theta share their phase history: only the pattern parts them, so the pair at
    +-0.3 deg (correlation over 0.9) is unresolved and the pair at +-1.1 deg (about 0.8) resolved; a
    lone point and a neighbour beyond one range resolution are resolved; a point outside the region is
    reported outside."""
    pos, beam, p_ref = _flight()
    kw = dict(position_m=pos, scan_angle_deg=beam, axis_deg=0.0, half_width_deg=4.8, dwell_half_width_deg=3.2,
              fc_hz=FC_HZ, slope_per_deg=SLOPE, beta_per_deg2=BETA, position_ref_m=p_ref, range_resolution_m=3.0)
    rng = [1700.0, 1700.0, 1750.0, 1750.0, 1800.0, 1806.0, 1700.0]
    az = [-0.3, 0.3, -1.1, 1.1, 2.0, 2.0, 7.0]
    inside, resolved = fit_resolved_flags(rng, az, **kw)
    assert list(inside) == [True] * 6 + [False]
    assert list(resolved[:6]) == [False, False, True, True, True, True]


def test_the_fit_runs_only_for_the_antenna_it_models(caplog):
    """The fit's weights are two Gaussian beams: a gaussian2 cube is fitted; sinc2, a table or a cube
    without /antenna is not (the dwell image alone), and the log says why."""
    from types import SimpleNamespace

    from fwdlook_cli.forward.dwell import fit_models_antenna

    assert fit_models_antenna(SimpleNamespace(antenna={"pattern": "gaussian2", "beta_per_deg2": 0.05}))
    for antenna in ({"pattern": "sinc2"}, {"pattern": "table"}, None):
        assert not fit_models_antenna(SimpleNamespace(antenna=antenna))
    assert "dwell_fit" in caplog.text and "sinc2" in caplog.text


def test_clusters_on_forked_workers_return_what_one_process_computes():
    """dsp.forked.map_jobs: the same results, in the jobs' order, on forked processes (a closure over data
    they inherit), on threads (where a process may not fork, or the system refuses one) and serially;
    a worker's exception reaches the caller."""
    import multiprocessing

    from fwdlook_cli.dsp.forked import map_jobs

    rng = np.random.default_rng(3)
    data = [rng.standard_normal((40, 64)) + 1j * rng.standard_normal((40, 64)) for _ in range(5)]

    def fit_one(job):                        # a closure: forked workers inherit it, nothing is pickled in
        return np.linalg.svd(data[job], compute_uv=False), job

    serial = map_jobs(fit_one, list(range(5)), 1)
    forked = map_jobs(fit_one, list(range(5)), 3, processes=True)
    for (s_a, j_a), (s_b, j_b) in zip(serial, forked):
        assert j_a == j_b and np.array_equal(s_a, s_b)
    on_threads = map_jobs(fit_one, list(range(5)), 3)               # the default
    assert all(a[1] == b[1] and np.array_equal(a[0], b[0]) for a, b in zip(serial, on_threads))
    proc = multiprocessing.current_process()
    daemon, proc.daemon = proc.daemon, True         # as in a daemonic worker: threads, same results
    try:
        threaded = map_jobs(fit_one, list(range(5)), 2, processes=True)
    finally:
        proc.daemon = daemon
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(serial, threaded))

    import fwdlook_cli.dsp.forked as forked

    def refused(*args, **kwargs):              # a system that refuses the processes: threads, same results
        raise OSError("fork refused")

    real_fork, forked._fork = forked._fork, refused
    try:
        fallback = map_jobs(fit_one, list(range(5)), 2, processes=True)
    finally:
        forked._fork = real_fork
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(serial, fallback))

    calls = []

    def second_refused():                     # the second fork refused: the first child killed, threads
        calls.append(1)
        if len(calls) > 1:
            raise OSError("fork refused")
        return real_fork()

    forked._fork = second_refused
    try:
        fallback = map_jobs(fit_one, list(range(5)), 3, processes=True)
    finally:
        forked._fork = real_fork
    assert len(calls) == 2 and all(np.array_equal(a[0], b[0]) for a, b in zip(serial, fallback))

    def no_fork():
        raise AssertionError("forked although the jobs' indices would not fit the pipe's buffer")

    real_max, forked._fork, forked.MAX_FORKED_JOBS = forked.MAX_FORKED_JOBS, no_fork, 3
    try:                                      # more jobs than the task pipe holds: threads, same results
        over = map_jobs(fit_one, list(range(5)), 2, processes=True)
    finally:
        forked._fork, forked.MAX_FORKED_JOBS = real_fork, real_max
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(serial, over))
    assert forked.MAX_FORKED_JOBS * 4 <= 4096  # a page: the smallest buffer a pipe has
    with pytest.raises(ChildProcessError):    # and reaped: no child of this process is left
        os.waitpid(-1, os.WNOHANG)

    def fails(job):
        raise ValueError(f"job {job}")

    for processes in (False, True):
        with pytest.raises(ValueError, match="job 0"):
            map_jobs(fails, [0, 1], 2, processes=processes)

    def dies(job):                             # a worker killed (the OOM killer, a signal): an error, not a hang
        if job == 1:
            os._exit(3)
        return job

    if forked._fork is not None:               # (on threads, os._exit would end the test run itself)
        with pytest.raises(RuntimeError, match="without a result"):
            map_jobs(dies, [0, 1, 2], 3, processes=True)
    many = map_jobs(lambda job: job * job, list(range(40)), 3, processes=True)   # more jobs than workers
    assert many == [j * j for j in range(40)]

    def forks_again(job):                      # a job that forks jobs of its own (the parent's lock is not held)
        return sum(map_jobs(lambda k: k + 1, list(range(job + 2)), 2, processes=True))

    import signal

    def hung(*args):
        raise TimeoutError("a job's own forks hung")

    previous = signal.signal(signal.SIGALRM, hung)   # a child stuck on the parent's lock: fail, not hang
    signal.alarm(60)
    try:
        assert map_jobs(forks_again, list(range(4)), 2, processes=True) == [3, 6, 10, 15]
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_the_filter_and_its_convolution_are_scipy_signals():
    """dsp.fir.kaiser_lowpass is scipy.signal.firwin's Kaiser low-pass and filter_same its fftconvolve
    (mode "same"), to rounding (scipy.signal is not imported by the chain: over a second)."""
    from scipy.signal import fftconvolve, firwin

    from fwdlook_cli.dsp.fir import filter_same, kaiser_lowpass

    for n_taps, cut, fs in ((401, 125.0, 2500.0), (81, 300.0, 2000.0)):
        np.testing.assert_allclose(kaiser_lowpass(n_taps, cut, fs),
                                   firwin(n_taps, cut, window=("kaiser", 8.0), fs=fs), rtol=0, atol=1e-15)
    rng = np.random.default_rng(5)
    x = (rng.standard_normal((3, 700)) + 1j * rng.standard_normal((3, 700))).astype(np.complex64)
    taps = kaiser_lowpass(401, 125.0, 2500.0)
    want = fftconvolve(x.astype(np.complex128), taps[None, :], mode="same", axes=1)
    np.testing.assert_allclose(filter_same(x, taps), want, rtol=0, atol=1e-12 * np.abs(want).max())


def _two_clusters():
    """Two clusters of two points each (range cells 8 and 30) for fit_region: (s, d, truth, kwargs)."""
    pos, beam, p_ref = _flight(50.0)
    truth = [(8, -1.1), (8, 1.1), (30, 0.4), (30, 2.5)]
    s, d, range_m = _cluster_data(pos, beam, p_ref, truth, seed=2)
    kw = dict(scan_angle_deg=beam, position_m=pos, range_m=range_m, profile=np.max(np.abs(s) ** 2, axis=0),
              level=30.0, axis_deg=0.0, half_width_deg=4.8, dwell_half_width_deg=3.2, angle_step_deg=0.05,
              fc_hz=FC_HZ, prf_hz=PRF_HZ, slope_per_deg=SLOPE, beta_per_deg2=BETA, position_ref_m=p_ref)
    return s, d, truth, kw


def test_the_fit_on_forked_workers_is_the_fit_in_one_process(monkeypatch):
    """fit_region with its clusters on forked workers (two clusters, two cores) gives bit for bit the
    angles and amplitudes it gives in one process: each worker runs the same code on the same data."""
    s, d, truth, kw = _two_clusters()
    fits = []
    for workers in (1, 2):
        monkeypatch.setattr(F, "worker_threads", lambda workers=workers: workers)
        fits.append(F.fit_region(s, d, **kw))
    (th1, prof1, cov1), (th2, prof2, cov2) = fits
    assert len(F.range_clusters(kw["profile"], kw["level"])) == 2 and len(th1) == len(truth)
    assert np.array_equal(th1, th2) and np.array_equal(prof1, prof2) and np.array_equal(cov1, cov2)
    if hasattr(os, "fork"):     # the workers forked by the spawner (dsp/spawner.py): the jobs pickle, the same
        from fwdlook_cli.dsp import forked, spawner

        def refused(*args, **kwargs):
            raise AssertionError("the caller forked the fit's workers itself")

        assert spawner.start() is not None
        monkeypatch.setattr(forked, "_fork", refused)
        th3, prof3, cov3 = F.fit_region(s, d, **kw)
        assert np.array_equal(th1, th3) and np.array_equal(prof1, prof3) and np.array_equal(cov1, cov3)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_the_clusters_are_prepared_on_the_workers(monkeypatch, tmp_path):
    """With forked workers the clusters' data and coarse dictionaries are made on the workers, beside
    one another, not in the calling process before they start (issue 11: the fit starts sooner): the
    caller builds no dictionary and no cluster's atoms (only the grid step's probe, two atoms a call:
    ``fit_angle_step``, 0.3 ms), the workers build them, and the fit is the one-process fit."""
    s, d, _, kw = _two_clusters()
    monkeypatch.setattr(F, "worker_threads", lambda: 1)
    one = F.fit_region(s, d, **kw)                                  # in this process
    log, real = tmp_path / "atoms_pids", F.FitModel.atoms

    def atoms(self, theta_deg, *args, **kwargs):
        with open(log, "a") as f:
            f.write(f"{os.getpid()} {np.size(theta_deg)}\n")
        return real(self, theta_deg, *args, **kwargs)

    monkeypatch.setattr(F.FitModel, "atoms", atoms)
    monkeypatch.setattr(F, "worker_threads", lambda: 2)
    forked = F.fit_region(s, d, **kw)
    calls = [tuple(map(int, line.split())) for line in log.read_text().splitlines()]
    probe = [n for pid, n in calls if pid == os.getpid()]
    assert probe and all(n == 2 for n in probe)                        # the grid probe only (its two edges)
    pids = {pid for pid, _ in calls if pid != os.getpid()}
    assert pids and len(pids) <= 2                   # on the workers (one may take both jobs: a free worker
    # takes the next one), every dictionary among them
    assert max(n for pid, n in calls if pid != os.getpid()) > 100
    assert all(np.array_equal(a, b) for a, b in zip(one, forked))


def test_cancelled_jobs_release_their_workers():
    """dsp.forked.start_jobs then cancel (the caller failed meanwhile): the jobs not started are
    dropped, the workers stop and none is left running; cancelling twice is harmless."""
    import multiprocessing
    import time

    from fwdlook_cli.dsp.forked import start_jobs

    def slow(job):
        time.sleep(0.5)
        return job

    for processes in (False, True):
        pending = start_jobs(slow, list(range(8)), 2, processes=processes)
        t0 = time.perf_counter()
        pending.cancel()
        pending.cancel()
        assert time.perf_counter() - t0 < 8 * 0.5 / 2      # not every job run (3 at most: the queued ones)
        assert not multiprocessing.active_children()
        if processes:                                       # the forked children killed and reaped
            with pytest.raises(ChildProcessError):
                os.waitpid(-1, os.WNOHANG)


def test_the_fit_grid_samples_the_statistics_lobe_at_any_carrier():
    """``fit_angle_step``: the paper's radar (18 GHz, a = 50, the region +-4.78 deg) keeps the image's
    0.05 deg; at 94 GHz the atoms' angle lobe is five times narrower (Doppler 2 v sin(theta) / lambda)
    and the step is halved until an atom half a step from an edge atom keeps half its power, and not
    halved further (the atoms correlated with numpy's vdot, not the module's sums)."""
    pos, beam, p_ref = _flight(accel_mps2=50.0, scan_deg=(-8.0, 8.0))
    r_m = 1600.0

    def corr2(model, theta, h):
        a = model.atoms([theta, theta + h], [r_m])[0]
        return abs(np.vdot(a[:, 0], a[:, 1])) ** 2 / (np.vdot(a[:, 0], a[:, 0]).real * np.vdot(a[:, 1], a[:, 1]).real)

    paper = _model(pos, beam, p_ref)
    assert FP.fit_angle_step(paper, 0.0, 4.78, r_m, 0.05) == 0.05
    w_band = F.FitModel(position_m=pos, scan_angle_deg=beam, fc_hz=94e9, slope_per_deg=SLOPE, beta_per_deg2=BETA,
                        position_ref_m=p_ref)
    step = FP.fit_angle_step(w_band, 0.0, 4.78, r_m, 0.05)
    assert step < 0.05
    assert min(corr2(w_band, e, 0.5 * step) for e in (-4.78, 4.78)) >= 0.5
    assert min(corr2(w_band, e, step) for e in (-4.78, 4.78)) < 0.5


def test_the_cell_history_change_is_the_range_derivative_of_the_history():
    """``cell_history_cycles`` (the gate on the joint fit's cell model) against the closed form for a
    straight flight along +y at height h over a point on the axis: R = sqrt((rho - y)^2 + h^2), so one
    range cell dr moves the history by dr [(rho - y) / R * r / rho - 1], which is 0 at the t_ref antenna
    (y = 0) and grows with h and the distance flown; in cycles 2 / lambda times its spread."""
    from fwdlook_cli.forward.dwell_fit_plan import cell_history_cycles

    for h, fc in ((50.0, 18e9), (500.0, 18e9), (500.0, 94e9)):
        y = np.linspace(0.0, 60.0, 400)
        pos = np.column_stack([np.zeros_like(y), y, np.full_like(y, h)])
        rng = 1800.0 + 2.5 * np.arange(9)
        got = cell_history_cycles(pos, np.zeros_like(y), rng, axis_deg=0.0, window_deg=1.0,
                                  position_ref_m=[0.0, 0.0, h], fc_hz=fc)
        r = float(np.median(rng))
        rho = np.sqrt(r * r - h * h)
        change = 2.5 * ((rho - y) / np.sqrt((rho - y) ** 2 + h * h) * r / rho - 1.0)
        want = 2.0 * np.ptp(change) * fc / 299_792_458.0
        assert got == pytest.approx(want, rel=1e-3), (h, fc, got, want)
    assert want > 0.25 > cell_history_cycles(pos[:, :] * [1, 1, 0.1], np.zeros_like(y), rng, axis_deg=0.0,
                                             window_deg=1.0, position_ref_m=[0.0, 0.0, 50.0], fc_hz=18e9)
