"""BLAS threading for small matrices.

The matrices here are small (a few hundred rows); OpenBLAS's threads only add contention,
and on a loaded 2-core machine a 560×90 SVD took 39 ms with 2 threads and 4.6 ms with one.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Limits BLAS/LAPACK to one thread inside the block (no-op without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield
