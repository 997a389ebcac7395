"""``baarda study``: design studies — a grid of simulated block designs × N Monte Carlo
replicates with a planted error, analysed and scored (issue 30, item 2; Molenaar 1984 §1: block
simulations are how the planning directives were found).

A recipe (JSON)::

    {"design": {simulate recipe: strips, images_per_strip, control, sigma_image, ...},
     "grid": {"side_overlap": [0.25, 0.6], "control": ["perimeter", "corners"]},
     "replicates": 100, "seed": 1, "alpha": 0.001, "beta": 0.8,
     "planted": {"kind": "image", "size": "mdb", "component": "x"}}

Each design (the base recipe with one combination of the grid) is simulated ``replicates``
times (:func:`baarda.simulate.simulate_block`), each replicate with its own seed (from
``numpy.random.SeedSequence([seed, design, replicate])``, recorded: ``baarda simulate --recipe``
of the design's recipe with that seed gives the replicate's block again), twice: without error
and with the planted one (same seed: the same noise). Both are analysed by
:func:`baarda.analysis.analyze` (w-test, σ0 a priori) and scored:

- empirical size: the rate of rejected w-tests in the block without error, per observation
  tested (r > 0); nominal α0 (B68: w ~ N(0, 1) under H0); its standard error from the spread of
  the replicates' rates (the tests of one block are correlated);
- empirical power: the rate at which the w-test of the planted observation rejects it; the
  expected power of each replicate is P(|N(s√r, 1)| > k) for an error of s σ in an observation
  of redundancy number r (B68; F80 eq. 8), β0 when s = δ0/√r (the MDB, ``"size": "mdb"``: s from
  the median r of the design's image observations, or the planted observation's own r);
- the MDBs in σ of their observation (δ0/√r) and δ̄0 (F80 eq. 17) of the block without error.

Replicates run as Dask tasks (a local cluster, or ``--scheduler``), or in this process
(``serial=True``).
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from .analysis import analyze
from .batch import dask_client, local_cluster
from .build import build
from .errors import BaardaError, InputError
from .io.output import csv_cell, write_text
from .io.study_plot import study_html, study_svg
from .lazy import lazy
from .simulate import check_recipe, simulate_block
from .stats.policy import TestPolicy
from .text import printable
from .threads import limit_native_threads

stats = lazy("scipy.stats")

#: the keys of a study recipe
KEYS = ("format", "design", "grid", "replicates", "seed", "alpha", "beta", "planted", "title")


def read_recipe(path) -> dict:
    """A study recipe from JSON, checked (:class:`InputError` naming the file otherwise)."""
    try:
        doc = json.loads(Path(path).read_bytes().decode("utf-8"))
    except OSError as err:
        raise InputError(path, 0, f"cannot read the study recipe: {err.strerror or err}") from None
    except UnicodeDecodeError as err:
        raise InputError(path, 0, f"the study recipe is not UTF-8 text (byte {err.start})") from None
    except (json.JSONDecodeError, RecursionError) as err:
        raise InputError(path, getattr(err, "lineno", 0), f"the study recipe is not JSON: {getattr(err, 'msg', err)}") from None
    try:
        return check_study(doc)
    except BaardaError as err:
        raise InputError(path, 0, str(err)) from None


def check_study(doc) -> dict:
    """The study recipe with its defaults, every design of its grid a valid simulate recipe."""
    if not isinstance(doc, dict):
        raise BaardaError("a study recipe is a JSON object")
    unknown = sorted(set(doc) - set(KEYS))
    if unknown:
        raise BaardaError(f"unknown keys in the study recipe: {', '.join(unknown)} (known: {', '.join(KEYS)})")
    s = {"design": {}, "grid": {}, "replicates": 100, "seed": 0, "alpha": 0.001, "beta": 0.8,
         "planted": {"kind": "image", "size": "mdb"}, "title": "", **doc}
    if not isinstance(s["grid"], dict) or not all(isinstance(v, list) and v for v in s["grid"].values()):
        raise BaardaError("grid: an object of non-empty lists, one per recipe key varied")
    n = s["replicates"]
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 1_000_000:
        raise BaardaError(f"replicates must be an integer from 1 to 1000000 (got {n!r})")
    for key, low, high in (("alpha", 1e-12, 0.5), ("beta", 0.05, 0.9999)):
        v = s[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not low <= v <= high:
            raise BaardaError(f"{key} must be a number from {low:g} to {high:g} (got {v!r})")
    if not isinstance(s["seed"], int) or isinstance(s["seed"], bool) or s["seed"] < 0:
        raise BaardaError(f"seed must be a non-negative integer (got {s['seed']!r})")
    p = s["planted"]
    if not isinstance(p, dict) or p.get("kind") != "image":
        raise BaardaError("planted: {\"kind\": \"image\", \"size\": \"mdb\" or σ, [\"image\", \"point\", \"component\"]}")
    if p.get("size", "mdb") != "mdb" and not (isinstance(p["size"], (int, float)) and 0 < p["size"] <= 1e6):
        raise BaardaError(f"planted.size must be \"mdb\" or a number of σ above 0 (got {p['size']!r})")
    for d in designs(s):
        check_recipe({**d, "errors": []})
    return s


def designs(study: dict) -> list[dict]:
    """The simulate recipes of the grid (the base design with each combination of its lists)."""
    keys = list(study["grid"])
    return [{**study["design"], **dict(zip(keys, combo))} for combo in itertools.product(*study["grid"].values())]


def replicate_seed(seed: int, design: int, replicate: int) -> int:
    """The seed of one replicate (recorded; independent streams, numpy's SeedSequence)."""
    return int(np.random.SeedSequence([seed, design, replicate]).generate_state(1, np.uint64)[0] >> np.uint64(1))


def _analyse(recipe: dict, policy: TestPolicy):
    block, truth = simulate_block(**recipe)
    return analyze(build(block), policy=policy), truth


def _columns(a) -> dict:
    return a.records("observations")


def _image_rows(cols) -> np.ndarray:
    return np.array([str(k).startswith("image") for k in cols["kind"]])


def planted_error(recipe: dict, study: dict) -> dict:
    """The error planted in every replicate of a design: the recipe's ``planted`` with its size
    in σ; where it names no image point, the image observation of median redundancy number of
    the design (design mode: no noise, seed of the study), and for ``"size": "mdb"`` its MDB,
    δ0/√r (B68; F80 eq. 8)."""
    spec = {k: v for k, v in study["planted"].items()}
    size = spec.pop("size", "mdb")
    if size != "mdb" and "image" in spec and "point" in spec:
        return {**spec, "size": float(size)}
    policy = TestPolicy(alpha0=study["alpha"], beta0=study["beta"], sigma0="apriori")
    a, _ = _analyse({**recipe, "errors": [], "design": True, "seed": study["seed"]}, policy)
    cols = _columns(a)
    r = np.asarray(cols["redundancy"], dtype=float)
    rows = np.flatnonzero(_image_rows(cols) & (r > 1e-9))
    if "image" in spec and "point" in spec:
        rows = [i for i in rows if str(cols["image"][i]) == str(spec["image"]) and str(cols["point"][i]) == str(spec["point"])
                and str(cols["component"][i]) == str(spec.get("component", "x"))] or rows
    else:
        rows = rows[np.argsort(r[rows], kind="stable")]
        rows = [rows[len(rows) // 2]]
    i = rows[0]
    spec.update(image=str(cols["image"][i]), point=str(cols["point"][i]), component=str(cols["component"][i]))
    spec["size"] = float(a.reliability.delta0 / math.sqrt(r[i])) if size == "mdb" else float(size)
    return spec


def replicate(recipe: dict, study: dict, planted: dict, seed: int) -> dict:
    """One replicate: the block without and with the planted error, analysed and scored."""
    limit_native_threads()
    t0 = time.perf_counter()
    policy = TestPolicy(alpha0=study["alpha"], beta0=study["beta"], sigma0="apriori")
    clean, _ = _analyse({**recipe, "errors": [], "seed": seed}, policy)
    c = _columns(clean)
    r = np.asarray(c["redundancy"], dtype=float)
    tested = r > 1e-9
    rejected = np.asarray(c["rejected_w"], dtype=bool) & tested
    mdb = np.array([m / s if m is not None and s else np.nan for m, s in zip(c["mdb"], c["sigma"])], dtype=float)
    ext = np.array([np.nan if e is None else e for e in c["external"]], dtype=float)
    size = planted["size"]
    bad, truth = _analyse({**recipe, "errors": [planted], "seed": seed}, policy)
    rows = list(truth["errors"][0]["rows"])
    kept = bad.adjustment.problem.notes.kept_rows
    if kept is not None:
        pos = {int(k): i for i, k in enumerate(kept)}
        rows = [pos[int(x)] for x in rows if int(x) in pos]
    b = _columns(bad)
    row = rows[0]
    r_row = float(b["redundancy"][row])
    k = float(bad.reliability.critical_w)
    delta = size * math.sqrt(max(r_row, 0.0))
    return {"seed": seed, "n_tested": int(tested.sum()), "false_alarms": int(rejected.sum()),
            "converged": bool(clean.adjustment.converged and bad.adjustment.converged),
            "planted_row": int(row), "planted_r": r_row, "planted_w": float(b["w"][row]),
            "detected": bool(b["rejected_w"][row]),
            "expected_power": float(stats.norm.sf(k - delta) + stats.norm.cdf(-k - delta)),
            "mdb_sigma_median": float(np.nanmedian(mdb[tested])), "mdb_sigma_max": float(np.nanmax(mdb[tested])),
            "delta_bar0_median": float(np.nanmedian(ext[tested])), "delta_bar0_max": float(np.nanmax(ext[tested])),
            "time_s": time.perf_counter() - t0}


def score(study: dict, design: dict, planted: dict, reps: list[dict]) -> dict:
    """The design's line of the table: empirical size and power with their standard errors."""
    n = len(reps)
    rates = np.array([x["false_alarms"] / x["n_tested"] for x in reps if x["n_tested"]], dtype=float)
    det = np.array([x["detected"] for x in reps], dtype=float)
    exp = np.array([x["expected_power"] for x in reps], dtype=float)
    return {**{f"design.{k}": v for k, v in design.items() if k in study["grid"]},
            "replicates": n, "alpha0": study["alpha"], "beta0": study["beta"], "planted_sigma": planted["size"],
            "planted": f"{planted['kind']}:{planted['image']}:{planted['point']}:{planted['component']}",
            "empirical_size": float(rates.mean()), "size_se": float(rates.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan,
            "false_alarms": int(sum(x["false_alarms"] for x in reps)), "tests": int(sum(x["n_tested"] for x in reps)),
            "empirical_power": float(det.mean()), "expected_power": float(exp.mean()),
            "power_se": float(math.sqrt(max(float(np.mean(exp * (1 - exp))), 1e-12) / n)),
            "mdb_sigma_median": float(np.median([x["mdb_sigma_median"] for x in reps])),
            "mdb_sigma_max": float(np.max([x["mdb_sigma_max"] for x in reps])),
            "delta_bar0_median": float(np.median([x["delta_bar0_median"] for x in reps])),
            "delta_bar0_max": float(np.max([x["delta_bar0_max"] for x in reps])),
            "not_converged": int(sum(not x["converged"] for x in reps)),
            "time_s": float(sum(x["time_s"] for x in reps))}


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    cols = list(dict.fromkeys(k for r in rows for k in r))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([repr(v) if isinstance(v, float) else csv_cell(v) if v is not None else "" for v in
                    (r.get(c) for c in cols)])
    return buf.getvalue()


def run_study(study: dict, out=None, *, scheduler: str | None = None, workers: int | None = None,
              serial: bool = False, stream=None) -> list[dict]:
    """Run every replicate of every design; the table (one dict per design). With ``out``:
    ``study.csv`` (the table), ``replicates.csv`` (every replicate with its seed),
    ``designs.json`` (each design's simulate recipe), ``study.svg`` (power, size and MDB per design,
    :mod:`baarda.io.study_plot`) and ``index.html`` (the plot and the table) written there."""
    grid = designs(study)
    sizes = [planted_error(d, study) for d in grid]
    jobs = [(i, k, replicate_seed(study["seed"], i, k)) for i in range(len(grid)) for k in range(study["replicates"])]
    results: dict[tuple, dict] = {}
    t0 = time.perf_counter()
    if serial:
        for i, k, seed in jobs:
            results[(i, k)] = replicate(grid[i], study, sizes[i], seed)
    else:
        Client, as_completed = dask_client()
        cluster = None if scheduler else local_cluster(workers)
        try:
            with Client(scheduler or cluster, timeout="30s") as client:
                if stream is not None:
                    print(printable(f"baarda: study: {len(jobs)} replicates of {len(grid)} design(s); dashboard "
                                    f"{client.dashboard_link}"), file=stream)
                futures = {client.submit(replicate, grid[i], study, sizes[i], seed, pure=False): (i, k)
                           for i, k, seed in jobs}
                for n, fut in enumerate(as_completed(futures), 1):
                    results[futures[fut]] = fut.result()
                    if stream is not None and stream.isatty():
                        eta = (time.perf_counter() - t0) / n * (len(jobs) - n)
                        print(f"\r{n}/{len(jobs)} replicates, ETA {int(eta) // 60}:{int(eta) % 60:02d} ", end="",
                              file=stream, flush=True)
        finally:
            if cluster is not None:
                cluster.close()
    table = [score(study, grid[i], sizes[i], [results[(i, k)] for k in range(study["replicates"])])
             for i in range(len(grid))]
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "study.csv", _csv(table))
        write_text(out / "replicates.csv", _csv([{"design": i, "replicate": k, **results[(i, k)]}
                                                 for i, k, _ in jobs]))
        write_text(out / "designs.json", json.dumps({"study": study, "designs": grid, "planted": sizes},
                                                    indent=1))
        title = str(study.get("title") or "")
        write_text(out / "study.svg", study_svg(table, title))
        write_text(out / "index.html", study_html(table, table_text(table), title))
    return table


def table_text(table: list[dict]) -> str:
    """The table as text: per design, size and power against their nominal values."""
    lines = []
    for i, t in enumerate(table):
        grid = ", ".join(f"{k.removeprefix('design.')}={v}" for k, v in t.items() if k.startswith("design."))
        lines.append(printable(
            f"design {i}{f' ({grid})' if grid else ''}: {t['replicates']} replicates; size {t['empirical_size']:.4g} "
            f"± {t['size_se']:.2g} (α0 {t['alpha0']:g}); power {t['empirical_power']:.3f} ± {t['power_se']:.3f} "
            f"(expected {t['expected_power']:.3f}, β0 {t['beta0']:g} at the MDB; planted {t['planted_sigma']:.3g} σ); "
            f"MDB {t['mdb_sigma_median']:.3g} σ median, {t['mdb_sigma_max']:.3g} σ max; δ̄0 {t['delta_bar0_median']:.3g} "
            f"median, {t['delta_bar0_max']:.3g} max"))
    return "\n".join(lines)


def command(args) -> int:
    """``baarda study`` (:func:`run_study`)."""
    recipe = read_recipe(args.recipe)
    if args.replicates is not None:
        recipe["replicates"] = args.replicates
    stream = None if args.quiet else sys.stderr
    table = run_study(recipe, args.out, scheduler=args.scheduler, workers=args.workers, serial=args.serial,
                      stream=stream)
    if not args.quiet:
        if stream is not None and stream.isatty():
            print(file=stream)
        print(table_text(table))
        print(printable(f"wrote {Path(args.out) / 'study.csv'}, replicates.csv, designs.json, study.svg, index.html"))
    return 0
