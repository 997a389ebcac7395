"""Readers and writers. :func:`read_problem` opens any supported file as an adjustment problem."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError

FORMATS = ("auto", "gama", "native")


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
    if head.lstrip().startswith("{") and '"baarda-block"' in head:
        return "native"
    if head.lstrip().startswith("{") and '"baarda-truth"' in head:
        raise InputError(path, 1, "this is a truth file of a simulated block, not a block "
                         "(open the block file beside it)")
    raise InputError(path, 1, f"unknown file format (extension '{ext}'); use --format "
                     f"({', '.join(FORMATS[1:])})")


def read_model(path, fmt: str = "auto"):
    """Read ``path`` into its file-level model (Network, Block or IModelBlock)."""
    p = Path(path)
    if not p.exists():
        raise InputError(path, 0, "no such file")
    if p.is_dir():
        raise InputError(path, 0, "is a directory, not a file")
    fmt = detect_format(p) if fmt == "auto" else fmt
    if fmt == "gama":
        from ..approx import approximate_coordinates
        from .gama import read_gama
        return approximate_coordinates(read_gama(p))
    if fmt == "native":
        from .native import read_native
        return read_native(p)
    raise InputError(path, 0, f"unknown format '{fmt}' (known: {', '.join(FORMATS)})")


def build(model):
    """The adjustment problem of a file-level model."""
    from ..bundle import Block, build_block_problem
    from ..imodel import IModelBlock, build_imodel_problem
    from ..network import Network

    if isinstance(model, Block):
        return build_block_problem(model)
    if isinstance(model, IModelBlock):
        return build_imodel_problem(model)
    if isinstance(model, Network):
        from ..approx import approximate_coordinates
        from ..geodetic import build_problem
        if any(getattr(p, a) is None for p in model.points for a in "xyz"
               if a in (p.adjusted + p.constrained).lower()):
            model = approximate_coordinates(model)
        return build_problem(model)
    raise TypeError(f"cannot build a problem from {type(model).__name__}")


def read_problem(path, fmt: str = "auto"):
    """Read ``path`` and return a :class:`baarda.problem.Problem` ready to adjust."""
    return build(read_model(path, fmt))


def read_truth(path) -> dict | None:
    """The truth file of a simulated block (``baarda-truth``), or None if ``path`` is None."""
    if path is None:
        return None
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as err:
        raise InputError(path, 0, f"cannot read: {err.strerror}") from None
    except json.JSONDecodeError as err:
        raise InputError(path, err.lineno, f"JSON syntax error: {err.msg}") from None
    if not isinstance(doc, dict) or doc.get("format") != "baarda-truth":
        raise InputError(path, 1, "not a baarda-truth file")
    return doc
