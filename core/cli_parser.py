"""The command line's parser: every command, its options and their ranges (``baarda --help``).

Light to import: argparse and the names of :mod:`baarda.catalog`, no numpy; the commands and the
computation are loaded by :func:`baarda.cli.main` once the arguments are parsed (issue 30, item 5:
``baarda --help`` well under a second; issue 25: a Ctrl-C while they load ends in one line).
"""

from __future__ import annotations

import argparse
import math

from . import __version__, cli_options
from .catalog import CAMERAS, HYPOTHESIS_SPECS, RANGES as RECIPE_RANGES
from .text import printable, shorten

#: exit status of a run whose adjustment did not converge (:mod:`baarda.cli`)
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


def _add_iteration_option(p):
    p.add_argument("--max-iter", type=_in_range(1, 100_000, integer=True), default=200, metavar="N",
                   help="at most N iterations of the adjustment (default 200); a run that does not "
                        "converge writes its results marked as such and exits with status 4")
    p.add_argument("--stop", choices=("optimum", "ceres"), default="optimum",          # baarda.iteration.STOPS
                   help="the stopping rule of the adjustment: optimum (default), the strict least-squares "
                        "optimum, where the tests and reliability belong; or ceres, Ceres Solver's at its "
                        "defaults (the cost within about 1e-6 of the optimum's, in fewer iterations: a faster "
                        "solve of a large SfM block whose statistics are those of that iterate)")


def _add_input_options(p):
    p.add_argument("--format", default="auto",
                   help="input format: auto (default), gama, native, bal, bundler, colmap")
    p.add_argument("--sigma-px", type=_in_range(1e-6, 1e6), default=None, metavar="S",
                   help="σ of image coordinates in pixels for BAL, Bundler and COLMAP input (default 1; "
                        "from 1e-06 to 1e+06)")
    p.add_argument("--refine-intrinsics", action=argparse.BooleanOptionalAction, default=None,
                   help="estimate the cameras' focal lengths and distortion (default: yes for BAL and "
                        "Bundler, as they define; no for COLMAP)")
    _add_control_option(p)
    _add_drop_option(p)


def _add_control_option(p):
    p.add_argument("--control", metavar="CSV",
                   help="control points id,X,Y,Z,sx,sy,sz to add as weighted observations (bundle blocks)")


def _add_drop_option(p):
    p.add_argument("--drop-undefined", action="store_true",
                   help="Gama input: drop observations to points no <point> defines, as gama-local does, "
                        "with a warning listing them (default: an error naming file and line)")


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
    an.add_argument("--parquet", metavar="DIR",
                    help="write the same tables as observations.parquet, points.parquet, groups.parquet into DIR "
                         "(typed columns for pandas, Polars, GIS; needs pyarrow, the batch extra)")
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
    _add_control_option(rp)
    cli_options.add_gnss_arguments(rp)
    _add_drop_option(rp)
    _add_test_options(rp)
    _add_iteration_option(rp)
    rp.add_argument("--quiet", "-q", action="store_true")
    rp.add_argument("--debug", action="store_true")

    for add in (_add_batch, _add_study):      # the commands on Dask (issue 30)
        add(sub, (_add_input_options, _add_test_options, _add_iteration_option), _in_range)
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
    cli_options.add_gnss_arguments(cv)
    cv.add_argument("--quiet", "-q", action="store_true")
    cv.add_argument("--debug", action="store_true")

    sv = sub.add_parser("serve", help="serve the dashboard in the browser",
                        description="Serve the Panel dashboard for FILE (default: the demo block).")
    sv.add_argument("input", nargs="?", help="the network or block file (default: data/demo-block.json)")
    _add_control_option(sv)
    cli_options.add_gnss_arguments(sv)
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


def _add_batch(sub, common, number) -> None:
    """The ``batch`` subcommand (:func:`baarda.batch.command`) of the CLI's ``sub``; ``common``: the CLI's functions adding the
    input, test and iteration options of ``baarda analyze``; ``number``: its range type."""
    bt = sub.add_parser("batch", help="analyse many blocks in parallel on Dask (one machine or a cluster)",
                        description="Analyse every block of FILES/GLOBS/DIRS once, in parallel on Dask distributed, "
                                    "as `baarda analyze --json` does: each block's JSON, summary.csv (and "
                                    "summary.parquet with pyarrow) and index.html under --out. A file that fails "
                                    "is a row with its error; a rerun with the same --out skips the blocks done.",
                        epilog="Exit status: 0 every file worked (read, adjusted, converged), 1 some did not "
                               "(the summary's error column says why), 2 usage, 130 interrupted (what is done "
                               "is kept).")
    bt.add_argument("inputs", nargs="+", metavar="FILE", help="files, glob patterns ('blocks/*.gkf') or folders")
    bt.add_argument("--out", "-o", default="batch-out", metavar="DIR", help="the results folder (default batch-out)")
    bt.add_argument("--scheduler", metavar="ADDRESS",
                    help="a running Dask scheduler, e.g. tcp://10.0.0.5:8786 (`dask scheduler`, and `dask worker "
                         "ADDRESS` per node); default: a local cluster on 127.0.0.1")
    bt.add_argument("--workers", type=number(1, 4096, integer=True), default=None, metavar="N",
                    help="local cluster: N single-threaded worker processes (default: one per core)")
    bt.add_argument("--memory-limit", default="auto", metavar="BYTES",
                    help="local cluster: memory limit per worker, e.g. 2GB (default: the machine's memory shared out)")
    for add in common:
        add(bt)
    bt.add_argument("--strict", action="store_true", help="local defects are an error (see analyze)")
    bt.add_argument("--snoop", action="store_true", help="iterative data snooping, in each block's JSON")
    bt.add_argument("--robust", choices=["huber", "danish", "r84"], help="robust estimation, in each block's JSON")
    bt.add_argument("--variance-components", nargs="?", const="families",
                    choices=["families", "radial", "radial-isotropic"], help="variance components (see analyze)")
    bt.add_argument("--merge-groups", default=None, metavar="A+B[,C+D]", help="see analyze")
    bt.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    bt.add_argument("--debug", action="store_true")


def _add_study(sub, common, number) -> None:
    """The ``study`` subcommand (:func:`baarda.study.command`) of the CLI's ``sub`` (``number``: its range type; ``common``, the
    analysis options of ``batch``, are not used: a study fixes its own)."""
    st = sub.add_parser("study", help="design study: simulated designs × Monte Carlo replicates with planted errors",
                        description="Simulate every design of RECIPE's grid REPLICATES times, without and with a "
                                    "planted error, analyse each (w-test) and score it: empirical size and power "
                                    "against α0 and the expected power, MDB and δ̄0 statistics. Writes study.csv, "
                                    "replicates.csv (each replicate's seed), designs.json, study.svg (the plot) and "
                                    "index.html under --out.")
    st.add_argument("recipe", help="the study recipe (JSON; README, 'Design studies')")
    st.add_argument("--out", "-o", default="study-out", metavar="DIR", help="the results folder (default study-out)")
    st.add_argument("--replicates", type=number(1, 1_000_000, integer=True), default=None, metavar="N",
                    help="replicates per design (default: the recipe's)")
    st.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler (see batch)")
    st.add_argument("--workers", type=number(1, 4096, integer=True), default=None, metavar="N",
                    help="local cluster: N worker processes (default: one per core)")
    st.add_argument("--serial", action="store_true", help="run the replicates in this process, without Dask")
    st.add_argument("--quiet", "-q", action="store_true")
    st.add_argument("--debug", action="store_true")
