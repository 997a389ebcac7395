"""A hypothesis matrix H read from a text file (``baarda test --hypothesis file:PATH``).

The format (docs/formats.md, "Hypothesis files"): one line per non-zero entry of H (n × q),

    # observation  column  value
    12  0  1.0
    13  1  1.0

three fields separated by blanks or commas: ``observation`` the 0-based index of the
observation (``observations[].index`` of the JSON result, the input file's order), ``column``
the component of ∇s it enters (0 … q − 1; every column needs an entry) and ``value`` the
coefficient (a finite number, ∂l/∂s). Blank lines and text after ``#`` are ignored; an entry
given twice is an error. E(l | Hₐ) = A x + H ∇s (F80 eq. 6).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, UsageError
from .source import read_text
from ..catalog import HYPOTHESIS_SPECS

FIELDS = ("observation", "column", "value")


def read_hypothesis(path, n: int) -> sp.csc_matrix:
    """H (n × q) of the file ``path`` for a problem of ``n`` observations; InputError naming
    the file, line and field at fault."""
    path = Path(path)
    text = read_text(path, small=True)      # at most BAARDA_MAX_SMALL_BYTES, decompressed; UTF-8
    rows, cols, vals, seen = [], [], [], {}
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].replace(",", " ").split()
        if not line:
            continue
        if len(line) != 3:
            raise InputError(path, lineno, f"expected 3 fields ({', '.join(FIELDS)}), found {len(line)}")
        i = _integer(path, lineno, "observation", line[0])
        j = _integer(path, lineno, "column", line[1])
        try:
            v = float(line[2])
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise InputError(path, lineno, f"value: not a finite number: {line[2]!r}", field="value")
        if not 0 <= i < n:
            raise InputError(path, lineno, f"observation: {i} is not an observation index (0 … {n - 1})",
                             field="observation")
        if (i, j) in seen:
            raise InputError(path, lineno, f"observation {i}, column {j} given twice (first at line {seen[i, j]})",
                             field="observation")
        seen[i, j] = lineno
        rows.append(i)
        cols.append(j)
        vals.append(v)
    if not rows:
        raise InputError(path, 0, "no entries: a hypothesis file lists 'observation column value' lines")
    q = max(cols) + 1
    used = set(cols)
    if len(used) < q:            # (found among the first len(used) + 1 columns: a column 10¹² lists no 10¹²)
        empty = [j for j in range(min(q, len(used) + 11)) if j not in used][:10]
        more = " …" if q - len(used) > len(empty) else ""
        raise InputError(path, 0, f"column(s) {', '.join(map(str, empty))}{more} have no entry (columns are "
                         f"0 … {q - 1}: every column needs an entry)", field="column")
    return sp.csc_matrix((np.array(vals), (np.array(rows), np.array(cols))), shape=(n, q))


def _integer(path, lineno: int, field: str, text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise InputError(path, lineno, f"{field}: not an integer: {text!r}", field=field) from None
    if value < 0:
        raise InputError(path, lineno, f"{field}: must not be negative: {value}", field=field)
    return value


#: The --hypothesis specifications of ``baarda test`` (fields separated by ':').


def parse_hypothesis(text: str) -> dict:
    """A --hypothesis SPEC as the specification dict of
    :func:`baarda.stats.hypotheses.hypothesis_matrix` (``file:PATH`` gives {"kind": "file", "path"});
    BaardaError naming the argument for a malformed one."""
    kind, _, rest = text.partition(":")
    forms = {spec.split(":", 1)[0]: spec for spec in HYPOTHESIS_SPECS}
    if kind not in forms:
        raise UsageError(f"--hypothesis {text!r}: unknown kind {kind!r} (one of {', '.join(forms)})")
    if kind == "file":
        if not rest:
            raise UsageError(f"--hypothesis {text!r}: expected file:PATH")
        return {"kind": "file", "path": rest}
    names = {"observation": ["index"], "group": ["group"], "image-point": ["image", "point"],
             "control": ["point"], "transfer": ["point", "images"], "ap-group": ["camera", "group"],
             "exchanged": ["image", "a", "b"], "model-point": ["model", "point"], "gnss": ["image"],
             "gnss-strip": ["strip"]}[kind]
    parts = rest.split(":") if rest else []
    if kind == "image-point" and len(parts) == 3:          # a COLMAP image's keypoint on the point
        names = names + ["keypoint"]
    if len(parts) != len(names) or not all(parts):
        raise UsageError(f"--hypothesis {text!r}: expected {forms[kind]}")
    spec = {"kind": kind, **dict(zip(names, parts))}
    if kind in ("observation", "group"):
        key = names[0]
        try:
            spec[key] = int(spec[key])
        except ValueError:
            raise UsageError(f"--hypothesis {text!r}: {key.upper()} must be an integer, not {spec[key]!r}") from None
    if kind == "transfer":
        spec["images"] = [im for im in spec["images"].split(",") if im]
    return spec
