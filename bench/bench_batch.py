"""Benchmark: batches of blocks and a design study on Dask (issue 30).

N small blocks (GNU Gama's textbook networks of ../shared/extdata/gama/krumm and the demo
files, repeated to N) analysed

- serially, one process per block as before ``baarda batch`` (``baarda analyze FILE --json``);
- by ``baarda batch`` on its local cluster (one process: the cluster started, the blocks run);
- by warm workers: a cluster already running whose workers have analysed one block each
  (imports and numba kernels loaded), through ``baarda batch --scheduler``;

with the start-up share of the serial runs (N × the time of ``python -c "import baarda.commands"``, what a command loads
over the serial time); then a design study of the demo recipe (data/demo-study.json,
≥ 200 replicates, 2 analyses each) on the warm workers, with its wall time.

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_batch [--blocks 24] [--replicates 200] [--workers N]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from baarda import batch, study
from baarda.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
EXT = ROOT.parent / "shared" / "extdata"
BIN = Path(sys.executable).parent


def blocks(n: int) -> list[str]:
    files = sorted(str(p) for p in (EXT / "gama" / "krumm").rglob("*.gkf")) if EXT.exists() else []
    files += [str(ROOT / "data" / f) for f in ("demo-levelling.gkf", "demo-imodel.json", "demo-block.json")]
    return [files[k % len(files)] for k in range(n)]


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--blocks", type=int, default=24)
    ap.add_argument("--replicates", type=int, default=200)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    files = blocks(args.blocks)
    # the copies of one file are separate blocks (names by path): link them under a folder each
    tmp = Path(tempfile.mkdtemp(prefix="bench-batch-"))
    inputs = []
    for k, f in enumerate(files):
        d = tmp / "in" / f"{k:04d}"
        d.mkdir(parents=True)
        os.symlink(f, d / Path(f).name)
        inputs.append(str(d / Path(f).name))
    imports = min(timed(lambda: subprocess.run([sys.executable, "-c", "import baarda.commands"], check=True))
                  for _ in range(3))

    def serial():
        for k, f in enumerate(inputs):
            subprocess.run([str(BIN / "baarda"), "analyze", f, "--json", str(tmp / f"s{k}.json"), "--quiet"],
                           check=False)
    t_serial = timed(serial)
    t_local = timed(lambda: subprocess.run([str(BIN / "baarda"), "batch", *inputs, "--out", str(tmp / "local"),
                                            "--workers", str(args.workers), "--quiet"], check=False))
    options = batch.options_of(build_parser().parse_args(["batch", "x"]))
    cluster = batch.local_cluster(args.workers)
    try:
        from distributed import Client
        with Client(cluster) as client:              # warm: every worker has analysed a block
            client.run(batch.analyze_block, inputs[0], options)
        t_warm = timed(lambda: batch.run_batch(inputs, tmp / "warm", options, scheduler=cluster.scheduler_address,
                                               quiet=True))
        recipe = study.read_recipe(ROOT / "data" / "demo-study.json")
        recipe["replicates"] = args.replicates
        t0 = time.perf_counter()
        table = study.run_study(recipe, tmp / "study", scheduler=cluster.scheduler_address)
        t_study = time.perf_counter() - t0
    finally:
        cluster.close()
    n = len(inputs)
    print(f"{n} blocks, {args.workers} worker(s), {os.cpu_count()} core(s)")
    print(f"{'way':<36s} {'wall s':>8s} {'per block s':>12s} {'vs serial':>10s}")
    for name, t in (("serial, one process per block", t_serial), ("baarda batch, local cluster", t_local),
                    ("baarda batch --scheduler, warm", t_warm)):
        print(f"{name:<36s} {t:8.2f} {t / n:12.3f} {t_serial / t:9.2f}x")
    print(f"start-up share of the serial runs: {n} x {imports:.2f} s import = {n * imports / t_serial:.0%}")
    print(f"design study: {args.replicates} replicates x 2 analyses of the demo design on the warm workers: "
          f"{t_study:.1f} s wall")
    print(study.table_text(table))


if __name__ == "__main__":
    main()
