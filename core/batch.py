"""``baarda batch``: many blocks analysed in parallel on Dask distributed (issue 30).

Every block is one task, :func:`analyze_block`: :func:`baarda.analysis.analyze` of the file
with the command line's options, then :meth:`~baarda.analysis.Analysis.to_dict` with the
extras asked for — the same calls as ``baarda analyze --json``, so the documents are the same
but for ``summary.timings``. The worker returns the document's text and one summary row; the
client writes both under ``--out`` (atomically; the workers need not share its file system,
only the input paths): ``blocks/NAME.json``, ``blocks/NAME.row.json``, then ``summary.csv``,
``summary.parquet`` (with pyarrow) and ``index.html``.

Without a scheduler address a :class:`distributed.LocalCluster` on 127.0.0.1 runs the tasks:
one single-threaded worker process per core (native BLAS limited to one thread,
:func:`baarda.threads.limit_native_threads`) with a memory limit each. Faults are rows: a file
that cannot be read, an adjustment that does not converge, a task whose worker died twice
(``distributed.scheduler.allowed-failures`` = 1 on the local cluster: one retry elsewhere) each
give a row with its ``error``, and the others go on. Ctrl-C cancels what runs and writes the
summary of what is done; a second run with the same ``--out`` skips the blocks done (same file
size and time, same options).
"""

from __future__ import annotations

import csv
import glob
import hashlib
import html
import io
import json
import logging
import math
import os
import resource
import secrets
import sys
import time
from dataclasses import asdict
from pathlib import Path
from urllib.parse import quote

from .analysis import Extras, SolverOptions, analyze
from .errors import BaardaError, InputError, SingularError, UsageError
from .io import detect_format, results
from .io.output import OutputError, atomic_write, csv_cell, write_text
from .text import printable, shorten
from .threads import limit_native_threads

#: the columns of summary.csv, in order (README, "Batches")
COLUMNS = ("file", "format", "n_observations", "n_unknowns", "dof", "converged", "iterations", "global_test_passed",
           "global_test_statistic", "omega", "sigma0_aposteriori", "statistic", "max_abs_w", "n_rejected",
           "worst_mdb_sigma", "worst_delta_bar0", "local_defects", "time_s", "peak_memory_mb", "status", "error",
           "json")
#: names a folder's entry needs to be taken as a block when a folder is given
SUFFIXES = (".gkf", ".json", ".txt", ".out")
COMPRESSED = (".gz", ".bz2", ".xz")
#: a row with one of these statuses is not done: run again by the next batch with the same --out
RETRY = ("killed", "interrupted")


def expand(specs) -> list[str]:
    """The input files of FILES/GLOBS/DIRS, in order, each once: a file as given; a pattern
    with ``* ? [`` its matches, sorted; a folder its blocks (files ending in .gkf, .json, .txt,
    .out, possibly compressed, not ``*.truth.json``; and COLMAP model folders in it), sorted, or
    itself if it is a COLMAP model. A name that matches nothing is a :class:`UsageError`."""
    out: list[str] = []
    for spec in specs:
        spec = str(spec)
        if any(c in spec for c in "*?["):
            found = sorted(glob.glob(spec, recursive=True))
        elif os.path.isdir(spec):
            found = [spec] if _is_colmap(spec) else sorted(
                os.path.join(spec, e) for e in os.listdir(spec) if _is_block_name(os.path.join(spec, e)))
        elif os.path.exists(spec):
            found = [spec]
        else:
            raise UsageError(f"batch: no such file or folder: {printable(spec)}")
        if not found:
            raise UsageError(f"batch: nothing matches {printable(spec)}")
        out.extend(found)
    seen, unique = set(), []
    for f in out:
        key = os.path.realpath(f)
        if key not in seen:
            seen.add(key)
            unique.append(f)
    return unique


def _is_colmap(path: str) -> bool:
    return any(os.path.exists(os.path.join(path, n + e)) for n in ("cameras", "images") for e in (".txt", ".bin"))


def _is_block_name(path: str) -> bool:
    if os.path.isdir(path):
        return _is_colmap(path)
    name = path.lower()
    for c in COMPRESSED:
        name = name.removesuffix(c)
    return name.endswith(SUFFIXES) and not name.endswith(".truth.json") and not name.endswith(".row.json")


def block_name(path: str) -> str:
    """The name of a block's files under --out: its file name and 8 hex digits of its absolute path
    (two ``problem.txt`` in different folders do not collide); only safe characters."""
    base = "".join(c if c.isalnum() or c in "-_." else "_" for c in Path(path).name)[:80] or "block"
    digest = hashlib.sha256(os.path.abspath(path).encode("utf-8", "surrogateescape")).hexdigest()[:8]
    return f"{base}-{digest}"


# -- on the worker ---------------------------------------------------------------------------------
def _reset_peak_memory() -> bool:
    """Reset this process's peak resident size (Linux: ``5`` to /proc/self/clear_refs); False where
    that is not possible (the peak is then the process's since it started)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_memory_mb() -> float:
    """The peak resident size of this process in MB (VmHWM, else ru_maxrss)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _truth_beside(path: str) -> str | None:
    """NAME.truth.json beside the input, as ``baarda analyze`` takes it when present."""
    try:
        guess = Path(path).with_suffix(".truth.json")
    except ValueError:
        return None
    return str(guess) if guess.exists() else None


def analyze_block(path: str, options: dict) -> dict:
    """The task of one block (runs on a worker): ``{"row": …, "json": text or None}``. Never
    raises for the file's faults: an unreadable file, an adjustment that does not converge, an
    internal error are the row's ``status`` and ``error``. ``options``: ``analyze``'s keyword
    arguments (``solver`` and ``policy`` as dicts) and ``extras`` (a dict of
    :class:`~baarda.analysis.Extras`)."""
    limit_native_threads()
    _reset_peak_memory()
    t0 = time.perf_counter()
    row = {c: None for c in COLUMNS}
    row.update(file=path, status="ok", error="")
    text = None
    try:
        fmt = options.get("format", "auto")
        row["format"] = detect_format(path) if fmt == "auto" else fmt
        kw = {k: v for k, v in options.items() if k not in ("extras", "solver")}
        extras = dict(options.get("extras") or {})
        if extras.get("truth") is None:
            extras["truth"] = _truth_beside(path)
        analysis = analyze(path, solver=SolverOptions(**options.get("solver", {})), **kw)
        adj = analysis.adjustment
        t1 = time.perf_counter()
        doc = analysis.to_dict()
        adj.timings["reliability"] = time.perf_counter() - t1
        analysis._add_extras(doc, Extras(**extras))
        doc["summary"]["timings"] = {k: round(v, 6) for k, v in adj.timings.items()}
        text = "".join(results.json_chunks(doc))
        row.update(summary_row(json.loads(text)))
        if not adj.converged:
            row["status"] = "not-converged"
            row["error"] = f"NOT converged after {adj.iterations} iterations: " \
                           f"{(adj.termination or '').removeprefix('not converged: ')}"
    except SingularError as err:
        row.update(status="not-converged", error=f"no reliability computed: {err}")
    except InputError as err:
        row.update(status="error", error=str(err))
    except BaardaError as err:
        row.update(status="error", error=f"{path}:0: {err}")
    except MemoryError:
        row.update(status="error", error="out of memory")
    except Exception as err:            # an internal error: the row says so, the batch goes on
        row.update(status="error", error=f"internal error: {type(err).__name__}: {err}")
    row["error"] = shorten(printable(row["error"]))
    row["time_s"] = time.perf_counter() - t0
    row["peak_memory_mb"] = _peak_memory_mb()
    return {"row": row, "json": text}


def summary_row(doc: dict) -> dict:
    """The numbers of one block's row from its result document (a serial ``baarda analyze
    --json`` gives the same): sizes, convergence, the global test, Ω = vᵀPv, the largest |w|,
    the rejected count, the largest MDB in σ of its observation (∇0l/σ = δ0/√r), the largest δ̄0
    (F80 eq. 17) and the count of local defects set aside. None where no observation has one."""
    s = doc["summary"]
    obs = doc.get("observations") or []

    def largest(values):
        vals = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
        return max(vals) if vals else None
    return {"n_observations": s["n_observations"], "n_unknowns": s["n_unknowns"], "dof": s["dof"],
            "converged": s["converged"], "iterations": s["iterations"],
            "global_test_passed": s["global_test"]["passed"], "global_test_statistic": s["global_test"]["statistic"],
            "omega": s["omega"], "sigma0_aposteriori": s["sigma0_aposteriori"], "statistic": s["statistic"],
            "max_abs_w": largest(abs(o["w"]) for o in obs if o.get("w") is not None),
            "n_rejected": s["n_rejected"],
            "worst_mdb_sigma": largest(o["mdb"] / o["sigma"] for o in obs
                                       if o.get("mdb") is not None and o.get("sigma")),
            "worst_delta_bar0": largest(o.get("external") for o in obs),
            "local_defects": len(s.get("local_defects") or [])}


# -- on the client ---------------------------------------------------------------------------------
def _stamp(path: str, options: dict) -> dict:
    """What makes a finished row valid for a rerun: the input's size and time, the options."""
    try:
        st = os.stat(path)
        size, mtime = st.st_size, st.st_mtime_ns
    except OSError:
        size = mtime = None
    opts = hashlib.sha256(json.dumps(options, sort_keys=True, default=str).encode()).hexdigest()[:16]
    return {"path": os.path.abspath(path), "size": size, "mtime_ns": mtime, "options": opts}


def _done_row(out: Path, path: str, stamp: dict) -> dict | None:
    """The row of a previous run with the same --out, if that run finished this block."""
    try:
        saved = json.loads((out / "blocks" / f"{block_name(path)}.row.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(saved, dict) or saved.get("stamp") != stamp or saved.get("row", {}).get("status") in RETRY:
        return None
    return saved["row"]


def _save(out: Path, path: str, result: dict, stamp: dict) -> dict:
    """Write a block's document and row under --out; the row (with ``json``, its relative path)."""
    row = dict(result["row"])
    row["file"] = path
    name = block_name(path)
    if result.get("json") is not None:
        write_text(out / "blocks" / f"{name}.json", result["json"])
        row["json"] = f"blocks/{name}.json"
    write_text(out / "blocks" / f"{name}.row.json", json.dumps({"stamp": stamp, "row": row}, allow_nan=False))
    return row


def _cell(v):
    if isinstance(v, float):
        return repr(v)              # round trip: the numbers of the JSON, bit for bit
    if v is None:
        return ""
    return csv_cell(v)


def write_summary(out: Path, rows: list[dict], stream=None) -> list[Path]:
    """summary.csv, summary.parquet (pyarrow; otherwise a note on ``stream``) and index.html."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in COLUMNS])
    write_text(out / "summary.csv", buf.getvalue())
    written = [out / "summary.csv"]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        if stream is not None:
            print("baarda: batch: summary.parquet not written: pyarrow is not installed (pip install pyarrow)",
                  file=stream)
    else:
        table = pa.Table.from_pylist([{c: r.get(c) for c in COLUMNS} for r in rows])
        with atomic_write(out / "summary.parquet", binary=True) as fh:
            pq.write_table(table, fh)
        written.append(out / "summary.parquet")
    write_text(out / "index.html", overview_html(rows))
    written.append(out / "index.html")
    return written


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def overview_html(rows: list[dict]) -> str:
    """The HTML overview: one line per block, linking its JSON; every string from a file is
    escaped text (:func:`html.escape` of :func:`baarda.text.printable`), never markup."""
    esc = lambda v: html.escape(printable(_fmt(v)), quote=True)
    ok = sum(1 for r in rows if not r.get("error"))
    head = "".join(f"<th>{esc(c)}</th>" for c in COLUMNS if c != "json")
    body = []
    for r in rows:
        cls = "" if not r.get("error") else ' class="fault"'
        cells = []
        for c in COLUMNS:
            if c == "json":
                continue
            if c == "file" and r.get("json"):
                cells.append(f'<td><a href="{html.escape(quote(r["json"]), quote=True)}">{esc(r.get(c))}</a></td>')
            else:
                cells.append(f"<td>{esc(r.get(c))}</td>")
        body.append(f"<tr{cls}>{''.join(cells)}</tr>")
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>baarda batch</title>"
            "<style>body{font-family:sans-serif}table{border-collapse:collapse;font-size:12px}"
            "td,th{border:1px solid #ccc;padding:2px 5px}tr.fault{background:#fdd}</style></head><body>"
            f"<h1>baarda batch</h1><p>{ok} of {len(rows)} blocks analysed without fault.</p>"
            f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table></body></html>\n")


class _Progress:
    """A progress bar on a terminal (blocks done, faults, ETA); nothing elsewhere."""

    def __init__(self, total: int, stream, show: bool):
        self.total, self.stream, self.show = total, stream, show
        self.done = self.faults = 0
        self.t0 = time.monotonic()

    def step(self, row: dict) -> None:
        self.done += 1
        self.faults += bool(row.get("error"))
        if not self.show:
            return
        elapsed = time.monotonic() - self.t0
        eta = elapsed / self.done * (self.total - self.done)
        filled = int(30 * self.done / max(self.total, 1))
        print(f"\r[{'#' * filled}{'.' * (30 - filled)}] {self.done}/{self.total} blocks, {self.faults} fault(s), "
              f"ETA {int(eta) // 60}:{int(eta) % 60:02d} ", end="", file=self.stream, flush=True)

    def close(self) -> None:
        if self.show and self.done:
            print(file=self.stream)


def dask_client():
    """distributed's ``Client`` and ``as_completed``; a :class:`UsageError` saying how to install
    them where the batch extra is missing."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise UsageError("this command needs Dask distributed: pip install 'dask[distributed]' "
                         "(make install does: the extra batch)") from None
    return Client, as_completed


def local_cluster(workers: int | None = None, memory_limit="auto"):
    """A :class:`distributed.LocalCluster` on 127.0.0.1: ``workers`` (default: the cores)
    single-threaded worker processes with ``memory_limit`` each (Dask's ``"auto"``: the memory
    shared out), the dashboard on a free port, a task that kills two workers reported as such
    (allowed-failures 1)."""
    import dask
    from distributed import LocalCluster
    n = workers or os.cpu_count() or 1
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address="127.0.0.1:0", memory_limit=memory_limit,
                            silence_logs=logging.ERROR)


def run_batch(specs, out, options: dict, *, scheduler: str | None = None, workers: int | None = None,
              memory_limit="auto", quiet: bool = False, stream=None, task=None) -> tuple[int, list[dict]]:
    """Analyse every block of ``specs`` (:func:`expand`) on Dask and write the results under ``out``
    (module docstring). Returns ``(exit status, rows)``: 0 when every file worked (read, adjusted,
    converged), 1 otherwise. KeyboardInterrupt (and the CLI's SIGTERM) cancel the tasks, write the
    summary of what is done (the rest marked ``interrupted``) and propagate. ``task``: the function
    run per block (default :func:`analyze_block`; the tests give one that kills its worker)."""
    Client, as_completed = dask_client()
    stream = stream if stream is not None else sys.stderr
    files = expand(specs)
    out = Path(out)
    try:
        (out / "blocks").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(out, f"cannot create the folder: {err.strerror or err}") from None
    stamps = {f: _stamp(f, options) for f in files}
    rows: dict[str, dict] = {}
    for f in files:
        done = _done_row(out, f, stamps[f])
        if done is not None:
            rows[f] = done
    todo = [f for f in files if f not in rows]
    bar = _Progress(len(files), stream, show=not quiet and stream.isatty())
    cluster = client = None
    if todo:
        cluster = None if scheduler else local_cluster(workers, memory_limit)
        try:
            client = Client(scheduler if scheduler else cluster, timeout="30s")
        except (OSError, TimeoutError) as err:
            if cluster is not None:
                cluster.close()
            raise UsageError(f"batch: cannot reach the Dask scheduler {printable(scheduler or '')}: {err}") from None
    run = secrets.token_hex(4)           # task keys of this run: never another run's results
    try:
        if todo:
            if not quiet:
                print(printable(f"baarda: batch: {len(todo)} block(s) to analyse ({len(files) - len(todo)} done "
                                f"before) on {len(client.scheduler_info().get('workers', {}))} worker(s); "
                                f"dashboard {client.dashboard_link}"), file=stream)
            futures = {client.submit(task or analyze_block, f, options, key=f"baarda-{block_name(f)}-{run}",
                                     pure=False): f
                       for f in todo}
            for fut in as_completed(futures):
                f = futures[fut]
                try:
                    result = fut.result()
                except Exception as err:            # KilledWorker (a block that killed two workers), ...
                    result = {"row": _fault_row(f, "killed", _killed_message(err)), "json": None}
                rows[f] = _save(out, f, result, stamps[f])
                bar.step(rows[f])
    except BaseException:
        bar.close()
        for f in files:                   # what was saved before the interruption is done
            if f not in rows:
                rows[f] = _done_row(out, f, stamps[f]) or _fault_row(f, "interrupted", "interrupted before it finished")
        write_summary(out, [rows[f] for f in files], stream)
        raise
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    bar.close()
    if not todo and not quiet:
        print(printable(f"baarda: batch: all {len(files)} block(s) done before (in {out}): nothing to analyse"),
              file=stream)
    ordered = [rows[f] for f in files]
    write_summary(out, ordered, None if quiet else stream)
    faults = [r for r in ordered if r.get("error")]
    if not quiet:
        print(printable(f"baarda: batch: {len(ordered) - len(faults)} of {len(ordered)} block(s) worked; "
                        f"summary in {out / 'summary.csv'}"), file=stream)
        for r in faults:
            print(printable(f"baarda: batch: {r['file']}: {r['status']}: {r['error']}"), file=stream)
    return (0 if not faults else 1), ordered


def _fault_row(path: str, status: str, error: str) -> dict:
    row = {c: None for c in COLUMNS}
    row.update(file=path, status=status, error=shorten(printable(error)))
    return row


def _killed_message(err) -> str:
    name = type(err).__name__
    if name == "KilledWorker":
        return "killed its worker twice (out of memory or a crash); not retried again"
    return f"{name}: {err}"


def options_of(args) -> dict:
    """The task options of ``baarda batch``'s arguments (those of ``baarda analyze``)."""
    sigma0 = None if args.statistic is None else ("aposteriori" if args.statistic == "tau" else "apriori")
    policy = {"alpha0": args.alpha, "beta0": args.beta, "b_method": args.b_method, "sigma0": sigma0,
              "global_test": args.global_test, "conf_pr": args.conf_pr}
    extras = asdict(Extras(snooping=bool(args.snoop), robust=args.robust,
                           variance_components=args.variance_components, merge_groups=args.merge_groups))
    return {"format": args.format, "control": args.control, "sigma_px": args.sigma_px,
            "refine_intrinsics": args.refine_intrinsics, "drop_undefined": args.drop_undefined,
            "strict": bool(args.strict), "solver": {"max_iter": args.max_iter, "stop": args.stop},
            "policy": policy, "extras": extras}


def command(args) -> int:
    """``baarda batch`` (:func:`run_batch`)."""
    code, _ = run_batch(args.inputs, args.out, options_of(args), scheduler=args.scheduler, workers=args.workers,
                        memory_limit=args.memory_limit, quiet=args.quiet)
    return code
