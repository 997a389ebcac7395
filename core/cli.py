"""The ``baarda`` command.

Exit status: 0 success; 1 the analysis ran but a check asked for failed (none yet);
2 bad input or usage (one line ``baarda: error: FILE:LINE: what is wrong``, no traceback
unless ``--debug``); 3 an internal error.
"""

from __future__ import annotations

import argparse
import sys
import time

from . import __version__
from .errors import BaardaError


def _add_test_options(p):
    p.add_argument("--alpha", type=float, default=0.001,
                   help="size α0 of the one-dimensional tests (data snooping), default 0.001")
    p.add_argument("--beta", type=float, default=0.80,
                   help="power β0 at which minimal detectable biases are computed, default 0.80")
    p.add_argument("--b-method", action="store_true",
                   help="Baarda's B-method: multi-dimensional tests get the δ0 and β0 of the 1D test")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="baarda",
        description="Reliability of geodetic networks and photogrammetric blocks: global test, "
                    "data snooping, redundancy numbers, MDB, external reliability.",
        epilog="Exit status: 0 ok, 2 bad input or usage, 3 internal error.")
    ap.add_argument("--version", action="version", version=f"baarda {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    an = sub.add_parser("analyze", help="adjust a network or block and test it",
                        description="Adjust INPUT, run the global test and data snooping, and "
                                    "compute redundancy numbers, MDBs and external reliability.")
    an.add_argument("input", help="the network or block file (GNU Gama .gkf ...)")
    an.add_argument("--format", default="auto", help="input format: auto (default), gama")
    _add_test_options(an)
    an.add_argument("--json", metavar="OUT", help="write the full results as JSON (docs/json-schema.md)")
    an.add_argument("--csv", metavar="DIR", help="write observations.csv, points.csv, groups.csv into DIR")
    an.add_argument("--top", type=int, default=8, help="how many entries each summary list shows")
    an.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    an.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    return ap


def _progress(quiet):
    if quiet or not sys.stderr.isatty():
        return None

    def show(it, ratio):
        print(f"\r  iteration {it}: max |Δx|/σ = {ratio:.3g}   ", end="", file=sys.stderr, flush=True)
    return show


def cmd_analyze(args) -> int:
    from .adjust import Options, adjust
    from .io import read_problem
    from .io import results

    t0 = time.perf_counter()
    problem = read_problem(args.input, args.format)
    t_read = time.perf_counter() - t0
    options = Options(alpha=args.alpha, beta=args.beta, b_method=args.b_method)
    adj = adjust(problem, options, progress=_progress(args.quiet))
    if not args.quiet and sys.stderr.isatty():
        print("", file=sys.stderr)
    t1 = time.perf_counter()
    doc = results.to_dict(adj)
    adj.timings["read"] = t_read
    adj.timings["reliability"] = time.perf_counter() - t1
    doc["summary"]["timings"] = {k: round(v, 6) for k, v in adj.timings.items()}
    if args.json:
        results.write_json(adj, args.json, doc)
    if args.csv:
        results.write_csv(adj, args.csv, doc)
    if not args.quiet:
        print(results.text_summary(adj, top=args.top))
    return 0


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    for name in ("alpha", "beta"):
        val = getattr(args, name, None)
        if val is not None and not 0 < val < 1:
            ap.error(f"--{name} must lie between 0 and 1 (got {val})")
    try:
        if args.command == "analyze":
            return cmd_analyze(args)
    except BaardaError as err:
        if getattr(args, "debug", False):
            raise
        print(f"baarda: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as err:  # an internal error: say so in one line, traceback with --debug
        if getattr(args, "debug", False):
            raise
        print(f"baarda: internal error: {type(err).__name__}: {err} (run with --debug for details)",
              file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
