"""Freed heap given back to the operating system between the stages of a large analysis.

glibc keeps the memory of freed arrays below its mmap threshold (which rises to 32 MB as large
arrays come and go) in its heap, where later arrays of other sizes often cannot reuse it: the
resident set of a large block carries hundreds of megabytes of freed heap from one stage into
the next (1 M image points: 1.63 GB resident after adjusting, 1.21 GB after
``malloc_trim``). :func:`trim` returns the free pages (``malloc_trim(0)``); it changes no
number, only what the process holds. Nothing happens below :data:`MIN_ROWS` observations (small
problems' heaps are small) or without glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: problems with fewer observations are not trimmed (their freed heap is small)
MIN_ROWS = 1 << 18

_TRIM = []


def _malloc_trim():
    if not _TRIM:
        fn = None
        if sys.platform.startswith("linux"):
            try:
                fn = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
                fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
            except (OSError, AttributeError):      # pragma: no cover - not glibc
                fn = None
        _TRIM.append(fn)
    return _TRIM[0]


def trim(rows: int) -> None:
    """Give the free pages of the heap back (glibc ``malloc_trim(0)``) when the problem has at
    least :data:`MIN_ROWS` observations (``rows``)."""
    if rows < MIN_ROWS:
        return
    fn = _malloc_trim()
    if fn is not None:
        fn(0)


#: glibc's mallopt parameter M_MMAP_THRESHOLD, and the threshold :func:`map_large` sets
M_MMAP_THRESHOLD = -3
MAP_THRESHOLD = 4 << 20

_MAPPED = []


def map_large(rows: int) -> None:
    """From a problem of at least :data:`MIN_ROWS` observations on, arrays of
    :data:`MAP_THRESHOLD` bytes and more get mappings of their own (glibc ``mallopt``), given
    back when freed, instead of heap that glibc's dynamic threshold (up to 32 MB) would keep
    (for the rest of the process: small problems analysed first are not affected)."""
    if rows < MIN_ROWS or _MAPPED:
        return
    _MAPPED.append(True)
    if not sys.platform.startswith("linux"):
        return
    try:
        fn = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):      # pragma: no cover - not glibc
        return
    fn.argtypes, fn.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    fn(M_MMAP_THRESHOLD, MAP_THRESHOLD)
