"""Solve speed on real BAL problems and a real COLMAP model: baarda's adjustment beside pycolmap's
Ceres, same run.

For each problem: baarda's solve (``adjust``: datum analysis, structure, iterations; read and
build excluded; numba kernels warmed up on a small problem first), then pycolmap's Ceres bundle
adjuster (set-up and solve; one thread; focal length, k1, k2 refined per camera as BAL defines;
the block written as a COLMAP RADIAL model with flipped axes, :func:`bench.bench_blocks.bal_as_colmap`),
the ratio of the two times, both final costs ½Σr² (Ceres' evaluated in BAL's model over the image
points COLMAP kept: it drops those whose point is behind the camera) and the relative difference
(baarda − Ceres)/Ceres, both iteration counts
(Ceres: successful + unsuccessful steps) and the end-to-end ``baarda analyze FILE --json`` time
and peak resident set (a subprocess: read, adjust, reliability, JSON).

Two rows per problem: "colmap", Ceres at COLMAP's tolerances (gradient 1e-4, function and
parameter 0) beside baarda's strict optimum (the default ``stop="optimum"``), and "ceres", Ceres at
its own defaults (function tolerance 1e-6, gradient 1e-10, parameter 1e-8) beside baarda's
``stop="ceres"`` (the same rule).

Usage (from the repository root): ``python -m bench.bench_solve [--problems DIR/FILE ...] [--no-analyze]
[--repeat N]``.
Compressed BAL files are decompressed to a temporary file when the reader does not take them. A
COLMAP model (a folder) is adjusted as it is, intrinsics fixed on both sides, and Ceres's cost
evaluated in COLMAP's camera model.
"""

from __future__ import annotations

import argparse
import bz2
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("GLOG_minloglevel", "2")     # quiet pycolmap/Ceres


from baarda.adjust import Options, adjust  # noqa: E402
from baarda.build import read_problem  # noqa: E402
from baarda.model.sfm import build_sfm_problem, initial_cost  # noqa: E402
from baarda.errors import InputError  # noqa: E402
from baarda.io.bal import read_bal  # noqa: E402
from bench.bench_blocks import bal_as_colmap  # noqa: E402

EXTDATA = Path(__file__).resolve().parents[2] / "shared" / "extdata" / "bal"
PROBLEMS = [EXTDATA / "problem-21-11315-pre.txt.bz2", EXTDATA / "problem-16-22106-pre.txt.bz2",
            EXTDATA / "problem-49-7776-pre.txt", EXTDATA.parent / "colmap" / "test_colmap-sparse0"]


def readable(path: Path, tmp: Path) -> Path:
    """``path``, or a decompressed copy in ``tmp`` when the BAL reader does not take it as is."""
    try:
        read_bal(path, check=False)
        return path
    except InputError:
        if path.suffix != ".bz2":
            raise
    out = tmp / path.stem
    out.write_bytes(bz2.decompress(path.read_bytes()))
    return out


#: Ceres's stopping rules: COLMAP's bundle adjuster's (pycolmap's defaults) and Ceres Solver's own
#: ``Solver::Options`` defaults (what a plain Ceres run of an SfM user stops at)
CERES_RULES = {"colmap": {"function_tolerance": 0.0, "gradient_tolerance": 1e-4, "parameter_tolerance": 0.0},
               "ceres": {"function_tolerance": 1e-6, "gradient_tolerance": 1e-10, "parameter_tolerance": 1e-8}}


def _ceres_solve(rec, refine: bool, threads: int, rule: str = "colmap"):
    """pycolmap's Ceres bundle adjustment of reconstruction ``rec`` in place, every image (focal
    length and extra parameters refined or not; principal point fixed), stopped by ``rule`` (a
    key of :data:`CERES_RULES`): (seconds of set-up and solve, iterations, termination)."""
    import pycolmap

    pycolmap.logging.minloglevel = 2
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = ba.refine_extra_params = refine
    ba.refine_principal_point = False
    ba.print_summary = False
    ba.ceres.solver_options.num_threads = threads
    for key, value in CERES_RULES[rule].items():
        setattr(ba.ceres.solver_options, key, value)
    config = pycolmap.BundleAdjustmentConfig()
    for i in rec.reg_image_ids():
        config.add_image(i)
    t0 = time.perf_counter()
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(ba, config, rec)
    summary = adjuster.solve().todict()["ceres_summary"]
    t = time.perf_counter() - t0
    its = int(summary["num_successful_steps"]) + int(summary["num_unsuccessful_steps"])
    return t, its, str(summary["termination_type"]).split(".")[-1]


def ceres(block, threads: int = 1, rule: str = "colmap"):
    """pycolmap's Ceres bundle adjustment of ``block`` (problem set-up and solve timed, as
    baarda's ``adjust``; f, k1, k2 refined per camera as BAL defines): (seconds, ½Σr² in BAL's
    model over the image points Ceres kept, iterations, how many of them, Ceres' termination)."""
    import pycolmap

    with tempfile.TemporaryDirectory() as tmp:
        bal_as_colmap(block, Path(tmp) / "in")
        rec = pycolmap.Reconstruction(str(Path(tmp) / "in"))
        t, its, term = _ceres_solve(rec, True, threads, rule)
        out = Path(tmp) / "out"
        out.mkdir()
        rec.write_text(str(out))
        problem = read_problem(out, "colmap")
        cost = initial_cost(problem)
    return t, cost, its, problem.n // 2, term


def ceres_colmap(model: Path, threads: int = 1, rule: str = "colmap"):
    """pycolmap's Ceres bundle adjustment of a COLMAP model as it is, intrinsics fixed (as baarda
    adjusts a COLMAP model): (seconds, ½Σr² in COLMAP's camera model, iterations, image points,
    termination)."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    t, its, term = _ceres_solve(rec, False, threads, rule)
    cost, n, undefined = 0.0, 0, 0
    for im in rec.images.values():
        cam, pose = rec.cameras[im.camera_id], im.cam_from_world()
        for p2 in im.points2D:
            if p2.has_point3D():
                x = cam.img_from_cam(pose * rec.points3D[p2.point3D_id].xyz)
                if x is None:             # at or behind the centre after Ceres's solve: no cost
                    undefined += 1
                    continue
                r = x - p2.xy
                cost, n = cost + 0.5 * float(r @ r), n + 1
    if undefined:
        return t, None, its, n, f"{term}, but the projection of {undefined} image point(s) is undefined " \
            "at its solution (a point at or behind a projection centre): no cost"
    return t, cost, its, n, term


#: runs ``baarda analyze`` in this process and prints its peak resident set (VmHWM: the
#: high-water mark of this process's own memory since exec; ru_maxrss of a child would include
#: the parent's resident set at the fork)
_PEAK = """
import sys, runpy
sys.argv = ["baarda"] + sys.argv[1:]
try:
    runpy.run_module("baarda.cli", run_name="__main__")
finally:
    hwm = next(s for s in open("/proc/self/status") if s.startswith("VmHWM"))
    print("PEAK_KB", hwm.split()[1], file=sys.stderr)
"""


def analyze_run(path: Path, out: Path) -> tuple[float, float | None]:
    """``baarda analyze FILE --json OUT`` end to end in a subprocess: (seconds, its peak
    resident set in MB, or None where /proc is not there)."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _PEAK, "analyze", str(path), "--quiet", "--json", str(out)],
                          stderr=subprocess.PIPE, text=True, check=False)
    t = time.perf_counter() - t0
    if proc.returncode:
        sys.stderr.write(proc.stderr)
    peak = [s.split()[1] for s in proc.stderr.splitlines() if s.startswith("PEAK_KB ")]
    return t, float(peak[-1]) / 1024.0 if peak else None


def warm_up():
    """Compile or load the numba kernels on a small block (not timed)."""
    small = EXTDATA / "problem-49-7776-pre.txt"
    if small.exists():
        adjust(build_sfm_problem(read_bal(small)), Options(max_iter=2))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", nargs="+", type=Path, default=PROBLEMS)
    ap.add_argument("--no-analyze", action="store_true", help="skip the end-to-end baarda analyze")
    ap.add_argument("--no-ceres", action="store_true", help="skip pycolmap's Ceres")
    ap.add_argument("--threads", type=int, default=1, help="Ceres threads (default 1, as baarda)")
    args = ap.parse_args()
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"load average {os.getloadavg()[0]:.2f}, cores {os.cpu_count()}", flush=True)
    warm_up()
    head = (f"{'problem':<28} {'rule':<7} {'baarda s':>8} {'its':>4} {'½Σr² baarda':>16} {'Ceres s':>8} {'its':>4} "
            f"{'½Σr² Ceres':>16} {'ratio':>6} {'rel.Δcost':>9} {'analyze s':>9} {'peak MB':>7}  status")
    print(head)
    print("-" * len(head), flush=True)
    with tempfile.TemporaryDirectory() as tmpdir:
        for path in args.problems:
            if not path.exists():
                print(f"{path.name:<28} skipped: not found", flush=True)
                continue
            colmap = path.is_dir()
            if colmap:
                problem = read_problem(path, "colmap")
            else:
                block = read_bal(readable(path, Path(tmpdir)))
                problem = build_sfm_problem(block)
            t_a = rss = None
            if not args.no_analyze:
                with tempfile.TemporaryDirectory() as out:
                    t_a, rss = analyze_run(path, Path(out) / "r.json")
            # COLMAP's tolerances beside baarda's strict optimum; Ceres's defaults beside stop="ceres"
            for rule, stop in (("colmap", "optimum"), ("ceres", "ceres")):
                t0 = time.perf_counter()
                adj = adjust(problem, Options(stop=stop))
                t_b = time.perf_counter() - t0
                cost_b = 0.5 * float(adj.v @ adj.v)
                t_c = cost_c = its_c = None
                note = ""
                if not args.no_ceres:
                    try:
                        t_c, cost_c, its_c, kept, term = (ceres_colmap(path, args.threads, rule) if colmap
                                                          else ceres(block, args.threads, rule))
                        note = f"; Ceres {term}" + (f" over {kept} of {problem.n // 2} image points"
                                                     if kept != problem.n // 2 and cost_c is not None else "")
                    except ImportError:
                        pass
                    except Exception as err:       # a peer's failure is a row, not the end of the table
                        note = f"; Ceres failed: {type(err).__name__}: {str(err)[:120]}"

                def fmt(v, spec):
                    return format(v, spec) if v is not None else "-".rjust(int(spec[1:].split(".")[0].strip(",")))
                if problem.notes.local_defects:
                    note += f"; baarda left out {len(problem.notes.local_defects)} local defect(s)"
                ratio = t_b / t_c if t_c else None
                rel = (cost_b - cost_c) / cost_c if cost_c else None
                print(f"{path.name:<28} {rule:<7} {t_b:>8.2f} {adj.iterations:>4} {cost_b:>16,.6f} {fmt(t_c, '>8.2f')} "
                      f"{fmt(its_c, '>4')} {fmt(cost_c, '>16,.6f')} {fmt(ratio, '>6.2f')} {fmt(rel, '>+9.1e')} "
                      f"{fmt(t_a if rule == 'colmap' else None, '>9.2f')} {fmt(rss if rule == 'colmap' else None, '>7.0f')}"
                      f"  {adj.termination.split(':')[0]} (status {adj.status}){note}", flush=True)
                del adj
            del problem
            block = None


if __name__ == "__main__":
    main()
