"""Write a synthetic BAL problem of realistic geometry (for bench/bench_memory.py; never committed).

A nadir block in BAL's conventions (P = R X + t, p = −P/P_z, p' = f (1 + k1‖p‖² + k2‖p‖⁴) p;
Agarwal et al. 2010): images on a grid at height H over gently rolling ground, 80 %/60 %
overlap, f = 1200 px on a 1600 × 1200 sensor with a little radial distortion; every ground
point keeps a random subset of 2 + Poisson(track − 2) of the images that see it. Image points
get N(0, σ) noise (σ = 0.5 px) and the start values are the truth perturbed (points by 0.05 m,
positions by 0.02 m, rotations by 1e-4 rad), as BAL's "pre" files are — so Levenberg-Marquardt
has a few iterations to do.

    python bench/make_big_bal.py --obs 5000000 --points 1600000 -o /tmp/big-5M.txt

The numbers of images follow from the numbers of points and observations (about 3,000 image
points per image, as in BAL's Venice and Final problems).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

F, K1, K2 = 1200.0, -0.02, 0.002          # BAL: k1, k2 act on the normalised p = −P/P_z
WIDTH, HEIGHT = 1600.0, 1200.0


def rodrigues_to_R(rho: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(rho, axis=1)
    k = rho / np.where(th > 0, th, 1.0)[:, None]
    K = np.zeros((rho.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - np.swapaxes(K, 1, 2)
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def make(n_obs: int, n_points: int, seed: int = 0, sigma_px: float = 0.5):
    """(cams (c × 9), X (m × 3), cam index (n,), point index (n,), xy (n × 2)): start values
    and observations; the observations sorted by camera as in BAL's files."""
    rng = np.random.default_rng(seed)
    track = n_obs / n_points
    n_img = max(4, int(round(n_obs / 3000)))
    H = 100.0
    W, Hg = WIDTH * H / F, HEIGHT * H / F            # footprint on the ground (m)
    side = int(np.ceil(np.sqrt(n_img)))
    B, A = 0.2 * W, 0.4 * Hg                         # 80 % forward, 60 % side overlap
    k = np.arange(n_img)
    gi, gj = divmod(k, side)
    C = np.column_stack([gj * B + rng.normal(0, 0.5, n_img), gi * A + rng.normal(0, 0.5, n_img),
                         H + rng.normal(0, 0.5, n_img)])
    rho = rng.normal(0, 0.01, (n_img, 3))
    R = rodrigues_to_R(rho)
    t = -np.einsum("kij,kj->ki", R, C)
    lo, hi = C[:, :2].min(axis=0), C[:, :2].max(axis=0)
    P = np.column_stack([rng.uniform(lo[0], hi[0], n_points), rng.uniform(lo[1], hi[1], n_points),
                         3.0 * np.sin(rng.uniform(0, 2 * np.pi, n_points)) + rng.normal(0, 0.5, n_points)])
    # candidate images: a window of the grid around each point
    wi, wj = int(np.ceil(Hg / A)) + 1, int(np.ceil(W / B)) + 1
    ci = np.clip(np.rint(P[:, 1] / A).astype(np.int64), 0, side - 1)
    cj = np.clip(np.rint(P[:, 0] / B).astype(np.int64), 0, side - 1)
    di, dj = np.meshgrid(np.arange(-wi, wi + 1), np.arange(-wj, wj + 1), indexing="ij")
    di, dj = di.ravel(), dj.ravel()
    want = 2 + rng.poisson(max(track - 2.0, 0.0) * 1.02, n_points)
    obs_c, obs_p, xy = [], [], []
    for s in range(0, n_points, 200_000):
        sl = slice(s, min(s + 200_000, n_points))
        m = sl.stop - sl.start
        cand = (ci[sl, None] + di) * side + (cj[sl, None] + dj)
        ok = (ci[sl, None] + di >= 0) & (ci[sl, None] + di < side) & (cj[sl, None] + dj >= 0) & \
            (cj[sl, None] + dj < side) & (cand < n_img)
        cand = np.where(ok, cand, 0)
        Pc = np.einsum("mkij,mj->mki", R[cand], P[sl]) + t[cand]
        p = -Pc[..., :2] / Pc[..., 2:3]
        r2 = (p * p).sum(-1)
        uv = F * (1 + K1 * r2 + K2 * r2 * r2)[..., None] * p
        ok &= (np.abs(uv[..., 0]) < 0.5 * WIDTH) & (np.abs(uv[..., 1]) < 0.5 * HEIGHT) & (Pc[..., 2] < 0)
        key = np.where(ok, rng.random(ok.shape), 2.0)
        order = np.argsort(key, axis=1)
        nvis = ok.sum(axis=1)
        take = np.minimum(want[sl], nvis)
        sel = np.arange(order.shape[1])[None, :] < take[:, None]
        rows = np.repeat(np.arange(m), take)
        colk = order[sel]
        obs_c.append(cand[rows, colk])
        obs_p.append(rows + sl.start)
        xy.append(uv[rows, colk])
    obs_c, obs_p, xy = np.concatenate(obs_c), np.concatenate(obs_p), np.concatenate(xy)
    # points in fewer than 2 images are dropped, the rest renumbered
    cnt = np.bincount(obs_p, minlength=n_points)
    keep_pt = cnt >= 2
    new = np.cumsum(keep_pt) - 1
    m = keep_pt[obs_p]
    obs_c, obs_p, xy = obs_c[m], new[obs_p[m]], xy[m]
    P = P[keep_pt]
    xy = xy + rng.normal(0, sigma_px, xy.shape)
    order = np.lexsort((obs_p, obs_c))
    obs_c, obs_p, xy = obs_c[order], obs_p[order], xy[order]
    # start values: truth perturbed
    C0 = C + rng.normal(0, 0.02, C.shape)
    rho0 = rho + rng.normal(0, 1e-4, rho.shape)
    t0 = -np.einsum("kij,kj->ki", rodrigues_to_R(rho0), C0)
    cams = np.column_stack([rho0, t0, np.full(n_img, F), np.full(n_img, K1), np.full(n_img, K2)])
    X0 = P + rng.normal(0, 0.05, P.shape)
    return cams, X0, obs_c, obs_p, xy


def write(path, cams, X, obs_c, obs_p, xy) -> None:
    with open(path, "w") as fh:
        fh.write(f"{cams.shape[0]} {X.shape[0]} {obs_c.size}\n")
        for s in range(0, obs_c.size, 500_000):
            sl = slice(s, s + 500_000)
            fh.write("".join(f"{c} {p} {u:.6f} {v:.6f}\n" for c, p, (u, v) in
                             zip(obs_c[sl].tolist(), obs_p[sl].tolist(), xy[sl].tolist())))
        fh.write("".join(f"{v:.16e}\n" for v in cams.ravel().tolist()))
        for s in range(0, X.shape[0], 500_000):
            fh.write("".join(f"{v:.16e}\n" for v in X[s:s + 500_000].ravel().tolist()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--obs", type=float, default=5e6, help="image points (default 5e6)")
    ap.add_argument("--points", type=float, default=None, help="3D points (default obs/3.1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-o", "--output", required=True)
    a = ap.parse_args(argv)
    n_obs = int(a.obs)
    n_pts = int(a.points) if a.points else int(n_obs / 3.1)
    t0 = time.perf_counter()
    cams, X, oc, op, xy = make(n_obs, n_pts, a.seed)
    write(a.output, cams, X, oc, op, xy)
    print(f"{a.output}: {cams.shape[0]} images, {X.shape[0]} points, {oc.size} image points "
          f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
