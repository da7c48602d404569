"""Thread use: how many threads array work may take, and single-threaded BLAS for small dense
linear algebra."""

from __future__ import annotations

import functools

from threadpoolctl import ThreadpoolController


@functools.cache
def _controller() -> ThreadpoolController:
    return ThreadpoolController()  # inspecting the loaded libraries takes ~1 ms: once


def blas_threads() -> int:
    """Threads BLAS may use now; array work follows it, so that ``threadpool_limits(1)`` (as in
    the worker processes of design and Monte Carlo) keeps everything serial."""
    return max([1] + [lib["num_threads"] for lib in _controller().info() if lib["user_api"] == "blas"])


def one_blas_thread():
    """Context manager: BLAS on one thread, for factorisations of p x p matrices (p ~ 10-500).
    Threads gain little at these sizes, and when the cores are busy OpenBLAS's waiting threads
    made an eigendecomposition of 496 x 496 take 1.3 s instead of 10 ms (measured)."""
    return _controller().limit(limits=1, user_api="blas")
