"""The optional numba: the one place it is imported.

Compiled kernels are twins of numpy formulas (same numbers; the tests compare them). Where numba
is not installed, :func:`njit` gives None and every caller takes its numpy path.
"""

from __future__ import annotations


def njit(**options):
    """``numba.njit(**options)`` (a decorator) where numba is installed, else None."""
    try:
        import numba
    except ImportError:          # pragma: no cover - numba is optional
        return None
    return numba.njit(**options)
