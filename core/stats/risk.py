"""Risk minimisation of the critical value (Molenaar 1984, §3.3).

An observation is erroneous with probability p. Rejecting a good one costs L1, accepting a bad
one costs L2. For a one-sided test value W ~ N(0, 1) under H0 and N(√λtol, 1) under Ha (an error
of the tolerance λtol), a critical value C has the risk

    r_C = (1 − p) α_C L1 + p (1 − β_C) L2,   α_C = 1 − Φ(C),  β_C = 1 − Φ(C − √λtol),

which is smallest at (M84 §3.3)

    C = (ln((1 − p)/p) + ln(L1/L2)) / √λtol + √λtol / 2.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize, stats

from ..errors import OptionError


def risk(C: float, p: float, L1: float, L2: float, lam_tol: float) -> float:
    """r_C for the critical value C (M84 §3.3)."""
    alpha = stats.norm.sf(C)
    beta = stats.norm.sf(C - np.sqrt(lam_tol))
    return float((1 - p) * alpha * L1 + p * (1 - beta) * L2)


def critical_value(p: float, L1: float, L2: float, lam_tol: float) -> float:
    """The C that minimises r_C (closed form, M84 §3.3)."""
    if not (0 < p < 1) or L1 <= 0 or L2 <= 0 or lam_tol <= 0:
        bad = next(k for k, ok in (("p", 0 < p < 1), ("L1", L1 > 0), ("L2", L2 > 0), ("lam_tol", lam_tol > 0)) if not ok)
        raise OptionError(bad, {"p": p, "L1": L1, "L2": L2, "lam_tol": lam_tol}[bad], (),
                          "need 0 < p < 1 and positive L1, L2, λtol")
    s = np.sqrt(lam_tol)
    return float((np.log((1 - p) / p) + np.log(L1 / L2)) / s + s / 2)


def critical_value_numeric(p: float, L1: float, L2: float, lam_tol: float) -> float:
    """The same C by minimising r_C numerically (a check of the closed form)."""
    s = np.sqrt(lam_tol)
    res = optimize.minimize_scalar(lambda c: risk(c, p, L1, L2, lam_tol), bounds=(-10 - s, 20 + s),
                                   method="bounded", options={"xatol": 1e-10})
    return float(res.x)
