"""Exact percentiles of data seen block by block (``dsp/order_stats.py``) against numpy on the whole
array: the same number bit for bit, whatever the blocks, the sample that places the bracket and the
number of values one pass may keep (small caps force the bracket to be moved and narrowed).  numpy
before 2.4 interpolated float32 percentiles with the fraction as a float64 array (``_lerp``), which can
round differently: there the bar is those roundings, two float32 ulps of the data's largest magnitude (the
order statistics stay exact)."""
import numpy as np
import pytest

from fwdlook_cli.dsp import order_stats

NUMPY_LERP_WEAK = tuple(int(v) for v in np.__version__.split(".")[:2]) >= (2, 4)


def _blocks(x, rows):
    return lambda: (x[i:i + rows] for i in range(0, x.shape[0], rows))


def _data(kind, rng, shape):
    if kind == "exponential":                   # the power of noise, as the calibration sees it
        return rng.exponential(size=shape).astype(np.float32)
    if kind == "sorted":                        # every pulse brighter than the last: a row sample is biased
        return np.sort(rng.exponential(size=shape[0] * shape[1])).astype(np.float32).reshape(shape)
    if kind == "ties":                          # few distinct values (quantised, or blanked samples)
        return rng.integers(0, 3, size=shape).astype(np.float32)
    if kind == "zeros":                         # a third exact zeros: the quartile is 0
        x = rng.exponential(size=shape).astype(np.float32)
        x[rng.random(shape) < 0.34] = 0.0
        return x
    if kind == "signed":
        return (rng.standard_normal(shape) * 1e3).astype(np.float32)
    return np.full(shape, 7.0, np.float32)      # constant


@pytest.mark.parametrize("kind", ["exponential", "sorted", "ties", "zeros", "signed", "constant"])
def test_percentile_of_blocks_is_numpys(kind):
    rng = np.random.default_rng(11)
    for trial in range(60):
        shape = (int(rng.integers(1, 70)), int(rng.integers(1, 40)))
        x = _data(kind, rng, shape)
        rows = int(rng.integers(1, shape[0] + 1))
        q = [25.0, 0.0, 100.0, 50.0, float(rng.uniform(0, 100))][trial % 5]
        # the bracket's sample: a few random pulses, or only the last (the brightest, when sorted)
        pick = [shape[0] - 1] if trial % 2 else rng.choice(shape[0], size=int(rng.integers(1, shape[0] + 1)))
        cap = [3, 50, 1 << 22][trial % 3]
        got = order_stats.percentile_of_blocks(_blocks(x, rows), x.size, q, x[pick], np.float32, cap=cap)
        want = np.percentile(x, q)
        assert np.asarray(got).dtype == np.asarray(want).dtype == np.float32
        if NUMPY_LERP_WEAK:
            assert got == want, (kind, shape, rows, q, cap, got, want)
        else:       # each of the two roundings of a + (b - a) t within half an ulp of the larger of |a|, |b - a|
            assert abs(float(got) - float(want)) <= 2 * np.finfo(np.float32).eps * float(np.abs(x).max())


def test_order_statistics_are_exact_when_the_sample_misses():
    """A sample from the far end of sorted data puts the first bracket in the wrong place: the passes
    move and narrow it (a few, with a cap of a twentieth of the data) and still return the partition's
    values."""
    rng = np.random.default_rng(2)
    x = np.sort(rng.exponential(size=40_000)).astype(np.float32).reshape(200, 200)
    passes = []
    real = order_stats._bracket_pass

    def counted(*args):
        passes.append(1)
        return real(*args)

    order_stats._bracket_pass = counted
    used = []
    try:
        for k in (0, 9_999, 10_000, 25_000, 39_999):
            passes.clear()
            got = order_stats.order_statistics_of_blocks(_blocks(x, 7), x.size, k, min(k + 1, x.size - 1),
                                                         x[-1], cap=2_000)
            part = np.partition(x.reshape(-1), [k, min(k + 1, x.size - 1)])
            assert got == (part[k], part[min(k + 1, x.size - 1)])
            used.append(len(passes))
    finally:
        order_stats._bracket_pass = real
    assert max(used) <= 8 and sorted(used)[1] > 1, used     # moved for all but the far end, and few passes


def test_bad_ranks_are_refused():
    x = np.arange(10, dtype=np.float32)
    with pytest.raises(ValueError):
        order_stats.order_statistics_of_blocks(_blocks(x.reshape(2, 5), 1), 10, 3, 10, x)
