"""Native thread pools of the processes baarda runs in: the command line, the server it starts
and its worker threads, and the Dask workers of ``baarda batch`` / ``study`` (each task limits its
process's pool first)."""

from __future__ import annotations

import os

from threadpoolctl import threadpool_limits

from .errors import UsageError
from .solve.compiled import numba


def blas_threads() -> int:
    """``BAARDA_BLAS_THREADS`` (default 1); UsageError for anything but a positive integer."""
    text = os.environ.get("BAARDA_BLAS_THREADS", "1").strip()
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise UsageError(f"BAARDA_BLAS_THREADS must be a positive integer (got {text!r})")
    return n


def limit_worker_threads(n: int | None = None) -> int:
    """Limit the compiled kernels' threads (numba's ``parallel=True`` loops) of the calling
    thread to ``n`` (default :func:`blas_threads`; numba's limit is per thread, the BLAS one of
    :func:`limit_native_threads` per process): a served session's worker then uses one core,
    and one session's adjustment never starves the others. Returns the limit."""
    n = blas_threads() if n is None else int(n)
    if numba is not None:
        numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))
    return n


def limit_native_threads() -> int:
    """Limit the BLAS thread pool of this process (the command line, the server it starts) to
    ``BAARDA_BLAS_THREADS`` threads, default 1: the analysis is sparse and its dense BLAS calls
    are small, so OpenBLAS's default (one thread per core) only spins — a plain ``baarda analyze``
    of Ladybug ran 1.7× slower with it on a quiet 2-core machine and 7.5× with one other job
    running. Returns the limit."""
    n = blas_threads()
    threadpool_limits(limits=n, user_api="blas")
    return n
