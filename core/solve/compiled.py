"""The optional numba: the one place it is imported.

Compiled kernels are twins of numpy formulas (same numbers; the tests compare them). Where numba
is not installed, :func:`njit` gives None, :func:`compiled` the plain Python function, and every
caller takes its numpy path (:data:`NUMBA` tells which).

numba is imported when the first kernel is compiled, not with this module (issue 30, item 5:
``baarda --help`` and commands that compile nothing do not pay its ≈ 0.7 s): :func:`compiled`
gives a :class:`Deferred` that compiles on its first call, and :func:`njit`'s decorator first
puts into the kernel's globals the compiled helpers and ``numba.prange`` it calls.
"""

from __future__ import annotations

from ..lazy import installed, lazy

#: whether numba is installed (the compiled kernels are available)
NUMBA = installed("numba")
numba = lazy("numba") if NUMBA else None


def prange(*args):
    """``range`` outside a kernel; inside one compiled by :func:`njit` it is ``numba.prange``
    (numba's parallel range of kernels compiled with ``parallel=True``)."""
    return range(*args)


class Deferred:
    """``fn`` compiled by ``numba.njit(**options)`` when first called (from Python, or as a
    helper of a kernel compiled by :func:`njit`)."""

    def __init__(self, fn, options: dict):
        self.fn, self.options, self._dispatcher, self._busy = fn, options, None, False
        self.__doc__, self.__name__ = fn.__doc__, fn.__name__

    def dispatcher(self):
        """The numba dispatcher (compiling the helpers it calls first)."""
        if self._dispatcher is None:
            self._busy = True                # (a helper that calls itself is left to numba)
            try:
                _resolve(self.fn)
                self._dispatcher = numba.njit(**self.options)(self.fn)
            finally:
                self._busy = False
        return self._dispatcher

    def __call__(self, *args, **kwargs):
        return self.dispatcher()(*args, **kwargs)


def _names(code) -> set:
    """The global names a function's code (and the code nested in it) uses."""
    names = set(code.co_names)
    for const in code.co_consts:
        if hasattr(const, "co_names"):
            names |= _names(const)
    return names


def _resolve(fn) -> None:
    """Replace, in the module globals of a kernel ``fn``, the :class:`Deferred` helpers it calls by
    their dispatchers and :func:`prange` by ``numba.prange`` (numba resolves a kernel's globals
    when compiling it)."""
    namespace = fn.__globals__
    for name in _names(fn.__code__):
        value = namespace.get(name)
        if value is prange:
            namespace[name] = numba.prange
        elif isinstance(value, Deferred) and not value._busy:
            namespace[name] = value.dispatcher()


def njit(**options):
    """``numba.njit(**options)`` (a decorator) where numba is installed, else None."""
    if not NUMBA:
        return None
    jit = numba.njit(**options)

    def decorate(fn):
        _resolve(fn)
        return jit(fn)
    return decorate


def compiled(fn, **options):
    """``fn`` compiled by ``numba.njit(**options)`` where numba is installed (when first called:
    :class:`Deferred`), else ``fn`` itself (helpers that compiled kernels call: numba resolves
    them as globals of the kernel's module)."""
    return Deferred(fn, options) if NUMBA else fn
