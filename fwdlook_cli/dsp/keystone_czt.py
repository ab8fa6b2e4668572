"""The CZT (Bluestein) keystone: chirps precomputed once per geometry, batched FFTs over all columns
(NOTES.md: the keystone as a scaled DFT with w = exp(-j 2 pi alpha / M), then an inverse FFT)."""
from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from .keystone_common import _as_2d, _check_dtype, _check_n, _cis, _n_cols, _per_column


# --------------------------------------------------------------------------- linear phases
def _linear_phasors(c0: int, n: int, slope_cycles, dtype):
    """``exp(j 2 pi (c0 + i) s_k)`` for rows i < n and columns k (``slope_cycles`` s, cycles per row):
    with i = a + K b, K ~ sqrt(n), the product of exp(j 2 pi (c0 + K b) s) and exp(j 2 pi a s), two
    tables of about sqrt(n) rows whose phases are reduced in float64, instead of n cosines and sines
    per column (the same phasors to rounding: two unit phasors of the dtype and one product)."""
    s = np.asarray(slope_cycles, dtype=np.float64).reshape(1, -1)
    if n < 16:
        return _cis((c0 + np.arange(n, dtype=np.float64))[:, None] * s, dtype)
    k = int(np.ceil(np.sqrt(n)))
    n_b = -(-n // k)
    low = _cis(np.arange(k, dtype=np.float64)[:, None] * s, dtype)                   # [K, cols]
    high = _cis((c0 + k * np.arange(n_b, dtype=np.float64))[:, None] * s, dtype)     # [n_b, cols]
    table = np.multiply(high[:, None, :], low[None, :, :]).reshape(n_b * k, s.shape[1])
    return table[:n]                 # leading rows of a C-ordered array: contiguous


# --------------------------------------------------------------------------- CZT plan
class KeystonePlan:
    """Precomputed CZT (Bluestein) keystone for one geometry.

    Parameters
    ----------
    n_slow : int
        Number of slow-time samples (length of axis 0 of the data).
    alpha : float or array_like, shape (n_cols,)
        Time-scale factor per column, ``f_c / (f_c + f_r)`` (eq. 8).
    t0_index : float or array_like, shape (n_cols,), optional
        Keystone time origin in samples (may be fractional).  Default 0.
    dtype : {complex64, complex128}, optional
        Precision of the chirps, the FFTs and the result.  Default complex64.
    period : int, optional
        The columns are groups of ``period`` with the same alphas (column ``c`` has the alpha of
        column ``c % period``: the decimated layout, one group per sub-sequence).  Checked; the
        filter spectrum is then stored per alpha (``L x period``) and broadcast over the groups.
        Default: distinct alphas are found by ``np.unique`` and gathered to the columns.

    Notes
    -----
    Calling the plan, ``plan(x, *, ambiguity=F)``, returns for every column ``k``::

        y[m', k] = exp(j 2 pi F[k] tau[m', k]) * (1/n) sum_c X_k(c) exp(j 2 pi c tau[m', k] / n)

    with ``tau = alpha (m' - t0) + t0`` (:func:`keystone_positions`) and the centred
    Doppler index ``c`` (fftfreq order).  Writing ``c = c_min + i`` (``c_min = -(n//2)``)
    and ``tau = alpha m' + (1 - alpha) t0``::

        Y_i  = X(c) exp(j 2 pi c (1 - alpha) t0 / n)                 (origin shift)
        y(m')= (1/n) W^(c_min m') sum_i Y_i W^(i m'),   W = exp(j 2 pi alpha / n)

    and the sum is Bluestein's chirp-Z transform [2]_ (the corrected eq. 21 of [1]_)::

        sum_i Y_i W^(i m') = W^(m'^2/2) sum_i [Y_i W^(i^2/2)] W^(-(m'-i)^2/2)

    evaluated as a linear convolution with FFTs of length
    ``L = next_fast_len(2 n - 1)``.  The final factor ``exp(j 2 pi F tau)`` is the
    Doppler-ambiguity correction (eq. 22 as corrected in the NOTES; eq. 22 as printed
    multiplies by ``exp(j 2 pi F m') = 1``).  All chirp phases are computed in float64
    and reduced modulo one cycle before they are stored in `dtype`.

    Per call the work is one length-``n`` FFT and two length-``L`` FFTs along axis 0,
    batched over all columns with ``workers=-1``, and three element-wise products.  The
    plan stores the input chirp (``n x n_cols``) and the filter spectrum
    (``L x n_cols``), and caches the chirps of the last few ambiguities it was called with
    (a new ambiguity costs one extra chirp evaluation: for a scalar F != 0 an input chirp
    with eq. (22)'s per-column constant folded in, ``n x n_cols``, and the output chirp,
    ``n x n_cols`` or per alpha with ``period``): about 20 MB plus 5-10 MB per cached
    ambiguity for ``n = 2500``, ``n_cols = 256`` in complex64; a call peaks at about 15 MB
    of temporaries and result.  A plan built with scalar
    `alpha` and `t0_index` applies to any number of columns.

    References
    ----------
    .. [1] Z.-S. Li and Y.-L. Li, Front. Signal Process. 2:1074053 (2023).
    .. [2] L. I. Rabiner, R. W. Schafer and C. M. Rader, "The chirp z-transform
       algorithm", IEEE Trans. Audio Electroacoust. 17(2), 86-92 (1969).

    Examples
    --------
    >>> import numpy as np
    >>> from fwdlook_cli.keystone import KeystonePlan
    >>> fr = np.linspace(-30e6, 30e6, 8)
    >>> plan = KeystonePlan(64, 18e9 / (18e9 + fr), t0_index=32.0)
    >>> y = plan(np.ones((64, 8), np.complex64), ambiguity=0)
    >>> bool(np.allclose(y, 1, atol=1e-5))
    True
    """

    _POST_CACHE_SIZE = 4

    def __init__(self, n_slow, alpha, *, t0_index=0.0, dtype=np.complex64, workers=-1, period=None):
        n = _check_n(n_slow)
        self.workers = workers          # scipy.fft workers of every transform of the plan
        self.dtype = _check_dtype(dtype)
        alpha = _per_column(alpha, "alpha", positive=True)
        t0 = _per_column(t0_index, "t0_index")
        self.n_cols = _n_cols(alpha, t0)
        alpha = np.broadcast_to(alpha, (self.n_cols,)).copy()
        t0 = np.broadcast_to(t0, (self.n_cols,)).copy()
        self.n_slow = n
        self.alpha = alpha
        self.t0_index = t0
        self.nfft = L = sfft.next_fast_len(2 * n - 1)
        self._c_min = c_min = -(n // 2)
        self._shift = n // 2  # FFT bin p lands at centred position (p + n//2) mod n

        # the chirps depend on alpha only, but the origin shift: computed once per distinct alpha
        # (decimated layouts repeat the same range-frequency alphas for every sub-sequence), gathered
        # to the columns only where alphas repeat (``inverse`` None: every column its own alpha).
        # ``period``: the caller's word that column c has the alpha of column c % period (the
        # decimated layout's groups); then the per-alpha filter and chirp are broadcast over the
        # groups instead of gathered to every column (the same numbers, less memory traffic)
        self._period = None
        if (period is not None and 1 <= int(period) < self.n_cols and self.n_cols % int(period) == 0
                and np.array_equal(alpha.reshape(-1, int(period)), np.broadcast_to(
                    alpha[:int(period)], (self.n_cols // int(period), int(period))))):
            self._period = int(period)
            alpha_u, inverse = alpha[: self._period], None
        else:
            alpha_u, inverse = np.unique(alpha, return_inverse=True)
            if alpha_u.size == alpha.size:
                alpha_u, inverse = alpha, None
        # h_d = W^(-d^2/2) for |d| = 0..L/2, phases reduced in float64 (eq. 21)
        d_half = np.arange(L // 2 + 1, dtype=np.float64)
        h_half = _cis(-(alpha_u / (2.0 * n)) * (d_half**2)[:, None], self.dtype)
        # input chirp: origin shift exp(j2pi c (1-alpha) t0 / n), linear in c = c_min + i (two phase
        # tables, :func:`_linear_phasors`), times W^(i^2/2) = conj(h_i) (i < n <= L/2 + 1)
        quad = h_half[:n] if inverse is None else h_half[:n, inverse]
        self._pre = np.ascontiguousarray(_linear_phasors(c_min, n, (1.0 - alpha) * t0 / n, self.dtype))
        if self._period is None:
            np.multiply(self._pre, quad.conj(), out=self._pre)
        else:                                          # [n, groups, period] x [n, 1, period]
            grouped = self._pre.reshape(n, -1, self._period)
            np.multiply(grouped, quad.conj()[:, None, :], out=grouped)
        del quad

        # filter h_d, d = -(n-1)..(n-1), wrapped into length L: circular lag d of FFT row j is j up to
        # L/2, j - L above; |d| <= n-1 is all that matters for L >= 2n-1.  h is even in d: the rows
        # of h_half gathered (the same numbers)
        j = np.arange(L)
        filt = sfft.fft(h_half[np.minimum(j, L - j)], axis=0, workers=workers, overwrite_x=True)
        self._filt = filt if inverse is None else filt[:, inverse]
        del h_half, filt

        # output chirp for F = 0: (1/n) W^(c_min m' + m'^2/2), a function of alpha only
        self._alpha_unique, self._alpha_inverse = alpha_u, inverse
        if self._period is not None:            # the columns' index into alpha_u, where one is asked for
            self._alpha_inverse = np.tile(np.arange(self._period), self.n_cols // self._period)
        self._post_cache = {}  # ambiguity -> output chirp, a few most recent

    # ----------------------------------------------------------------------------
    def _post_chirp(self, ambiguity):
        """(input chirp, output chirp) for ambiguity number(s) ``ambiguity``, the most recent few cached.

        For one scalar F the per-column constant of eq. (22), exp(j 2 pi F (1 - alpha) t0) / n, is
        folded into that F's input chirp (a constant per column commutes with the column's linear
        transform), and the output chirp is the per-alpha one: [n, period] for a plan with ``period``
        (the groups share it, broadcast over them where it is applied: no [n, n_cols] output chirp
        gathered or read), else gathered to the columns; for per-column F, [n, n_cols]."""
        F = _per_column(ambiguity, "ambiguity", integer=True)
        _n_cols(F, n_cols=self.n_cols)
        key = (F.size, F.tobytes())
        chirps = self._post_cache.get(key)
        if chirps is None:
            m = np.arange(self.n_slow, dtype=np.float64)[:, None]
            a_u, inv = self._alpha_unique, self._alpha_inverse
            base = (a_u / self.n_slow) * (self._c_min * m + 0.5 * m**2)   # [n, n_unique]
            pre = self._pre
            if F.size == 1:
                # eq. (22) corrected: exp(j 2 pi F tau), tau = alpha m' + (1-alpha) t0: the alpha m'
                # part per distinct alpha, the constant (1-alpha) t0 part and the 1/n per column, each
                # factor's phase reduced in float64 and taken in the plan's precision
                f = float(F.reshape(-1)[0])
                post = _cis(base + np.mod(f * a_u * m, 1.0), self.dtype)
                if f != 0.0:                            # the column constant into the input chirp
                    col = _cis(np.mod(f * (1.0 - self.alpha) * self.t0_index, 1.0)) / self.n_slow
                    pre = pre * col.astype(self.dtype)[None, :]
                else:
                    post *= self.dtype.type(1.0 / self.n_slow)
                if self._period is None and inv is not None:    # per alpha, gathered to the columns
                    post = post[:, inv]
            else:
                tau = self.alpha * m + (1.0 - self.alpha) * self.t0_index
                post = _cis((base if inv is None else base[:, inv]) + np.mod(F * tau, 1.0), self.dtype)
                post *= self.dtype.type(1.0 / self.n_slow)
            if len(self._post_cache) >= self._POST_CACHE_SIZE:
                self._post_cache.pop(next(iter(self._post_cache)), None)
            chirps = self._post_cache[key] = (pre, post)
        return chirps

    def post_cycles_f0(self):
        """The F = 0 output chirp's phase per column, in cycles (float64 [n_slow, n_cols]), without
        the 1/n: a caller that multiplies the output by its own phase (the tracking keystone's
        remodulation) adds it here and passes ``post=(1/n) exp(j 2 pi (both))`` to the call."""
        m = np.arange(self.n_slow, dtype=np.float64)[:, None]
        base = (self._alpha_unique / self.n_slow) * (self._c_min * m + 0.5 * m**2)
        return base if self._alpha_inverse is None else base[:, self._alpha_inverse]

    def post_cycles_f0_factors(self):
        """:meth:`post_cycles_f0` as its two factors, (rows [n_slow], columns [n_cols]): the phase is
        ``rows[m] * columns[k]``, ``(c_min m + m^2 / 2) * alpha_k / n`` (for a caller that builds its
        phase as a matrix product)."""
        m = np.arange(self.n_slow, dtype=np.float64)
        return self._c_min * m + 0.5 * m**2, self.alpha / self.n_slow

    def __call__(self, x, *, ambiguity=0, post=None):
        """Keystone `x` (``[n_slow, n_cols]``) with Doppler ambiguity number(s) `ambiguity`.

        Parameters
        ----------
        x : array_like, shape (n_slow, n_cols)
            Slow time along axis 0.  Cast to the plan's dtype if needed.
        ambiguity : int or array_like of int, shape (n_cols,), optional
            Doppler ambiguity number ``F`` (eq. 15-17), scalar or per column.
        post : ndarray, shape (n_slow, n_cols), optional
            The output chirp to use instead of the plan's (see :meth:`post_cycles_f0`); then
            ``ambiguity`` is ignored.

        Returns
        -------
        y : ndarray, shape (n_slow, n_cols), plan dtype
        """
        return self.apply(_as_2d(x), ambiguity=ambiguity, post=post)

    def apply(self, x, *, ambiguity=0, post=None, out=None):
        """:meth:`__call__` for ``x`` of shape (n_slow, n_cols) or (n_slow, groups, width), into ``out``.

        Parameters
        ----------
        x : array_like, shape (n_slow, n_cols) or (n_slow, groups, width)
            Slow time along axis 0.  Cast to the plan's dtype if needed.  A 3-D ``x`` holds the
            columns ``g * width + w`` in C order (a strided view of a wider array is read where it
            lies, not gathered first).
        ambiguity : int or array_like of int, shape (n_cols,), optional
            Doppler ambiguity number ``F`` (eq. 15-17), scalar or per column.
        post : ndarray, shape (n_slow, n_cols), optional
            The output chirp to use instead of the plan's (see :meth:`post_cycles_f0`); then
            ``ambiguity`` is ignored.
        out : ndarray, optional
            Where to write the result (the plan's dtype, ``n_slow`` rows and ``n_cols`` columns in the
            layout of ``x``; it may be a strided view of a wider array).

        Returns
        -------
        y : ndarray, shape of ``x``, plan dtype (``out`` where given)
        """
        x = np.asarray(x)
        if x.ndim != 3:
            x = _as_2d(x)
        n, L, s = self.n_slow, self.nfft, self._shift
        if x.shape[0] != n:
            raise ValueError(f"x has {x.shape[0]} slow-time samples, the plan expects {n}")
        nc = int(np.prod(x.shape[1:]))
        if out is not None and (out.shape != x.shape or out.dtype != self.dtype):
            raise ValueError(f"out has shape {out.shape} and dtype {out.dtype}; expected {x.shape}, {self.dtype}")
        if self.n_cols not in (1, nc):
            raise ValueError(f"x has {nc} columns, the plan expects {self.n_cols}")
        pre = self._pre
        if post is None:
            pre, post = self._post_chirp(ambiguity)
        grouped_post = post.shape[1] != nc and self._period is not None and post.shape[1] == self._period
        if post.shape[1] not in (1, nc) and not grouped_post:
            raise ValueError(f"ambiguity has {post.shape[1]} columns, x has {nc}")
        if x.dtype != self.dtype:
            x = x.astype(self.dtype)

        X = sfft.fft(x, axis=0, workers=self.workers).reshape(n, nc)   # slow-time spectrum, FFT order
        buf = np.empty((L, nc), dtype=self.dtype)
        # centre the Doppler index while applying the input chirp (no fftshift pass)
        np.multiply(X[: n - s], pre[s:], out=buf[s:n])
        np.multiply(X[n - s :], pre[:s], out=buf[:s])
        del X
        buf[n:] = 0
        buf = sfft.fft(buf, axis=0, workers=self.workers, overwrite_x=True)
        if self._period is None:                  # eq. (21): convolution with h = W^(-m^2/2)
            buf *= self._filt
        else:                                     # the same, the per-alpha filter over the groups
            grouped = buf.reshape(L, -1, self._period)
            grouped *= self._filt[:, None, :]
        buf = sfft.ifft(buf, axis=0, workers=self.workers, overwrite_x=True)
        # output chirp W^(m'^2/2 + c_min m') / n and ambiguity correction exp(j2pi F tau)
        if grouped_post:                           # [n, period] over the groups
            grouped = (n, nc // self._period, self._period)
            into = out if out is not None and out.shape == grouped else None
            y = np.multiply(buf[:n].reshape(grouped), post[:, None, :], out=into)
            if out is None:
                return y.reshape(x.shape)
            if into is None:                       # another layout of out: written through its own shape
                out[...] = y.reshape(out.shape)
            return out
        if out is None and x.ndim == 2:
            return np.multiply(buf[:n], post)
        shape = x.shape
        post = post.reshape(shape if post.shape[1] == nc else (n,) + (1,) * (len(shape) - 1))
        return np.multiply(buf[:n].reshape(shape), post, out=out)
