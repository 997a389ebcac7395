"""The ``baarda`` command.

Exit status: 0 success; 1 the analysis ran but a check asked for failed (none yet);
2 bad input or usage (one line ``baarda: error: FILE:LINE: what is wrong`` or ``baarda: error:
COMMAND: what is wrong with the options``, no traceback unless ``--debug``): also an output that
names an input or cannot be written; 3 an internal error; 4 (:data:`NOT_CONVERGED`) the
adjustment did not converge within ``--max-iter`` iterations (or stalled): the results are
written, marked as not converged (JSON ``summary.converged`` false and ``summary.termination``,
a column ``adjustment`` in every CSV, a banner in the report), and one line ``baarda: FILE: NOT
converged: ...`` goes to stderr — unless the normal equations are singular at the last iterate,
when nothing is written and the line says so; 130 interrupted (SIGINT, Ctrl-C) and 143
terminated (SIGTERM), with one line ``baarda: interrupted`` / ``baarda: terminated``; 141 the
reader of the output went away (a broken pipe, ``baarda ... | head``), quietly, as other
commands do.

Outputs are checked before anything is read (:func:`baarda.io.output.check_outputs`: never
an input, also through a link; writable) and written atomically (:func:`baarda.io.output.atomic_write`):
an interrupted run leaves the previous file as it was.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import sys
import time
import warnings
from pathlib import Path

from . import __version__, batch, cli_options, study
from .analysis import Extras, SolverOptions, analyze
from .errors import BaardaError, HypothesisError, InputError, NotFoundError, OptionError, SingularError, UsageError
from .io import read_model, results
from .io.analysis_text import robust_lines
from .io.control import add_control
from .io.gama import UndefinedPointsWarning
from .io.geojson import write_geojson
from .io.hypothesis import HYPOTHESIS_SPECS, parse_hypothesis
from .io.native import write_native
from .io.output import OutputError, check_outputs, write_text
from .io.source import read_text
from .model.sfm import SfmBlock, to_block
from .sfm_defects import degenerate_geometry
from .simulate import CAMERAS, RANGES as RECIPE_RANGES, check_recipe, gnss_path, simulate_to_files
from .stats import analyses, separability
from .text import number, printable, printable_lines, shorten
from .threads import limit_native_threads

#: exit status of a run whose adjustment did not converge (module docstring)
NOT_CONVERGED = 4


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors in one line, ``baarda: error: COMMAND: what`` (exit 2)."""

    def error(self, message):
        command = self.prog.removeprefix("baarda").strip()
        where = f"{command}: " if command else ""
        self.exit(2, f"baarda: error: {where}{shorten(printable(message))} (see {self.prog} --help)\n")


def _in_range(low, high, integer=False):
    """An argparse type: a finite number (an integer if ``integer``) from ``low`` to ``high``."""
    kind = "an integer" if integer else "a number"

    def parse(text: str):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {kind}: {text!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"must be {kind} from {low:g} to {high:g} (got {text!r})")
        return value
    return parse


#: the ranges of α0 and β0 that the test's critical values and δ0 are computed in (and β0 > α0)
ALPHA_RANGE = (1e-12, 0.5)
BETA_RANGE = (0.05, 0.9999)


def _add_test_options(p):
    p.add_argument("--alpha", type=_in_range(*ALPHA_RANGE), default=0.001,
                   help="size α0 of the one-dimensional tests (data snooping), default 0.001 "
                        f"(from {ALPHA_RANGE[0]:g} to {ALPHA_RANGE[1]:g})")
    p.add_argument("--beta", type=_in_range(*BETA_RANGE), default=0.80,
                   help="power β0 at which minimal detectable biases are computed, default 0.80 "
                        f"(from {BETA_RANGE[0]:g} to {BETA_RANGE[1]:g}, above α0)")
    p.add_argument("--b-method", action="store_true",
                   help="Baarda's B-method: multi-dimensional tests get the δ0 and β0 of the 1D test")
    p.add_argument("--global-test", choices=["one-sided", "two-sided", "b-method"], default="one-sided",
                   help="the global test of vᵀPv = Ω/σ0² ~ χ²(r) (F80 §4.1): one-sided (default), rejected when "
                        "σ0 a priori lies below the conf-pr confidence interval of σ̂0, size (1 − conf-pr)/2 = "
                        "2.5 %% at 0.95, for any redundancy; two-sided, gama-local's interval at conf-pr; or "
                        "b-method, one-sided at the B-method's α_r (the λ0 and β0 of the 1D test, F80 §7.2; "
                        "α_r exceeds 50 %% once r ≳ 200)")
    p.add_argument("--conf-pr", type=_in_range(1e-9, 1 - 1e-9), default=None, metavar="P",
                   help="confidence level of the global test and of σ̂0's interval (default: the file's "
                        "conf-pr, else 0.95)")
    p.add_argument("--statistic", choices=["w", "tau"], default=None,
                   help="the statistic that flags observations and that --snoop removes by: Baarda's w "
                        "(σ0 a priori) or Pope's τ (σ0 a posteriori); default: τ where the file asks for "
                        "σ0 a posteriori (GNU Gama's sigma-act), w otherwise")


def _policy(args) -> dict:
    """The test policy of the command line as TestPolicy's fields; without --statistic the
    decisions use the σ0 the file asks for (:func:`baarda.analysis.analyze`)."""
    sigma0 = None if args.statistic is None else ("aposteriori" if args.statistic == "tau" else "apriori")
    return {"alpha0": args.alpha, "beta0": args.beta, "b_method": args.b_method, "sigma0": sigma0,
            "global_test": args.global_test, "conf_pr": args.conf_pr}


def _add_iteration_option(p):
    p.add_argument("--max-iter", type=_in_range(1, 100_000, integer=True), default=200, metavar="N",
                   help="at most N iterations of the adjustment (default 200); a run that does not "
                        "converge writes its results marked as such and exits with status 4")


def _add_input_options(p):
    p.add_argument("--format", default="auto",
                   help="input format: auto (default), gama, native, bal, bundler, colmap")
    p.add_argument("--sigma-px", type=_in_range(1e-6, 1e6), default=None, metavar="S",
                   help="σ of image coordinates in pixels for BAL, Bundler and COLMAP input (default 1; "
                        "from 1e-06 to 1e+06)")
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
    """One warning line on stderr listing the observations dropped by --drop-undefined, and
    one per note of the reader on what it set aside or repaired (a problem's ``notes``, a model's
    ``extra``)."""
    notes = getattr(model_or_problem, "notes", None)
    if notes is not None:
        reader_notes, dropped = notes.reader_notes, list(notes.dropped_observations)
    else:
        extra = getattr(model_or_problem, "extra", {}) or {}
        reader_notes, dropped = extra.get("reader_notes", ()), list(extra.get("dropped", []))
    for note in reader_notes if not quiet else ():
        print(printable(f"baarda: warning: {path}: {note}"), file=sys.stderr)
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


def _recipe_range(key: str):
    """The argparse type of a simulate option: the range of its recipe key (baarda.simulate.RANGES)."""
    low, high, integer = RECIPE_RANGES[key]
    return _in_range(low, high, integer)


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="baarda", description="Reliability of geodetic networks and photogrammetric blocks: global test, "
                    "data snooping, redundancy numbers, MDB, external reliability.",
        epilog="Exit status: 0 ok, 2 bad input or usage (also an output that names an input or cannot be "
               "written), 3 internal error, 4 the adjustment did not converge (results written and marked as "
               "not converged, unless its normal equations are singular: then nothing is written), 130 "
               "interrupted, 143 terminated, 141 broken pipe.")
    ap.add_argument("--version", action="version", version=f"baarda {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    an = sub.add_parser("analyze", help="adjust a network or block and test it",
                        description="Adjust INPUT, run the global test and data snooping, and "
                                    "compute redundancy numbers, MDBs and external reliability.")
    an.add_argument("input", help="the network or block: GNU Gama .gkf, native .json, BAL problem .txt, "
                                  "Bundler .out, COLMAP model directory (docs/formats.md)")
    _add_input_options(an)
    cli_options.add_gnss_arguments(an)
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
    an.add_argument("--risk-lambda-bar", type=_in_range(1e-12, 1e12), metavar="TOL",
                    help="tolerance λ̄tol of Baarda's datum-invariant λ̄ (general purpose, M84 §3.2-3.3)")
    an.add_argument("--risk-coordinate", type=_in_range(1e-12, 1e12), metavar="METRES",
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
    an.add_argument("--criterion-c0", type=_in_range(0.0, 1e12), default=0.0, metavar="C0",
                    help="the constant part of the criterion, chosen first from the precision of the "
                         "measurements (M84 §2.3): m² (linear, logarithmic) or m (exponential); default 0")
    an.add_argument("--variance-components", nargs="?", const="families",
                    choices=["families", "radial", "radial-isotropic"],
                    help="estimate variance components (F80 eq. 9, iterated): a factor per observation "
                         "family (default), or the radial model σ_r² = a² + b²c²/cos⁴α of image "
                         "observations (F80 §2.1, blocks; b acts on the radial component, "
                         "radial-isotropic: on x and y alike)")
    an.add_argument("--merge-groups", default=None, metavar="A+B[,C+D]",
                    help="with --variance-components families: estimate one factor for the groups joined "
                         "by + (e.g. control+image for a group with too little redundancy of its own)")
    an.add_argument("--strict", action="store_true",
                    help="local defects (points, images, cameras or coordinates the observations do not "
                         "determine) are an error instead of being named and left out")
    an.add_argument("--top", type=_in_range(0, 10**6, integer=True), default=8,
                    help="how many entries each summary list shows")
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
    cli_options.add_gnss_arguments(ts)
    _add_test_options(ts)
    _add_iteration_option(ts)
    ts.add_argument("--json", metavar="OUT", help="write the tests as JSON (docs/json-schema.md, 'baarda test')")
    ts.add_argument("--top", type=_in_range(0, 10**6, integer=True), default=10,
                    help="how many points of each deformation field to print")
    ts.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    ts.add_argument("--debug", action="store_true", help="show tracebacks of errors")

    sim = sub.add_parser("simulate", help="simulate an aerial block with planted errors",
                         description="Simulate an aerial bundle block (s strips × m images) and write "
                                     "it in baarda's native format, with a truth file of what was planted.")
    sim.add_argument("out", help="the block file to write (.json)")
    sim.add_argument("--truth", metavar="FILE", help="truth file (default: OUT with .truth.json)")
    sim.add_argument("--strips", type=_recipe_range("strips"), default=3, help="number of strips (default 3)")
    sim.add_argument("--images", type=_recipe_range("images_per_strip"), default=8,
                     help="images per strip (default 8)")
    sim.add_argument("--camera", default="aerial", choices=sorted(CAMERAS),
                     help="aerial (153 mm, 230 mm format) or drone")
    sim.add_argument("--flying-height", type=_recipe_range("flying_height"), default=1500.0,
                     help="metres above ground (default 1500)")
    sim.add_argument("--forward-overlap", type=_recipe_range("forward_overlap"), default=0.6, help="default 0.6")
    sim.add_argument("--side-overlap", type=_recipe_range("side_overlap"), default=0.25, help="default 0.25")
    sim.add_argument("--pattern", type=_in_range(3, 5, integer=True), nargs=2, default=[3, 3], metavar=("NX", "NY"),
                     help="tie points per image (default 3 3, von Gruber; or 5 3)")
    sim.add_argument("--control", default="perimeter",
                     help="control configuration: corners, perimeter, dense, minimal, none (free block)")
    sim.add_argument("--control-spacing", type=_recipe_range("control_spacing"), default=2,
                     help="perimeter control every k base lengths")
    sim.add_argument("--check", type=_recipe_range("check"), default=0, help="number of check points")
    sim.add_argument("--sigma-image", type=_recipe_range("sigma_image"), default=None,
                     help="σ of image coordinates, mm (default 0.005)")
    sim.add_argument("--radial", type=_recipe_range("radial"), default=0.0,
                     help="planted radial distortion at the image corner, mm")
    sim.add_argument("--error", action="append", default=[], metavar="KIND:SIZE[:K=V...]",
                     help="plant an error, e.g. image:20, transfer:10:images=3, control:20:axis=z, "
                          "image-point:6, misidentification:1, exchange:1, with --gnss-sigma gnss:20:image=203 "
                          "or gnss-strip:10:strip=2:axis=y (size in σ; repeatable)")
    sim.add_argument("--design", action="store_true", help="design mode: exact observations (no noise)")
    cli_options.add_simulate_gnss_arguments(sim)
    sim.add_argument("--seed", type=_recipe_range("seed"), default=0, help="random seed (default 0)")
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
    rp.add_argument("--out", "-o", metavar="HTML",
                    help="the report to write (default: INPUT with .html, which must not exist yet unless "
                         "--force is given)")
    rp.add_argument("--force", action="store_true", help="replace an existing INPUT.html (the default --out)")
    rp.add_argument("--format", default="auto", help="input format (see analyze)")
    _add_drop_option(rp)
    _add_test_options(rp)
    _add_iteration_option(rp)
    rp.add_argument("--quiet", "-q", action="store_true")
    rp.add_argument("--debug", action="store_true")

    for module in (batch, study):      # the commands on Dask (issue 30)
        module.add_parser(sub, (_add_input_options, _add_test_options, _add_iteration_option), _in_range)
    rk = sub.add_parser("risk", help="risk-minimising critical value of a test (M84 §3.3)",
                        description="Critical value C minimising (1−p) α L1 + p (1−β) L2 for a one-sided "
                                    "normal test against an error of tolerance λtol.")
    rk.add_argument("--p", type=_in_range(1e-12, 1 - 1e-12), required=True,
                    help="probability that an observation is erroneous")
    rk.add_argument("--L1", type=_in_range(1e-12, 1e12), default=1.0, help="cost of rejecting a good observation")
    rk.add_argument("--L2", type=_in_range(1e-12, 1e12), default=10.0, help="cost of missing a bad one")
    rk.add_argument("--lambda-tol", type=_in_range(1e-12, 1e6), default=17.07,
                    help="tolerance λtol (non-centrality)")
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
        guess = _truth_beside(args.input)
        truth_path = guess if guess is not None and guess.exists() else None
    sbase = tuple(b.strip() for b in args.sbase.split(",")) if args.sbase else None
    return Extras(snooping=bool(args.snoop), risk=risk, risk_lambda_bar=args.risk_lambda_bar,
                  risk_coordinate=args.risk_coordinate,
                  exchanges=tuple((spec, True) for spec in args.exchange or ())
                  + tuple((spec, False) for spec in args.misidentified or ()),
                  sbase=sbase, criterion=args.criterion, criterion_c0=args.criterion_c0, robust=args.robust,
                  variance_components=args.variance_components, merge_groups=args.merge_groups,
                  truth=None if truth_path is None else str(truth_path))


def _analysis(args, progress=None, strict=None):
    """:func:`baarda.analysis.analyze` of the input with the command line's reader options,
    solver options and test policy; the dropped-observations warning printed."""
    policy = _policy(args)
    analysis = _read_quietly(analyze, args.input, format=args.format, control=getattr(args, "control", None),
                             gnss=cli_options.gnss_options(args), imu=cli_options.imu_options(args),
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
        return _diverged(args, analysis, err, extras)
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


def _diverged(args, analysis, err, extras=None) -> int:
    """Normal equations singular at the last iterate (not converged, or converged at a singular
    point): no reliability there. A gross error is the usual cause (R84 §6), found by the robust
    estimation: ``--robust``'s method, else R84's (not for a degenerate geometry). Where least
    squares without its suspects converges, its results are written with them named (``robust``,
    ``summary.robust_left_out``) and one stderr line, exit 0; else one line, exit
    :data:`NOT_CONVERGED` (a converged adjustment: the singular system's error, exit 2). With a
    truth file (``extras.truth``) the planted errors are compared with what was found as far as
    there is something to compare: with the least squares without the suspects and the suspects
    (``planted``, :func:`baarda.truth.compare`), else in the text with the suspects alone."""
    adj = analysis.adjustment
    why = (adj.termination or "not converged").removeprefix("not converged: ")
    head = (f"baarda: {args.input}: {'converged' if adj.converged else 'NOT converged'} after {adj.iterations} "
            f"iterations ({why}) and the normal equations at the last iterate are singular ({err})")
    geometry = degenerate_geometry(analysis.problem.notes.local_model)     # the cause, when it is the geometry
    method = args.robust or (None if geometry else "r84")
    rob = final = doc = None
    try:
        rob = analysis.robust(method) if method else None
        final = rob.final if rob is not None else None
        doc = results.to_dict(final) if final is not None and final.converged else None
    except SingularError:
        if args.robust and rob is None:
            raise
    if doc is None:
        if adj.converged and not args.robust and isinstance(err, SingularError):
            raise err
        tried = f"; the least squares without the suspects of the robust estimation ({method}) gives none either"
        print(printable(f"{head}: no reliability computed, no JSON/CSV written{tried if method else ''}"
                        f"{f'; {geometry}' if geometry else ''}"), file=sys.stderr)
        if rob is not None and not args.quiet:
            planted = (analysis.planted(extras.truth, robust=rob, final=None)
                       if extras is not None and extras.truth is not None else None)
            print("\n".join(robust_lines(rob, planted)))
        return NOT_CONVERGED
    left = [sp["ids"] for sp in rob.suspects]
    asked = f", so the robust estimation ({method}, R84 §6-8) was run (choose its method with --robust)"
    print(printable(f"{head}{'' if args.robust else asked}; without the {len(left)} suspect(s) of the robust "
                    f"estimation the adjustment converged: its results are written"), file=sys.stderr)
    doc["robust"] = results.finite(rob.as_dict())
    doc["summary"]["robust_left_out"] = left
    doc["summary"]["robust"] = results.finite(rob.summary())
    planted = None
    if extras is not None and extras.truth is not None:
        planted = analysis.planted(extras.truth, robust=rob, final=final)
        doc["planted"] = results.finite(planted)
    if args.json:
        results.write_json(final, args.json, doc)
    if args.csv:
        results.write_csv(final, args.csv, doc)
    if args.geojson:
        write_geojson(final, args.geojson)
    if not args.quiet:
        print(results.text_summary(final, top=args.top))
        print("\n".join(robust_lines(rob, planted)))
    return 0


def _convergence_status(path, adj) -> int:
    """0, or :data:`NOT_CONVERGED` with one line on stderr when the adjustment did not converge."""
    if adj.converged:
        return 0
    why = getattr(adj, "termination", "") or "not converged"
    notes = getattr(getattr(adj, "problem", None), "notes", None)
    geometry = degenerate_geometry(notes.local_model if notes is not None else None)
    print(f"baarda: {printable(str(path))}: NOT converged after {adj.iterations} iterations: "
          f"{why.removeprefix('not converged: ')}{f'; {geometry}' if geometry else ''}", file=sys.stderr)
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
    partly = separability.partly_inseparable(adj, matrices) if len(matrices) > 1 else []
    doc = {"schema": f"baarda-test/{results.SCHEMA_VERSION}", "summary": analysis.summary(),
           "tests": tests, "inseparable": [{"hypotheses": list(g.members), "rho": g.rho} for g in apart]}
    if partly:
        doc["partly_inseparable"] = [{"hypotheses": list(g.members), "largest": g.largest, "smallest": g.smallest,
                                      "direction": list(g.direction)} for g in partly]
    if args.json:
        write_text(args.json, json.dumps(results.finite(doc), indent=1, allow_nan=False))
    if not args.quiet:
        print(printable_lines(results.tests_text(adj, rel, tests, top=args.top)))
        for g in apart:
            print(printable(f"the data cannot tell these hypotheses apart (test statistics correlated, "
                            f"ρ ≥ {g.rho:.4f}; F80 §7.4): {', '.join(g.members)}"))
        for g in partly:
            print(printable(f"partly inseparable (canonical correlations {g.largest:.4f} … {g.smallest:.4f}; F80 §7.4): "
                            f"{', '.join(g.members)} — an error along ({', '.join(f'{x:+.3f}' for x in g.direction)}) "
                            f"of the first is seen by both tests alike and cannot be attributed"))
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
    write_native(model, out)
    if not args.quiet:
        print(printable(f"wrote {out}{note}"))
    return 0


def cmd_simulate(args) -> int:
    recipe = {"strips": args.strips, "images_per_strip": args.images, "camera": args.camera,
              "flying_height": args.flying_height, "forward_overlap": args.forward_overlap,
              "side_overlap": args.side_overlap, "pattern": list(args.pattern), "control": args.control,
              "control_spacing": args.control_spacing, "check": args.check,
              "sigma_image": args.sigma_image, "radial": args.radial,
              "errors": [cli_options.parse_error(e) for e in args.error], "design": args.design,
              "seed": args.seed, "title": args.title,
              "datum": "free" if args.control == "none" else "control", **cli_options.gnss_recipe(args)}
    where = "simulate"
    if args.recipe:
        where = f"{args.recipe}:0"
        try:
            doc = json.loads(read_text(args.recipe, small=True))   # at most BAARDA_MAX_SMALL_BYTES
        except json.JSONDecodeError as err:
            raise InputError(args.recipe, err.lineno, f"the recipe is not JSON: {err.msg}") from None
        except RecursionError:
            raise InputError(args.recipe, 0, "the recipe is nested too deeply") from None
        recipe = doc.get("recipe", doc) if isinstance(doc, dict) else None
        if not isinstance(recipe, dict):
            raise BaardaError(f"{args.recipe}:1: a recipe must be a JSON object")
    try:
        recipe = check_recipe(recipe)
    except OptionError as err:
        raise BaardaError(f"{where}: {err}") from None
    out = Path(args.out)
    truth = Path(args.truth) if args.truth else _truth_beside(out)
    try:
        block, t = simulate_to_files(recipe, out, truth)
    except OptionError as err:
        raise BaardaError(f"{where}: {err}") from None
    except (ValueError, KeyError, TypeError, IndexError, ZeroDivisionError, OverflowError, StopIteration):
        raise BaardaError(f"{where}: cannot simulate this recipe (check its camera and the planted errors' "
                          f"points, images and sizes)") from None
    if not args.quiet:
        print(f"wrote {out} ({len(block.images)} images, {len(block.points)} points, "
              f"{len(t.get('errors', []))} planted errors) and {truth}"
              + (f"; GNSS centres in {gnss_path(out)} (analyse with --gnss)" if block.gnss is not None else "")
              + (f"; IMU attitudes in {gnss_path(out, '.imu.csv')} (--imu)" if block.imu is not None else ""))
    return 0


def cmd_report(args) -> int:
    try:
        analysis = _analysis(args, strict=False)
    except InputError:
        raise
    except BaardaError as err:         # a singular normal matrix ...: the file's fault, name it
        raise InputError(args.input, 0, str(err)) from None
    out = _report_path(args)

    logging.getLogger("bokeh").setLevel(logging.ERROR)   # static export warns about server callbacks
    from .dashboard.report import write_analysis_report

    write_analysis_report(analysis, out)
    if not args.quiet:
        print(printable(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)"))
    return _convergence_status(args.input, analysis.adjustment)


def _truth_beside(path) -> Path | None:
    """NAME.truth.json beside ``path`` (a simulated block's truth file), None for a path
    without a name (``.``)."""
    try:
        return Path(path).with_suffix(".truth.json")
    except ValueError:
        return None


def _report_path(args) -> Path:
    """The report's file: --out, or INPUT with .html, which must not exist unless --force."""
    if args.out:
        return Path(args.out)
    try:
        out = Path(args.input).with_suffix(".html")
    except ValueError:
        raise BaardaError(f"{args.input}:0: name the report with --out") from None
    if out.exists() and not args.force:
        raise OutputError(out, "exists: name the report with --out, or give --force to replace it")
    return out


def _io_paths(args) -> tuple[list, list, list]:
    """The files a command reads, the files it writes and the folders it writes into (for
    :func:`baarda.io.output.check_outputs`)."""
    command = args.command
    if command == "simulate":
        out = Path(args.out)
        return [args.recipe], [out, Path(args.truth) if args.truth else _truth_beside(out),
                               gnss_path(out) if args.gnss_sigma is not None else None,
                               gnss_path(out, ".imu.csv") if args.imu_sigma is not None else None], []
    if command == "convert":
        return [args.input, args.control], [args.out], []
    if command == "report":
        return [args.input], [_report_path(args)], []
    if command == "test":
        files = [t.partition(":")[2] for t in args.hypothesis if t.startswith("file:")]
        return [args.input, args.control, args.gnss, args.imu, *files], [args.json], []
    if command == "analyze":
        guess = _truth_beside(args.input)
        truth_file = args.truth or (guess if guess is not None and guess.exists() else None)
        csv = [Path(args.csv) / f"{name}.csv" for name in ("observations", "points", "groups")] if args.csv else []
        return [args.input, args.control, args.gnss, args.imu, truth_file], [args.json, args.geojson, *csv], \
            [args.csv] * bool(args.csv)
    return [], [], []


class Terminated(BaseException):
    """SIGTERM, raised in the main thread as SIGINT raises KeyboardInterrupt (exit status 143)."""


def _terminate(signum, frame):
    raise Terminated


def cmd_serve(args) -> int:
    from .dashboard.app import serve

    serve(args.input, port=args.port, address=args.address, show=args.show, webgl=args.webgl,
          allow_hosts=args.allow_host, token=args.token, allow_remote=args.allow_remote)
    return 0


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        limit_native_threads()
    except UsageError as err:
        print(f"baarda: error: {printable(err)}", file=sys.stderr)
        return 2
    previous = None
    if args.command != "serve":        # (the server keeps its own way of ending)
        try:
            previous = signal.signal(signal.SIGTERM, _terminate)
        except ValueError:             # not the main thread (main() called from a thread)
            pass
    try:
        code = _run(args)
        sys.stdout.flush()             # a broken pipe shows here, not at exit
        return code
    except BaardaError as err:
        if getattr(args, "debug", False):
            raise
        print(f"baarda: error: {shorten(printable(err))}", file=sys.stderr)   # one line, whatever the file holds
        return 2
    except KeyboardInterrupt:
        print("baarda: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("baarda: terminated", file=sys.stderr)
        return 143
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
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _run(args) -> int:
    """The command of ``args``, its outputs checked first (never an input, writable)."""
    if getattr(args, "beta", None) is not None and not args.beta > args.alpha:
        raise BaardaError(f"{args.command}: --beta ({args.beta:g}) must be larger than --alpha ({args.alpha:g}): "
                          f"the power of a test exceeds its size")
    inputs, outputs, folders = _io_paths(args)
    check_outputs(inputs, outputs, folders)
    commands = {"analyze": cmd_analyze, "simulate": cmd_simulate, "test": cmd_test, "convert": cmd_convert, "serve": cmd_serve,
                "report": cmd_report, "risk": cmd_risk, "batch": batch.command, "study": study.command}
    return commands[args.command](args)


def cmd_risk(args) -> int:
    """``baarda risk``: the risk-minimising critical value (M84 §3.3)."""
    try:
        rc = analyses.risk_analysis(args.p, args.L1, args.L2, args.lambda_tol)
    except ValueError as err:
        raise BaardaError(f"risk: {err}") from None
    if not all(math.isfinite(rc[k]) for k in ("C", "alpha", "r_C")):
        raise BaardaError(f"risk: no finite critical value for p = {args.p:g}, L1 = {args.L1:g}, L2 = {args.L2:g}, "
                          f"λtol = {args.lambda_tol:g} (the costs or the tolerance are too extreme)")
    print(f"critical value C = {rc['C']:.4f} (α = {rc['alpha']:.3g}), risk r_C = {rc['r_C']:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
