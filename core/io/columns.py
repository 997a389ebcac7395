"""Tables of the result document as columns: the same records as
:class:`baarda.io.results.Records` makes one dict at a time, made as arrays and written as JSON
lines, CSV rows or numpy columns a chunk of rows at a time.

A table is a list of :class:`Field` (one key each, in the records' key order); a field absent
from some records has a ``present`` mask. The texts are those the compiled JSON encoder writes
for the dicts (``float.__repr__``, ``null`` for a number that does not exist, strings escaped
to ASCII), so the document is the same byte for byte; the per-record path stays the reference
(tests/io/test_columns.py compares both).

Numbers become text through orjson where it is installed (the ``fast`` extra; compiled shortest
round-trip digits, ~5× ``float.__repr__``), else through ``float.__repr__``: the same bytes
(orjson writes a finite double as ``repr`` does but for 0 < |x| < 1e-4, ``0.00001`` and
``1e-7`` for ``1e-05`` and ``1e-07``; those few are written by ``repr``; tests/io/test_columns.py
compares both paths).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from json.encoder import encode_basestring_ascii

import numpy as np

from ..lazy import installed, lazy

#: orjson where installed (the numbers' texts, :func:`num_texts`), else None (``float.__repr__``)
orjson = lazy("orjson") if installed("orjson") else None
#: pyarrow where installed (the ``batch`` extra; :func:`arrow_array`), else None
pa = lazy("pyarrow") if installed("pyarrow") else None
pq = lazy("pyarrow.parquet") if pa is not None else None

#: numbers whose texts orjson must write as ``repr`` does before it is used (a version that
#: writes ``1e16`` for ``1e+16`` or drops ``-0.0``'s sign is not)
_PROBE = (1e16, 1.5e16, 1e22, 1.7976931348623157e308, 123456789012345680.0, 1e15, 0.0001, 0.00012345,
          0.1, 1 / 3, 2.0, -0.0, 0.0, -2.5e-300, 5e-324, 9007199254740993.0, float("nan"), float("inf"))
_AGREES: dict = {}


def _fast():
    """:data:`orjson` if it is installed and writes the probe numbers as ``repr`` does, else None."""
    mod = orjson
    if mod is None:
        return None
    if id(mod) not in _AGREES:
        probe = np.array(_PROBE)
        ref = ",".join("null" if not np.isfinite(x) else (repr(x) if abs(x) >= 1e-4 or x == 0 else "")
                       for x in probe.tolist())
        got = mod.dumps(probe, option=mod.OPT_SERIALIZE_NUMPY).decode("ascii")[1:-1].split(",")
        got = ",".join("" if x != 0 and abs(x) < 1e-4 else t for x, t in zip(probe.tolist(), got))
        _AGREES[id(mod)] = got == ref
    return mod if _AGREES[id(mod)] else None

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

    def cells(self, sl: slice, prefix: str) -> list:
        """``prefix`` + the JSON text of each row of ``sl`` ("" where the key is absent)."""
        k, v = self.kind, self.values
        if k == "num":
            out = num_texts(v[sl], prefix)
        elif k == "int" and _fast() is not None:
            fast = _fast()
            out = _prefixed(fast.dumps(np.ascontiguousarray(v[sl], dtype=np.int64), option=fast.OPT_SERIALIZE_NUMPY),
                            prefix)
        elif k == "bool":
            out = np.array([prefix + "false", prefix + "true"], dtype=object)[np.asarray(v[sl], dtype=np.intp)].tolist()
        elif k == "str":
            out = str_texts(v[sl], prefix)
        else:
            out = list(map(prefix.__add__, self.texts(sl)))
        if self.present is not None:
            out = [t if p else "" for t, p in zip(out, self.present[sl].tolist())]
        return out

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


def _prefixed(dumped: bytes, prefix: str) -> list:
    """``prefix`` + each item of a JSON array of numbers as orjson writes it (b"[1,2.5,null]")."""
    text = dumped[1:-1].decode("ascii")
    if not text:
        return []
    return (prefix + text.replace(",", "\n" + prefix)).split("\n")   # (no line break in a prefix)


def num_texts(a: np.ndarray, prefix: str = "") -> list:
    """``prefix`` + ``float.__repr__`` of each number (as json writes them), ``null`` where not
    finite; through :data:`orjson` where installed (the same texts)."""
    a = np.ascontiguousarray(a, dtype=float).ravel()
    bits = a.view(np.int64)                # (bits: 0.0 and -0.0 are two texts)
    if a.size > 1 and bits[0] == bits[-1] and (bits == bits[0]).all():     # one value (σ of every image point)
        return num_texts(a[:1], prefix) * a.size
    fast = _fast()
    if fast is not None:
        out = _prefixed(fast.dumps(a, option=fast.OPT_SERIALIZE_NUMPY), prefix)
        # (orjson writes null for NaN and ±inf; 0 < |x| < 1e-4 in its own way: those by repr)
        for i in np.flatnonzero((np.abs(a) < 1e-4) & (a != 0)).tolist():
            out[i] = prefix + float.__repr__(float(a[i]))
        return out
    if a.size > 64:                        # a few values repeating over the rows (σ, critical values, α)
        u, inv = np.unique(bits, return_inverse=True)                  # (of the bits: 0.0 ≠ -0.0)
        if u.size * 8 <= a.size:
            return np.array(num_texts(u.view(float), prefix), dtype=object)[inv.ravel()].tolist()
    out = list(map(float.__repr__, a.tolist()))
    for i in np.flatnonzero(~np.isfinite(a)).tolist():
        out[i] = "null"
    return list(map(prefix.__add__, out)) if prefix else out


def list_texts(a: np.ndarray, real: bool = True) -> list:
    """The JSON lists (``[1.5, 2.0]``) of the rows of a 2-d array (numbers, ``null`` where not
    finite, as :func:`num_texts`, if ``real``; else integers); through :data:`orjson` where
    installed and no number needs ``repr`` (0 < |x| < 1e-4), the same texts."""
    a = np.ascontiguousarray(a, dtype=float if real else np.int64)
    n, k = a.shape
    if n == 0:
        return []
    if k == 0:
        return ["[]"] * n
    fast = _fast()
    if fast is not None and not (real and ((np.abs(a) < 1e-4) & (a != 0)).any()):
        text = fast.dumps(a, option=fast.OPT_SERIALIZE_NUMPY).decode("ascii")[1:-1]
        return text.replace(",", ", ").replace("], [", "]\n[").split("\n")
    t = num_texts(a.ravel()) if real else list(map(str, a.ravel().tolist()))
    return list(map(("[" + ", ".join(["%s"] * k) + "]").__mod__, zip(*(t[j::k] for j in range(k)))))


def ragged_texts(flat: np.ndarray, ptr: np.ndarray, real: bool = True) -> list:
    """The JSON lists of ``flat[ptr[i]:ptr[i + 1]]`` for each i (``ptr`` from ``ptr[0]``), as
    :func:`list_texts`: the rows of each length at once."""
    ptr = np.asarray(ptr, dtype=np.int64)
    start, size = ptr[:-1] - ptr[0], np.diff(ptr)
    flat = np.asarray(flat)[ptr[0]:ptr[-1]]
    if size.size and (size == size[0]).all():            # lists of one length (q = 2 of image points)
        return list_texts(flat.reshape(size.size, int(size[0])), real)
    out = np.empty(size.size, dtype=object)
    for k in np.unique(size).tolist():
        rows = np.flatnonzero(size == k)
        out[rows] = list_texts(flat[start[rows, None] + np.arange(k)], real)
    return out.tolist()


def num_values(a: np.ndarray) -> list:
    """The numbers as Python floats, None where not finite (:func:`baarda.io.results._num`)."""
    a = np.asarray(a, dtype=float)
    out = a.tolist()
    for i in np.flatnonzero(~np.isfinite(a)).tolist():
        out[i] = None
    return out


def _string(x) -> str:
    """The JSON text of a string (escaped to ASCII), ``null`` for None."""
    return encode_basestring_ascii(x) if type(x) is str else _ENCODE(x)


def str_texts(values, prefix: str = "") -> list:
    """``prefix`` + the JSON text of each of a sequence of strings (each distinct one encoded
    once); None → null. A sequence of categories (``categories``, ``codes``:
    :class:`baarda.model.problem.Categorical`) is encoded by its categories."""
    cats = getattr(values, "categories", None)
    if cats is not None and not isinstance(values, np.ndarray):
        codes = np.asarray(values.codes)
        enc = np.full(len(cats) + 1, prefix + "null", dtype=object)      # (a code −1: null, where absent)
        used = np.unique(codes[codes >= 0]).tolist()
        enc[used] = [prefix + _string(cats[c]) for c in used]
        return enc[codes].tolist()
    values = list(values)
    memo = {s: prefix + _string(s) for s in set(values)}
    return list(map(memo.__getitem__, values))


def rows_text(fields: list[Field], sl: slice, n: int, sep: str = ",\n  ") -> str:
    """The compact JSON objects of the rows of ``sl`` (``n`` rows), keys in the fields' order,
    joined by ``sep``: the cells of all rows, each with its key (``{"index": 0``, ``, "w": 1.5``),
    in one list row by row, joined once (no format applied per row). A row's JSON has no line
    break (strings are escaped to ASCII)."""
    if n == 0:
        return ""
    if not fields:
        return sep.join(["{}"] * n)
    if fields[0].present is not None:
        raise ValueError("the first field of a table must be in every row")
    width = len(fields) + 1
    flat = [None] * (width * n)
    for j, f in enumerate(fields):
        flat[j::width] = f.cells(sl, ("{" if j == 0 else ", ") + _string(f.key) + ": ")
    flat[width - 1::width] = ["}" + sep] * n
    flat[-1] = "}"
    return "".join(flat)


def row_texts(fields: list[Field], sl: slice, n: int) -> list[str]:
    """The compact JSON object of each row of ``sl`` (``n`` rows), keys in the fields' order
    (:func:`rows_text`)."""
    return rows_text(fields, sl, n, "\n").split("\n") if n else []


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


def arrow_array(f: Field, n: int):
    """Field ``f`` over ``n`` rows as a typed Arrow array, null where the key is absent: numbers
    float64 (null where the JSON has null), integers int64, booleans bool, strings string
    (dictionary-coded where they are categories), anything else as Arrow types its values (lists
    of numbers), or as its JSON text where they have no one type."""
    k, v = f.kind, f.values
    absent = None if f.present is None else ~np.asarray(f.present, dtype=bool)
    if k == "num":
        a = np.ascontiguousarray(v, dtype=float)
        missing = ~np.isfinite(a) if absent is None else ~np.isfinite(a) | absent
        return pa.array(a, mask=missing if missing.any() else None)
    if k in ("int", "bool"):
        return pa.array(np.ascontiguousarray(v, dtype=np.int64 if k == "int" else bool), mask=absent)
    if k == "str" and getattr(v, "categories", None) is not None and not isinstance(v, np.ndarray):
        codes = np.asarray(v.codes)
        missing = codes < 0 if absent is None else (codes < 0) | absent
        return pa.DictionaryArray.from_arrays(pa.array(np.maximum(codes, 0).astype(np.int32), mask=missing),
                                              pa.array(list(v.categories), type=pa.string()))
    vals = f.python(slice(0, n))
    if k == "str":
        return pa.array(vals, type=pa.string())
    return _arrow_values(vals)


def _arrow_values(vals: list):
    """Python values as Arrow infers their type; where they have none, their JSON texts."""
    try:
        return pa.array(vals)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return pa.array([None if x is None else _ENCODE(x) for x in vals], type=pa.string())


def arrow_column(a: np.ndarray):
    """A column of :func:`column` (NaN where null or absent) as a typed Arrow array."""
    if a.dtype == float:
        missing = np.isnan(a)
        return pa.array(a, mask=missing if missing.any() else None)
    if a.dtype in (np.int64, bool):
        return pa.array(a)
    return _arrow_values(a.tolist())
