"""Small batched matrix products with the BLAS thread pool held to one thread.

``np.matmul`` over a stack of small matrices (the Doppler zoom: one 64 x 32 by 32 x n_range product
per CPI) calls the BLAS once per matrix.  A multithreaded OpenBLAS wakes and parks its pool on every
call; with the cores shared, a call can wait for a descheduled thread for milliseconds, and 78 calls
ranged from 55 ms to 1.8 s (issue 11).  One thread per call makes each product a few microseconds of
work that cannot stall; the batch is what is large, not the matrices.  ``threadpoolctl`` controls
the pool of whichever BLAS numpy loaded (OpenBLAS, MKL, BLIS).
"""
from __future__ import annotations

import numpy as np

try:                                            # a dependency (pyproject.toml); tolerated if absent
    from threadpoolctl import threadpool_limits
except ImportError:                             # pragma: no cover
    threadpool_limits = None


def batched_matmul(a, b):
    """``np.matmul(a, b)`` over stacks of small matrices, the BLAS limited to one thread."""
    if threadpool_limits is None:               # pragma: no cover
        return np.matmul(a, b)
    with threadpool_limits(limits=1, user_api="blas"):
        return np.matmul(a, b)
