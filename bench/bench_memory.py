"""Benchmark: time and peak memory of every stage of an analysis (issue 11, item 5).

For each size a synthetic BAL problem (:mod:`bench.make_big_bal`, written to /tmp, never
committed) is analysed end to end in a fresh subprocess — read, build the Problem, adjust
(Levenberg-Marquardt from the perturbed start), reliability (r, w, MDB, δ̄0 of every observation
and the 2D test of every image point), optionally the JSON document written to a temporary file — and a 2D network of
10⁵ points and 3·10⁵ distances likewise (build the network, build the Problem, adjust,
reliability). After each stage the table shows its seconds, the process's peak resident set so
far (``ru_maxrss``) and its resident set after the stage (what the stage keeps), with wall and CPU
seconds (CPU seconds are the fairer figure on a shared machine).

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_memory [--sizes 1e6 2.5e6 5e6] [--network 100000]
        [--json] [--limit-gb 8]

``--limit-gb`` caps each worker's address space (RLIMIT_AS is not RSS, so it is set well above
the limit; the check against the limit is on the peak RSS reported).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


class Stages:
    def __init__(self):
        self.t, self.c = time.perf_counter(), cpu_s()

    def __call__(self, name: str, **extra) -> None:
        now, c = time.perf_counter(), cpu_s()
        row = {"stage": name, "seconds": round(now - self.t, 2), "cpu": round(c - self.c, 2),
               "peak_mb": round(peak_mb()), "rss_mb": round(rss_mb())}
        row.update(extra)
        print(json.dumps(row), flush=True)
        self.t, self.c = time.perf_counter(), cpu_s()


def reliability(adj) -> dict:
    """Every per-observation measure and the group tests, as the CLI's analysis computes them."""
    import numpy as np

    from baarda.stats.reliability import reliability_of

    rel = reliability_of(adj)
    r, w, mdb, ext = adj.r, adj.w, rel.mdb, rel.external
    groups = rel.groups
    return {"sum_r": float(r.sum()), "max_w": float(np.nanmax(np.abs(w))), "max_mdb": float(np.nanmax(mdb)),
            "finite_ext": int(np.isfinite(ext).sum()), "groups": len(groups)}


def worker_bal(path: str, with_json: bool, until: str = "") -> None:
    import numpy as np

    from baarda.adjust import Options, adjust
    from baarda.build import build
    from baarda.io import read_model

    st = Stages()
    model = read_model(path, "bal")
    st("read", image_points=int(model.obs_image.size))
    if until == "read":
        return
    problem = build(model)
    del model
    st("build", n=int(problem.n), unknowns=int(problem.params.size))
    if until == "build":
        return
    adj = adjust(problem, Options())
    st("adjust", iterations=int(adj.iterations), converged=bool(adj.converged),
       cost=float(0.5 * adj.vPv))
    out = reliability(adj)
    st("reliability", **out)
    if with_json:
        import tempfile

        from baarda.io import results
        doc = results.to_dict(adj)
        with tempfile.TemporaryDirectory() as tmp:      # (written, measured, deleted)
            out = Path(tmp) / "r.json"
            results.write_json(adj, out, doc)
            size = out.stat().st_size
        st("json", observations=len(doc["observations"]), json_mb=round(size / 2 ** 20))
    del np


def network(n_points: int, seed: int = 1):
    """A planimetric network of ``n_points`` points on a jittered square grid with ≈ 3 distances
    per point (right, up and one diagonal neighbour), σ = 2 mm, two fixed points."""
    import numpy as np

    from baarda.model.network import Cluster, NetObservation, NetPoint, Network

    rng = np.random.default_rng(seed)
    side = int(round(np.sqrt(n_points)))
    ids = [f"P{k}" for k in range(side * side)]
    xy = np.stack(np.meshgrid(np.arange(side) * 100.0, np.arange(side) * 100.0, indexing="ij"), -1).reshape(-1, 2)
    xy += rng.normal(scale=5.0, size=xy.shape)
    pts = []
    for k, pid in enumerate(ids):
        if k in (0, side * side - 1):
            pts.append(NetPoint(pid, x=float(xy[k, 0]), y=float(xy[k, 1]), fixed="xy"))
        else:
            pts.append(NetPoint(pid, x=float(xy[k, 0] + rng.normal(scale=0.01)),
                                y=float(xy[k, 1] + rng.normal(scale=0.01)), adjusted="xy"))
    k = np.arange(side * side).reshape(side, side)
    pairs = np.concatenate([np.column_stack([k[:-1, :].ravel(), k[1:, :].ravel()]),
                            np.column_stack([k[:, :-1].ravel(), k[:, 1:].ravel()]),
                            np.column_stack([k[:-1, :-1].ravel(), k[1:, 1:].ravel()])])
    d = np.hypot(*(xy[pairs[:, 1]] - xy[pairs[:, 0]]).T) + rng.normal(scale=0.002, size=len(pairs))
    obs = tuple(NetObservation("distance", (ids[a], ids[b]), float(v)) for (a, b), v in zip(pairs.tolist(), d.tolist()))
    C = np.array([[0.002 ** 2]])
    clusters = tuple(Cluster((i,), C) for i in range(len(obs)))
    return Network(tuple(pts), obs, clusters, sigma_act="apriori")


def worker_network(n_points: int) -> None:
    from baarda.adjust import Options, adjust
    from baarda.model.network_problem import build_problem

    st = Stages()
    net = network(n_points)
    st("network", points=len(net.points), observations=len(net.observations))
    problem = build_problem(net)
    del net
    st("build", n=int(problem.n), unknowns=int(problem.params.size))
    adj = adjust(problem, Options())
    st("adjust", iterations=int(adj.iterations), converged=bool(adj.converged))
    st("reliability", **reliability(adj))


def run(args: list[str], limit_gb: float | None) -> list[dict]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS=os.environ.get("OPENBLAS_NUM_THREADS", "1"))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", *args]

    def cap():
        if limit_gb:
            lim = int(3 * limit_gb * 2 ** 30)     # address space, not RSS: numba/BLAS reserve a lot
            resource.setrlimit(resource.RLIMIT_AS, (lim, lim))

    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, preexec_fn=cap)
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or ["(no message)"]
        rows.append({"stage": "FAILED", "seconds": 0, "cpu": 0, "peak_mb": 0, "rss_mb": 0, "error": tail[0][:120]})
    return rows


def table(name: str, rows: list[dict], limit_gb: float | None) -> None:
    print(f"\n{name}")
    print(f"{'stage':<12} {'seconds':>8} {'CPU s':>8} {'peak RSS':>10} {'RSS after':>10}  notes")
    total = cpu = 0.0
    for r in rows:
        total += r["seconds"]
        cpu += r.get("cpu", 0.0)
        notes = ", ".join(f"{k}={v}" for k, v in r.items()
                          if k not in ("stage", "seconds", "cpu", "peak_mb", "rss_mb"))
        print(f"{r['stage']:<12} {r['seconds']:>8.1f} {r.get('cpu', 0.0):>8.1f} {r['peak_mb'] / 1024:>8.2f} GB "
              f"{r['rss_mb'] / 1024:>7.2f} GB  {notes}")
    peak = max((r["peak_mb"] for r in rows), default=0) / 1024
    verdict = "" if not limit_gb else (" within" if peak <= limit_gb else " OVER") + f" the {limit_gb:g} GB limit"
    print(f"{'total':<12} {total:>8.1f} {cpu:>8.1f} {peak:>8.2f} GB peak{verdict}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="*", type=float, default=[1e6, 2.5e6, 5e6], help="image points per BAL block")
    ap.add_argument("--network", type=int, default=100_000, help="points of the 2D network (0: none)")
    ap.add_argument("--json", action="store_true", help="also write the JSON document (results.write_json, "
                    "to a temporary file)")
    ap.add_argument("--limit-gb", type=float, default=8.0)
    ap.add_argument("--dir", default="/tmp", help="where the synthetic BAL files are written")
    ap.add_argument("--until", choices=("read", "build", ""), default="",
                    help="stop the BAL runs after this stage (blocks too big for the machine)")
    ap.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        if a.worker[0] == "bal":
            worker_bal(a.worker[1], a.json, a.until)
        else:
            worker_network(int(a.worker[1]))
        return 0
    for size in a.sizes:
        path = Path(a.dir) / f"baarda-big-{size / 1e6:g}M.txt"
        if not path.exists():
            subprocess.run([sys.executable, str(HERE / "make_big_bal.py"), "--obs", str(size), "-o", str(path)],
                           check=True)
        head = path.open().readline().split()
        rows = run(["bal", str(path)] + (["--json"] if a.json else []) + (["--until", a.until] if a.until else []),
                   a.limit_gb)
        table(f"BAL {path.name}: {int(head[0])} images, {int(head[1])} points, {int(head[2])} image points",
              rows, a.limit_gb)
    if a.network:
        table(f"2D network: {a.network} points, distances only", run(["network", str(a.network)], a.limit_gb),
              a.limit_gb)
    return 0


if __name__ == "__main__":
    sys.exit(main())
