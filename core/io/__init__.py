"""Readers and writers. :func:`read_problem` opens any supported file as an adjustment problem."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

FORMATS = ("auto", "gama")


def detect_format(path) -> str:
    """The format of a file from its extension, then its content."""
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".gkf":
        return "gama"
    try:
        head = p.read_bytes()[:4096].decode("utf-8", "replace")
    except OSError as err:
        raise InputError(path, 0, f"cannot read: {err.strerror}") from None
    if "<gama-local" in head:
        return "gama"
    raise InputError(path, 1, f"unknown file format (extension '{ext}'); use --format "
                     f"({', '.join(FORMATS[1:])})")


def read_problem(path, fmt: str = "auto"):
    """Read ``path`` and return a :class:`baarda.problem.Problem` ready to adjust."""
    p = Path(path)
    if not p.exists():
        raise InputError(path, 0, "no such file")
    if p.is_dir():
        raise InputError(path, 0, "is a directory, not a file")
    fmt = detect_format(p) if fmt == "auto" else fmt
    if fmt == "gama":
        from ..approx import approximate_coordinates
        from ..geodetic import build_problem
        from .gama import read_gama
        return build_problem(approximate_coordinates(read_gama(p)))
    raise InputError(path, 0, f"unknown format '{fmt}' (known: {', '.join(FORMATS)})")
