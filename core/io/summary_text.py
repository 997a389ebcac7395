"""The results of an analysis as text for a terminal (``baarda analyze``, ``baarda test``): the
summary of the global test, the worst w-tests, the weakest redundancy numbers, the largest δ̄0, and
the tests of hypotheses (F80 §4.1, eq. 8, 10-17). Every string from a file goes through
:func:`baarda.text.printable`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..stats.ap_tests import ap_tests
from ..stats.reliability import reliability_of
from ..text import number, printable
from .results import sigma0_interval, summary


def text_summary(adj, top: int = 8, reliability=None) -> str:
    """A readable summary: global test, worst w-tests, weakest r_i, largest δ̄0 (the tests under
    ``reliability``, default ``reliability_of(adj)``)."""
    rel = reliability_of(adj) if reliability is None else reliability
    s = summary(adj, rel)
    g = s["global_test"]
    info = adj.problem.info
    lines = []
    title = s["title"] or Path(s["source"]).name
    lines.append(f"baarda analysis of {title}")
    lines.append(f"  observations {s['n_observations']}, unknowns {s['n_unknowns']}, datum defect "
                 f"{s['datum_defect']} ({s['datum']}), redundancy {s['dof']}")
    conv = "converged" if s["converged"] else "NOT converged"
    method = "Levenberg-Marquardt" if getattr(adj, "damped", False) else "Gauss-Newton"
    lines.append(f"  {method} {conv} in {s['iterations']} iterations"
                 + (f" ({s['termination']})" if s["termination"] else ""))
    if s.get("duplicate_keypoints"):
        dk = s["duplicate_keypoints"]
        lines.append(f"  {dk['points']} point(s) observed by two or more keypoints of one image: "
                     f"{dk['observations']} extra image point(s), each tested on its own")
    if s["far_points"]:
        far = s["far_points"]
        lines.append(f"  {len(far)} point(s) near infinity (depth hardly determined, not in the default "
                     f"S-base): {', '.join(far[:10])}{' ...' if len(far) > 10 else ''}")
    if s["local_defects"]:
        defects = adj.problem.notes.local_defects
        lines.append(f"  {len(defects)} local defect(s): not determined by the observations "
                     f"(--strict makes them an error):")
        for d in defects[:50]:
            lines.append(f"    {d.text()}")
        if len(defects) > 50:
            rest = ", ".join(f"{d.entity} {d.id}" for d in defects[50:])
            lines.append(f"    and {len(defects) - 50} more: {rest}")
    lines.append(global_test_text(g, s))
    lines.append(f"  {sigma0_text(g, s)}")
    stat = "τ" if s["statistic"] == "tau" else "w"
    lines.append(f"  α0 = {s['alpha0']}, β0 = {s['beta0']}: δ0 = {number(s['delta0'], '.3f')}, critical |w| = "
                 f"{number(s['critical_w'], '.3f')}, |τ| = {number(s['critical_tau'], '.3f')}; "
                 f"{s['n_rejected']} observation(s) rejected by {stat}")

    def label(i):
        ids = " ".join(f"{k}={v}" for k, v in info.ids[i].items())
        return f"#{i:<5d} {info.kind[i]:<15s} {ids}"

    w = np.nan_to_num(np.abs(adj.w), nan=-1.0)
    lines.append("  largest |w| (data snooping):")
    for i in np.argsort(-w)[:top]:
        flag = "  REJECTED" if rel.rejected[i] else ""
        wi = (f"{number(adj.w[i], '+8.3f'):>8s}" if np.isfinite(adj.w[i])
              else f"{'—':>8s}  ((P C_vv P)_ii = 0: not testable)")       # the criterion of uncontrolled
        lines.append(f"    {label(i):<48s} w = {wi}  r = {number(adj.r[i], '.3f')}{flag}")
    lines.append("  weakest redundancy numbers:")
    for i in np.argsort(adj.r)[:top]:
        lines.append(f"    {label(i):<48s} r = {number(adj.r[i], '.3f')}  u_k = {number(adj.u_k[i], '.3f')}  "
                     f"u_t = {number(adj.u_t[i], '.3f')}  MDB = {_unbounded(rel.mdb[i], '.4g')}")
    ext = np.where(np.isfinite(rel.external), rel.external, np.inf)
    lines.append("  largest external reliability δ̄0:")
    for i in np.argsort(-ext)[:top]:
        lines.append(f"    {label(i):<48s} δ̄0 = {_unbounded(rel.external[i], '.3f')}  λ̄ = "
                     f"{_unbounded(rel.external[i] ** 2, '.3g')}  r = {number(adj.r[i], '.3f')}")
    for a in (ap_tests(adj, rel.policy) if adj.problem.notes.ap_groups else []):
        what = (f"GNSS {a['group'][5:]} of strip {a['camera']}" if a["group"].startswith("gnss-")
                else f"additional parameters {a['group']} of camera {a['camera']}")
        lines.append(f"  {what} (F80 §7.2-7.3): T = "
                     f"{number(a['T'], '.3f')} (crit {number(a['critical'], '.2f')}, q = {a['q']}) → "
                     f"{'SIGNIFICANT' if a['significant'] else 'not significant'};  δ0′max = "
                     f"{_unbounded(a['delta0_prime_max'], '.3g')} (determinability), δ̄0max = "
                     f"{_unbounded(a['reliability_max'], '.3g')} (reliability, F80 eq. 17)")
    groups = rel.groups
    if groups:
        lines.append(f"  group tests (F80 eq. 10-14): {len(groups)} groups, {int(groups.rejected.sum())} rejected; "
                     f"largest T/critical:")
        ratio = np.where(groups.dimension > 0, groups.T / groups.critical, -1.0)
        for k in np.argsort(-np.nan_to_num(ratio, nan=-1.0))[:top].tolist():
            g = groups[k]
            first = int(g["members"][0])
            ids = {"gnss": "GNSS ", "imu-": "IMU "}.get(info.kind[first][:4], "") + " ".join(
                f"{a}={b}" for a, b in info.ids[first].items() if a != "component")
            nab = ", ".join(f"{number(a, '+.3g')} ± {number(b, '.2g')}" for a, b in zip(g["nabla"], g["nabla_sigma"]))
            axes = ", ".join(number(a, ".3g") for a in g["ellipse_axes"])
            lines.append(f"    group {g['group']:<6d} {ids:<34s} q = {g['dimension']}  T = "
                         f"{number(g['T'], '.3f')} (crit {number(g['critical'], '.2f')})  R = {number(g['R'], '.3f')} "
                         f"(crit {number(g['critical_R'], '.2f')}){'  REJECTED' if g['rejected'] else ''}")
            lines.append(f"    {'':13s}∇ŝ = {nab};  lower-bound semi-axes {axes};  δ0′max = "
                         f"{_unbounded(g['delta0_prime_max'], '.3g')}")
    return "\n".join(printable(line) for line in lines)     # ids and titles come from the file


def global_test_text(g: dict, s: dict) -> str:
    """The global test in one line: which test, its α, the critical value(s), the verdict (F80
    §4.1, §7.2); :func:`sigma0_text` says σ̂0 with its confidence interval."""
    if g["passed"] is None:
        return "  global test: not applicable (no redundancy)"
    T = g["statistic"]              # the relation to the bound(s) as it is: "> bound" when failed
    if g["test"] == "two-sided":
        rel = "in" if g["lower"] <= T <= g["upper"] else "not in"
        how = (f"two-sided at conf-pr {number(g['conf_pr'], '.3g')} (gama-local): vᵀPv = {number(T)} "
               f"{rel} [{number(g['lower'])}, {number(g['upper'])}] (χ², r = {g['dof']})")
    else:
        rel = "≤" if T <= g["upper"] else ">"
        what = (f"one-sided (F80 §4.1) at α = {number(100 * g['alpha'], '.3g')} %" if g["test"] == "one-sided" else
                f"one-sided at the B-method's α_{g['dof']} = {number(100 * g['alpha'], '.3g')} % (F80 §7.2)")
        how = f"{what}: vᵀPv = {number(T)} {rel} {number(g['upper'])} (χ², r = {g['dof']})"
    verdict = "passed" if g["passed"] else "FAILED"
    if g["side"] is not None:
        verdict += f": {g['verdict']}" + (", not an error in the data" if g["side"] == "low" else "")
    return f"  global test {how} → {verdict}"


def sigma0_text(g: dict, s: dict) -> str:
    """"σ0 a priori 1, a posteriori σ̂0 = 1.01, 95 % interval [0.99, 1.03]: σ0 a priori inside":
    what the global test says about the precision, in the numbers' own terms."""
    iv = (s.get("global_test") or {}).get("sigma0_interval") or sigma0_interval(g, s["sigma0_apriori"] or 1.0)
    post, pri = s["sigma0_aposteriori"], s["sigma0_apriori"]
    if not iv or iv["lower"] is None or iv["upper"] is None:
        return f"σ0 a priori {number(pri)}, a posteriori {number(post)}"
    where = ("below it (σ̂0 significantly larger)" if pri < iv["lower"] else
             "above it (σ̂0 significantly smaller)" if pri > iv["upper"] else "inside it")
    return (f"σ0 a priori {number(pri)}, a posteriori σ̂0 = {number(post, '.4g')}, "
            f"{number(100 * iv['confidence'], '.3g')} % interval [{number(iv['lower'], '.4g')}, "
            f"{number(iv['upper'], '.4g')}]: σ0 a priori {where}")


def _unbounded(x, spec: str) -> str:
    """An MDB or δ̄0 for printing: ∞ for an uncontrolled observation (r = 0), never inf/nan."""
    return "∞ (uncontrolled)" if x is not None and np.isposinf(x) else number(x, spec)


def _vector(values, spec: str = "+.4g") -> str:
    return "(" + ", ".join(number(v, spec) for v in values) + ")"


def tests_text(adj, reliability, tests: list[dict], top: int = 10) -> str:
    """The text of ``baarda test``: per hypothesis (dicts of
    :func:`baarda.stats.analyses.hypothesis_analysis`, or ``ap_test`` ones) T, R, the decision,
    ∇ŝ ± σ∇ŝ, the lower-bound ellipse, δ0′max, δ̄0max with λ̄ and the ``top`` largest point
    shifts of the deformation field (F80 eq. 10-18)."""
    s = summary(adj, reliability)
    lines = [f"baarda test of {s['title'] or Path(s['source']).name}: redundancy {s['dof']}, α0 = {s['alpha0']}, "
             f"β0 = {s['beta0']}{', B-method' if s['b_method'] else ''}, σ0 "
             f"{'a posteriori (decisions on R)' if s['statistic'] == 'tau' else 'a priori (decisions on T)'}"]
    for t in tests:
        lines.append(f"hypothesis {t['hypothesis']}")
        if "ap_test" in t:
            a = t["ap_test"]
            lines.append(f"  estimated AP group (F80 §7.2-7.3): T = {number(a['T'], '.3f')} (critical "
                         f"{number(a['critical'], '.3f')}, q = {a['q']}, α = {number(a['alpha'], '.3g')}) → "
                         f"{'SIGNIFICANT' if a['significant'] else 'not significant'}")
            lines.append(f"  ŝ = {_vector(a['estimate'])} ± {_vector(a['sigma'], '.2g')}")
            lines.append(f"  δ0′max = {_unbounded(a['delta0_prime_max'], '.4g')} (determinability, F80 eq. 14), "
                         f"δ̄0max = {_unbounded(a['reliability_max'], '.4g')} (reliability, F80 eq. 17)")
            continue
        rows = t["rows"]
        lines.append(f"  q = {t['dimension']}, observations {', '.join(f'#{i}' for i in rows[:12])}"
                     f"{' ...' if len(rows) > 12 else ''}")
        decision = "REJECTED" if t["rejected"] else "accepted"
        lines.append(f"  T = {number(t['T'], '.4f')} (critical {number(t['critical_T'], '.4f')}, α = "
                     f"{number(t['alpha'], '.3g')}), R = {number(t['R'], '.4f')} (critical "
                     f"{number(t['critical_R'], '.4f')}) → {decision} on {t['decided_on']} (F80 eq. 10-12)")
        nab = ", ".join(f"{number(a, '+.4g')} ± {number(b, '.2g')}" for a, b in zip(t["nabla"], t["nabla_sigma"]))
        lines.append(f"  ∇ŝ = {nab}")
        if t["dimension"] == 0:
            lines.append("  the test sees no error of this hypothesis (q = 0): no lower bound, no δ̄0")
            continue
        axes = "; ".join(f"{number(a, '.4g')} along {_vector(d, '+.3f')}"
                         for a, d in zip(t["ellipse_axes"], t["ellipse_directions"]))
        if t["dimension"] == 1:
            lines.append(f"  lower bound (F80 eq. 13, δ0 = {number(t['delta0'], '.3f')}): |∇0s| = {axes}")
        else:
            lines.append(f"  lower-bound {'ellipse' if t['dimension'] == 2 else 'ellipsoid'} (F80 eq. 13, δ0 = "
                         f"{number(t['delta0'], '.3f')}): semi-axes {axes}")
        q_cols = len(t["nabla"])
        if t["dimension"] < q_cols:
            lines.append(f"  δ0′max = ∞: the test sees {t['dimension']} of {q_cols} directions; an error in direction "
                         f"{_vector(t['weakest'], '+.3f')} is not detectable at all (F80 eq. 14); δ̄0 below is over "
                         f"the directions seen")
        else:
            lines.append(f"  δ0′max = {number(t['delta0_prime_max'], '.4g')} in direction {_vector(t['weakest'], '+.3f')} "
                         f"(F80 eq. 14)")
        lines.append(f"  δ̄0max = {_unbounded(t['delta_bar0_max'], '.4g')} (λ̄ = {_unbounded(t['lambda_bar_max'], '.4g')}) "
                     f"in direction {_vector(t['delta_bar0_direction'], '+.3f')} (F80 eq. 17): an undetected error "
                     f"moves no function of the coordinates by more than {_unbounded(t['delta_bar0_max'], '.3g')} σ_f "
                     f"(eq. 18)")
        d = t["deformation"]
        pts = d["points"]
        lines.append(f"  deformation by that undetectable error ∇0s = {_vector(d['nabla0_s'])} (F80 eq. 16), "
                     f"{min(top, len(pts))} largest of {len(pts)} points:")
        for p in pts[:top]:
            lines.append(f"    {p['id']:<12s} dx = {number(p['dx'], '+.3e')}  dy = {number(p['dy'], '+.3e')}  "
                         f"dz = {number(p['dz'], '+.3e')}  |d| = {number(p['norm'], '.3e')}")
    return "\n".join(printable(line) for line in lines)
