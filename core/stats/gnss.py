"""Hypotheses about the GNSS positions of projection centres and their tests: an error in one
centre (q = 3) and a shift common to one strip's centres (a cycle slip), F80 §2.2, eq. 10-12."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..model.bundle import gnss_rows, problem_of
from .hypotheses import common_error, selection


def h_gnss_centre(problem, image: str) -> sp.csc_matrix:
    """H of a 3-D error in the GNSS position of one projection centre (F80 §2.2, q = 3).

    Parameters
    ----------
    problem : baarda.model.problem.Problem or baarda.result.Adjustment
        A block with GNSS observations of its projection centres (or its adjustment).
    image : str
        The image whose centre is suspected.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 3, dimensionless: the selection of the centre's x, y, z rows; ∇s in metres.
    """
    problem = problem_of(problem)
    return selection(problem.n, gnss_rows(problem, image))


def h_gnss_strip(problem, images) -> sp.csc_matrix:
    """H of one 3-D shift common to the GNSS positions of ``images`` (a strip's cycle slip).

    F80 §2.2: H = (0 … I₃ … I₃ … 0)ᵀ. Not testable where the model estimates that strip's shift
    (H then lies in the column space of A): the shift's AP-group test is its test (§7.2).

    Parameters
    ----------
    problem : baarda.model.problem.Problem or baarda.result.Adjustment
        A block with GNSS observations of its projection centres (or its adjustment).
    images : iterable of str
        The images of the strip.

    Returns
    -------
    scipy.sparse.csc_matrix
        n × 3, dimensionless; ∇s (the shift) in metres.
    """
    problem = problem_of(problem)
    rows = np.array([gnss_rows(problem, im) for im in images], dtype=np.int64).reshape(-1, 3)
    return common_error(problem.n, [rows[:, a] for a in range(3)])


def strip_tests(adj, reliability) -> list[dict]:
    """The test of a shift of each strip's GNSS positions (a cycle slip; F80 §2.2, eq. 10-12).

    H = :func:`h_gnss_strip`, for the strips whose shift the model does not estimate (those have
    their AP-group test, F80 §7.2).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        An adjustment of a block with GNSS centres that carry a ``strip``.
    reliability : baarda.stats.reliability.Reliability
        Its tests under a policy (critical values; the decision on T, or on R when σ0 is a posteriori).

    Returns
    -------
    list of dict
        One per strip: ``strip``, ``images``, ``q``, ``T`` and ``critical`` (dimensionless), ``R``,
        ``critical_R``, ``rejected``, ``nabla`` and ``nabla_sigma`` (metres).
    """
    problem = adj.problem
    strips: dict = {}
    for k, ids in zip(problem.info.kind, problem.info.ids):
        if k == "gnss-x" and "strip" in ids:
            strips.setdefault(str(ids["strip"]), []).append(str(ids["image"]))
    out = []
    for s, images in strips.items():
        if f"{s}:gnss-shift" in problem.notes.ap_groups:
            continue
        h = reliability.test(h_gnss_strip(problem, images), label=f"GNSS strip {s}")
        rejected = h.rejected_R if reliability.policy.sigma0 == "aposteriori" else h.rejected_T
        out.append({"strip": s, "images": images, "q": int(h.q), "T": float(h.T), "critical": float(h.critical_T),
                    "R": float(h.R), "critical_R": float(h.critical_R), "rejected": bool(rejected),
                    "nabla": h.nabla.tolist(), "nabla_sigma": h.nabla_sigma.tolist()})
    return out
