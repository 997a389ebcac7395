"""Benchmark: reading large BAL files (time and peak memory of the reader alone).

Writes a synthetic BAL problem of N image points (default 5 M; about 1.6 M points, one point
in ~3 images, 800 cameras) to a temporary directory — never into the repository — plain and,
with ``--bz2``, bzip2-compressed, then reads each in a fresh process and prints a table: file,
size, seconds, peak RSS of the process (``ru_maxrss``), for baarda's chunked reader and for the
naive baseline "read the text, split it into tokens, convert them" that the reader used before
(each token a Python string with its line number). CPU seconds (user + system) are printed
beside the wall-clock seconds: on a loaded machine they are the steadier figure.

    python -m bench.bench_read [--obs 5000000] [--dir /tmp/baarda-bench] [--bz2] [--no-before]
    python -m bench.bench_read --colmap 40 50000     # COLMAP text and binary: baarda vs pycolmap
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
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"seconds": dt, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024, "obs": n}))
"""


COLMAP_CHILD = r"""
import resource, sys, time, json
import numpy as np
path, how = sys.argv[1], sys.argv[2]
t = time.perf_counter()
if how == "baarda":
    from baarda.io.colmap import read_colmap
    b = read_colmap(path, check=False)
    n = b.obs_image.size
    t_read = time.perf_counter() - t
else:
    import pycolmap
    rec = pycolmap.Reconstruction(path)
    t_read = time.perf_counter() - t
    # what a reader through pycolmap must still do: the observations as arrays
    img, pt, kp, xy = [], [], [], []
    for pid, p3 in rec.points3D.items():
        for el in p3.track.elements:
            img.append(el.image_id); pt.append(pid); kp.append(el.point2D_idx)
            xy.append(rec.images[el.image_id].points2D[el.point2D_idx].xy)
    n = len(img)
dt = time.perf_counter() - t
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"seconds": dt, "read": t_read, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024,
                  "obs": n}))
"""


def measure(path: Path, how: str, child: str = CHILD) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", child, str(path), how], capture_output=True, text=True, env=env)
    if out.returncode:
        return {"seconds": float("nan"), "cpu": float("nan"), "rss_mb": float("nan"), "obs": 0,
                "error": out.stderr.strip()[-200:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def colmap_table(d: Path, frames: int, points: int) -> None:
    """A synthetic COLMAP model (pycolmap; every point in every frame), text and binary, read by
    baarda's reader and by pycolmap (its read, then the observations taken out as arrays)."""
    import pycolmap

    base = d / f"colmap-{frames}x{points}"
    if not (base / "bin" / "points3D.bin").exists():
        opt = pycolmap.SyntheticDatasetOptions(num_rigs=1, num_cameras_per_rig=1, num_frames_per_rig=frames,
                                               num_points3D=points, num_points2D_without_point3D=10)
        rec = pycolmap.synthesize_dataset(opt)
        for kind in ("txt", "bin"):
            (base / kind).mkdir(parents=True, exist_ok=True)
            (rec.write_text if kind == "txt" else rec.write_binary)(str(base / kind))
    print(f"{'COLMAP model':<24s} {'MB':>8s} {'reader':<10s} {'image pts':>10s} {'seconds':>8s} {'CPU s':>7s} "
          f"{'peak RSS MB':>12s}  (pycolmap: its own read)")
    for kind in ("txt", "bin"):
        m = base / kind
        size = sum(f.stat().st_size for f in m.iterdir()) / 1e6
        for how in ("baarda", "pycolmap"):
            r = measure(m, how, COLMAP_CHILD)
            extra = f"  ({r['read']:.2f} s)" if how == "pycolmap" and "read" in r else ""
            print(f"{base.name + '/' + kind:<24s} {size:8.1f} {how:<10s} {r['obs']:>10d} {r['seconds']:8.2f} "
                  f"{r.get('cpu', float('nan')):7.2f} {r['rss_mb']:12.0f}{extra}"
                  + (f"  {r['error']}" if "error" in r else ""))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--obs", type=int, default=5_000_000)
    ap.add_argument("--dir", default=None, help="where to write the files (default: a temporary directory)")
    ap.add_argument("--bz2", action="store_true", help="also read a bzip2-compressed copy")
    ap.add_argument("--no-before", action="store_true", help="skip the naive baseline")
    ap.add_argument("--colmap", type=int, nargs=2, metavar=("FRAMES", "POINTS"),
                    help="instead: a synthetic COLMAP model read by baarda and by pycolmap")
    args = ap.parse_args(argv)
    tmp = None
    if args.dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="baarda-bench-read-")
        d = Path(tmp.name)
    else:
        d = Path(args.dir)
        d.mkdir(parents=True, exist_ok=True)
    if args.colmap:
        colmap_table(d, *args.colmap)
        if tmp is not None:
            tmp.cleanup()
        return
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
    print(f"{'file':<24s} {'MB':>8s} {'reader':<10s} {'image pts':>10s} {'seconds':>8s} {'CPU s':>7s} "
          f"{'peak RSS MB':>12s}")
    for f in files:
        size = f.stat().st_size / 1e6
        hows = ["baarda"] + ([] if args.no_before or f.suffix == ".bz2" else ["before"])
        for how in hows:
            r = measure(f, how)
            print(f"{f.name:<24s} {size:8.1f} {how:<10s} {r['obs']:>10d} {r['seconds']:8.2f} "
                  f"{r.get('cpu', float('nan')):7.2f} {r['rss_mb']:12.0f}"
                  + (f"  {r['error']}" if "error" in r else ""))
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
