"""The bad-input contract of the ``baarda`` command, fuzzed (issue 12).

Every format's valid files (Gama XML, native JSON, BAL, Bundler, COLMAP text and binary, the
control CSV) are mutated with fixed seeds — byte flips, deleted, duplicated or swapped lines,
numbers replaced by huge, tiny, long or Unicode digits, control characters, truncation, deep
nesting, a BOM, CR or CRLF line ends, a 200,000-character field — and run in-process through
``baarda.cli.main(["analyze", FILE, "--json", OUT])``. The contract for each case:

* exit status 0, 2, or the documented non-convergence status (``baarda.cli.NOT_CONVERGED``, if
  the CLI defines one, with one line on stderr);
* on 2: exactly one line on stderr, ``baarda: error: FILE:LINE[:FIELD]: what is wrong``
  (``FILE:byte N:`` in binary files), with no control character in it;
* no warning of any kind (numpy RuntimeWarnings included), no traceback;
* on 0 (and non-convergence): no number printed as ``nan``/``inf``, no raw control character
  on stdout, and the JSON written is strict JSON (no ``NaN``/``Infinity``).

The unmarked tests run a fast subset (25 cases per seed, 15 more with ``--snoop --robust
--variance-components``); the ``slow`` ones 300 per seed (60 of the 0.4 s bundle block): about
3,900 cases with the Gama examples of ``../shared/extdata``, ~70 s of CPU.
Exploring: ``python tests/test_fuzz_contract.py SEED_NAME N [BASE_SEED [OPTION...]]`` lists the
cases that break the contract.
The minimal cases found this way are kept as files in ``tests/malformed/`` (``test_bad_input.py``).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import re
import shutil
import struct
import time
import warnings
from pathlib import Path

import pytest

from baarda import cli

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
VALID = HERE / "malformed" / "valid"
EXTDATA_GAMA = (REPO / ".." / "shared" / "extdata" / "gama").resolve()

# the documented status of an adjustment that did not converge (one line on stderr), if any
NOT_CONVERGED = getattr(cli, "EXIT_NOT_CONVERGED", getattr(cli, "NOT_CONVERGED", None))
OK_CODES = {0, 2} | ({NOT_CONVERGED} if NOT_CONVERGED is not None else set())
ERROR_LINE = re.compile(r"baarda: error: [^\n]*?:(\d+|byte \d+)(:[^\s:][^\n:]*)?: [^\n]+\n")
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\u2028\u2029]")
# a number printed as nan/inf (" = nan", "a posteriori inf", "[nan, ..."); ids and titles come
# from the file and may be the word "nan" ("from=nan", a title "nan benchmarks")
NAN = re.compile(r"(\s=\s+|posteriori\s+|priori\s+|\[)[+-]?(nan|inf)\b", re.IGNORECASE)


# --------------------------------------------------------------------------------------------
# running one case
# --------------------------------------------------------------------------------------------
def run_cli(argv: list[str]) -> tuple[int, str, str, list[str]]:
    """``cli.main(argv)`` in-process: exit status, stdout, stderr, warnings raised."""
    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err):
        warnings.simplefilter("always")
        try:
            code = cli.main(argv)
        except SystemExit as exc:          # argparse usage errors
            code = exc.code
    return code, out.getvalue(), err.getvalue(), [f"{w.category.__name__}: {w.message}" for w in caught]


def _strict_json(text: str):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def check_contract(argv: list[str], json_out: Path | None = None, what: str = "") -> int:
    """Run ``argv`` and assert the contract (module docstring); returns the exit status."""
    code, out, err, caught = run_cli(argv)
    where = f"{what}: exit {code}, stderr {err!r}"
    assert code in OK_CODES, where
    assert not caught, f"{where}; warnings {caught}"
    assert "Traceback" not in err, where
    if code == 2:
        assert ERROR_LINE.fullmatch(err), where
        assert not CONTROL.search(err[:-1]), where
    if code == NOT_CONVERGED:
        assert err.count("\n") == 1 and err.startswith("baarda: ") and err[:-1].isprintable(), where
    if code in (0, NOT_CONVERGED):
        assert not NAN.search(out), f"{where}; stdout {out!r}"
        assert not CONTROL.search(out.replace("\n", "")), f"{where}; stdout {out!r}"
        if json_out is not None and json_out.exists():
            _strict_json(json_out.read_text())
    return code


# --------------------------------------------------------------------------------------------
# seeds: each a dict of files (relative path -> bytes) and how to run it
# --------------------------------------------------------------------------------------------
def colmap_binary(directory: Path) -> dict[str, bytes]:
    """The COLMAP text model in ``directory`` written as cameras.bin, images.bin, points3D.bin
    (COLMAP's src/colmap/scene/reconstruction_io.cc layout), by hand — no pycolmap needed."""
    from baarda.io.colmap import CAMERA_MODELS, MODEL_IDS

    ids = {name: k for k, name in MODEL_IDS.items()}
    cams = [ln.split() for ln in (directory / "cameras.txt").read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    cb = struct.pack("<Q", len(cams))
    for c in cams:
        k = len(CAMERA_MODELS[c[1]][0])
        cb += struct.pack("<IiQQ", int(c[0]), ids[c[1]], int(c[2]), int(c[3]))
        cb += struct.pack("<" + "d" * k, *map(float, c[4:4 + k]))
    lines = [ln for ln in (directory / "images.txt").read_text().splitlines() if not ln.startswith("#")]
    ib = struct.pack("<Q", len(lines) // 2)
    for head, pts in zip(lines[0::2], lines[1::2]):
        h = head.split()
        ib += struct.pack("<I7dI", int(h[0]), *map(float, h[1:8]), int(h[8])) + h[9].encode() + b"\0"
        t = pts.split()
        ib += struct.pack("<Q", len(t) // 3)
        for j in range(0, len(t), 3):
            pid = int(t[j + 2])
            ib += struct.pack("<ddQ", float(t[j]), float(t[j + 1]), pid if pid >= 0 else 2**64 - 1)
    pts = [ln.split() for ln in (directory / "points3D.txt").read_text().splitlines()
           if ln.strip() and not ln.startswith("#")]
    pb = struct.pack("<Q", len(pts))
    for p in pts:
        track = list(map(int, p[8:]))
        pb += struct.pack("<Q3d3BdQ", int(p[0]), *map(float, p[1:4]), *map(int, p[4:7]), float(p[7]),
                          len(track) // 2)
        pb += struct.pack("<" + "I" * len(track), *track)
    return {"cameras.bin": cb, "images.bin": ib, "points3D.bin": pb}


def _colmap_text() -> dict[str, bytes]:
    return {f"model/{f}": (VALID / "colmap-valid" / f).read_bytes()
            for f in ("cameras.txt", "images.txt", "points3D.txt")}


def seeds() -> dict[str, dict]:
    """name -> {"files": {rel: bytes}, "input": rel, "mutable": [rel, ...], "binary": bool,
    "control": rel or None}."""
    s = {}

    def add(name, files, inp, mutable=None, binary=False, control=None):
        s[name] = {"files": files, "input": inp, "mutable": mutable or [inp], "binary": binary,
                   "control": control}

    add("gama-levelling", {"a.gkf": (REPO / "data" / "demo-levelling.gkf").read_bytes()}, "a.gkf")
    add("gama-loop", {"a.gkf": (VALID / "levelling-valid.gkf").read_bytes()}, "a.gkf")
    for name in ("geodet-pc-123.gkf", "jezerka-ang.gkf", "local_3d.gkf"):
        if (EXTDATA_GAMA / name).exists():
            add(f"gama-{name[:-4]}", {"a.gkf": (EXTDATA_GAMA / name).read_bytes()}, "a.gkf")
    add("native-levelling", {"a.json": (VALID / "levelling-valid.json").read_bytes()}, "a.json")
    add("native-imodel", {"a.json": (REPO / "data" / "demo-imodel.json").read_bytes()}, "a.json")
    add("native-block", {"a.json": (REPO / "data" / "demo-block.json").read_bytes()}, "a.json")
    add("bal", {"a.txt": (VALID / "bal-valid.txt").read_bytes()}, "a.txt")
    add("bundler", {"a.out": (VALID / "bundler-valid.out").read_bytes()}, "a.out")
    text = _colmap_text()
    add("colmap-text", text, "model", mutable=list(text))
    binary = {f"model/{k}": v for k, v in colmap_binary(VALID / "colmap-valid").items()}
    add("colmap-binary", binary, "model", mutable=list(binary), binary=True)
    add("control", {"a.txt": (VALID / "bal-valid.txt").read_bytes(),
                    "c.csv": (VALID / "control-valid.csv").read_bytes()}, "a.txt", mutable=["c.csv"],
        control="c.csv")
    return s


SEEDS = seeds()


# --------------------------------------------------------------------------------------------
# mutations
# --------------------------------------------------------------------------------------------
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
REPLACEMENTS = [b"1e308", b"-1e308", b"1e-300", b"1e-320", b"1e300", b"0", b"-0", b"nan", b"inf", b"-1",
                b"9" * 400, b"1" + b"0" * 5000, "\u00b2".encode(), "\u2460".encode(), "\u0663".encode(),
                "1\u00b2".encode(), b"0x10", b"1_000", b"", b"x", b"\"", b"<", b",", b"{", b"]",
                b"1e1000", b"4.9e-324", b"1.7976931348623157e308", b"-2147483649", b"4294967296",
                b"18446744073709551616"]
CONTROLS = [b"\x1b[2J", b"\x1b]0;owned\x07", b"\r", b"\n", b"\x07", "\u202e".encode(), "\u0085".encode(),
            b"\x00", b"\x7f", "\u2028".encode(), b"\t"]


def _lines(b: bytes) -> list[bytes]:
    return b.split(b"\n")


def mutate_text(data: bytes, rng: random.Random, kind: str) -> bytes:
    """One mutation of a text file."""
    ops = ["flip", "delete", "duplicate", "swap", "number", "number", "number", "control", "truncate",
           "span", "bom", "crlf", "cr", "long", "nest"]
    op = rng.choice(ops)
    lines = _lines(data)
    k = rng.randrange(len(lines)) if lines else 0
    if op == "flip" and data:
        i = rng.randrange(len(data))
        return data[:i] + bytes([rng.randrange(256)]) + data[i + 1:]
    if op == "delete" and lines:
        del lines[k]
        return b"\n".join(lines)
    if op == "duplicate" and lines:
        lines.insert(k, lines[k])
        return b"\n".join(lines)
    if op == "swap" and lines:
        j = rng.randrange(len(lines))
        lines[k], lines[j] = lines[j], lines[k]
        return b"\n".join(lines)
    if op == "number":
        found = list(NUMBER.finditer(data))
        if found:
            m = rng.choice(found)
            return data[:m.start()] + rng.choice(REPLACEMENTS) + data[m.end():]
    if op == "control" and data:
        # next to an id or a number: ids end up in messages and summaries
        quote = [m.end() - 1 for m in re.finditer(rb'"[A-Za-z0-9_]+"', data)] if kind in ("json", "xml") else []
        i = rng.choice(quote) if quote and rng.random() < 0.7 else rng.randrange(len(data))
        return data[:i] + rng.choice(CONTROLS) + data[i:]
    if op == "truncate" and data:
        return data[:rng.randrange(len(data))]
    if op == "span" and data:
        i = rng.randrange(len(data))
        return data[:i] + data[i + rng.randint(1, 32):]
    if op == "bom":
        return b"\xef\xbb\xbf" + data
    if op == "crlf":
        return data.replace(b"\n", b"\r\n")
    if op == "cr":
        return data.replace(b"\n", b"\r")
    if op == "long" and data:
        i = rng.randrange(len(data))
        return data[:i] + rng.choice([b"x", b"7", b" "]) * 200_000 + data[i:]
    if op == "nest":
        depth = rng.choice([100, 1000, 5000])
        if kind == "json":
            found = list(NUMBER.finditer(data))
            if found:
                m = rng.choice(found)
                return data[:m.start()] + b"[" * depth + m.group() + b"]" * depth + data[m.end():]
        if kind == "xml":
            i = data.find(b"<points-observations>")
            if i >= 0:
                i += len(b"<points-observations>")
                return data[:i] + b"<a>" * depth + b"</a>" * depth + data[i:]
    return data


def mutate_binary(data: bytes, rng: random.Random) -> bytes:
    op = rng.choice(["flip", "flip", "delete", "insert", "truncate", "big"])
    if not data:
        return data
    i = rng.randrange(len(data))
    if op == "flip":
        return data[:i] + bytes([rng.randrange(256)]) + data[i + 1:]
    if op == "delete":
        return data[:i] + data[i + rng.randint(1, 16):]
    if op == "insert":
        return data[:i] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 16))) + data[i:]
    if op == "truncate":
        return data[:i]
    # a double or count replaced by an extreme value
    i -= i % 8
    val = rng.choice([struct.pack("<d", v) for v in (1e308, 1e-300, float("nan"), float("inf"), 0.0)]
                     + [struct.pack("<Q", v) for v in (2**63, 2**32, 0)])
    return data[:i] + val + data[i + 8:]


def _kind(rel: str) -> str:
    return {"gkf": "xml", "json": "json"}.get(rel.rsplit(".", 1)[-1], "text")


def make_case(seed: dict, rng: random.Random) -> dict[str, bytes]:
    files = dict(seed["files"])
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        rel = rng.choice(seed["mutable"])
        files[rel] = (mutate_binary(files[rel], rng) if seed["binary"]
                      else mutate_text(files[rel], rng, _kind(rel)))
    return files


def run_case(name: str, files: dict[str, bytes], tmp: Path, what: str = "", extra=()) -> int:
    seed = SEEDS[name]
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    for rel, data in files.items():
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp / rel).write_bytes(data)
    out = tmp / "result.json"
    argv = ["analyze", str(tmp / seed["input"]), "--json", str(out), "--top", "3", *extra]
    if seed["control"]:
        argv += ["--control", str(tmp / seed["control"])]
    return check_contract(argv, out, what or name)


def fuzz(name: str, n: int, tmp: Path, base_seed: int = 0, extra=()) -> dict[int, int]:
    """``n`` mutated cases of seed ``name``; returns how many ended with each exit status."""
    counts: dict[int, int] = {}
    for k in range(n):
        rng = random.Random(f"{name}:{base_seed}:{k}")
        files = make_case(SEEDS[name], rng)
        code = run_case(name, files, tmp / "case", what=f"{name} case {k} (seed {base_seed})", extra=extra)
        counts[code] = counts.get(code, 0) + 1
    return counts


# --------------------------------------------------------------------------------------------
# tests
# --------------------------------------------------------------------------------------------
# cases per seed: the fast subset (unmarked) and the big run (slow); the native bundle block
# costs ~0.4 s per analysis, the others 10-50 ms
FAST = {"native-block": 4}
SLOW = {"native-block": 60}


@pytest.mark.parametrize("name", sorted(SEEDS))
def test_valid_seed_keeps_the_contract(name, tmp_path):
    assert run_case(name, SEEDS[name]["files"], tmp_path / "case") == 0


@pytest.mark.parametrize("name", sorted(SEEDS))
def test_fuzz_contract_fast(name, tmp_path):
    counts = fuzz(name, FAST.get(name, 25), tmp_path, base_seed=1)
    assert sum(counts.values()) == FAST.get(name, 25)


# the analyses after the adjustment print their own logs (ids, σ̂0, weights)
ANALYSES = ["--snoop", "--robust", "huber", "--variance-components"]


@pytest.mark.parametrize("name", ["gama-loop", "native-levelling", "bal"])
def test_fuzz_contract_with_snooping_robust_and_variance_components(name, tmp_path):
    assert run_case(name, SEEDS[name]["files"], tmp_path / "valid", extra=ANALYSES) == 0
    counts = fuzz(name, 15, tmp_path, base_seed=3, extra=ANALYSES)
    assert sum(counts.values()) == 15


# --------------------------------------------------------------------------------------------
# edge classes (issue 25): outputs naming inputs, option values at and beyond their ranges,
# malformed truth files beside the input, encodings, hypothesis columns, recipes. Each case is
# refused with exit status 2 and one line, leaves every file as it was and ends in bounded time.
# --------------------------------------------------------------------------------------------
EDGE_SECONDS = 20.0
# text that is Python's, not ours: a message must say what is wrong in the user's terms
RAW = re.compile(r"invalid literal|could not convert|dtype|NoneType|object of type|not subscriptable|"
                 r"unsupported operand|Errno|<class|cannot be empty unless", re.IGNORECASE)
USAGE_LINE = re.compile(r"baarda: error: [^\n]+\n")


def edge_files(tmp: Path) -> None:
    """The valid inputs the edge cases start from."""
    shutil.copy(REPO / "data" / "demo-levelling.gkf", tmp / "a.gkf")
    shutil.copy(VALID / "levelling-valid.json", tmp / "a.json")
    shutil.copy(VALID / "bal-valid.txt", tmp / "bal.txt")
    shutil.copy(VALID / "control-valid.csv", tmp / "c.csv")
    shutil.copytree(VALID / "colmap-valid", tmp / "model")
    (tmp / "h.txt").write_text("0 0 1\n")
    (tmp / "hard.json").hardlink_to(tmp / "a.json")
    (tmp / "sym.json").symlink_to("a.gkf")
    (tmp / "r.json").write_text(json.dumps({"strips": 2, "images_per_strip": 3}))


TRUTHS = [b"\xff\xfe{\x00", b"[]", b"{", b"[" * 100_000, json.dumps({"format": "baarda-truth", "errors": 5}).encode()] + [
    json.dumps({"format": "baarda-truth", "errors": [e]}).encode() for e in
    (1, {"kind": 5}, {"kind": None}, {"kind": "image", "rows": [1e9]}, {"kind": "image", "rows": [-1]},
     {"kind": "image", "rows": [10**9]}, {"kind": "image", "rows": "0"}, {"kind": "image", "ids": []},
     {"kind": "image", "ids": {"a": {}}}, {"kind": "image", "size_sigma": "x"}, {"kind": "image", "class": 5})
]
RECIPES = [b"\xff\xfe", b"[1, 2]", b"{", b"[" * 100_000] + [json.dumps(r).encode() for r in (
    {"strips": 1e9}, {"strips": 10**9}, {"strips": 1.5}, {"strips": "3"}, {"forward_overlap": 1},
    {"flying_height": 1e20, "strips": 1}, {"sigma_image": 1e300}, {"seed": -1}, {"pattern": [4, 3]},
    {"pattern": 3}, {"camera": "x"}, {"camera": {"c": -1}}, {"camera": {"id": "c", "c": 1, "bogus": 1}},
    {"errors": [{"kind": "image", "size": "x"}]}, {"errors": [{"kind": "nope"}]}, {"errors": [5]},
    {"errors": [{"kind": "image", "point": "nope"}]}, {"errors": [{"kind": "image", "image": "nope"}]},
    {"errors": [{"kind": "exchange", "image": "nope"}]}, {"errors": [{"kind": "image", "component": "q"}]},
    {"errors": [{"kind": "transfer", "images": 50}]}, {"errors": [{"kind": "image", "size": 1e300}]},
    {"strips": 1, "images_per_strip": 1, "errors": [{"kind": "transfer"}]}, {"design": "yes"}, {"nope": 1})]


def edge_cases() -> list[tuple[str, list[str], dict[str, bytes]]]:
    """(name, argv relative to the case folder, extra files) of every edge case."""
    cases = []

    def add(name, argv, files=None):
        cases.append((name, argv, files or {}))

    # an output that names an input (also through a link, inside a model folder, the truth beside it)
    add("json=input", ["analyze", "a.json", "--json", "a.json"])
    add("geojson=input", ["analyze", "a.json", "--geojson", "a.json"])
    add("json=hard link", ["analyze", "a.json", "--json", "hard.json"])
    add("json=symlink", ["analyze", "a.gkf", "--json", "sym.json"])
    add("json in model", ["analyze", "model", "--json", "model/points3D.txt"])
    add("json=control", ["analyze", "bal.txt", "--control", "c.csv", "--json", "c.csv"])
    add("csv=control", ["analyze", "bal.txt", "--control", "points.csv", "--csv", "."],
        {"points.csv": (VALID / "control-valid.csv").read_bytes()})
    add("test json=input", ["test", "a.json", "-H", "observation:0", "--json", "a.json"])
    add("test json=H file", ["test", "a.json", "-H", "file:h.txt", "--json", "h.txt"])
    add("json=truth", ["analyze", "a.json", "--json", "a.truth.json"], {"a.truth.json": b"{}"})
    add("convert=link", ["convert", "a.gkf", "sym.json"])
    add("report=link", ["report", "a.json", "-o", "hard.json"])
    add("report exists", ["report", "a.json"], {"a.html": b"old"})
    add("simulate=recipe", ["simulate", "r.json", "--recipe", "r.json"])
    add("json unwritable", ["analyze", "a.json", "--json", "/nonexistent/x.json"])
    add("json folder", ["analyze", "a.json", "--json", "model"])
    add("json /proc", ["analyze", "a.json", "--json", "/proc/x.json"])
    # option values at and beyond their ranges
    for opt, vals in {"--alpha": ["0", "1", "0.9", "1e-21", "nan", "inf", "-0.1", "x", ""],
                      "--beta": ["0.001", "0", "1", "nan", "x"], "--max-iter": ["0", "-1", "1e9", "x"],
                      "--top": ["-1", "x", "1e99"], "--sigma-px": ["0", "-1", "1e300", "nan", "inf"],
                      "--criterion-c0": ["-1", "nan"], "--risk-lambda-bar": ["0", "inf"]}.items():
        inp = "bal.txt" if opt == "--sigma-px" else "a.json"
        for v in vals:
            add(f"analyze {opt} {v!r}", ["analyze", inp, opt, v])
    add("beta below alpha", ["analyze", "a.json", "--alpha", "0.3", "--beta", "0.2"])
    for opt, vals in {"--forward-overlap": ["1", "-0.1", "nan"], "--side-overlap": ["1"],
                      "--flying-height": ["1e20", "0", "-5"], "--strips": ["1e9", "0", "1000000000", "x"],
                      "--images": ["0", "100000"], "--seed": ["-1", "x"], "--check": ["-1"],
                      "--sigma-image": ["0", "1e300"], "--radial": ["1e300"], "--camera": ["x"],
                      "--error": ["image:x", "image:20:bogus", "image:1e300", "nope:1", "image:20:point=nope"],
                      "--control-spacing": ["0"]}.items():
        for v in vals:
            add(f"simulate {opt} {v!r}", ["simulate", "s.json", opt, v])
    add("simulate strips 1 height 1e20", ["simulate", "s.json", "--strips", "1", "--flying-height", "1e20"])
    add("simulate pattern 4 3", ["simulate", "s.json", "--pattern", "4", "3"])
    for opt, vals in {"--p": ["0", "1", "nan", "x"], "--L1": ["0", "-1", "inf"], "--L2": ["0"],
                      "--lambda-tol": ["0", "1e300"]}.items():
        for v in vals:
            add(f"risk {opt} {v!r}", ["risk", *(["--p", "0.1"] if opt != "--p" else []), opt, v])
    for argv in ([], ["analyze"], ["nope"], ["analyze", "a.json", "--nope"], ["analyze", "a.json", "--alpha"],
                 ["test", "a.json"], ["analyze", "a.json", "--statistic", "x"]):
        add(f"usage {' '.join(argv)!r}", argv)
    # malformed truth files beside the input (and given with --truth)
    for k, data in enumerate(TRUTHS):
        add(f"truth beside {k}", ["analyze", "a.json"], {"a.truth.json": data})
    add("truth given", ["analyze", "a.json", "--truth", "t.json"], {"t.json": TRUTHS[0]})
    # encodings
    add("xml unknown encoding", ["analyze", "e.gkf"],
        {"e.gkf": b'<?xml version="1.0" encoding="x-no-such"?>\n<gama-local/>'})
    add("xml utf-16 declared, utf-8 given", ["analyze", "e.gkf"],
        {"e.gkf": b'<?xml version="1.0" encoding="utf-16"?>\n<gama-local/>'})
    add("hypothesis not utf-8", ["test", "a.json", "-H", "file:hx.txt"], {"hx.txt": b"0 0 \xff\n"})
    # hypothesis columns far beyond the entries (each column needs one: never a q of 10^12)
    for col in ("100000000", "1000000000000", "9" * 30, "1e8", "-1"):
        add(f"hypothesis column {col[:12]}", ["test", "a.json", "-H", "file:hc.txt"], {"hc.txt": f"0 {col} 1\n".encode()})
    # recipes
    for k, data in enumerate(RECIPES):
        add(f"recipe {k}", ["simulate", "s.json", "--recipe", "rx.json"], {"rx.json": data})
    return cases


EDGE_CASES = edge_cases()


def _tree(folder: Path) -> dict:
    return {str(p): (os.readlink(p) if p.is_symlink() else p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("name, argv, files", EDGE_CASES, ids=[c[0] for c in EDGE_CASES])
def test_edge_case_is_one_line_exit_2(name, argv, files, tmp_path, monkeypatch):
    edge_files(tmp_path)
    for rel, data in files.items():
        (tmp_path / rel).write_bytes(data)
    monkeypatch.chdir(tmp_path)
    before = _tree(tmp_path)
    t0 = time.monotonic()
    code, out, err, caught = run_cli(argv)
    seconds = time.monotonic() - t0
    where = f"{name}: exit {code}, stderr {err!r}"
    assert code == 2, where
    assert USAGE_LINE.fullmatch(err), where
    assert not CONTROL.search(err[:-1]) and not RAW.search(err), where
    assert not caught, f"{where}; warnings {caught}"
    assert seconds < EDGE_SECONDS, f"{where}; {seconds:.1f} s"
    assert _tree(tmp_path) == before, f"{where}: a file changed"


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SEEDS))
def test_fuzz_contract_slow(name, tmp_path):
    n = SLOW.get(name, 300)
    counts = fuzz(name, n, tmp_path, base_seed=2)
    assert sum(counts.values()) == n
    assert counts.get(2, 0) > 0          # the mutations do reach the readers' checks


if __name__ == "__main__":   # exploration: python tests/test_fuzz_contract.py NAME N [SEED [OPTION...]]
    import sys
    import tempfile

    name, n = sys.argv[1], int(sys.argv[2])
    base = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    fails = 0
    with tempfile.TemporaryDirectory() as d:
        for k in range(n):
            rng = random.Random(f"{name}:{base}:{k}")
            files = make_case(SEEDS[name], rng)
            try:
                run_case(name, files, Path(d) / "case", what=f"{name} case {k} (seed {base})", extra=sys.argv[4:])
            except AssertionError as e:
                fails += 1
                print(str(e)[:400])
    print(f"{name}: {fails} of {n} broke the contract")
