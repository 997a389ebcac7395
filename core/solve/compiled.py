"""The optional numba: the one place it is imported.

Compiled kernels are twins of numpy formulas (same numbers; the tests compare them). Where numba
is not installed, :func:`njit` gives None, :func:`compiled` the plain Python function, and every
caller takes its numpy path (:data:`NUMBA` tells which).
"""

from __future__ import annotations

try:
    import numba
except ImportError:              # pragma: no cover - numba is optional
    numba = None

#: whether numba is installed (the compiled kernels are available)
NUMBA = numba is not None
#: numba's parallel range inside kernels compiled with ``parallel=True`` (``range`` without numba)
prange = numba.prange if numba is not None else range


def njit(**options):
    """``numba.njit(**options)`` (a decorator) where numba is installed, else None."""
    return numba.njit(**options) if numba is not None else None


def compiled(fn, **options):
    """``fn`` compiled by ``numba.njit(**options)`` where numba is installed, else ``fn`` itself
    (helpers that compiled kernels call: numba resolves them as globals of the kernel's module)."""
    return numba.njit(**options)(fn) if numba is not None else fn
