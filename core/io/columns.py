"""Tables of the result document as columns: the same records as
:class:`baarda.io.results.Records` makes one dict at a time, made as arrays and written as JSON
lines, CSV rows or numpy columns a chunk of rows at a time.

A table is a list of :class:`Field` (one key each, in the records' key order); a field absent
from some records has a ``present`` mask. The texts are those the compiled JSON encoder writes
for the dicts (``float.__repr__``, ``null`` for a number that does not exist, strings escaped
to ASCII), so the document is the same byte for byte; the per-record path stays the reference
(tests/io/test_columns.py compares both).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

#: Rows per chunk of text: a block of millions of image points never holds all its lines.
CHUNK = 32768

_ENCODE = json.JSONEncoder(allow_nan=False, ensure_ascii=True, separators=(", ", ": ")).encode


@dataclass
class Codes:
    """Strings as ``categories[codes]`` (−1: none), sliced as a sequence is."""

    def __init__(self, categories, codes):
        self.categories, self.codes = tuple(categories), np.asarray(codes)

    def __getitem__(self, sl):
        return Codes(self.categories, self.codes[sl])

    def __len__(self):
        return self.codes.shape[0]


@dataclass
class Field:
    """One key of a table. ``kind``: "num" (a float array; a non-finite number is null),
    "int", "bool" (arrays), "str" (a sequence of str, None where absent) or "obj" (``values(sl)``
    gives the records' Python values of rows ``sl``, ``text(sl)`` optionally their JSON texts).
    ``present``: the rows that have the key (None: all). A "str" field's values may be
    categories (``categories`` and ``codes``, −1 where absent) instead of the strings."""

    key: str
    kind: str
    values: object
    present: np.ndarray | None = None
    text: object = None

    def texts(self, sl: slice) -> list:
        """The JSON texts of rows ``sl`` (anything where the key is absent)."""
        k, v = self.kind, self.values
        if k == "num":
            return num_texts(v[sl])
        if k == "int":
            return list(map(str, v[sl].tolist()))
        if k == "bool":
            return np.where(v[sl], "true", "false").tolist()
        if k == "str":
            return str_texts(v[sl])
        if self.text is not None:
            return self.text(sl)
        return [_ENCODE(x) for x in v(sl)]

    def python(self, sl: slice) -> list:
        """The records' values of rows ``sl`` (None where a number does not exist or the key is absent)."""
        k, v = self.kind, self.values
        if k == "num":
            return num_values(v[sl])
        if k == "str" and getattr(v, "categories", None) is not None:
            cats = list(v.categories) + [None]
            out = [cats[c] for c in np.asarray(v.codes[sl]).tolist()]
        elif k in ("int", "bool", "str"):
            out = v[sl].tolist() if isinstance(v, np.ndarray) else list(v[sl])
        else:
            out = list(v(sl))
        if self.present is not None:
            out = [x if p else None for x, p in zip(out, self.present[sl].tolist())]
        return out


def num_texts(a: np.ndarray) -> list:
    """``float.__repr__`` of each number (as json writes them), ``null`` where not finite."""
    a = np.asarray(a, dtype=float)
    out = list(map(float.__repr__, a.tolist()))
    for i in np.flatnonzero(~np.isfinite(a)).tolist():
        out[i] = "null"
    return out


def num_values(a: np.ndarray) -> list:
    """The numbers as Python floats, None where not finite (:func:`baarda.io.results._num`)."""
    a = np.asarray(a, dtype=float)
    out = a.tolist()
    for i in np.flatnonzero(~np.isfinite(a)).tolist():
        out[i] = None
    return out


def str_texts(values) -> list:
    """The JSON texts of a sequence of strings (each distinct one encoded once); None → null.
    A sequence of categories (``categories``, ``codes``: :class:`baarda.model.problem.Categorical`)
    is encoded by its categories."""
    cats = getattr(values, "categories", None)
    if cats is not None and not isinstance(values, np.ndarray):
        enc = np.array([_ENCODE(c) for c in cats] + ["null"], dtype=object)
        return enc[np.asarray(values.codes)].tolist()       # (a code −1: null, where absent)
    values = list(values)
    memo = {s: _ENCODE(s) for s in set(values)}
    return list(map(memo.__getitem__, values))


class _Null:
    """A number that does not exist, in a row's format (``%r``): ``null``."""

    def __repr__(self):
        return "null"


_NULL = _Null()


def _num_cells(a: np.ndarray) -> tuple[str, list]:
    """The conversion and the cells of a number column in a row's format: the floats themselves
    (``%r`` is ``float.__repr__``, non-finite ones :data:`_NULL`), or, where a few values repeat
    over the rows (σ, critical values, α), their texts made once each (``%s``)."""
    a = np.asarray(a, dtype=float)
    if a.size > 64:
        u, inv = np.unique(a, return_inverse=True)
        if u.size * 8 <= a.size:
            return "%s", np.array(num_texts(u), dtype=object)[inv.ravel()].tolist()
    out = a.tolist()
    for i in np.flatnonzero(~np.isfinite(a)).tolist():
        out[i] = _NULL
    return "%r", out


def row_texts(fields: list[Field], sl: slice, n: int) -> list[str]:
    """The compact JSON object of each row of ``sl`` (``n`` rows), keys in the fields' order:
    one format per table (``'{"index": %s, "w": %r, ...}'``) applied to each row's cells."""
    fmt, cols = [], []
    for j, f in enumerate(fields):
        prefix = (("{" if j == 0 else ", ") + _ENCODE(f.key) + ": ").replace("%", "%%")
        if f.present is not None:
            if j == 0:
                raise ValueError("the first field of a table must be in every row")
            frag = list(map(prefix.__add__, f.texts(sl)))
            cols.append([t if p else "" for t, p in zip(frag, f.present[sl].tolist())])
            fmt.append("%s")
        elif f.kind == "num":
            conv, cells = _num_cells(f.values[sl])
            fmt.append(prefix + conv)
            cols.append(cells)
        else:
            fmt.append(prefix + "%s")
            cols.append(f.texts(sl))
    if not fields:
        return ["{}"] * n
    return list(map(("".join(fmt) + "}").__mod__, zip(*cols)))


def chunks(n: int, size: int = CHUNK):
    """The slices of ``n`` rows, ``size`` at a time."""
    for a in range(0, n, size):
        yield slice(a, min(n, a + size))


def key_order(fields: list[Field], n: int) -> list[str]:
    """The keys in the order in which the records first have them (the union over the rows in
    order, as the CSV writer and :func:`baarda.io.results.columns` take them)."""
    partial = [j for j, f in enumerate(fields) if f.present is not None]
    if not partial or n == 0:
        return [f.key for f in fields] if n else []
    masks = np.stack([fields[j].present for j in partial], axis=1)
    _, first = np.unique(masks, axis=0, return_index=True)
    keys: dict = {}
    for row in sorted(first.tolist()):
        keys.update(dict.fromkeys(f.key for f in fields if f.present is None or f.present[row]))
    return list(keys)


def column(vals: list):
    """One column of records' values (None where absent or null) as a numpy array (the rules of
    :func:`baarda.io.results.columns`)."""
    present = [v for v in vals if v is not None]
    if present and all(isinstance(v, bool) for v in present) and len(present) == len(vals):
        return np.array(vals, dtype=bool)
    if present and all(isinstance(v, int) and not isinstance(v, bool) for v in present) and len(present) == len(vals):
        return np.array(vals, dtype=np.int64)
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        return np.array([np.nan if v is None else float(v) for v in vals], dtype=float)
    arr = np.empty(len(vals), dtype=object)
    arr[:] = vals
    return arr


def field_column(f: Field, n: int):
    """:func:`column` of field ``f`` over ``n`` rows, without making Python values where arrays do."""
    full = f.present is None
    if f.kind == "num":
        a = np.array(f.values, dtype=float)
        a[~np.isfinite(a)] = np.nan
        if not full:
            a[~f.present] = np.nan
        return a
    if f.kind == "int" and full:
        return np.asarray(f.values, dtype=np.int64).copy()
    if f.kind == "int":
        a = np.asarray(f.values, dtype=float).copy()
        a[~f.present] = np.nan
        return a
    if f.kind == "bool" and full:
        return np.asarray(f.values, dtype=bool).copy()
    return column(f.python(slice(0, n)))
