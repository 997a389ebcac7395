"""The steps of the adjustment's loop (baarda.iteration.Iteration), one at a time: the damping
of a step, the gauge of a free block's damped and undamped steps, the trust region's verdicts,
the end game, Gauss-Newton's divergence test, the termination statuses, a singular system
after the start — and the loop of these steps is baarda.adjust.adjust, bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baarda import iteration as iteration_mod
from baarda.adjust import Options, adjust
from baarda.build import read_problem
from baarda.errors import DatumDefectError
from baarda.iteration import (DIVERGENCE, INITIAL_RADIUS, MIN_RADIUS, MIN_RELATIVE_DECREASE, STATUS, Iteration,
                              Trial)
from baarda.model.bundle import build_block_problem
from baarda.simulate import simulate_block

DEMO = Path(__file__).resolve().parents[1] / "data" / "demo-block.json"


def _free_block():
    block, _ = simulate_block(strips=2, images_per_strip=5, seed=4, datum="free")
    return build_block_problem(block)


def _trial(run, lam, cost, rho, step=1.0):
    """A made-up trial point (only what the verdicts read)."""
    return Trial(lam=lam, dx=np.zeros(run.keep.size), step=step, x=run.x.copy(), f=run.f, v=run.v,
                 cost=cost, rho=rho)


def _loop(run, max_iter):
    """The loop of baarda.adjust.adjust, step by step."""
    for it in range(1, max_iter + 1):
        lam = run.begin(it)
        trial = run.solve(lam)
        if trial is not None and run.judge(trial):
            run.move(trial)
            if run.converged(trial):
                break
        elif run.status:
            break
    run.release()
    return run.result()


def test_the_loop_of_steps_is_adjust():
    """The steps driven by hand give adjust()'s result, bit for bit (a network solved by the
    generic factor and a free block through the reduced camera system)."""
    for problem, options in ((read_problem(str(DEMO)), Options()), (_free_block(), Options(solver="schur"))):
        ref = adjust(problem, options)
        got = _loop(Iteration(problem, options), options.max_iter)
        assert np.array_equal(got.x, ref.x)
        assert got.iterations == ref.iterations and got.status == ref.status and got.history == ref.history
        assert got.vPv == ref.vPv and got.solver == ref.solver


def test_first_step_undamped_then_the_trust_region():
    """A block whose points are eliminated is damped from the second step on, λ = 1/μ0; the
    first step is undamped (a singular system there is a defect, not something to damp)."""
    run = Iteration(_free_block(), Options(solver="schur"))
    assert run.use_schur and run.damped
    assert run.begin(1) == 0.0
    assert run.begin(2) == 1.0 / INITIAL_RADIUS
    run.endgame = True
    assert run.begin(3) == 0.0                   # the end game is undamped
    net = Iteration(read_problem(str(DEMO)), Options())
    assert not net.damped and net.begin(2) == 0.0   # Gauss-Newton for a network


def test_free_block_damped_steps_solve_for_the_gauge_too():
    """A free block's damped steps solve for every unknown (the damping makes N + λD regular);
    its undamped steps hold the datum's coordinates again."""
    run = Iteration(_free_block(), Options(solver="schur"))
    assert run.plan.defect > 0
    held = run.keep.size
    run.begin(2)
    assert run.keep.size == run.free.size > held and run.Ar.shape[1] == run.free.size
    assert run.st.matches(run.Ar)
    run.begin(1)                                  # undamped: back to the held gauge
    assert run.keep is run.keep_all and run.Ar.shape[1] == held and run.st.matches(run.Ar)


def test_solve_gives_the_trial_point_of_the_step():
    """solve: the trial point is x + Δx over the unknowns solved for, vᵀPv there, the gain ratio
    of gain_ratio and one trace entry."""
    run = Iteration(read_problem(str(DEMO)), Options())
    x0, cost0 = run.x.copy(), run.cost
    t = run.solve(run.begin(1))
    assert np.array_equal(t.x[run.free[run.keep]], x0[run.free[run.keep]] + t.dx)
    v = run.problem.misclosure(run.lin.values(t.x))
    assert t.cost == float(v @ (run.P @ v)) and t.cost < cost0
    assert run.trace == [(0.0, t.step, t.cost, t.rho)]
    assert run.judge(t)
    run.move(t)
    assert np.array_equal(run.x, t.x) and run.cost == t.cost and t.rel_drop == (cost0 - t.cost) / cost0


def test_rejected_damped_step_shrinks_the_trust_region():
    run = Iteration(read_problem(str(DEMO)), Options())
    run.it, mu = 2, run.mu
    assert not run.judge(_trial(run, 1e-4, 2.0 * run.cost, MIN_RELATIVE_DECREASE / 2))
    assert (run.mu, run.decrease) == (mu / 2.0, 4.0) and run.history == [1.0] and run.status == 0
    assert run.judge(_trial(run, 1e-4, 0.5 * run.cost, 1.0))
    assert (run.mu, run.decrease) == (3.0 * mu / 2.0, 2.0)


def test_collapsed_trust_region_stops_with_status_minus_one():
    run = Iteration(read_problem(str(DEMO)), Options())
    run.it, run.mu = 2, 1.5 * MIN_RADIUS
    assert not run.judge(_trial(run, 1e30, 2.0 * run.cost, -1.0))
    assert run.status == -1 and STATUS[-1].startswith("not converged")


def test_damped_step_at_round_off_starts_the_end_game():
    """vᵀPv unchanged to round-off: the gain ratio is noise; the undamped end game decides."""
    run = Iteration(read_problem(str(DEMO)), Options())
    run.it, mu = 2, run.mu
    assert not run.judge(_trial(run, 1e-4, run.cost * (1 + 1e-12), -5.0))
    assert run.endgame and run.mu == mu and run.status == 0


def test_gauss_newton_divergence_switches_to_levenberg_marquardt():
    run = Iteration(read_problem(str(DEMO)), Options())
    run.it = 2
    assert run.judge(_trial(run, 0.0, 1.2 * run.cost, -1.0))               # a little worse: taken
    assert not run.damped
    assert not run.judge(_trial(run, 0.0, 1.01 * DIVERGENCE * run.cost, -1.0))
    assert run.damped and run.ever_damped


def test_termination_after_undamped_and_damped_steps():
    run = Iteration(read_problem(str(DEMO)), Options(tol=1e-9))
    t = _trial(run, 0.0, run.cost, 1.0, step=1e-3)
    assert not run.converged(t) and run.last_undamped == 1e-3
    assert run.converged(_trial(run, 0.0, run.cost, 1.0, step=1e-10)) and run.status == 1
    run.status, run.n_far = 0, 3
    assert run.converged(_trial(run, 0.0, run.cost, 1.0, step=1e-10)) and run.status == 4
    # damped steps at the function tolerance: the end game at once, after a failed one every 2nd
    run = Iteration(read_problem(str(DEMO)), Options())
    quiet = _trial(run, 1e-4, run.cost, 1.0, step=0.1)
    assert not run.converged(quiet) and run.endgame
    run.endgame, run.failed = False, 1
    assert not run.converged(quiet) and not run.endgame and run.quiet == 1
    assert not run.converged(quiet) and run.endgame and run.quiet == 0


def test_singular_system_after_the_start_is_damped_more(monkeypatch):
    """A singular N at the first step is a defect (DatumDefectError); later, the step is tried
    again from the same point with more damping."""
    run = Iteration(read_problem(str(DEMO)), Options())

    def singular(*a, **k):
        raise DatumDefectError(1, ["point 1.x"], "singular")

    monkeypatch.setattr(iteration_mod, "factor_step", singular)
    with pytest.raises(DatumDefectError):
        run.solve(run.begin(1))
    x = run.x.copy()
    assert run.solve(run.begin(2)) is None
    assert run.damped and run.history == [float("inf")] and (run.mu, run.decrease) == (INITIAL_RADIUS, 2.0)
    lam = run.begin(3)
    assert lam == 1.0 / INITIAL_RADIUS and run.solve(lam) is None
    assert (run.mu, run.decrease) == (INITIAL_RADIUS / 2.0, 4.0) and np.array_equal(run.x, x)


def test_release_frees_the_iterations_layouts_then_the_result():
    run = Iteration(_free_block(), Options(solver="schur"))
    run.begin(2)                                   # the free gauge's layout
    run.release()
    assert run.keep is run.keep_all and run.A is not None and run.st is None and run.lin._key is None
    adj = run.result()
    assert adj.solver == "schur" and adj.schur_structure.matches(adj.Ar) and adj.iterations == 2
    assert adj.status == 0 and not adj.converged and adj.damped
