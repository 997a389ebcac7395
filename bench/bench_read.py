"""Benchmark: reading large BAL files (time and peak memory of the reader alone).

Writes a synthetic BAL problem of N image points (default 5 M; about 1.6 M points, one point
in ~3 images, 800 cameras) to a temporary directory — never into the repository — plain and,
with ``--bz2``, bzip2-compressed, then reads each in a fresh process and prints a table: file,
size, seconds, peak RSS of the process (``ru_maxrss``), for baarda's chunked reader and for the
naive baseline "read the text, split it into tokens, convert them" that the reader used before
(each token a Python string with its line number).

    python bench/bench_read.py [--obs 5000000] [--dir /tmp/baarda-bench] [--bz2] [--no-before]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def write_bal(path: Path, n_obs: int, seed: int = 1) -> None:
    """A valid BAL problem of about ``n_obs`` image points (3 per point), written in chunks."""
    rng = np.random.default_rng(seed)
    npt = n_obs // 3
    ncam = max(int(n_obs // 6000), 3)
    n_obs = 3 * npt
    with open(path, "w") as f:
        f.write(f"{ncam} {npt} {n_obs}\n")
        step = 200_000
        for a in range(0, npt, step):
            m = min(step, npt - a)
            pts = np.repeat(np.arange(a, a + m), 3)
            cams = (pts * 7 + np.tile([0, 1, 2], m) * (ncam // 3 + 1)) % ncam
            xy = rng.normal(scale=300.0, size=(pts.size, 2))
            lines = np.char.add(np.char.add(cams.astype(str), " "), pts.astype(str))
            body = "\n".join(f"{c} {x:.6e} {y:.6e}" for c, (x, y) in zip(lines, xy))
            f.write(body + "\n")
        cam = np.c_[rng.normal(scale=0.1, size=(ncam, 3)), rng.normal(size=(ncam, 3)),
                    np.full(ncam, 500.0), rng.normal(scale=1e-3, size=(ncam, 2))]
        f.write("\n".join(f"{v:.16e}" for v in cam.ravel()) + "\n")
        for a in range(0, npt, step):
            m = min(step, npt - a)
            X = rng.normal(scale=10.0, size=(m, 3))
            f.write("\n".join(f"{v:.16e}" for v in X.ravel()) + "\n")


CHILD = r"""
import resource, sys, time, json
import numpy as np
path, how = sys.argv[1], sys.argv[2]
t = time.perf_counter()
if how == "baarda":
    from baarda.io.bal import read_bal
    b = read_bal(path, check=False)
    n = b.obs_image.size
else:
    text = open(path, "rb").read().decode("utf-8")
    toks, lines = [], []
    for ln, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        toks.extend(parts)
        lines.extend([ln] * len(parts))
    ncam, npt, nobs = (int(v) for v in toks[:3])
    obs = np.array(toks[3:3 + 4 * nobs], dtype=object).reshape(nobs, 4)
    idx = obs[:, :2].astype(np.int64)
    xy = obs[:, 2:].astype(float)
    rest = np.array(toks[3 + 4 * nobs:], dtype=float)
    n = nobs
dt = time.perf_counter() - t
print(json.dumps({"seconds": dt, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "obs": n}))
"""


def measure(path: Path, how: str) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD, str(path), how], capture_output=True, text=True, env=env)
    if out.returncode:
        return {"seconds": float("nan"), "rss_mb": float("nan"), "obs": 0, "error": out.stderr.strip()[-200:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--obs", type=int, default=5_000_000)
    ap.add_argument("--dir", default=None, help="where to write the files (default: a temporary directory)")
    ap.add_argument("--bz2", action="store_true", help="also read a bzip2-compressed copy")
    ap.add_argument("--no-before", action="store_true", help="skip the naive baseline")
    args = ap.parse_args(argv)
    tmp = None
    if args.dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="baarda-bench-read-")
        d = Path(tmp.name)
    else:
        d = Path(args.dir)
        d.mkdir(parents=True, exist_ok=True)
    path = d / f"bal-{args.obs}.txt"
    if not path.exists():
        t = time.perf_counter()
        write_bal(path, args.obs)
        print(f"wrote {path} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    files = [path]
    if args.bz2:
        zpath = path.with_name(path.name + ".bz2")
        if not zpath.exists():
            subprocess.run(["bzip2", "-k", "-f", str(path)], check=True)
        files.append(zpath)
    print(f"{'file':<24s} {'MB':>8s} {'reader':<10s} {'image pts':>10s} {'seconds':>8s} {'peak RSS MB':>12s}")
    for f in files:
        size = f.stat().st_size / 1e6
        hows = ["baarda"] + ([] if args.no_before or f.suffix == ".bz2" else ["before"])
        for how in hows:
            r = measure(f, how)
            print(f"{f.name:<24s} {size:8.1f} {how:<10s} {r['obs']:>10d} {r['seconds']:8.2f} {r['rss_mb']:12.0f}"
                  + (f"  {r['error']}" if "error" in r else ""))
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
