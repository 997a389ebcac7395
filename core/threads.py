"""Native thread pools of the processes baarda runs in: the command line, the server it starts
and the Dask workers of ``baarda batch`` / ``study`` (each task limits its process's pool first)."""

from __future__ import annotations

import os

from threadpoolctl import threadpool_limits

from .errors import UsageError


def limit_native_threads() -> int:
    """Limit the BLAS thread pool of this process (the command line, the server it starts) to
    ``BAARDA_BLAS_THREADS`` threads, default 1: the analysis is sparse and its dense BLAS calls
    are small, so OpenBLAS's default (one thread per core) only spins — a plain ``baarda analyze``
    of Ladybug ran 1.7× slower with it on a quiet 2-core machine and 7.5× with one other job
    running. Returns the limit."""
    text = os.environ.get("BAARDA_BLAS_THREADS", "1").strip()
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise UsageError(f"BAARDA_BLAS_THREADS must be a positive integer (got {text!r})")
    threadpool_limits(limits=n, user_api="blas")
    return n
