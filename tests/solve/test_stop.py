"""The stopping rules of the adjustment (issue 29, item 4): the strict optimum by default, and
Ceres Solver's rule at its defaults (``stop="ceres"``: an accepted step changing vᵀPv by less
than 1e-6 relative ends the run) — the cost to 1e-6 of the optimum's, in fewer iterations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import baarda
from baarda.adjust import FUNCTION_TOL, Options, adjust
from baarda.analysis import SolverOptions
from baarda.build import read_problem
from baarda.errors import OptionError

from ..extdata import GAMA, require_extdata

DATA = Path(__file__).resolve().parents[2] / "data"


def _cases():
    yield read_problem(DATA / "demo-block.json")          # Levenberg-Marquardt (points eliminated)
    yield read_problem(DATA / "demo-imodel.json")
    yield read_problem(require_extdata(GAMA) / "jezerka-dir.gkf")     # Gauss-Newton (a network)


@pytest.mark.parametrize("k", range(3))
def test_ceres_rule_reaches_the_optimum_cost_to_its_tolerance(k):
    problem = list(_cases())[k]
    strict = adjust(problem, Options())
    ceres = adjust(problem, Options(stop="ceres"))
    assert strict.status in (1, 2, 3, 4) and ceres.status == 5 and ceres.converged
    assert ceres.iterations <= strict.iterations
    c_opt, c = float(strict.v @ (strict.P @ strict.v)), float(ceres.v @ (ceres.P @ ceres.v))
    assert c_opt <= c * (1 + 1e-9)                        # the optimum is the lower cost (to round-off)
    assert (c - c_opt) / c_opt <= FUNCTION_TOL            # and the rule's within its tolerance of it
    # it stopped at the first step that changed vᵀPv by less than the tolerance: the trace's
    # accepted costs before the last fell by more
    costs = [t[2] for t in ceres.trace]
    drops = [(a - b) / a for a, b in zip(costs, costs[1:]) if b < a]
    assert all(d >= FUNCTION_TOL for d in drops[:-1])


def test_default_is_the_strict_optimum_and_bad_stop_refused():
    assert Options().stop == "optimum" and SolverOptions().stop == "optimum"
    with pytest.raises(OptionError):
        SolverOptions(stop="fast")
    with pytest.raises(OptionError):
        adjust(read_problem(DATA / "demo-levelling.gkf"), Options(stop="fast"))
    a = baarda.analyze(DATA / "demo-block.json", solver=SolverOptions(stop="ceres"))
    assert a.adjustment.status == 5 and "Ceres" in a.adjustment.termination
    b = baarda.analyze(DATA / "demo-block.json")
    np.testing.assert_allclose(a.adjustment.w, b.adjustment.w, atol=1e-3)
