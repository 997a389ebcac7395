"""Benchmark: full analysis (adjustment + all reliability measures) of planimetric grid networks.

Prints a table: points, observations, unknowns, half-bandwidth after RCM, seconds for building
the problem, the adjustment and the reliability (r, w, MDB, δ̄0, u_k), peak memory, and — for
sizes where it fits — the time of a dense numpy reference computing r_i from the full inverse in
the same process, with the ratio.

    python -m bench.bench_network [--sizes 10 30 100] [--dense-max 900]     # (from the repository root)
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from baarda.adjust import adjust
from baarda.model.network import Cluster, NetObservation, NetPoint, Network
from baarda.model.network_problem import build_problem
from baarda.stats.reliability import reliability_of
from tests.oracle import redundancy          # the tests' dense oracle, F80 §5


def grid(n_side: int, spacing=100.0, seed=1) -> Network:
    rng = np.random.default_rng(seed)
    ids = [f"P{i}_{j}" for i in range(n_side) for j in range(n_side)]
    xy = np.array([(i * spacing, j * spacing) for i in range(n_side) for j in range(n_side)])
    xy += rng.normal(scale=5.0, size=xy.shape)
    pts = []
    for k, pid in enumerate(ids):
        if k in (0, n_side - 1):
            pts.append(NetPoint(pid, x=xy[k, 0], y=xy[k, 1], fixed="xy"))
        else:
            pts.append(NetPoint(pid, x=xy[k, 0] + rng.normal(scale=0.01), y=xy[k, 1] + rng.normal(scale=0.01), adjusted="xy"))
    obs, sig = [], []
    nb = [(1, 0), (0, 1), (1, 1), (1, -1)]
    for i in range(n_side):
        for j in range(n_side):
            a = i * n_side + j
            o = rng.uniform(0, 2 * np.pi)
            targets = []
            for di, dj in nb + [(-p, -q) for p, q in nb]:
                ii, jj = i + di, j + dj
                if 0 <= ii < n_side and 0 <= jj < n_side:
                    targets.append(ii * n_side + jj)
            for b in targets:
                d = xy[b] - xy[a]
                if a < b:
                    obs.append(NetObservation("distance", (ids[a], ids[b]), float(np.hypot(*d)) + rng.normal() * 0.002))
                    sig.append(0.002)
                obs.append(NetObservation("direction", (ids[a], ids[b]),
                                          float((np.arctan2(d[1], d[0]) - o + rng.normal() * 1e-5) % (2 * np.pi)), set_id=a))
                sig.append(1e-5)
    clusters = tuple(Cluster((k,), np.array([[s * s]])) for k, s in enumerate(sig))
    return Network(tuple(pts), tuple(obs), clusters, sigma_act="apriori")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 30, 60, 100],
                    help="grid side lengths (points = side²); 100 → 10⁴ points")
    ap.add_argument("--dense-max", type=int, default=2500, help="largest point count for the dense reference")
    args = ap.parse_args()
    head = f"{'points':>7} {'obs':>7} {'unknowns':>8} {'band':>5} {'build s':>8} {'adjust s':>9} {'reliab. s':>9} {'peak MB':>8} {'dense s':>8} {'ratio':>6} {'max|Δr|':>9}"
    print(head)
    print("-" * len(head))
    for side in args.sizes:
        net = grid(side)
        t0 = time.perf_counter()
        problem = build_problem(net)
        t1 = time.perf_counter()
        adj = adjust(problem)
        t2 = time.perf_counter()
        rel = reliability_of(adj)
        r, w, mdb, ext = adj.r, adj.w, rel.mdb, rel.external
        t3 = time.perf_counter()
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        dense_s = ratio = dr = float("nan")
        if side * side <= args.dense_max:
            t4 = time.perf_counter()
            rd = redundancy(adj.Ar, adj.P)
            dense_s = time.perf_counter() - t4
            ratio = dense_s / (t3 - t2)
            dr = float(np.abs(rd - r).max())
        print(f"{side * side:>7d} {adj.n:>7d} {adj.n_unknowns:>8d} {adj.factor.bandwidth:>5d} {t1 - t0:>8.2f} "
              f"{t2 - t1:>9.2f} {t3 - t2:>9.2f} {peak:>8.0f} {dense_s:>8.2f} {ratio:>6.1f} {dr:>9.1e}")
        assert np.isfinite(w).all() and np.isfinite(mdb).all() and np.isfinite(ext).all()


if __name__ == "__main__":
    main()
