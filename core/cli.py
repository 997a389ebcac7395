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

from . import __version__
from .analysis import Extras, SolverOptions, analyze
from .errors import BaardaError, HypothesisError, InputError, NotFoundError, SingularError, UsageError
from .io import read_model, results
from .io.analysis_text import robust_lines
from .io.control import add_control
from .io.gama import UndefinedPointsWarning
from .io.geojson import write_geojson
from .io.hypothesis import HYPOTHESIS_SPECS, parse_hypothesis
from .io.native import write_native
from .model.sfm import SfmBlock, to_block
from .simulate import simulate_to_files
from .stats import analyses, separability
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


def _policy(args) -> dict:
    """The test policy of the command line as TestPolicy's fields; without --statistic the
    decisions use the σ0 the file asks for (:func:`baarda.analysis.analyze`)."""
    sigma0 = None if args.statistic is None else ("aposteriori" if args.statistic == "tau" else "apriori")
    return {"alpha0": args.alpha, "beta0": args.beta, "b_method": args.b_method, "sigma0": sigma0,
            "global_test": args.global_test}


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
                    help="address to listen on (default 127.0.0.1; 0.0.0.0 exposes it to the network)")
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
    except (InputError, UsageError):          # the file's or the options' own message
        raise
    except BaardaError as err:
        raise InputError(args.input, 0, str(err)) from None


def _extras(args) -> Extras:
    """What ``baarda analyze``'s options ask for beyond the adjustment and its tests."""
    risk = None
    if args.risk:
        try:
            risk = tuple(float(x) for x in args.risk.split(","))
        except ValueError:
            risk = ()
        if len(risk) != 3:
            raise UsageError(f"--risk: expected P,L1,L2 (three numbers), got {args.risk!r}")
    elif args.risk_lambda_bar is not None or args.risk_coordinate is not None:
        raise UsageError("--risk-lambda-bar / --risk-coordinate need --risk P,L1,L2")
    if risk is not None and (args.risk_lambda_bar is None) == (args.risk_coordinate is None):
        raise UsageError("--risk: give one tolerance, --risk-lambda-bar TOL or --risk-coordinate METRES")
    truth_path = args.truth
    if truth_path is None:
        guess = Path(args.input).with_suffix(".truth.json")
        truth_path = guess if guess.exists() else None
    sbase = tuple(b.strip() for b in args.sbase.split(",")) if args.sbase else None
    return Extras(snooping=bool(args.snoop), risk=risk, risk_lambda_bar=args.risk_lambda_bar,
                  risk_coordinate=args.risk_coordinate,
                  exchanges=tuple((spec, True) for spec in args.exchange or ())
                  + tuple((spec, False) for spec in args.misidentified or ()),
                  sbase=sbase, criterion=args.criterion, criterion_c0=args.criterion_c0, robust=args.robust,
                  variance_components=args.variance_components,
                  truth=None if truth_path is None else str(truth_path))


def _analysis(args, progress=None, strict=None):
    """:func:`baarda.analysis.analyze` of the input with the command line's reader options,
    solver options and test policy; the dropped-observations warning printed."""
    policy = _policy(args)
    analysis = _read_quietly(analyze, args.input, format=args.format, control=getattr(args, "control", None),
                             sigma_px=getattr(args, "sigma_px", None),
                             refine_intrinsics=getattr(args, "refine_intrinsics", None),
                             strict=bool(getattr(args, "strict", False) if strict is None else strict),
                             drop_undefined=args.drop_undefined,
                             solver=SolverOptions(max_iter=getattr(args, "max_iter", 200)),
                             policy=policy, progress=progress)
    _warn_dropped(args.input, analysis.problem, args.quiet)
    return analysis


def _analyze(args) -> int:
    extras = _extras(args)                   # usage errors first
    analysis = _analysis(args, progress=_progress(args.quiet))
    adj = analysis.adjustment
    if not args.quiet and sys.stderr.isatty():
        print("", file=sys.stderr)
    t1 = time.perf_counter()
    try:
        doc = analysis.to_dict()
    except SingularError as err:
        if adj.converged:
            raise
        return _diverged(args, analysis, err)
    adj.timings["reliability"] = time.perf_counter() - t1
    analysis._add_extras(doc, extras)
    doc["summary"]["timings"] = {k: round(v, 6) for k, v in adj.timings.items()}
    if args.json:
        results.write_json(adj, args.json, doc)
    if args.csv:
        results.write_csv(adj, args.csv, doc)
    if args.geojson:
        write_geojson(adj, args.geojson)
    if not args.quiet:
        print(analysis.text(top=args.top, extras=extras))
    return _convergence_status(args.input, adj)


def _diverged(args, analysis, err) -> int:
    """An adjustment that did not converge and whose normal equations are singular at its last
    iterate: no reliability can be computed there. Say so in one line (exit status
    :data:`NOT_CONVERGED`), and run the robust estimation if asked — it is what finds the gross
    error that makes least squares diverge (R84 §6: a large error)."""
    adj = analysis.adjustment
    why = (adj.termination or "not converged").removeprefix("not converged: ")
    hint = ("" if args.robust else
            f"; a gross error is the likely cause: try `baarda analyze {args.input} --robust r84`")
    print(printable(f"baarda: {args.input}: NOT converged after {adj.iterations} iterations ({why}) and the normal "
                    f"equations at the last iterate are singular ({err}): no reliability computed, no JSON/CSV "
                    f"written{hint}"), file=sys.stderr)
    if args.robust and not args.quiet:
        print("\n".join(robust_lines(analysis.robust(args.robust))))
    return NOT_CONVERGED


def _convergence_status(path, adj) -> int:
    """0, or :data:`NOT_CONVERGED` with one line on stderr when the adjustment did not converge."""
    if adj.converged:
        return 0
    why = getattr(adj, "termination", "") or "not converged"
    print(f"baarda: {printable(str(path))}: NOT converged after {adj.iterations} iterations: "
          f"{why.removeprefix('not converged: ')}", file=sys.stderr)
    return NOT_CONVERGED


def cmd_test(args) -> int:
    """``baarda test``: each hypothesis in full (:meth:`baarda.analysis.Analysis.test`)."""
    specs = [(text, parse_hypothesis(text)) for text in args.hypothesis]     # usage errors first
    analysis = _analysis(args, strict=False)
    adj, rel = analysis.adjustment, analysis.reliability
    tests, matrices = [], []
    for text, spec in specs:
        try:
            t = analysis.test(spec, label=text)
        except InputError:
            raise
        except (NotFoundError, HypothesisError) as err:
            raise UsageError(f"--hypothesis {text!r}: {err}") from None
        if "ap_test" in t:
            tests.append({"hypothesis": text, "spec": spec, "ap_test": t["ap_test"]})
            continue
        matrices.append((text, analysis.matrix(spec)))
        t.pop("spec")
        tests.append({"hypothesis": text, "spec": spec, **t})
    # hypotheses the data cannot tell apart (F80 §7.4, M84 §3.3): their statistics correlate |ρ| ≥ 0.99
    apart = separability.inseparable_pairs(adj, matrices) if len(matrices) > 1 else []
    doc = {"schema": f"baarda-test/{results.SCHEMA_VERSION}", "summary": analysis.summary(),
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
    out = Path(args.out) if args.out else Path(args.input).with_suffix(".html")
    if out.resolve() == Path(args.input).resolve():
        raise BaardaError(f"{out}: refusing to overwrite the input file")
    try:
        analysis = _analysis(args, strict=False)
    except InputError:
        raise
    except BaardaError as err:         # a singular normal matrix ...: the file's fault, name it
        raise InputError(args.input, 0, str(err)) from None

    logging.getLogger("bokeh").setLevel(logging.ERROR)   # static export warns about server callbacks
    from .dashboard.report import write_analysis_report

    write_analysis_report(analysis, out)
    if not args.quiet:
        print(printable(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)"))
    return _convergence_status(args.input, analysis.adjustment)


def cmd_serve(args) -> int:
    from .dashboard.app import serve

    serve(args.input, port=args.port, address=args.address, show=args.show, webgl=args.webgl)
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
