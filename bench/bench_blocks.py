"""Benchmark: full reliability of large bundle blocks (issue 6).

For each block prints the phases — build (simulation + problem), solve (Gauss-Newton), reliability
(factor at the solution, selected inverse, r, w, MDB, δ̄0, u_k/u_t; median of 3 runs) — for the reduced-camera-system
path (:mod:`baarda.solve.schur`) and, in the same run, its peers: the generic sparse-Cholesky path of
:mod:`baarda.solve.linalg`, a dense numpy reference (r from the full inverse of N, small blocks only),
and pycolmap (Ceres) ``bundle_adjustment`` + ``estimate_ba_covariance`` on a synthetic
reconstruction of the same numbers of images and points. Also the time of a 2D point-transfer
retest (:meth:`baarda.result.Adjustment.test`, q = 2, three images) and of leaving one image
point out (:func:`baarda.exclusion.exclude`, Woodbury) on the analysed block.

Blocks: synthetic aerial blocks (:func:`baarda.simulate.simulate_block`, design mode: exact
observations, approximations = truth, so Gauss-Newton stops after one step), a block shaped like
BAL's Dubrovnik problem (356 images, ≈ 227k points, ≈ 1.25 M image points; random nadir
geometry, free 7-DOF datum) and, when present, BAL Ladybug (49 images): Levenberg-Marquardt
from the published start values, then the analysis (r, w, MDB, δ̄0; median of 5 runs), beside
pycolmap's bundle adjustment from the same start and its pose covariance, and SciPy's
least_squares (peers "pycolmap", "scipy").

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_blocks [--blocks aerial-100 aerial-1000 ...]   # (from the repository root)

Peak memory is the process's maximum resident set (ru_maxrss) after each block.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("GLOG_minloglevel", "2")     # quiet pycolmap/Ceres
import resource
import time
from pathlib import Path

import numpy as np

from baarda.adjust import Options, adjust
from baarda.stats.reliability import reliability_of
from baarda.exclusion import exclude
from baarda.model.bundle import Block, Camera, Image, ImageObservations, ObjectPoint, build_block_problem
from baarda.observations.collinearity import project
from baarda.stats.hypotheses import common_error
from baarda.simulate import simulate_block
from tests.oracle import redundancy          # the tests' dense oracle, F80 §5

LADYBUG = Path("/work/shared/extdata/bal/problem-49-7776-pre.txt")
AERIAL = {"aerial-100": (5, 20), "aerial-1000": (20, 50), "aerial-5000": (50, 100)}


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def dubrovnik_like(n_images=356, n_points=227_000, mean_track=5.5, seed=0) -> Block:
    """A nadir block with the numbers of BAL Dubrovnik: a 19 × 19 grid less 5 images at 80 m
    with 80 %/70 % overlap (every ground point inside ≈ 16 footprints); each point keeps a random
    subset of 2 + Poisson(mean_track − 2) of the images that see it. Free datum."""
    rng = np.random.default_rng(seed)
    cam = Camera(id="drone", c=3650.0, width=5472.0, height=3648.0, unit="px", pixel_size=0.0024)
    H = 80.0
    W, Hg = cam.width * H / cam.c, cam.height * H / cam.c
    side = int(np.ceil(np.sqrt(n_images)))
    B, A = 0.2 * W, 0.3 * Hg
    images = []
    for k in range(n_images):
        i, j = divmod(k, side)
        images.append(Image(id=f"I{k:04d}", camera=cam.id, X0=j * B + rng.normal(0, 0.5),
                            Y0=i * A + rng.normal(0, 0.5), Z0=H + rng.normal(0, 0.5),
                            omega=rng.normal(0, 0.01), phi=rng.normal(0, 0.01), kappa=rng.normal(0, 0.01),
                            strip=str(i + 1)))
    X0 = np.array([[im.X0, im.Y0] for im in images])
    lo, hi = X0.min(axis=0), X0.max(axis=0)
    P = np.column_stack([rng.uniform(lo[0], hi[0], n_points), rng.uniform(lo[1], hi[1], n_points),
                         rng.normal(0.0, 2.0, n_points)])
    obs_i, obs_p, xy = [], [], []
    half = 0.45 * np.array([W, Hg])
    seen = [[] for _ in range(n_points)]
    for k, im in enumerate(images):
        near = np.flatnonzero((np.abs(P[:, 0] - im.X0) < half[0]) & (np.abs(P[:, 1] - im.Y0) < half[1]))
        for p in near:
            seen[p].append(k)
    want = np.minimum(2 + rng.poisson(mean_track - 2, n_points), [len(s) for s in seen])
    for p in range(n_points):
        if want[p] < 2:
            continue
        for k in rng.choice(seen[p], size=want[p], replace=False):
            obs_i.append(k)
            obs_p.append(p)
    obs_i, obs_p = np.array(obs_i), np.array(obs_p)
    used = np.unique(obs_p)
    newp = np.full(n_points, -1)
    newp[used] = np.arange(used.size)
    obs_p = newp[obs_p]
    P = P[used]
    order = np.lexsort((obs_p, obs_i))
    obs_i, obs_p = obs_i[order], obs_p[order]
    xy = np.empty((obs_i.size, 2))
    starts = np.searchsorted(obs_i, np.arange(n_images + 1))
    for k, im in enumerate(images):
        sl = slice(starts[k], starts[k + 1])
        xy[sl] = project(cam, [im] * (starts[k + 1] - starts[k]), P[obs_p[sl]])
    m = obs_i.size
    cov = np.repeat((0.5 ** 2 * np.eye(2))[None], m, axis=0)
    points = tuple(ObjectPoint(id=f"P{k}", X=float(x), Y=float(y), Z=float(z)) for k, (x, y, z) in enumerate(P))
    obs = ImageObservations(image=obs_i, point=obs_p, xy=xy, cov=cov, line=np.zeros(m, dtype=np.int64))
    return Block(cameras=(cam,), images=tuple(images), points=points, obs=obs, datum="free",
                 title="Dubrovnik-shaped")


def analyse(problem, solver, repeat: int = 3):
    """Solve, then the full reliability (factor at the solution included) ``repeat`` times on
    fresh copies of the result: the median (this VM's timings scatter by ±20 %)."""
    import dataclasses

    t0 = time.perf_counter()
    adj = adjust(problem, Options(solver=solver))
    t_solve = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        a = dataclasses.replace(adj, timings={})
        if adj.solver == "schur":
            a.seed(schur_structure=adj.schur_structure)
        t0 = time.perf_counter()
        for name in ("r", "w", "mdb", "external", "u_t"):
            getattr(a, name)
        times.append(time.perf_counter() - t0)
    return a, t_solve, float(np.median(times))


def transfer_rows(problem):
    """Rows (x, y) of a tie point's measurements in its first three images (or two)."""
    groups = problem.info.group
    kinds = problem.info.kind
    by_point: dict = {}
    for i in range(0, min(problem.n, 4000), 2):
        if kinds[i] == "image-x":
            by_point.setdefault(problem.info.ids[i]["point"], []).append(i)
    pid = max(by_point, key=lambda p: len(by_point[p]))
    rows = np.array(by_point[pid][:3])
    del groups
    return rows, rows + 1


def retests(adj):
    rx, ry = transfer_rows(adj.problem)
    H = common_error(adj.n, [rx, ry])
    reliability_of(adj).test(H)
    t0 = time.perf_counter()
    for _ in range(5):
        reliability_of(adj).test(H)
    t_test = (time.perf_counter() - t0) / 5
    t0 = time.perf_counter()
    exclude(adj, [rx[0], ry[0]], method="woodbury").w
    t_excl = time.perf_counter() - t0
    return t_test, t_excl


def pycolmap_peer(n_images, n_points, track):
    """pycolmap bundle_adjustment + estimate_ba_covariance on a synthetic reconstruction."""
    try:
        import pycolmap
    except ImportError:
        return None
    pycolmap.logging.minloglevel = 2
    opt = pycolmap.SyntheticDatasetOptions()
    opt.num_rigs = n_images
    opt.num_frames_per_rig = 1
    opt.num_points3D = n_points
    opt.num_points2D_without_point3D = 0
    opt.track_length = max(2, int(round(track)))
    t0 = time.perf_counter()
    rec = pycolmap.synthesize_dataset(opt)
    t_build = time.perf_counter() - t0
    n_obs = sum(len(p.track.elements) for p in rec.points3D.values())
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = False
    ba.refine_extra_params = False
    ba.refine_principal_point = False
    t0 = time.perf_counter()
    pycolmap.bundle_adjustment(rec, ba)
    t_ba = time.perf_counter() - t0
    t_cov, ok = pycolmap_covariance(pycolmap, rec, ba)
    return {"images": n_images, "points": len(rec.points3D), "obs": n_obs, "build": t_build,
            "solve": t_ba, "cov": t_cov, "ok": ok}


def pycolmap_covariance(pycolmap, rec, ba) -> tuple[float, bool]:
    """Seconds of pycolmap's estimate_ba_covariance (poses; gauge fixed by three points), and
    whether it succeeded."""
    config = pycolmap.BundleAdjustmentConfig()
    for iid in rec.images:
        config.add_image(iid)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.THREE_POINTS)
    t0 = time.perf_counter()
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(ba, config, rec)
    cov = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(), rec, adjuster)
    return time.perf_counter() - t0, cov is not None


def bal_as_colmap(block, directory: Path) -> None:
    """Write a BAL block as a COLMAP text model: one RADIAL camera per image (f, c = 0, k1, k2:
    BAL's camera exactly), the pose turned to COLMAP's look-along-+z convention
    (R' = D R, t' = D t, D = diag(1, −1, −1)), image y → −y. Same residuals, so the same cost."""
    from baarda.observations.rotation import R_from_rodrigues, quaternion_from_R

    D = np.diag([1.0, -1.0, -1.0])
    directory.mkdir(parents=True, exist_ok=True)
    cam = {c.id: c for c in block.cameras}
    lines = []
    for k, im in enumerate(block.images):
        f, k1, k2 = cam[im.camera].params
        lines.append(f"{k + 1} RADIAL 4000 4000 {f:.17g} 0 0 {k1:.17g} {k2:.17g}")
    (directory / "cameras.txt").write_text("\n".join(lines) + "\n")
    per_image = [np.flatnonzero(block.obs_image == k) for k in range(len(block.images))]
    slot = np.empty(block.obs_image.size, dtype=np.int64)
    lines = []
    for k, im in enumerate(block.images):
        q = quaternion_from_R(D @ R_from_rodrigues(np.asarray(im.rodrigues)))
        t = D @ np.asarray(im.t)
        lines.append(f"{k + 1} " + " ".join(f"{v:.17g}" for v in (*q, *t)) + f" {k + 1} image{k}")
        lines.append(" ".join(f"{block.xy[o, 0]:.17g} {-block.xy[o, 1]:.17g} {block.obs_point[o] + 1}"
                              for o in per_image[k]))
        slot[per_image[k]] = np.arange(per_image[k].size)
    (directory / "images.txt").write_text("\n".join(lines) + "\n")
    order = np.argsort(block.obs_point, kind="stable")
    bounds = np.searchsorted(block.obs_point[order], np.arange(len(block.points) + 1))
    lines = []
    for i in range(len(block.points)):
        obs = order[bounds[i]:bounds[i + 1]]
        track = " ".join(f"{block.obs_image[o] + 1} {slot[o]}" for o in obs)
        lines.append(f"{i + 1} " + " ".join(f"{v:.17g}" for v in block.X[i]) + f" 0 0 0 0 {track}")
    (directory / "points3D.txt").write_text("\n".join(lines) + "\n")


def ladybug_peers(block, x_solution_cost: float, peers=("pycolmap", "scipy")) -> list[str]:
    """pycolmap (Ceres) bundle_adjustment from the same start (f, k1, k2 refined per camera,
    as BAL defines the problem) and estimate_ba_covariance of its poses; SciPy least_squares
    (trf, sparse Jacobian, LSMR) on the same residuals. Rows of the table as strings."""
    import tempfile

    rows = []
    try:
        import pycolmap
    except ImportError:
        pycolmap = None
    if "pycolmap" not in peers:
        pycolmap = None
    if pycolmap is not None:
        pycolmap.logging.minloglevel = 2
        with tempfile.TemporaryDirectory() as tmp:
            bal_as_colmap(block, Path(tmp) / "in")
            rec = pycolmap.Reconstruction(str(Path(tmp) / "in"))
            ba = pycolmap.BundleAdjustmentOptions()
            ba.refine_focal_length = True
            ba.refine_extra_params = True
            ba.refine_principal_point = False
            t0 = time.perf_counter()
            pycolmap.bundle_adjustment(rec, ba)
            t_ba = time.perf_counter() - t0
            out = Path(tmp) / "out"
            out.mkdir()
            rec.write_text(str(out))
            from baarda.model.sfm import initial_cost
            from baarda.build import read_problem
            cost = initial_cost(read_problem(out, "colmap"))
            t_cov, ok = pycolmap_covariance(pycolmap, rec, ba)
        rows.append(f"{'':<18} {'pycolmap':<8} {'':>6} {'':>7} {'':>8} {'':>8} {t_ba:>8.2f} {t_cov:>8.2f} "
                    f"{peak_mb():>8.0f}  Ceres BA to cost {cost:,.1f}; estimate_ba_covariance (poses, intrinsics "
                    f"refined as in the solve) ok={ok}")
    if "scipy" not in peers:
        return rows
    from scipy.optimize import least_squares

    from baarda.model.sfm import build_sfm_problem
    problem = build_sfm_problem(block)
    free = problem.params.free
    x_all = problem.params.x0.astype(float).copy()
    sig = problem.cov.sigma()

    def fun(xf):
        x_all[free] = xf
        f, _ = problem.evaluate(x_all)
        return problem.misclosure(f) / sig

    def jac(xf):
        x_all[free] = xf
        _, J = problem.evaluate(x_all)
        return (J[:, free].T.multiply(1.0 / sig)).T.tocsr()

    t0 = time.perf_counter()
    res = least_squares(fun, x_all[free].copy(), jac=jac, method="trf", tr_solver="lsmr", x_scale="jac",
                        max_nfev=100, ftol=1e-6)
    t_ls = time.perf_counter() - t0
    rows.append(f"{'':<18} {'scipy':<8} {'':>6} {'':>7} {'':>8} {'':>8} {t_ls:>8.2f} {'-':>8} {peak_mb():>8.0f}  "
                f"least_squares trf/lsmr to cost {res.cost:,.1f} in {res.nfev} evaluations "
                f"(baarda: {x_solution_cost:,.1f})")
    return rows


def row(name, solver, problem, adj, t_build, t_solve, t_rel, extra=""):
    n_img = len(problem.geometry.images) if problem.geometry is not None else "-"
    n_pts = len(problem.points.ids)
    print(f"{name:<18} {solver:<8} {n_img!s:>6} {n_pts:>7} {problem.n // 2:>8} {t_build:>8.2f} {t_solve:>8.2f} "
          f"{t_rel:>8.2f} {peak_mb():>8.0f}  {extra}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blocks", nargs="+", default=["aerial-100", "aerial-1000", "dubrovnik", "ladybug", "aerial-5000"])
    ap.add_argument("--peers", nargs="+", default=["generic", "dense", "pycolmap", "scipy"])
    ap.add_argument("--generic-max", type=int, default=400_000, help="largest n for the generic path")
    ap.add_argument("--pycolmap-max", type=int, default=50_000, help="largest point count for the pycolmap peer")
    ap.add_argument("--dense-max", type=int, default=4000, help="largest unknown count for the dense reference")
    args = ap.parse_args()
    from baarda.solve import schur
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"pair kernels: {schur.default_backend()}, load average {os.getloadavg()[0]:.2f}, cores {os.cpu_count()}")
    t0 = time.perf_counter()
    b, _ = simulate_block(strips=2, images_per_strip=3, design=True)
    pr = build_block_problem(b)
    a = adjust(pr, Options(solver="schur"))
    a.r
    print(f"warm-up (numba kernels loaded or compiled): {time.perf_counter() - t0:.2f} s")
    head = (f"{'block':<18} {'path':<8} {'images':>6} {'points':>7} {'img.pts':>8} {'build s':>8} {'solve s':>8} "
            f"{'reliab s':>8} {'peak MB':>8}  notes")
    print(head)
    print("-" * len(head))
    for name in args.blocks:
        t0 = time.perf_counter()
        if name in AERIAL:
            s, m = AERIAL[name]
            block, _ = simulate_block(strips=s, images_per_strip=m, design=True, seed=1)
        elif name == "dubrovnik":
            block = dubrovnik_like()
        elif name == "ladybug":
            if not LADYBUG.exists():
                print(f"{name:<18} skipped: {LADYBUG} not found")
                continue
            try:
                from baarda.model.sfm import build_sfm_problem
                from baarda.io.bal import read_bal
            except ImportError as err:
                print(f"{name:<18} skipped: BAL reader not available ({err})")
                continue
            block = read_bal(LADYBUG)
        else:
            raise SystemExit(f"unknown block {name}")
        problem = build_sfm_problem(block) if name == "ladybug" else build_block_problem(block)
        t_build = time.perf_counter() - t0
        if name == "ladybug":
            import dataclasses
            t0 = time.perf_counter()
            adj = adjust(problem, Options(solver="schur", max_iter=100))
            t_solve = time.perf_counter() - t0
            times = []
            for _ in range(5):                       # analysis only, after the solve: median of 5
                a = dataclasses.replace(adj, timings={})
                a.seed(schur_structure=adj.schur_structure)
                t0 = time.perf_counter()
                for q in ("r", "w", "mdb", "external"):
                    getattr(a, q)
                times.append(time.perf_counter() - t0)
            t_rel = float(np.median(times))
            n_img = len(block.images) if hasattr(block, "images") else "-"
            cost = 0.5 * adj.vPv
            print(f"{name:<18} {'schur':<8} {n_img!s:>6} {len(problem.points.ids):>7} {problem.n // 2:>8} "
                  f"{t_build:>8.2f} {t_solve:>8.2f} {t_rel:>8.2f} {peak_mb():>8.0f}  LM from the start values "
                  f"to cost {cost:,.1f} ({adj.iterations} its); r, w, MDB, δ̄0 median of 5; "
                  f"Σr − dof {a.r.sum() - a.dof:.1e}", flush=True)
            if "pycolmap" in args.peers or "scipy" in args.peers:
                for line in ladybug_peers(block, cost, args.peers):
                    print(line, flush=True)
            if "generic-ladybug" in args.peers:     # 440 s and 18.5 GB here: off by default
                g = dataclasses.replace(adj, solver="generic", timings={})
                t0 = time.perf_counter()
                for q in ("r", "w", "mdb", "external", "u_t"):
                    getattr(g, q)
                t_g = time.perf_counter() - t0
                print(f"{'':<18} {'generic':<8} {'':>6} {'':>7} {'':>8} {'':>8} {'':>8} {t_g:>8.2f} {peak_mb():>8.0f}"
                      f"  same x; max|Δr| {np.abs(g.r - adj.r).max():.1e}; ratio {t_g / t_rel:.1f}×", flush=True)
            continue
        adj, t_solve, t_rel = analyse(problem, "schur")
        t_test, t_excl = retests(adj)
        st = adj.schur_structure
        note = (f"S {st.n_cameras} unknowns, band {adj.factor.bandwidth}; retest q=2 {1e3 * t_test:.1f} ms; "
                f"exclude {1e3 * t_excl:.0f} ms; auto: {'schur' if st.worthwhile() else 'generic'}")
        row(name, adj.solver, problem, adj, t_build, t_solve, t_rel, note)
        if "generic" in args.peers and adj.solver == "schur" and problem.n <= args.generic_max:
            g, g_solve, g_rel = analyse(problem, "generic")
            dr = np.abs(g.r - adj.r).max()
            row("", "generic", problem, g, 0.0, g_solve, g_rel,
                f"max|Δr| {dr:.1e}; ratio solve {g_solve / t_solve:.1f}×, reliability {g_rel / t_rel:.1f}×")
            del g
        if "dense" in args.peers and adj.Ar.shape[1] <= args.dense_max:
            t0 = time.perf_counter()
            rd = redundancy(adj.Ar, adj.P)
            t_d = time.perf_counter() - t0
            print(f"{'':<18} {'dense':<8} {'':>6} {'':>7} {'':>8} {'':>8} {'':>8} {t_d:>8.2f} {peak_mb():>8.0f}"
                  f"  max|Δr| {np.abs(rd - adj.r).max():.1e}; ratio {t_d / t_rel:.1f}×", flush=True)
        if "pycolmap" in args.peers and len(block.points) <= args.pycolmap_max:
            n_img = len(block.images)
            res = pycolmap_peer(n_img, len(block.points), block.obs.size / max(len(block.points), 1))
            if res is not None:
                print(f"{'':<18} {'pycolmap':<8} {res['images']:>6} {res['points']:>7} {res['obs']:>8} "
                      f"{res['build']:>8.2f} {res['solve']:>8.2f} {res['cov']:>8.2f} {peak_mb():>8.0f}"
                      f"  BA (poses+points) then estimate_ba_covariance; ok={res['ok']}", flush=True)
        del adj, problem, block


if __name__ == "__main__":
    main()
