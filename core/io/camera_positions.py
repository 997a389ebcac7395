"""Camera positions as Agisoft Metashape and Pix4D export them, read as GNSS projection centres.

``--gnss FILE`` recognises the layout by its first lines (:func:`sniff`):

- **Metashape** (Reference pane → Export, "Cameras"): a comment header naming the columns,
  ``# Label,X/East,Y/North,Z/Altitude,...`` (also ``X/Easting``, ``Y/Northing``, or plain ``X``,
  ``Y``, ``Z``); other ``#`` lines before it (``# Cameras (24)``) are skipped. The accuracy is
  read from ``X accuracy``, ``Y accuracy``, ``Z accuracy`` (also written ``X_accuracy``,
  ``Accuracy X``), or ``Accuracy X/Y (m)`` and ``Accuracy Z (m)``, or one ``Accuracy (m)`` for
  all three. Angles (``Yaw``, ``Pitch``, ``Roll`` or ``Omega``, ``Phi``, ``Kappa``), their
  accuracies, and the estimated and error columns Metashape adds after an alignment (``X est``,
  ``X error``, ``Error (m)`` …) are recognised and not used: baarda takes the *reference*
  (measured) position. Any other column is refused with its name.
- **Pix4D** image geolocation file (PIX4Dmapper, PIX4Dmatic): no header (an optional first
  ``#`` comment line), 7 or 9 comma-separated columns ``imagename, coordinate1, coordinate2, z,
  yaw|omega, pitch|phi, roll|kappa[, accuracy horizontal, accuracy vertical]``. Only the 9-column
  layout gives the σ the adjustment needs (horizontal for X and Y, vertical for Z); the angles
  are not used.

Units: metres in the frame of the block's object coordinates (a projected or local frame); Z as
the file gives it (altitude). Geographic latitude/longitude are refused — "project to a metric
frame first": a Metashape header naming ``Longitude``/``Latitude``, a Pix4D comment header naming
them, or Pix4D coordinates that all lie within ±90 and ±180 and spread over less than 0.1 (0.1°
is ~10 km; no block of metric centres spans less than 10 cm; a file of more than one row).

Each row's label is matched to an image of the block by :func:`baarda.io.gnss.image_matcher`
(the image id, its file name, its name without extension; then the same ignoring case).
Errors name the file, the line and the field (:class:`baarda.errors.InputError`).
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..errors import InputError
from ..model.gnss import GnssCentre
from ..validate import SIGMA_MAX, SIGMA_MIN, VALUE_LIMIT
from .bal import read_text
from .control import csv_rows

#: Metashape's position columns (normalised names) → x, y, z
_POSITION = {"x/east": "x", "x/easting": "x", "x": "x", "y/north": "y", "y/northing": "y", "y": "y",
             "z/altitude": "z", "z/height": "z", "z": "z"}
_GEOGRAPHIC = ("x/longitude", "y/latitude", "x/lon", "y/lat")
#: Metashape's accuracy columns (normalised) → the axes they give
_ACCURACY = {"x accuracy": "x", "accuracy x": "x", "y accuracy": "y", "accuracy y": "y", "z accuracy": "z",
             "accuracy z": "z", "accuracy x/y (m)": "xy", "accuracy x/y": "xy", "accuracy xy": "xy",
             "accuracy z (m)": "z", "accuracy (m)": "xyz", "accuracy": "xyz"}
_ANGLES = ("yaw", "pitch", "roll", "omega", "phi", "kappa")


def _norm(name: str) -> str:
    """A header name lower-cased, ``_`` as space, spaces collapsed (``Accuracy_X/Y_(m)`` →
    ``accuracy x/y (m)``)."""
    return re.sub(r"\s+", " ", name.replace("_", " ").strip().lower()).replace("( ", "(").replace(" )", ")")


def _unused(n: str) -> bool:
    """A Metashape column baarda recognises and does not use: angles, their accuracies, the
    estimated and error columns of an aligned project, an enable flag."""
    words = n.replace("(", " ").replace(")", " ").split()
    return (n in _ANGLES or n in ("enable", "enabled", "error (m)", "error (deg)", "error (pix)", "error (px)",
                                  "accuracy (deg)", "projections", "error")
            or (len(words) >= 2 and words[-1] in ("est", "error", "accuracy") and words[0] in (*_ANGLES, "x", "y", "z"))
            or (len(words) >= 2 and words[0] == "accuracy" and words[1] in _ANGLES))


def _is_number(tok: str) -> bool:
    try:
        return math.isfinite(float(tok))
    except ValueError:
        return False


def sniff(path) -> tuple[str, list]:
    """The layout of a camera-position text file: ("metashape" | "pix4d" | "baarda", its
    non-blank CSV records with their lines (:func:`baarda.io.control.csv_rows`)). Decided at the
    first record that is not a ``#`` comment: Metashape where it, or the comment line before it,
    starts with ``Label``; Pix4D where it has 7 or 9 fields, a label and six or eight numbers (no
    header: baarda's CSV starts with one); baarda's CSV
    otherwise (its reader says what is wrong)."""
    rows = [(ln, r) for ln, r in csv_rows(path, read_text(path)) if r and any(c.strip() for c in r)]
    last_comment = None
    for _, r in rows:
        if r[0].lstrip().startswith("#"):
            last_comment = r
            continue
        first = [c.strip() for c in r]
        if _norm(first[0]) == "label" or (last_comment is not None
                                          and _norm(last_comment[0].lstrip().lstrip("#")) == "label"):
            return "metashape", rows
        if len(first) in (7, 9) and all(_is_number(c) for c in first[1:]):
            return "pix4d", rows
        break
    return "baarda", rows


def _number(path, ln, label, name, tok):
    tok = tok.strip()
    try:
        v = float(tok)
    except ValueError:
        raise InputError(path, ln, f"image {label}: {name} = '{tok[:40]}' is not a number", field=name) from None
    if not math.isfinite(v):
        raise InputError(path, ln, f"image {label}: {name} = {tok[:40]} is not finite", field=name)
    if abs(v) > VALUE_LIMIT:
        raise InputError(path, ln, f"image {label}: {name} = {v:g} is outside ±{VALUE_LIMIT:g}", field=name)
    return v


def _sigma(path, ln, label, name, tok):
    s = _number(path, ln, label, name, tok)
    if not SIGMA_MIN <= s <= SIGMA_MAX:
        raise InputError(path, ln, f"image {label}: {name} = {s:g} must lie in [{SIGMA_MIN:g}, {SIGMA_MAX:g}] m",
                         field=name)
    return s


def _centre(path, ln, label, xyz, sd, seen) -> GnssCentre:
    if not label:
        raise InputError(path, ln, "empty image label", field="label")
    if label in seen:
        raise InputError(path, ln, f"duplicate image {label} (first at line {seen[label]})", field="label")
    seen[label] = ln
    cov = np.diag(np.square(sd))
    return GnssCentre(label, tuple(float(v) for v in xyz), tuple(map(tuple, cov.tolist())), "", float("nan"), ln)


def read_metashape(path, rows) -> list[GnssCentre]:
    """The reference positions of a Metashape camera export (module docstring)."""
    header = None
    for k, (ln, r) in enumerate(rows):
        if _norm(r[0].lstrip().lstrip("#")) == "label":
            header, data = (ln, [c.lstrip().lstrip("#") if j == 0 else c for j, c in enumerate(r)]), rows[k + 1:]
            break
    hline, names = header[0], [_norm(c) for c in header[1]]
    geo = [n for n in names if n in _GEOGRAPHIC]
    if geo:
        raise InputError(path, hline, f"geographic coordinates ({', '.join(geo)}): baarda needs metric "
                         f"positions — project to a metric frame first (export the cameras in a projected or local "
                         f"coordinate system)", field=geo[0])
    col, acc = {}, {}
    for j, n in enumerate(names):
        if j == 0:
            continue
        if n in _POSITION and _POSITION[n] not in col:
            col[_POSITION[n]] = j
        elif n in _ACCURACY:
            for a in _ACCURACY[n]:
                acc.setdefault(a, (j, header[1][j].strip()))
        elif not _unused(n):
            raise InputError(path, hline, f"unknown column '{header[1][j].strip()[:40]}' in a Metashape camera "
                             f"export (docs/formats.md lists the columns read)", field=header[1][j].strip()[:40])
    missing = [a for a in "xyz" if a not in col]
    if missing:
        raise InputError(path, hline, f"a Metashape camera export needs the position columns X/East, Y/North, "
                         f"Z/Altitude (missing: {', '.join(missing)})")
    if len(acc) < 3:
        raise InputError(path, hline, "no accuracy columns (X/Y/Z accuracy, or Accuracy X/Y and Z): baarda needs "
                         "the σ of every position — export them from the Reference pane's settings")
    out, seen = [], {}
    for ln, r in data:
        if r[0].lstrip().startswith("#"):
            continue
        if len(r) != len(names):
            raise InputError(path, ln, f"{len(r)} fields, the header has {len(names)}")
        label = r[0].strip()
        xyz = [_number(path, ln, label, header[1][col[a]].strip(), r[col[a]]) for a in "xyz"]
        sd = [_sigma(path, ln, label, acc[a][1], r[acc[a][0]]) for a in "xyz"]
        out.append(_centre(path, ln, label, xyz, sd, seen))
    if not out:
        raise InputError(path, hline, "no camera positions after the header")
    return out


def read_pix4d(path, rows) -> list[GnssCentre]:
    """The positions of a Pix4D image geolocation file (module docstring)."""
    names = ("imagename", "coordinate1", "coordinate2", "z", "angle1", "angle2", "angle3",
             "accuracy horizontal", "accuracy vertical")
    comment = " ".join(",".join(r).lower() for _, r in rows if r[0].lstrip().startswith("#"))
    data = [(ln, r) for ln, r in rows if not r[0].lstrip().startswith("#")]
    width = len(data[0][1])
    if any(w in comment for w in ("latitude", "longitude")):
        raise InputError(path, data[0][0], "geographic coordinates (the header names latitude/longitude): baarda "
                         "needs metric positions — project to a metric frame first", field="coordinate1")
    out, seen, pos = [], {}, []
    for ln, r in data:
        if len(r) != width:
            raise InputError(path, ln, f"{len(r)} fields, the first row has {width} (Pix4D: 7 or 9)")
        label = r[0].strip()
        xyz = [_number(path, ln, label, names[1 + a], r[1 + a]) for a in range(3)]
        for a in range(3):
            _number(path, ln, label, names[4 + a], r[4 + a])
        if width != 9:
            raise InputError(path, ln, "a Pix4D geolocation file without accuracy columns: baarda needs the σ of "
                             "every position (the 9-column layout with accuracy horizontal and vertical)")
        h = _sigma(path, ln, label, names[7], r[7])
        v = _sigma(path, ln, label, names[8], r[8])
        out.append(_centre(path, ln, label, xyz, (h, h, v), seen))
        pos.append(xyz[:2])
    P = np.array(pos)
    if len(P) > 1 and (np.abs(P[:, 0]) <= 90).all() and (np.abs(P[:, 1]) <= 180).all() and np.ptp(P, axis=0).max() < 0.1:
        raise InputError(path, data[0][0], "the coordinates look geographic (all within ±90/±180 and spread over "
                         "less than 0.1): baarda needs metric positions — project to a metric frame first",
                         field="coordinate1")
    return out
