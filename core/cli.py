"""The ``baarda`` command.

Exit status: 0 success; 1 the analysis ran but a check asked for failed (none yet);
2 bad input or usage (one line ``baarda: error: FILE:LINE: what is wrong``, no traceback
unless ``--debug``); 3 an internal error; 4 (:data:`NOT_CONVERGED`) the adjustment did not
converge within ``--max-iter`` iterations (or stalled): the results are written, marked as
not converged (JSON ``summary.converged`` false and ``summary.termination``, a column
``adjustment`` in every CSV, a banner in the report), and one line ``baarda: FILE: NOT
converged: ...`` goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from . import __version__, truth
from .adjust import Options
from .build import read_problem
from .datum import split_normal
from .errors import BaardaError, DatumDefectError, HypothesisError, InputError, NotFoundError, SingularError
from .io import read_model, read_truth, results
from .io.control import add_control
from .io.gama import UndefinedPointsWarning
from .io.geojson import write_geojson
from .io.hypothesis import read_hypothesis
from .io.native import write_native
from .model.sfm import SfmBlock, to_block
from .network_defects import adjust_network
from .sfm_defects import adjust_block
from .simulate import simulate_to_files
from .stats import (analyses, hypotheses, misidentification, precision, risk, robust, separability, snooping,
                    variance)
from .stats.ap_tests import ap_test
from .text import number, printable, printable_lines, shorten

#: exit status of a run whose adjustment did not converge (module docstring)
NOT_CONVERGED = 4


def _add_test_options(p):
    p.add_argument("--alpha", type=float, default=0.001,
                   help="size α0 of the one-dimensional tests (data snooping), default 0.001")
    p.add_argument("--beta", type=float, default=0.80,
                   help="power β0 at which minimal detectable biases are computed, default 0.80")
    p.add_argument("--b-method", action="store_true",
                   help="Baarda's B-method: multi-dimensional tests get the δ0 and β0 of the 1D test")
    p.add_argument("--global-test", choices=["one-sided", "two-sided"], default="one-sided",
                   help="the global test of vᵀPv = Ω/σ0²: one-sided at the B-method's α_r, the λ0 and β0 of "
                        "the 1D test (F80 §4.1, §7.2; default), or gama-local's two-sided interval at the "
                        "file's conf-pr (default 0.95)")
    p.add_argument("--statistic", choices=["w", "tau"], default=None,
                   help="the statistic that flags observations and that --snoop removes by: Baarda's w "
                        "(σ0 a priori) or Pope's τ (σ0 a posteriori); default: τ where the file asks for "
                        "σ0 a posteriori (GNU Gama's sigma-act), w otherwise")


def _options(args, problem) -> Options:
    """The adjustment's options and test policy from the command line; the statistic of the
    decisions defaults to the σ0 the file asks for (``problem.sigma_act``)."""
    if args.statistic is None:
        sigma0 = "aposteriori" if getattr(problem, "sigma_act", "apriori") == "aposteriori" else "apriori"
    else:
        sigma0 = "aposteriori" if args.statistic == "tau" else "apriori"
    return Options(alpha0=args.alpha, beta0=args.beta, b_method=args.b_method, max_iter=args.max_iter,
                   sigma0=sigma0, global_test=args.global_test)


def _add_iteration_option(p):
    p.add_argument("--max-iter", type=_positive_int, default=200, metavar="N",
                   help="at most N iterations of the adjustment (default 200); a run that does not "
                        "converge writes its results marked as such and exits with status 4")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


def _add_input_options(p):
    p.add_argument("--format", default="auto",
                   help="input format: auto (default), gama, native, bal, bundler, colmap")
    p.add_argument("--sigma-px", type=float, default=None, metavar="S",
                   help="σ of image coordinates in pixels for BAL, Bundler and COLMAP input (default 1)")
    p.add_argument("--refine-intrinsics", action=argparse.BooleanOptionalAction, default=None,
                   help="estimate the cameras' focal lengths and distortion (default: yes for BAL and "
                        "Bundler, as they define; no for COLMAP)")
    p.add_argument("--control", metavar="CSV",
                   help="control points id,X,Y,Z,sx,sy,sz to add as weighted observations (bundle blocks)")
    _add_drop_option(p)


def _add_drop_option(p):
    p.add_argument("--drop-undefined", action="store_true",
                   help="Gama input: drop observations to points no <point> defines, as gama-local does, "
                        "with a warning listing them (default: an error naming file and line)")


def _warn_dropped(path, model_or_problem, quiet=False):
    """One warning line on stderr listing the observations dropped by --drop-undefined."""
    extra = getattr(model_or_problem, "extra", {}) or {}
    dropped = extra.get("dropped_observations", extra.get("dropped", []))
    if dropped and not quiet:
        ids = sorted({pid for d in dropped for pid in d.get("undefined", ())})
        lines = ", ".join(str(d["line"]) for d in dropped[:20]) + (" ..." if len(dropped) > 20 else "")
        print(printable(f"baarda: warning: {path}: {len(dropped)} observation(s) to undefined point(s) "
                        f"{', '.join(map(str, ids))} dropped (--drop-undefined; line(s) {lines})"), file=sys.stderr)


def _adjust_with_defects(problem, options, progress=None, strict=False):
    """Adjust; local defects found by the adjustment are set aside (networks: geodetic, blocks:
    sfm_defects) unless ``strict``. Returns ``(adjustment, problem adjusted)``."""
    if "network_model" in problem.extra:
        return adjust_network(problem, options, progress=progress, strict=strict)
    return adjust_block(problem, options, progress=progress, strict=strict)


def _read_quietly(fn, *a, **kw):
    """Call a reader with its UndefinedPointsWarning silenced (the CLI prints its own line)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UndefinedPointsWarning)
        return fn(*a, **kw)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="baarda",
        description="Reliability of geodetic networks and photogrammetric blocks: global test, "
                    "data snooping, redundancy numbers, MDB, external reliability.",
        epilog="Exit status: 0 ok, 2 bad input or usage, 3 internal error, 4 the adjustment did not "
               "converge (results written and marked as not converged).")
    ap.add_argument("--version", action="version", version=f"baarda {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    an = sub.add_parser("analyze", help="adjust a network or block and test it",
                        description="Adjust INPUT, run the global test and data snooping, and "
                                    "compute redundancy numbers, MDBs and external reliability.")
    an.add_argument("input", help="the network or block: GNU Gama .gkf, native .json, BAL problem .txt, "
                                  "Bundler .out, COLMAP model directory (docs/formats.md)")
    _add_input_options(an)
    _add_test_options(an)
    _add_iteration_option(an)
    an.add_argument("--json", metavar="OUT", help="write the full results as JSON (docs/json-schema.md)")
    an.add_argument("--csv", metavar="DIR", help="write observations.csv, points.csv, groups.csv into DIR")
    an.add_argument("--geojson", metavar="OUT", help="write the points with r_min, MDB, δ̄0 as GeoJSON (for GIS)")
    an.add_argument("--truth", metavar="FILE",
                    help="truth file of a simulated block: report which planted errors the tests find "
                         "(default: NAME.truth.json beside INPUT, if present)")
    an.add_argument("--snoop", action="store_true",
                    help="iterative data snooping: remove the worst rejected observation, readjust, repeat; "
                         "prints the log of decisions")
    an.add_argument("--exchange", action="append", metavar="IMAGE:A:B",
                    help="test whether points A and B were exchanged in IMAGE (F80 §7.1; linear within 50σ, "
                         "iterated by a refit beyond; says when the exchange is not testable); repeatable")
    an.add_argument("--misidentified", action="append", metavar="IMAGE:A:B",
                    help="test whether point A was measured at B's place in IMAGE (F80 §7.1, as --exchange); "
                         "repeatable")
    an.add_argument("--risk", metavar="P,L1,L2",
                    help="risk minimisation (M84 §3.3): a critical value C_i and risk r_C per observation from "
                         "the error rate P and the costs L1 (rejecting a good one), L2 (missing a bad one), "
                         "with a tolerance --risk-lambda-bar or --risk-coordinate")
    an.add_argument("--risk-lambda-bar", type=float, metavar="TOL",
                    help="tolerance λ̄tol of Baarda's datum-invariant λ̄ (general purpose, M84 §3.2-3.3)")
    an.add_argument("--risk-coordinate", type=float, metavar="METRES",
                    help="tolerance for every point coordinate in the datum, metres (special purpose, M84 §3.3)")
    an.add_argument("--robust", choices=["huber", "danish", "r84"],
                    help="robust estimation (IRLS) with this weight function; its suspects are listed with "
                         "their R84 class beside data snooping")
    an.add_argument("--sbase", metavar="ID,ID,...",
                    help="give point standard deviations and ellipses in this S-base (Baarda's S-transformation); "
                         "redundancy numbers and tests do not change. In 3D two points suffice: the normal of the "
                         "plane through them and a third point is held too (M84 §2.2; name it with normal=ID, "
                         "else the point farthest from their line)")
    an.add_argument("--criterion", choices=["linear", "logarithmic", "exponential"],
                    help="compare the coordinate covariance with a fitted chaotic criterion matrix (M84 §2): "
                         "prints λmax/λmin and C1, C2 (in the --sbase, default the first two points); planimetric "
                         "networks, heights (with point positions) and 3D blocks and networks")
    an.add_argument("--criterion-c0", type=float, default=0.0, metavar="C0",
                    help="the constant part of the criterion, chosen first from the precision of the "
                         "measurements (M84 §2.3): m² (linear, logarithmic) or m (exponential); default 0")
    an.add_argument("--variance-components", nargs="?", const="families",
                    choices=["families", "radial", "radial-isotropic"],
                    help="estimate variance components (F80 eq. 9, iterated): a factor per observation "
                         "family (default), or the radial model σ_r² = a² + b²c²/cos⁴α of image "
                         "observations (F80 §2.1, blocks; b acts on the radial component, "
                         "radial-isotropic: on x and y alike)")
    an.add_argument("--strict", action="store_true",
                    help="local defects (points, images, cameras or coordinates the observations do not "
                         "determine) are an error instead of being named and left out")
    an.add_argument("--top", type=int, default=8, help="how many entries each summary list shows")
    an.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    an.add_argument("--debug", action="store_true", help="show tracebacks of errors")

    ts = sub.add_parser("test", help="test hypotheses of your own (F80 eq. 10-18)",
                        description="Adjust INPUT and test each --hypothesis: T, R, the decision, ∇ŝ ± σ∇ŝ, "
                                    "the lower-bound ellipse, δ0′max, δ̄0(s) at its maximum and the "
                                    "deformation field of that undetectable error (F80 eq. 10-18).")
    ts.add_argument("input", help="the network or block file (see analyze)")
    ts.add_argument("--hypothesis", "-H", action="append", required=True, metavar="SPEC",
                    help="repeatable: " + "; ".join(HYPOTHESIS_SPECS) + " (ids as in the file; "
                         "FILE: docs/formats.md, 'Hypothesis files')")
    _add_input_options(ts)
    _add_test_options(ts)
    _add_iteration_option(ts)
    ts.add_argument("--json", metavar="OUT", help="write the tests as JSON (docs/json-schema.md, 'baarda test')")
    ts.add_argument("--top", type=int, default=10, help="how many points of each deformation field to print")
    ts.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    ts.add_argument("--debug", action="store_true", help="show tracebacks of errors")

    sim = sub.add_parser("simulate", help="simulate an aerial block with planted errors",
                         description="Simulate an aerial bundle block (s strips × m images) and write "
                                     "it in baarda's native format, with a truth file of what was planted.")
    sim.add_argument("out", help="the block file to write (.json)")
    sim.add_argument("--truth", metavar="FILE", help="truth file (default: OUT with .truth.json)")
    sim.add_argument("--strips", type=int, default=3, help="number of strips (default 3)")
    sim.add_argument("--images", type=int, default=8, help="images per strip (default 8)")
    sim.add_argument("--camera", default="aerial", help="aerial (153 mm, 230 mm format) or drone")
    sim.add_argument("--flying-height", type=float, default=1500.0, help="metres above ground (default 1500)")
    sim.add_argument("--forward-overlap", type=float, default=0.6, help="default 0.6")
    sim.add_argument("--side-overlap", type=float, default=0.25, help="default 0.25")
    sim.add_argument("--pattern", type=int, nargs=2, default=[3, 3], metavar=("NX", "NY"),
                     help="tie points per image (default 3 3, von Gruber)")
    sim.add_argument("--control", default="perimeter",
                     help="control configuration: corners, perimeter, dense, minimal, none (free block)")
    sim.add_argument("--control-spacing", type=int, default=2, help="perimeter control every k base lengths")
    sim.add_argument("--check", type=int, default=0, help="number of check points")
    sim.add_argument("--sigma-image", type=float, default=None, help="σ of image coordinates, mm (default 0.005)")
    sim.add_argument("--radial", type=float, default=0.0, help="planted radial distortion at the image corner, mm")
    sim.add_argument("--error", action="append", default=[], metavar="KIND:SIZE[:K=V...]",
                     help="plant an error, e.g. image:20, transfer:10:images=3, control:20:axis=z, "
                          "image-point:6, misidentification:1, exchange:1 (size in σ; repeatable)")
    sim.add_argument("--design", action="store_true", help="design mode: exact observations (no noise)")
    sim.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    sim.add_argument("--title", default="", help="a title stored in the block")
    sim.add_argument("--recipe", metavar="FILE",
                     help="take the whole recipe from a JSON file (a recipe object, or a truth file, whose "
                          "recipe is reused: reproduces that block exactly); other options are ignored")
    sim.add_argument("--quiet", "-q", action="store_true")
    sim.add_argument("--debug", action="store_true")

    rp = sub.add_parser("report", help="write the client report: standalone HTML, three A4 pages when printed",
                        description="Analyse INPUT and write the client report (standalone HTML, opens without a "
                                    "server or network; three A4 pages when printed to PDF): the verdict in plain "
                                    "language with the key numbers and the map of the tests; the reliability maps; "
                                    "the suspects and the rejected group tests. The full tables: analyze --csv.")
    rp.add_argument("input", help="the network or block file")
    rp.add_argument("--out", "-o", metavar="HTML", help="the report to write (default: INPUT with .html)")
    rp.add_argument("--format", default="auto", help="input format (see analyze)")
    _add_drop_option(rp)
    _add_test_options(rp)
    _add_iteration_option(rp)
    rp.add_argument("--quiet", "-q", action="store_true")
    rp.add_argument("--debug", action="store_true")

    rk = sub.add_parser("risk", help="risk-minimising critical value of a test (M84 §3.3)",
                        description="Critical value C minimising (1−p) α L1 + p (1−β) L2 for a one-sided "
                                    "normal test against an error of tolerance λtol.")
    rk.add_argument("--p", type=float, required=True, help="probability that an observation is erroneous")
    rk.add_argument("--L1", type=float, default=1.0, help="cost of rejecting a good observation")
    rk.add_argument("--L2", type=float, default=10.0, help="cost of missing a bad one")
    rk.add_argument("--lambda-tol", type=float, default=17.07, help="tolerance λtol (non-centrality)")
    rk.add_argument("--debug", action="store_true")

    cv = sub.add_parser("convert", help="convert any readable network or block to the native JSON format",
                        description="Read INPUT (any format baarda reads) and write it as a native "
                                    "baarda-block JSON file (docs/native-format.md). Structure-from-motion "
                                    "cameras are written with their intrinsics as fixed calibrations.")
    cv.add_argument("input", help="the network or block to read")
    cv.add_argument("out", help="the native JSON file to write")
    _add_input_options(cv)
    cv.add_argument("--quiet", "-q", action="store_true")
    cv.add_argument("--debug", action="store_true")

    sv = sub.add_parser("serve", help="serve the dashboard in the browser",
                        description="Serve the Panel dashboard for FILE (default: the demo block).")
    sv.add_argument("input", nargs="?", help="the network or block file (default: data/demo-block.json)")
    sv.add_argument("--port", type=int, default=5006, help="port (default 5006)")
    sv.add_argument("--address", default="127.0.0.1",
                    help="address to listen on (default 127.0.0.1; another address, such as 0.0.0.0, serves the "
                         "network and needs --token or --allow-remote)")
    sv.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                    help="also answer requests for the host NAME (a proxy's or the machine's DNS name); "
                         "others than localhost and loopback addresses are refused (DNS rebinding)")
    sv.add_argument("--token", metavar="TOKEN",
                    help="require signing in with TOKEN as the password (any user name)")
    sv.add_argument("--allow-remote", action="store_true",
                    help="serve a non-loopback --address without authentication")
    sv.add_argument("--show", action="store_true", help="open a browser (only where there is a display)")
    sv.add_argument("--webgl", action="store_true",
                    help="draw the maps with WebGL: smoother on a GPU for blocks of 10^5 and more image points, "
                         "very slow where the browser has no GPU (default: the 2D canvas)")
    sv.add_argument("--debug", action="store_true")
    return ap


def _progress(quiet):
    if quiet or not sys.stderr.isatty():
        return None

    def show(it, ratio):
        print(f"\r  iteration {it}: max |Δx|/σ = {ratio:.3g}   ", end="", file=sys.stderr, flush=True)
    return show


def cmd_analyze(args) -> int:
    """``baarda analyze``; an error of the analysis that is the file's fault (a singular normal
    matrix found while computing reliability, ...) is reported against the file."""
    try:
        return _analyze(args)
    except InputError:
        raise
    except BaardaError as err:
        if str(err).startswith("--"):          # a bad option value (--sbase, --criterion)
            raise
        raise InputError(args.input, 0, str(err)) from None


def _finite(x):
    """A float for JSON: None for ∞ / NaN."""
    x = float(x)
    return x if np.isfinite(x) else None


def _risk(adj, args):
    """The risk-minimising tests of --risk with its tolerance (baarda.stats.risk.per_observation)."""
    if not args.risk:
        raise BaardaError("--risk-lambda-bar / --risk-coordinate need --risk P,L1,L2")
    try:
        p, L1, L2 = (float(x) for x in args.risk.split(","))
    except ValueError:
        raise BaardaError(f"--risk: expected P,L1,L2 (three numbers), got {args.risk!r}") from None
    if (args.risk_lambda_bar is None) == (args.risk_coordinate is None):
        raise BaardaError("--risk: give one tolerance, --risk-lambda-bar TOL or --risk-coordinate METRES")
    try:
        return risk.per_observation(adj, p, L1, L2, lambda_bar_tol=args.risk_lambda_bar,
                                    coordinate_tol=args.risk_coordinate)
    except BaardaError as err:
        raise BaardaError(f"--risk: {err}") from None


def _exchange_test(adj, spec: str, both: bool):
    """The test of one --exchange / --misidentified IMAGE:A:B (baarda.stats.misidentification)."""
    option = "--exchange" if both else "--misidentified"
    parts = [x.strip() for x in spec.split(":")]
    if len(parts) != 3 or not all(parts):
        raise BaardaError(f"{option}: expected IMAGE:A:B, got {spec!r}")
    try:
        return misidentification.exchange_test(adj, *parts, both=both)
    except BaardaError as err:
        raise BaardaError(f"{option} {spec}: {err}") from None


def _analyze(args) -> int:
    t0 = time.perf_counter()
    problem = _read_quietly(read_problem, args.input, args.format, control=args.control,
                            sigma_px=args.sigma_px, refine_intrinsics=args.refine_intrinsics,
                            strict=args.strict, drop_undefined=args.drop_undefined)
    _warn_dropped(args.input, problem, args.quiet)
    t_read = time.perf_counter() - t0
    options = _options(args, problem)
    try:
        # blocks: unknowns found undetermined by a few points/images are left out (sfm_defects)
        adj, problem = _adjust_with_defects(problem, options, progress=_progress(args.quiet),
                                            strict=args.strict)
    except DatumDefectError as err:
        raise InputError(args.input, 0, _defect_message(err, problem)) from None
    if not args.quiet and sys.stderr.isatty():
        print("", file=sys.stderr)
    t1 = time.perf_counter()
    try:
        doc = results.to_dict(adj)
    except SingularError as err:
        if adj.converged:
            raise
        return _diverged(args, problem, options, adj, err)
    adj.timings["read"] = t_read
    adj.timings["reliability"] = time.perf_counter() - t1
    doc["summary"]["timings"] = {k: round(v, 6) for k, v in adj.timings.items()}
    if args.json:
        results.write_json(adj, args.json, doc)
    written = set(doc)             # (written again below only when the steps below add to it)
    if args.csv:
        results.write_csv(adj, args.csv, doc)
    if args.geojson:
        write_geojson(adj, args.geojson)
    truth_path = args.truth
    if truth_path is None:
        guess = Path(args.input).with_suffix(".truth.json")
        truth_path = guess if guess.exists() else None
    findings = None
    if truth_path is not None:
        findings = truth.compare(adj, read_truth(truth_path))
        doc["planted"] = findings
    snoop = None
    if args.snoop:
        snoop = snooping.iterate(problem, options, use_tau=options.sigma0 == "aposteriori")
        doc["snooping"] = [s.__dict__ for s in snoop.steps]
    obs_risk = _risk(adj, args) if args.risk or args.risk_lambda_bar or args.risk_coordinate else None
    if obs_risk is not None:
        doc["risk"] = {"p": obs_risk.p, "L1": obs_risk.L1, "L2": obs_risk.L2, "tolerance": obs_risk.tolerance,
                       "rejected": int(obs_risk.rejected.sum())}
        def risk_of(i, r=obs_risk):
            d = {k: _finite(getattr(r, k)[i]) for k in ("lam_tol", "C", "alpha", "beta", "r_C")}
            return {"risk": {**d, "rejected": bool(r.rejected[i])}}
        doc["observations"].add(risk_of)
    exchanges = [_exchange_test(adj, spec, both) for both, specs in ((True, args.exchange), (False, args.misidentified))
                 for spec in specs or ()]
    if exchanges:
        doc["exchange_tests"] = [e.as_dict() for e in exchanges]

    prec_lines = []
    if args.sbase or args.criterion:
        ids = problem.points.ids
        base = [b.strip() for b in args.sbase.split(",")] if args.sbase else list(ids[:2])
        named, normal = split_normal(base)
        unknown = [b for b in named + ([normal] if normal is not None else []) if b not in ids]
        if unknown:
            raise BaardaError(f"--sbase: unknown point id(s) {', '.join(unknown)}")
        cc = precision.covariance(adj, sbase=base)
        base = named + [b for b in cc.sbase if b.startswith("normal=")]     # a 3D base: the normal's point
        ell = cc.ellipses()
        sd = np.sqrt(np.maximum(np.diag(cc.cov), 0.0))
        def transformed(i, cc=cc, sd=sd, ell=ell):      # (point i's record is point i of ids)
            d = {"s" + "xyz"[cc.axis[c]]: float(sd[c]) for c in np.flatnonzero(cc.point == i)}
            if i < len(ell) and np.isfinite(ell[i, 0]):
                d["ellipse"] = {"a": float(ell[i, 0]), "b": float(ell[i, 1]), "bearing": float(ell[i, 2])}
            return d
        doc["points"].add(transformed)
        doc["summary"]["sbase"] = base
        prec_lines.append(f"  S-base {', '.join(base)}: point standard deviations and ellipses transformed")
        if args.criterion:
            reason = analyses.criterion_reason(adj)
            if reason:
                raise BaardaError(f"--criterion: {reason}")
            try:
                fit = analyses.criterion_fit(analyses.criterion_setup(adj, base, cov=cc), kind=args.criterion,
                                             C0=args.criterion_c0)
            except BaardaError as err:
                raise BaardaError(f"--criterion: {err}") from None
            doc["criterion"] = fit
            u = analyses.criterion_units(fit["kind"])
            c2 = f", C2 = {fit['C2']:.4g} {u['C2']}" if fit["kind"] != "linear" else ""
            bound = (" (C2 at the end of its range: d² hardly varies with distance over this network)"
                     if fit["C2_at_bound"] else "")
            prec_lines.append(f"  criterion matrix ({fit['kind']}, M84 §2.3): fitted C1 = {fit['C1']:.4g} {u['C1']}"
                              f"{c2}, λmax/λmin = {fit['ratio']:.3g}{bound}")
    rob = None
    if args.robust:
        rob = robust.estimate(problem, args.robust, options)
        doc["robust"] = rob.as_dict()
    vc = None
    if args.variance_components:
        try:
            if args.variance_components.startswith("radial"):
                structure = "isotropic" if args.variance_components == "radial-isotropic" else "radial"
                est = analyses.radial_variance(problem, options, structure)
                doc["variance_components"] = est.as_dict()
                doc["variance_estimate"] = {"kind": args.variance_components, "converged": bool(est.converged),
                                            "iterations": int(est.iterations), "std_error": "rigorous",
                                            "notes": list(est.notes)}
                prec_lines.append(f"  radial variance model, {structure} (F80 §2.1, {est.iterations} iterations"
                                  f"{'' if est.converged else ', NOT converged'}):")
                for d in est.as_dict():
                    se = "held at 0" if d["std_error"] is None else f"± {number(d['std_error'], '.2g')}"
                    prec_lines.append(f"    {d['component']:<8s} θ = {number(d['theta'])} {se}   "
                                      f"redundancy {d['redundancy']:.2f}")
                prec_lines += [f"    {note}" for note in est.notes]
                vc = None
            else:
                vc = variance.estimate(problem, options=options)
                doc["variance_components"] = vc.as_dict()
                doc["variance_estimate"] = vc.summary()
        except BaardaError as err:
            doc["variance_components"] = {"error": str(err)}
            prec_lines.append(f"  {err}")
    if args.json and (set(doc) != written or args.sbase or args.criterion):
        results.write_json(adj, args.json, doc)
    if not args.quiet:
        print(results.text_summary(adj, top=args.top))
        if snoop is not None:
            info = problem.info
            stat = "τ" if snoop.use_tau else "w"
            print(f"  iterative data snooping on {stat}: {len(snoop.steps)} observation(s) removed, σ̂0 "
                  f"{number(adj.sigma0_post)} → {number(snoop.adjustment.sigma0_post)}")
            for k, st in enumerate(snoop.steps, 1):
                ids = printable(" ".join(f"{a}={b}" for a, b in info.ids[st.removed].items()))
                print(f"    {k:>2d}. #{st.removed:<5d} {info.kind[st.removed]:<15s} {ids:<40s} "
                      f"|{stat}| = {number(st.statistic, '7.2f')} > {number(st.critical, '.2f')}  ∇̂ = {number(st.nabla, '+.4g')}")
                if st.twins:
                    print("        the data cannot tell it from (w-tests correlated |ρ| ≥ 0.99, F80 §7.4): " + "; ".join(
                        f"#{j} " + printable(" ".join(f"{a}={b}" for a, b in info.ids[j].items()))
                        + f" (ρ = {number(rho, '+.4f')})" for j, rho in zip(st.twins, st.twin_rho)))
        if obs_risk is not None:
            fin = np.isfinite(obs_risk.C)
            print(printable(f"  risk minimisation (M84 §3.3; p = {obs_risk.p:g}, L1 = {obs_risk.L1:g}, L2 = "
                            f"{obs_risk.L2:g}, tolerance {obs_risk.tolerance}): C_i from "
                            f"{number(obs_risk.C[fin].min() if fin.any() else np.nan, '.3g')} to "
                            f"{number(obs_risk.C[fin].max() if fin.any() else np.nan, '.3g')}; "
                            f"{int(obs_risk.rejected.sum())} rejected (|w| > C_i), {int(adj.rejected.sum())} at α0"))
            info = problem.info
            for i in np.argsort(-np.nan_to_num(obs_risk.r_C), kind="stable")[:args.top]:
                ids = printable(" ".join(f"{a}={b}" for a, b in info.ids[i].items()))
                print(f"    #{i:<5d} {info.kind[i]:<15s} {ids:<40s} λtol = {number(obs_risk.lam_tol[i], '9.3g')}  "
                      f"C = {number(obs_risk.C[i], '6.3g')}  r_C = {number(obs_risk.r_C[i], '.3g')}"
                      f"{'  REJECTED' if obs_risk.rejected[i] else ''}")
        for e in exchanges:
            what = "exchange" if e.both else "misidentification"
            verdict = (f"T = {number(e.T, '.4g')} (crit {number(e.critical, '.2f')}) "
                       f"{'REJECTED' if e.rejected else 'accepted'}, ŝ = {number(e.s_hat, '.3g')}") if e.testable else "not testable"
            print(printable(f"  {what} of {e.point_a}/{e.point_b} in image {e.image} (F80 §7.1): {verdict}"))
            print(printable(f"    {e.message}"))
        for line in prec_lines:
            print(printable(line))
        if rob is not None:
            _print_robust(rob)
        if vc is not None:
            print(f"  variance components (F80 eq. 9, {vc.iterations} iterations"
                  f"{'' if vc.converged else ', NOT converged'}):")
            for d in vc.as_dict():
                print(f"    {d['group']:<20s} σ̂²/σ² = {number(d['factor'], '8.4f')} ± {number(d['std_error'], '.4f')}   "
                      f"redundancy {d['redundancy']:.2f}")
            va = vc.adjustment
            print(f"    with these components: {int(va.rejected.sum())} observation(s) rejected "
                  f"(before: {int(adj.rejected.sum())}), global test "
                  f"{'passed' if va.global_test['passed'] else 'FAILED'}")
        if findings is not None:
            print(printable_lines(truth.text(findings)))
    return _convergence_status(args.input, adj)


def _print_robust(rob) -> None:
    """The robust estimation's lines of the text summary (R84 §6-8)."""
    print(f"  robust estimation ({rob.method}, {rob.iterations} iterations"
          f"{'' if rob.converged else ', NOT converged'}): {len(rob.suspects)} suspect(s) confirmed by "
          f"least squares (R84 §7; {rob.candidates} candidate(s), {len(rob.readmitted)} readmitted)")
    for sp in rob.suspects:
        ids = printable(" ".join(f"{a}={b}" for a, b in sp["ids"].items()))
        base = "" if sp["size_base"] is None else f" = {number(sp['size_base'], '.3g')} base lengths"
        print(f"    #{sp['index']:<5d} {sp['kind']:<15s} {ids:<40s} error ≈ {number(sp['size_sigma'], '6.1f')}σ"
              f"{base} ({sp['class']}), T = {number(sp['T'], '.1f')}, robust weight {sp['weight']:.3g}")
    for fl in rob.floored:
        print(f"    weight floor raised to {fl['floor']:.0e} for {', '.join(fl['unknowns']) or 'all'} "
              f"(down-weighted, they would leave unknowns undetermined)")
    if rob.final is not None:
        print(f"    least squares without them: {int(rob.final.rejected.sum())} rejected by data snooping, "
              f"σ̂0 = {number(rob.final.sigma0_post)}")


def _diverged(args, problem, options, adj, err) -> int:
    """An adjustment that did not converge and whose normal equations are singular at its last
    iterate: no reliability can be computed there. Say so in one line (exit status
    :data:`NOT_CONVERGED`), and run the robust estimation if asked — it is what finds the gross
    error that makes least squares diverge (R84 §6: a large error)."""
    why = (adj.termination or "not converged").removeprefix("not converged: ")
    hint = ("" if args.robust else
            f"; a gross error is the likely cause: try `baarda analyze {args.input} --robust r84`")
    print(printable(f"baarda: {args.input}: NOT converged after {adj.iterations} iterations ({why}) and the normal "
                    f"equations at the last iterate are singular ({err}): no reliability computed, no JSON/CSV "
                    f"written{hint}"), file=sys.stderr)
    if args.robust:
        rob = robust.estimate(problem, args.robust, options)
        if not args.quiet:
            _print_robust(rob)
    return NOT_CONVERGED


def _convergence_status(path, adj) -> int:
    """0, or :data:`NOT_CONVERGED` with one line on stderr when the adjustment did not converge."""
    if adj.converged:
        return 0
    why = getattr(adj, "termination", "") or "not converged"
    print(f"baarda: {printable(str(path))}: NOT converged after {adj.iterations} iterations: "
          f"{why.removeprefix('not converged: ')}", file=sys.stderr)
    return NOT_CONVERGED


def _defect_message(err, problem) -> str:
    """The datum-defect message with the counts and the undetermined unknowns by entity."""
    n, u = problem.n, problem.params.free.size
    groups: dict[str, list[str]] = {}
    for label in err.undetermined:
        entity, _, name = label.rpartition(".")
        if entity:
            groups.setdefault(entity, []).append(name)
    entities = list(groups)
    kinds: dict[str, list[str]] = {}
    for e in entities:
        kind, _, ident = e.rpartition(" ")
        kinds.setdefault(kind or "unknown", []).append(ident or e)
    summary = "; ".join(f"{k}s {', '.join(v[:12])}{' ...' if len(v) > 12 else ''}" if k != "unknown"
                        else ", ".join(v[:12]) for k, v in kinds.items())
    gauge = " (7 of them fixed by the free-block datum)" if problem.convention else ""
    lines = f"{n} observations for {u} unknowns{gauge}"
    return f"{lines}; {err.message}" + (f" [by entity: {summary}]" if summary and len(entities) > 1 else "")


#: The --hypothesis specifications of ``baarda test`` (fields separated by ':').
HYPOTHESIS_SPECS = ("observation:INDEX", "group:G", "image-point:IMAGE:POINT[:KEYPOINT]", "control:POINT",
                    "transfer:POINT:IMAGE,IMAGE,...", "ap-group:CAMERA:brown|ebner", "exchanged:IMAGE:A:B",
                    "model-point:MODEL:POINT", "file:PATH")


def parse_hypothesis(text: str) -> dict:
    """A --hypothesis SPEC as the specification dict of
    :func:`baarda.stats.hypotheses.hypothesis_matrix` (``file:PATH`` gives {"kind": "file", "path"});
    BaardaError naming the argument for a malformed one."""
    kind, _, rest = text.partition(":")
    forms = {spec.split(":", 1)[0]: spec for spec in HYPOTHESIS_SPECS}
    if kind not in forms:
        raise BaardaError(f"--hypothesis {text!r}: unknown kind {kind!r} (one of {', '.join(forms)})")
    if kind == "file":
        if not rest:
            raise BaardaError(f"--hypothesis {text!r}: expected file:PATH")
        return {"kind": "file", "path": rest}
    names = {"observation": ["index"], "group": ["group"], "image-point": ["image", "point"],
             "control": ["point"], "transfer": ["point", "images"], "ap-group": ["camera", "group"],
             "exchanged": ["image", "a", "b"], "model-point": ["model", "point"]}[kind]
    parts = rest.split(":") if rest else []
    if kind == "image-point" and len(parts) == 3:          # a COLMAP image's keypoint on the point
        names = names + ["keypoint"]
    if len(parts) != len(names) or not all(parts):
        raise BaardaError(f"--hypothesis {text!r}: expected {forms[kind]}")
    spec = {"kind": kind, **dict(zip(names, parts))}
    if kind in ("observation", "group"):
        key = names[0]
        try:
            spec[key] = int(spec[key])
        except ValueError:
            raise BaardaError(f"--hypothesis {text!r}: {key.upper()} must be an integer, not {spec[key]!r}") from None
    if kind == "transfer":
        spec["images"] = [im for im in spec["images"].split(",") if im]
    return spec


def cmd_test(args) -> int:
    """``baarda test``: each hypothesis in full (:func:`baarda.stats.analyses.hypothesis_analysis`)."""
    specs = [(text, parse_hypothesis(text)) for text in args.hypothesis]     # usage errors first
    problem = _read_quietly(read_problem, args.input, args.format, control=args.control,
                            sigma_px=args.sigma_px, refine_intrinsics=args.refine_intrinsics,
                            drop_undefined=args.drop_undefined)
    _warn_dropped(args.input, problem, args.quiet)
    options = _options(args, problem)
    try:
        adj, problem = _adjust_with_defects(problem, options)
    except DatumDefectError as err:
        raise InputError(args.input, 0, _defect_message(err, problem)) from None
    rel = adj.reliability
    tests, matrices = [], []
    for text, spec in specs:
        try:
            if spec["kind"] == "file":
                H = read_hypothesis(spec["path"], adj.n)
            elif spec["kind"] == "ap-group" and f"{spec['camera']}:{spec['group']}" in problem.extra.get("ap_groups", {}):
                t = ap_test(adj, str(spec["camera"]), str(spec["group"]), policy=rel.policy)
                tests.append({"hypothesis": text, "spec": spec, "ap_test": t.as_dict()})
                continue
            else:
                H = hypotheses.hypothesis_matrix(adj, spec)
        except InputError:
            raise
        except (NotFoundError, HypothesisError) as err:
            raise BaardaError(f"--hypothesis {text!r}: {err}") from None
        matrices.append((text, H))
        tests.append({"hypothesis": text, "spec": spec,
                      **analyses.hypothesis_analysis(adj, H, label=text, reliability=rel)})
        if spec["kind"] == "exchanged":      # the linear range, q = 0 and the iterated test (F80 §7.1)
            tests[-1]["exchange_test"] = misidentification.exchange_test(
                adj, str(spec["image"]), str(spec["a"]), str(spec["b"]), policy=rel.policy).as_dict()
    # hypotheses the data cannot tell apart (F80 §7.4, M84 §3.3): their statistics correlate |ρ| ≥ 0.99
    apart = separability.inseparable_pairs(adj, matrices) if len(matrices) > 1 else []
    doc = {"schema": f"baarda-test/{results.SCHEMA_VERSION}", "summary": results.summary(adj, rel),
           "tests": tests, "inseparable": [{"hypotheses": list(g.members), "rho": g.rho} for g in apart]}
    if args.json:
        Path(args.json).write_text(json.dumps(results.finite(doc), indent=1, allow_nan=False))
    if not args.quiet:
        print(printable_lines(results.tests_text(adj, rel, tests, top=args.top)))
        for g in apart:
            print(printable(f"the data cannot tell these hypotheses apart (test statistics correlated, "
                            f"ρ ≥ {g.rho:.4f}; F80 §7.4): {', '.join(g.members)}"))
        for t in tests:
            if "exchange_test" in t:
                e = t["exchange_test"]
                verdict = (f"T = {number(e['T'], '.4g')} (crit {number(e['critical_T'], '.2f')}) "
                           f"{'REJECTED' if e['rejected'] else 'accepted'}, ŝ = {number(e['s_hat'], '.3g')}"
                           if e["testable"] else "not testable")
                print(printable(f"{t['hypothesis']} (exchange, F80 §7.1): {verdict}; {e['message']}"))
    return _convergence_status(args.input, adj)


def cmd_convert(args) -> int:
    model = _read_quietly(read_model, args.input, args.format, sigma_px=args.sigma_px,
                          refine_intrinsics=args.refine_intrinsics, drop_undefined=args.drop_undefined)
    _warn_dropped(args.input, model, args.quiet)
    if args.control:
        model = add_control(model, args.control)
    note = ""
    if isinstance(model, SfmBlock):
        try:
            model = to_block(model)
        except ValueError as err:
            raise BaardaError(f"{args.input}:0: cannot convert: {err}") from None
        note = " (camera intrinsics written as fixed calibrations)"
    out = Path(args.out)
    if out.resolve() == Path(args.input).resolve():
        raise BaardaError(f"{args.out}:0: refusing to overwrite the input file")
    write_native(model, out)
    if not args.quiet:
        print(printable(f"wrote {out}{note}"))
    return 0


def _parse_error(spec: str) -> dict:
    parts = spec.split(":")
    d = {"kind": parts[0]}
    if len(parts) > 1 and parts[1]:
        d["size"] = float(parts[1])
    for kv in parts[2:]:
        k, _, v = kv.partition("=")
        try:
            d[k] = int(v)
        except ValueError:
            try:
                d[k] = float(v)
            except ValueError:
                d[k] = v
    return d


def cmd_simulate(args) -> int:
    recipe = {"strips": args.strips, "images_per_strip": args.images, "camera": args.camera,
              "flying_height": args.flying_height, "forward_overlap": args.forward_overlap,
              "side_overlap": args.side_overlap, "pattern": list(args.pattern), "control": args.control,
              "control_spacing": args.control_spacing, "check": args.check,
              "sigma_image": args.sigma_image, "radial": args.radial,
              "errors": [_parse_error(e) for e in args.error], "design": args.design,
              "seed": args.seed, "title": args.title,
              "datum": "free" if args.control == "none" else "control"}
    if args.recipe:
        try:
            doc = json.loads(Path(args.recipe).read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise BaardaError(f"{args.recipe}:0: cannot read the recipe: {err}") from None
        recipe = doc.get("recipe", doc) if isinstance(doc, dict) else None
        if not isinstance(recipe, dict):
            raise BaardaError(f"{args.recipe}:1: a recipe must be a JSON object")
    out = Path(args.out)
    truth = Path(args.truth) if args.truth else out.with_suffix(".truth.json")
    try:
        block, t = simulate_to_files(recipe, out, truth)
    except (ValueError, KeyError, TypeError) as err:
        raise BaardaError(f"simulate: {err}") from None
    if not args.quiet:
        print(f"wrote {out} ({len(block.images)} images, {len(block.points)} points, "
              f"{len(t.get('errors', []))} planted errors) and {truth}")
    return 0


def cmd_report(args) -> int:
    problem = _read_quietly(read_problem, args.input, args.format, drop_undefined=args.drop_undefined)
    _warn_dropped(args.input, problem, args.quiet)
    try:
        adj, problem = _adjust_with_defects(problem, _options(args, problem))
    except InputError:
        raise
    except BaardaError as err:         # a singular normal matrix ...: the file's fault, name it
        raise InputError(args.input, 0, str(err)) from None
    out = Path(args.out) if args.out else Path(args.input).with_suffix(".html")
    if out.resolve() == Path(args.input).resolve():
        raise BaardaError(f"{out}: refusing to overwrite the input file")

    logging.getLogger("bokeh").setLevel(logging.ERROR)   # static export warns about server callbacks
    from .dashboard.report import write_report
    from .dashboard.state import State

    write_report(adj, out, state=State.from_adjustment(adj, policy=adj.policy))
    if not args.quiet:
        print(printable(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)"))
    return _convergence_status(args.input, adj)


def cmd_serve(args) -> int:
    from .dashboard.app import serve

    serve(args.input, port=args.port, address=args.address, show=args.show, webgl=args.webgl,
          allow_hosts=args.allow_host, token=args.token, allow_remote=args.allow_remote)
    return 0


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    for name in ("alpha", "beta"):
        val = getattr(args, name, None)
        if val is not None and not 0 < val < 1:
            ap.error(f"--{name} must lie between 0 and 1 (got {val})")
    sigma_px = getattr(args, "sigma_px", None)
    if sigma_px is not None and not (0 < sigma_px < float("inf")):
        ap.error(f"--sigma-px must be a positive number (got {sigma_px})")
    try:
        if args.command == "analyze":
            return cmd_analyze(args)
        if args.command == "simulate":
            return cmd_simulate(args)
        if args.command == "test":
            return cmd_test(args)
        if args.command == "convert":
            return cmd_convert(args)
        if args.command == "serve":
            return cmd_serve(args)
        if args.command == "report":
            return cmd_report(args)
        if args.command == "risk":
            try:
                rc = analyses.risk_analysis(args.p, args.L1, args.L2, args.lambda_tol)
            except ValueError as err:
                raise BaardaError(f"risk: {err}") from None
            print(f"critical value C = {rc['C']:.4f} (α = {rc['alpha']:.3g}), risk r_C = {rc['r_C']:.4g}")
            return 0
    except BaardaError as err:
        if getattr(args, "debug", False):
            raise
        print(f"baarda: error: {shorten(printable(err))}", file=sys.stderr)   # one line, whatever the file holds
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:            # the reader of our output went away (`baarda ... | head`)
        try:
            sys.stdout = open(os.devnull, "w")   # no second error when Python flushes at exit
        except OSError:
            pass
        return 141
    except Exception as err:  # an internal error: say so in one line, traceback with --debug
        if getattr(args, "debug", False):
            raise
        print(f"baarda: internal error: {type(err).__name__}: {shorten(printable(err))} (run with --debug for details)",
              file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
