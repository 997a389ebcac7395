"""Readers and writers. :func:`read_model` opens any supported file as its file-level model
(:func:`baarda.build.read_problem` builds the adjustment problem from it).

Formats (``docs/formats.md``): GNU Gama XML (``gama``), baarda's native JSON (``native``),
Bundle Adjustment in the Large (``bal``), Bundler v0.3 (``bundler``), COLMAP sparse models,
text or binary (``colmap``); control points from CSV (:mod:`baarda.io.control`); GeoJSON of
the analysed points (:mod:`baarda.io.geojson`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..approx import approximate_coordinates
from ..errors import BaardaError, InputError
from .bal import looks_like_bal, read_bal
from .bundler import looks_like_bundler, read_bundler
from .colmap import find_file, read_colmap
from .gama import read_gama
from .native import read_native
from .source import head as read_head, logical_path, read_text

FORMATS = ("auto", "gama", "native", "bal", "bundler", "colmap")
SFM_FORMATS = ("bal", "bundler", "colmap")


def detect_format(path) -> str:
    """The format of a file (or a COLMAP model directory) from its name, then its content.

    A compressed file (``.gz``, ``.bz2``, ``.xz``, or any name with such content) is judged by
    its name without the compression extension and by its decompressed content
    (:mod:`baarda.io.source`)."""
    p = Path(path)
    name = logical_path(p)
    ext = name.suffix.lower()
    if p.is_dir():
        if any(find_file(p, n, e) for n in ("cameras", "images", "points3D") for e in (".txt", ".bin")):
            return "colmap"
        raise InputError(path, 0, "is a directory but not a COLMAP model (cameras, images, points3D "
                         ".txt or .bin)")
    if ext == ".gkf":
        return "gama"
    if name.stem in ("cameras", "images", "points3D") and ext in (".txt", ".bin"):
        return "colmap"
    head = read_head(p, 4096).decode("utf-8", "replace")
    if "<gama-local" in head:
        return "gama"
    if not head.strip():
        raise InputError(path, 1, "empty file")
    if ext == ".out" or looks_like_bundler(head):
        return "bundler"
    if looks_like_bal(head):
        return "bal"
    if head.lstrip().startswith("{") and '"baarda-block"' in head:
        return "native"
    if head.lstrip().startswith("{") and '"baarda-truth"' in head:
        raise InputError(path, 1, "this is a truth file of a simulated block, not a block "
                         "(open the block file beside it)")
    raise InputError(path, 1, f"unknown file format (extension '{ext}'); use --format "
                     f"({', '.join(FORMATS[1:])})")


def read_model(path, fmt: str = "auto", sigma_px: float | None = None,
               refine_intrinsics: bool | None = None, drop_undefined: bool = False):
    """Read ``path`` into its file-level model (Network, Block, IModelBlock or SfmBlock).

    sigma_px (σ of image coordinates, pixels, default 1) and refine_intrinsics (default: True
    for BAL and Bundler, False for COLMAP) apply to structure-from-motion formats only.
    drop_undefined (Gama input): observations to points no ``<point>`` defines are dropped, as
    gama-local does, with an :class:`~baarda.io.gama.UndefinedPointsWarning` and a list in
    ``Network.extra["dropped"]``; by default they are an InputError naming file and line.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(path, 0, "no such file")
    fmt = detect_format(p) if fmt == "auto" else fmt
    if p.is_dir() and fmt != "colmap":
        raise InputError(path, 0, "is a directory, not a file")
    if fmt in SFM_FORMATS:
        if sigma_px is not None and not (sigma_px > 0 and math.isfinite(sigma_px)):
            raise BaardaError(f"the σ of image coordinates must be a positive number (got {sigma_px})")
        opts = {"sigma_px": 1.0 if sigma_px is None else float(sigma_px)}
        if refine_intrinsics is not None:
            opts["refine_intrinsics"] = bool(refine_intrinsics)
        if fmt == "bal":
            return read_bal(p, **opts)
        if fmt == "bundler":
            return read_bundler(p, **opts)
        return read_colmap(p, **opts)
    if sigma_px is not None or refine_intrinsics:
        raise BaardaError(f"σ of image coordinates and intrinsics refinement apply to "
                          f"{', '.join(SFM_FORMATS)} input, not to {fmt}")
    if fmt == "gama":
        net = read_gama(p, unknown_points="drop" if drop_undefined else "error")
        return approximate_coordinates(net, missing="keep")  # undetermined ones: build() decides
    if fmt == "native":
        return read_native(p)
    raise InputError(path, 0, f"unknown format '{fmt}' (known: {', '.join(FORMATS)})")


def read_truth(path) -> dict | None:
    """The truth file of a simulated block (``baarda-truth``), or None if ``path`` is None;
    InputError naming the file and the entry at fault unless it is UTF-8 JSON whose ``errors``
    are objects with a ``kind`` (text), ``ids`` (an object of texts, numbers or lists of them),
    ``rows`` (observation indices) and optional ``class`` (text) and ``size_sigma`` (a number)."""
    if path is None:
        return None
    try:
        doc = json.loads(read_text(path, small=True))     # at most BAARDA_MAX_SMALL_BYTES, decompressed
    except json.JSONDecodeError as err:
        raise InputError(path, err.lineno, f"JSON syntax error: {err.msg}") from None
    except RecursionError:
        raise InputError(path, 0, "JSON nested too deeply") from None
    if not isinstance(doc, dict) or doc.get("format") != "baarda-truth":
        raise InputError(path, 1, "not a baarda-truth file")
    errors = doc.get("errors", [])
    if not isinstance(errors, list):
        raise InputError(path, 0, "errors: must be a list", field="errors")
    for k, e in enumerate(errors):
        what = f"errors[{k}]"
        if not isinstance(e, dict):
            raise InputError(path, 0, f"{what}: must be an object", field=what)
        if not isinstance(e.get("kind"), str):
            raise InputError(path, 0, f"{what}.kind: must be a text", field=f"{what}.kind")
        if not isinstance(e.get("class", ""), (str, type(None))):
            raise InputError(path, 0, f"{what}.class: must be a text", field=f"{what}.class")
        size = e.get("size_sigma")
        if size is not None and not (isinstance(size, (int, float)) and not isinstance(size, bool)):
            raise InputError(path, 0, f"{what}.size_sigma: must be a number", field=f"{what}.size_sigma")
        ids = e.get("ids", {})
        scalar = (str, int, float)
        if not isinstance(ids, dict) or not all(
                isinstance(v, scalar) or (isinstance(v, list) and all(isinstance(x, scalar) for x in v))
                for v in ids.values()):
            raise InputError(path, 0, f"{what}.ids: must be an object of texts, numbers or lists of them",
                             field=f"{what}.ids")
        rows = e.get("rows", [])
        if not isinstance(rows, list) or not all(type(r) is int and 0 <= r < 2**62 for r in rows):
            raise InputError(path, 0, f"{what}.rows: must be a list of observation indices (integers ≥ 0)",
                             field=f"{what}.rows")
    return doc
