"""The text of an analysis beyond its summary (what ``baarda analyze`` prints for snooping, risk,
exchange tests, the S-base and criterion, robust estimation and variance components), and the
HTML summary a notebook shows (:meth:`baarda.analysis.Analysis._repr_html_`).

Every string from a file (ids, names, messages) goes through :func:`baarda.text.printable`
(text) or :func:`html.escape` (HTML): never terminal control or markup.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from .. import truth
from ..errors import BaardaError
from ..stats import analyses
from ..stats.reliability import reliability_of
from ..text import number, printable, printable_lines


def _ids(info, i) -> str:
    return printable(" ".join(f"{a}={b}" for a, b in info.ids[i].items()))


def snooping_lines(analysis) -> list[str]:
    """Iterative data snooping, one line per removed observation (B68, P76)."""
    snoop, adj = analysis.snooping(), analysis.adjustment
    info = adj.problem.info
    stat = "τ" if snoop.use_tau else "w"
    out = [f"  iterative data snooping on {stat}: {len(snoop.steps)} observation(s) removed, σ̂0 "
           f"{number(adj.sigma0_post)} → {number(snoop.adjustment.sigma0_post)}"]
    for k, st in enumerate(snoop.steps, 1):
        out.append(f"    {k:>2d}. #{st.removed:<5d} {info.kind[st.removed]:<15s} {_ids(info, st.removed):<40s} "
                   f"|{stat}| = {number(st.statistic, '7.2f')} > {number(st.critical, '.2f')}  ∇̂ = {number(st.nabla, '+.4g')}")
        if st.twins:
            out.append("        the data cannot tell it from (w-tests correlated |ρ| ≥ 0.99, F80 §7.4): " + "; ".join(
                f"#{j} {_ids(info, j)} (ρ = {number(rho, '+.4f')})" for j, rho in zip(st.twins, st.twin_rho)))
    return out


def risk_lines(r, adj, top: int) -> list[str]:
    """Risk minimisation (M84 §3.3): the range of C_i and the largest r_C."""
    fin = np.isfinite(r.C)
    out = [printable(f"  risk minimisation (M84 §3.3; p = {r.p:g}, L1 = {r.L1:g}, L2 = {r.L2:g}, tolerance "
                     f"{r.tolerance}): C_i from {number(r.C[fin].min() if fin.any() else np.nan, '.3g')} to "
                     f"{number(r.C[fin].max() if fin.any() else np.nan, '.3g')}; {int(r.rejected.sum())} rejected "
                     f"(|w| > C_i), {int(reliability_of(adj).rejected.sum())} at α0")]
    info = adj.problem.info
    for i in np.argsort(-np.nan_to_num(r.r_C), kind="stable")[:top]:
        out.append(f"    #{i:<5d} {info.kind[i]:<15s} {_ids(info, i):<40s} λtol = {number(r.lam_tol[i], '9.3g')}  "
                   f"C = {number(r.C[i], '6.3g')}  r_C = {number(r.r_C[i], '.3g')}"
                   f"{'  REJECTED' if r.rejected[i] else ''}")
    return out


def exchange_lines(e) -> list[str]:
    """One exchange or misidentification test (F80 §7.1)."""
    what = "exchange" if e.both else "misidentification"
    verdict = (f"T = {number(e.T, '.4g')} (crit {number(e.critical, '.2f')}) "
               f"{'REJECTED' if e.rejected else 'accepted'}, ŝ = {number(e.s_hat, '.3g')}") if e.testable else "not testable"
    return [printable(f"  {what} of {e.point_a}/{e.point_b} in image {e.image} (F80 §7.1): {verdict}"),
            printable(f"    {e.message}")]


def precision_lines(analysis, ex) -> list[str]:
    """The S-base and the criterion-matrix fit (M84 §2.2-2.3)."""
    cc = analysis.precision(ex.sbase)
    out = [f"  S-base {', '.join(analysis._sbase(cc))}: point standard deviations and ellipses transformed"]
    if ex.criterion:
        fit = analysis.criterion(ex.criterion, ex.criterion_c0, ex.sbase)
        u = analyses.criterion_units(fit["kind"])
        c2 = f", C2 = {fit['C2']:.4g} {u['C2']}" if fit["kind"] != "linear" and not fit["C1_zero"] else ""
        bound = (" (C2 at the end of its range: d² hardly varies with distance over this network)"
                 if fit["C2_at_bound"] and not fit["C1_zero"] else "")
        c0 = f"C0 = {fit['C0']:.4g} {u['C0']} (given), " if fit["C0"] else ""
        out.append(f"  criterion matrix ({fit['kind']}, M84 §2.3): {c0}fitted C1 = {fit['C1']:.4g} {u['C1']}"
                   f"{c2}, λmax = {fit['lam_max']:.4g}, λmax/λmin = {fit['ratio']:.3g}{bound}")
        if fit["note"]:
            out.append(f"    {fit['note']}")
    return out


def robust_lines(rob, planted=None) -> list[str]:
    """Robust estimation (R84 §6-8) and least squares without its suspects; then ``planted``, the
    comparison with a truth file (:func:`baarda.truth.compare`), if given."""
    out = [f"  robust estimation ({rob.method}, {rob.iterations} iterations"
           f"{'' if rob.converged else ', NOT converged'}): {len(rob.suspects)} suspect(s) confirmed by "
           f"least squares (R84 §7; {rob.candidates} candidate(s), {len(rob.readmitted)} readmitted)"]
    for sp in rob.suspects:
        ids = printable(" ".join(f"{a}={b}" for a, b in sp["ids"].items()))
        base = "" if sp["size_base"] is None else f" = {number(sp['size_base'], '.3g')} base lengths"
        out.append(f"    #{sp['index']:<5d} {sp['kind']:<15s} {ids:<40s} error ≈ {number(sp['size_sigma'], '6.1f')}σ"
                   f"{base} ({sp['class']}), T = {number(sp['T'], '.1f')}, robust weight {sp['weight']:.3g}")
        if sp.get("kept_in") or sp.get("point_left_out"):
            out.append(printable(f"           {sp['note']}"))
        if sp.get("inseparable_from"):
            twins = "; ".join(" ".join(f"{a}={b}" for a, b in alt["ids"].items() if a != "component")
                              + f" (canonical correlations {', '.join(f'{c:.2f}' for c in alt['canonical_correlations'])})"
                              for alt in sp["inseparable_from"])
            out.append(printable(f"           not separable along a shared direction (F80 §7.4) from: {twins}"))
    for fl in rob.floored:
        out.append(f"    weight floor raised to {fl['floor']:.0e} for {printable(', '.join(fl['unknowns'])) or 'all'} "
                   f"(down-weighted, they would leave unknowns undetermined)")
    if rob.final is not None:
        out.append(f"    least squares without them: {int(reliability_of(rob.final).rejected.sum())} rejected by data snooping, "
                   f"σ̂0 = {number(rob.final.sigma0_post)}")
        if not rob.cleaned["complete"]:
            g = reliability_of(rob.final).global_test
            out.append(printable(f"    the robust step did NOT clean the block: without its suspects least squares still "
                                 f"fails the global test (vᵀPv = {number(g['statistic'])} > {number(g['upper'])}, "
                                 f"σ̂0 = {number(rob.final.sigma0_post)}): {rob.cleaned['reason']}"))
    if planted is not None:
        out += printable_lines(truth.text(planted)).split("\n")
    return out


def variance_lines(analysis, kind: str, merge: str | None = None) -> list[str]:
    """Variance components by family (F80 eq. 9; ``merge`` families estimated together) or the
    radial model (F80 §2.1)."""
    try:
        est = analysis.variance_components(kind, merge)
    except BaardaError as err:
        return [printable(f"  {err}")]
    if kind != "families":
        structure = "isotropic" if kind == "radial-isotropic" else "radial"
        out = [f"  radial variance model, {structure} (F80 §2.1, {est.iterations} iterations"
               f"{'' if est.converged else ', NOT converged'}):"]
        for d in est.as_dict():
            se = "held at 0" if d["std_error"] is None else f"± {number(d['std_error'], '.2g')}"
            out.append(f"    {d['component']:<8s} θ = {number(d['theta'])} {se}   redundancy {d['redundancy']:.2f}")
        return out + [printable(f"    {note}") for note in est.notes]
    out = [f"  variance components (F80 eq. 9, {est.iterations} iterations"
           f"{f', factors within {est.tolerance:g} of the fixed point' if est.converged else ', NOT converged'}):"]
    for d in est.as_dict():
        out.append(printable(f"    {d['group']:<20s} σ̂²/σ² = {number(d['factor'], '8.4f')} ± "
                             f"{number(d['std_error'], '.4f')}   redundancy {d['redundancy']:.2f}"))
    va, adj = est.adjustment, analysis.adjustment
    out.append(f"    with these components: {int(reliability_of(va).rejected.sum())} observation(s) rejected "
               f"(before: {int(reliability_of(adj).rejected.sum())}), global test {'passed' if reliability_of(va).global_test['passed'] else 'FAILED'}")
    return out


def check_point_lines(rep: dict, top: int = 20) -> list[str]:
    """The check points (:func:`baarda.model.bundle.check_points`): the RMSE per axis and the
    largest differences adjusted − known."""
    rms, mean = rep["rms"], rep["mean"]
    out = [f"  check points (not in the adjustment): {rep['n']}; RMSE X {number(rms[0], '.4g')}, Y "
           f"{number(rms[1], '.4g')}, Z {number(rms[2], '.4g')}; mean X {number(mean[0], '+.3g')}, Y "
           f"{number(mean[1], '+.3g')}, Z {number(mean[2], '+.3g')}"]
    exp = rep.get("expected_rms")
    if exp is not None and np.isfinite(np.asarray(exp, dtype=float)).all():
        out.append(f"    RMSE the precision predicts X {number(exp[0], '.4g')}, Y {number(exp[1], '.4g')}, Z "
                   f"{number(exp[2], '.4g')}; {rep['n_rejected']} of {rep['n']} rejected by T = dᵀ(Σx̂ + Σref)⁻¹d > "
                   f"{number(rep['critical'], '.2f')} (χ²(3), α = {number(rep['alpha'], '.3g')})")
    elif rep.get("note"):
        out.append(f"    {rep['note']}")
    worst = sorted(rep["points"], key=lambda p: -float(np.linalg.norm(p["diff"])))[:top]
    for p in worst:
        d, sd = p["diff"], p["sigma"]
        T = p.get("T")
        test = "" if T is None or not np.isfinite(T) else f"  T {number(T, '.3g')}{'  REJECTED' if p['rejected'] else ''}"
        out.append(printable(f"    {str(p['id']):<16s} dX {number(d[0], '+9.4f')}  dY {number(d[1], '+9.4f')}  "
                             f"dZ {number(d[2], '+9.4f')}   (σ {number(sd[0], '.3g')}, {number(sd[1], '.3g')}, "
                             f"{number(sd[2], '.3g')}){test}"))
    if rep["n"] > top:
        out.append(f"    ... {rep['n'] - top} more in the JSON document (check_points)")
    return out


def strip_test_lines(tests: list) -> list[str]:
    """The tests of a shift of each strip's GNSS centres (:func:`baarda.stats.gnss.strip_tests`)."""
    out = ["  GNSS strip tests (a shift common to a strip's centres, F80 eq. 10-12):"]
    for t in tests:
        nab = ", ".join(f"{number(a, '+.3g')} ± {number(b, '.2g')}" for a, b in zip(t["nabla"], t["nabla_sigma"]))
        out.append(printable(f"    strip {t['strip']:<10s} {len(t['images']):>3d} centres  q = {t['q']}  T = "
                             f"{number(t['T'], '.3f')} (crit {number(t['critical'], '.2f')})  R = {number(t['R'], '.3f')}"
                             f" (crit {number(t['critical_R'], '.2f')}){'  REJECTED' if t['rejected'] else ''};  "
                             f"∇ŝ = {nab} m"))
    return out


def extras_text(analysis, ex, top: int = 8) -> list[str]:
    """The lines ``baarda analyze`` prints after the summary for what ``ex``
    (:class:`baarda.analysis.Extras`) asked for, in the CLI's order."""
    out: list[str] = []
    if ex.snooping:
        out += snooping_lines(analysis)
    if ex.risk is not None:
        r = analysis.risk(*ex.risk, lambda_bar_tol=ex.risk_lambda_bar, coordinate_tol=ex.risk_coordinate)
        out += risk_lines(r, analysis.adjustment, top)
    for spec, both in ex.exchanges:
        out += exchange_lines(analysis.exchange(spec, both))
    if ex.sbase is not None or ex.criterion:
        out += [printable(x) for x in precision_lines(analysis, ex)]
    if ex.robust:
        out += robust_lines(analysis.robust(ex.robust))
    if ex.variance_components:
        out += variance_lines(analysis, ex.variance_components, ex.merge_groups)
    if ex.truth is not None:
        out.append(printable_lines(truth.text(analysis.planted(ex.truth))))
    return out


def summary_html(analysis) -> str:
    """A notebook's view of an analysis: the key numbers, the global test, the worst tests and the
    local defects, as an HTML table (every string escaped)."""
    s = analysis.summary()
    g = s["global_test"]
    esc = html.escape
    rel, adj = analysis.reliability, analysis.adjustment
    rows = [("observations / unknowns / redundancy", f"{s['n_observations']} / {s['n_unknowns']} / {s['dof']}"),
            ("datum", esc(str(s["datum"]))),
            ("σ̂0 (a posteriori / a priori)", f"{number(s['sigma0_aposteriori'])} / {number(s['sigma0_apriori'])}"),
            ("global test", f"{'passed' if g['passed'] else '<b>failed</b>'} ({esc(str(g['verdict']))})"),
            ("policy", f"α0 = {s['alpha0']:g}, β0 = {s['beta0']:g}{', B-method' if s['b_method'] else ''}, "
                       f"decisions on {'τ' if s['statistic'] == 'tau' else 'w'}, δ0 = {number(s['delta0'], '.3f')}"),
            ("rejected observations", f"{s['n_rejected']} (|{'τ' if s['statistic'] == 'tau' else 'w'}| > "
                                      f"{number(rel.critical, '.3f')})"),
            ("converged", f"{'yes' if s['converged'] else '<b>no</b>'} after {s['iterations']} iterations")]
    head = "".join(f"<tr><th style='text-align:left'>{k}</th><td style='text-align:left'>{v}</td></tr>" for k, v in rows)
    info = adj.problem.info
    stat = np.abs(np.nan_to_num(rel.statistic))
    worst = np.argsort(-stat, kind="stable")[:5]
    tests = "".join(
        f"<tr><td>{int(analysis.kept[i])}</td><td>{esc(str(info.kind[i]))}</td>"
        f"<td>{esc(' '.join(f'{a}={b}' for a, b in info.ids[i].items()))}</td>"
        f"<td>{number(rel.statistic[i], '.2f')}</td><td>{number(adj.r[i], '.3f')}</td>"
        f"<td>{number(rel.mdb[i], '.3g')}</td><td>{'rejected' if rel.rejected[i] else ''}</td></tr>" for i in worst)
    defects = "".join(f"<li>{esc(d.text())}</li>" for d in analysis.local_defects)
    name = esc(Path(analysis.name).name or "problem")
    return (f"<div class='baarda-analysis'><h4>baarda analysis of {name}</h4><table>{head}</table>"
            f"<p>largest tests</p><table><tr><th>#</th><th>kind</th><th>ids</th><th>statistic</th><th>r</th>"
            f"<th>MDB</th><th></th></tr>{tests}</table>"
            + (f"<p>local defects set aside</p><ul>{defects}</ul>" if defects else "") + "</div>")
