"""The commands of :mod:`baarda.cli` (``baarda analyze``, ``test``, ``simulate``, ``convert``,
``report``, ``risk``, ``serve``; ``batch`` and ``study`` are in :mod:`baarda.batch` and
:mod:`baarda.study`): what each does with its parsed arguments. Exit statuses and the contract of
their messages: :mod:`baarda.cli`; their options: :mod:`baarda.cli_parser`.
"""

from __future__ import annotations

import json
import logging
import math
import sys
import time
import warnings
from pathlib import Path

from . import batch, cli_options, study
from .analysis import Extras, SolverOptions, analyze
from .cli_parser import NOT_CONVERGED
from .errors import BaardaError, HypothesisError, InputError, NotFoundError, OptionError, SingularError, UsageError
from .io import read_model, results, summary_text
from .io.analysis_text import robust_lines
from .io.control import add_control
from .io.gama import UndefinedPointsWarning
from .io.geojson import write_geojson
from .io.gnss import add_gnss, add_imu
from .io.hypothesis import parse_hypothesis
from .io.native import write_native
from .io.output import OutputError, check_outputs, write_text
from .io.source import read_text
from .model.sfm import SfmBlock, to_block
from .sfm_defects import degenerate_geometry
from .simulate import check_recipe, gnss_path, simulate_to_files
from .stats import analyses, separability
from .text import number, printable, printable_lines


def _policy(args) -> dict:
    """The test policy of the command line as TestPolicy's fields; without --statistic the
    decisions use the σ0 the file asks for (:func:`baarda.analysis.analyze`)."""
    sigma0 = None if args.statistic is None else ("aposteriori" if args.statistic == "tau" else "apriori")
    return {"alpha0": args.alpha, "beta0": args.beta, "b_method": args.b_method, "sigma0": sigma0,
            "global_test": args.global_test, "conf_pr": args.conf_pr}


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
                             solver=SolverOptions(max_iter=getattr(args, "max_iter", 200),
                                                  stop=getattr(args, "stop", "optimum")),
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
    _write_outputs(args, adj, doc)
    if not args.quiet:
        print(analysis.text(top=args.top, extras=extras))
    return _convergence_status(args.input, adj)


def _write_outputs(args, adj, doc) -> None:
    """The files ``baarda analyze`` was asked for (--json, --csv, --parquet, --geojson) of ``adj``."""
    if args.json:
        results.write_json(adj, args.json, doc)
    if args.csv:
        results.write_csv(adj, args.csv, doc)
    if args.parquet:
        results.write_parquet(adj, args.parquet, doc)
    if args.geojson:
        write_geojson(adj, args.geojson)


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
    _write_outputs(args, final, doc)
    if not args.quiet:
        print(summary_text.text_summary(final, top=args.top))
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
        print(printable_lines(summary_text.tests_text(adj, rel, tests, top=args.top)))
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
    gnss, imu = cli_options.gnss_options(args), cli_options.imu_options(args)
    if gnss is not None:
        model = add_gnss(model, gnss)
    if imu is not None:
        model = add_imu(model, imu)
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
        return [args.input, args.control, args.gnss, args.imu], [args.out], []
    if command == "report":
        return [args.input, args.control, args.gnss, args.imu], [_report_path(args)], []
    if command == "serve":
        return [args.input, args.control, args.gnss, args.imu], [], []
    if command == "test":
        files = [t.partition(":")[2] for t in args.hypothesis if t.startswith("file:")]
        return [args.input, args.control, args.gnss, args.imu, *files], [args.json], []
    if command == "analyze":
        guess = _truth_beside(args.input)
        truth_file = args.truth or (guess if guess is not None and guess.exists() else None)
        tables = ("observations", "points", "groups")
        csv = [Path(args.csv) / f"{name}.csv" for name in (*tables, "images", "check_points")] if args.csv else []
        parquet = [Path(args.parquet) / f"{name}.parquet" for name in tables] if args.parquet else []
        return [args.input, args.control, args.gnss, args.imu, truth_file], [args.json, args.geojson, *csv, *parquet], \
            [d for d in (args.csv, args.parquet) if d]
    return [], [], []


def cmd_serve(args) -> int:
    from .dashboard.app import serve

    inputs = {"control": args.control, "gnss": cli_options.gnss_options(args), "imu": cli_options.imu_options(args)}
    inputs = {k: v for k, v in inputs.items() if v is not None}
    if inputs:
        if args.input is None:
            raise UsageError("--control, --gnss and --imu name the companion files of FILE: give FILE")
    serve(args.input, port=args.port, address=args.address, show=args.show, webgl=args.webgl,
          allow_hosts=args.allow_host, token=args.token, allow_remote=args.allow_remote, inputs=inputs)
    return 0


def run(args) -> int:
    """The command of ``args``, its outputs checked first (never an input, writable)."""
    if getattr(args, "beta", None) is not None and not args.beta > args.alpha:
        raise BaardaError(f"{args.command}: --beta ({args.beta:g}) must be larger than --alpha ({args.alpha:g}): "
                          f"the power of a test exceeds its size")
    if getattr(args, "parquet", None) and not results.can_write_parquet():
        raise BaardaError(f"{args.command}: --parquet needs pyarrow, which is not installed "
                          f"(pip install 'baarda[batch]')")
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
