"""The adjustment loop: Levenberg-Marquardt's trust region, termination statuses, the end game,
``--max-iter`` and the exit status of a run that does not converge, the compiled projection."""

from __future__ import annotations

import csv
import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from baarda import datum
from baarda.adjust import STATUS, Options, adjust, gain_ratio, update_radius
from baarda.build import read_problem
from baarda.cli import NOT_CONVERGED, main

from tests.extdata import EXTDATA, require_extdata

BAL = EXTDATA / "bal"
DEMO = str(Path(__file__).resolve().parents[1] / "data" / "demo-block.json")
adjust_mod = importlib.import_module("baarda.adjust")
iteration_mod = importlib.import_module("baarda.iteration")


def test_radius_update_is_ceres_rule():
    """Ceres' LevenbergMarquardtStrategy: accepted, μ / max(1/3, 1 − (2ρ − 1)³) and the decrease
    factor back to 2; rejected, μ / factor and the factor doubles (values by hand)."""
    assert update_radius(1e4, 2.0, 1.0, True) == (3e4, 2.0)              # ρ = 1: × 3
    assert update_radius(1e4, 8.0, 0.5, True) == (1e4, 2.0)              # ρ = ½: unchanged
    mu, dec = update_radius(1e4, 2.0, 0.25, True)
    assert mu == pytest.approx(1e4 / 1.125) and dec == 2.0
    mu, dec = update_radius(1e4, 2.0, -1.0, False)
    assert (mu, dec) == (5e3, 4.0)
    mu, dec = update_radius(mu, dec, -1.0, False)
    assert (mu, dec) == (1250.0, 8.0)
    assert update_radius(1e16, 2.0, 1.0, True)[0] == adjust_mod.MAX_RADIUS


def test_gain_ratio_of_a_linear_model_is_one():
    """For a linear model the decrease the damped step predicts is the decrease it achieves,
    whatever the damping: ρ = 1 (checks the predicted-decrease formula)."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(30, 5))
    p = rng.uniform(0.5, 2.0, 30)
    v = rng.normal(size=30)
    N = A.T @ (p[:, None] * A)
    g = -A.T @ (p * v)
    cost = float(v @ (p * v))
    for lam in (0.0, 1e-3, 1.0, 1e3):
        dx = np.linalg.solve(N + lam * np.diag(np.diag(N)), g)
        vn = v + A @ dx
        rho = gain_ratio(cost, float(vn @ (p * vn)), dx, g, lam, np.diag(N))
        assert rho == pytest.approx(1.0, abs=1e-9)


def test_every_status_has_a_message_and_converged_follows_it():
    assert all(isinstance(m, str) and m for m in STATUS.values())
    assert all(m.startswith("converged") for k, m in STATUS.items() if k > 0)
    assert all(m.startswith("not converged") for k, m in STATUS.items() if k <= 0)
    problem = read_problem(DEMO)
    one = adjust(problem, Options(max_iter=1))
    assert not one.converged and one.status == 0 and one.termination == STATUS[0]
    full = adjust(problem)
    assert full.converged and full.status > 0 and full.iterations > 1
    # the converged result is the fixed point: one more Gauss-Newton step from it is round-off
    again = adjust(problem, Options(method="gauss-newton", max_iter=1), x0=full.x)
    assert again.history[0] < 1e-6
    with pytest.raises(ValueError):
        adjust(problem, Options(max_iter=0))
    with pytest.raises(ValueError):
        adjust(problem, Options(method="newton"))


def test_not_converged_run_exits_4_and_marks_json_csv_report(tmp_path, capsys):
    out, csv_dir = tmp_path / "r.json", tmp_path / "csv"
    code = main(["analyze", DEMO, "--max-iter", "1", "--quiet", "--json", str(out), "--csv", str(csv_dir)])
    assert code == NOT_CONVERGED == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "NOT converged after 1 iterations" in err[0]
    s = json.loads(out.read_text())["summary"]
    assert s["converged"] is False and s["termination"] == STATUS[0]
    for name in ("observations", "points", "groups"):
        with (csv_dir / f"{name}.csv").open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert all(r["adjustment"] == "NOT converged" for r in rows)
    html = tmp_path / "r.html"
    code = main(["report", DEMO, "--max-iter", "1", "--quiet", "--out", str(html)])
    assert code == 4 and "class='notconv'><b>NOT converged</b>" in html.read_text()
    # converged: exit 0, no mark
    capsys.readouterr()
    assert main(["analyze", DEMO, "--quiet", "--json", str(out), "--csv", str(csv_dir)]) == 0
    assert capsys.readouterr().err == ""
    s = json.loads(out.read_text())["summary"]
    assert s["converged"] is True and s["termination"].startswith("converged")
    assert "adjustment" not in (csv_dir / "points.csv").read_text().splitlines()[0].split(",")


def test_max_iter_must_be_positive(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["analyze", DEMO, "--max-iter", "0"])
    assert exc.value.code == 2


def test_compiled_projection_equals_the_numpy_formulas():
    """The numba kernel of the BAL projection gives the numbers of the vectorised numpy
    reference, at the start values and at a perturbed point."""
    pytest.importorskip("numba")
    require_extdata(BAL)
    problem = read_problem(BAL / "problem-49-7776-pre.txt")
    s = problem.sets[0]
    x = problem.params.x0.astype(float)
    rng = np.random.default_rng(1)
    for xx in (x, x + 1e-3 * rng.normal(size=x.size) * np.maximum(np.abs(x), 1e-3)):
        ref, got = s.evaluate_numpy(xx), s.evaluate(xx)
        assert np.array_equal(ref[1], got[1]) and np.array_equal(ref[2], got[2])
        for a, b in ((ref[0], got[0]), (ref[3], got[3])):
            assert np.allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(a).max())


def test_trafalgar_reaches_ceres_optimum_in_cost_and_parameters():
    """BAL Trafalgar-21 (read compressed, as distributed) converges to pycolmap's Ceres optimum
    ½Σr² = 30,378.635796 (extdata README) within 1e-6 relative; the free block's S-base
    condition Eᵀ(x̂ − x0) = 0 holds (the S-transformation of the increments, M84 §2), and one
    more undamped step from x̂ is round-off (the parameters are at the fixed point)."""
    require_extdata(BAL)
    problem = read_problem(BAL / "problem-21-11315-pre.txt.bz2")
    adj = adjust(problem)
    assert adj.converged and adj.status in (1, 2, 3), adj.termination
    cost = 0.5 * float(adj.v @ adj.v)
    assert abs(cost - 30378.635796) / 30378.635796 < 1e-6
    assert adj.plan.defect == 7
    free = problem.params.free
    x0 = problem.params.x0.astype(float)
    shift = adj.x[free] - x0[free]
    # the S-base of the iterations: the similarities at the start values
    _, J0 = problem.evaluate(x0)
    plan0 = datum.plan(problem, x0, J0[:, free].tocsr(), adj.P, free)
    assert np.abs(plan0.K @ shift).max() < 1e-9 * np.abs(shift).max()
    again = adjust(problem, Options(method="gauss-newton", max_iter=1), x0=adj.x)
    assert again.history[0] < 1e-4


def _step_factor_takes_the_reference_steps(st, Ar, P, v, monkeypatch):
    """StepFactor against SchurFactor (square-root elimination), damped and undamped: the same
    diag(N) and steps; and the same numbers, bit for bit, whether the factor keeps every E_c for
    its solves or makes them again from the design matrix (schur.factor.KEEP_E_BYTES)."""
    from baarda.solve import schur

    assert schur.StepFactor.applicable(st, P)
    g = -(Ar.T @ (P @ v))
    for lam in (0.0, 1e-6, 1e-2):
        ref, fast = schur.SchurFactor(st, Ar, P, damping=lam), schur.StepFactor(st, Ar, P, damping=lam)
        assert fast._Et.shape[0] == st.cl_sn.shape[0]          # small blocks keep E_c
        assert np.allclose(fast.diagonal, ref.diagonal, rtol=1e-12, atol=0)
        d = np.sqrt(ref.diagonal)
        x_ref, x_fast = ref.solve(g) * d, fast.solve(g) * d        # in conditional σ
        assert np.abs(x_fast - x_ref).max() <= 1e-6 * max(np.abs(x_ref).max(), 1.0)
        with monkeypatch.context() as m:
            m.setattr(schur.factor, "KEEP_E_BYTES", 0)
            again = schur.StepFactor(st, Ar, P, damping=lam)
        assert again._Et.shape[0] == 0
        assert np.array_equal(again.solve(g), fast.solve(g))


def test_step_factor_equals_schur_factor(monkeypatch):
    """The fused compiled factor of the iterations (schur.StepFactor) takes the steps of the
    reference SchurFactor on BAL Ladybug (far points: 3 × 3 blocks of condition 1e12) after a
    few iterations."""
    pytest.importorskip("numba")

    require_extdata(BAL)
    problem = read_problem(BAL / "problem-49-7776-pre.txt")
    adj = adjust(problem, Options(max_iter=5))
    _step_factor_takes_the_reference_steps(adj.schur_structure, adj.Ar, adj.P, adj.v, monkeypatch)
    # the numpy backend keeps the reference factor for the steps: same result
    a = adjust(problem, Options(max_iter=8, backend="numpy"))
    b = adjust(problem, Options(max_iter=8))
    assert a.iterations == b.iterations
    assert abs(a.vPv - b.vPv) <= 1e-9 * a.vPv


def test_step_factor_with_duplicate_keypoints(tmp_path, monkeypatch):
    """Two keypoints of one point in one image: a pair of clusters of one point on the same
    diagonal block of S (the pair's product and its transpose both go there)."""
    pytest.importorskip("numba")
    from tests.io.test_colmap import duplicate_model

    txt, _, _, added = duplicate_model(tmp_path)
    problem = read_problem(txt)
    adj = adjust(problem, Options(solver="schur", max_iter=3))
    st = adj.schur_structure
    g = st.cl_sn[:, 0]
    same = [e for e in range(st.ent_size.size)
            if np.unique(g[st.ent_ptr[e]:st.ent_ptr[e + 1]]).size < st.ent_ptr[e + 1] - st.ent_ptr[e]]
    assert len(same) == len(added)
    _step_factor_takes_the_reference_steps(st, adj.Ar, adj.P, adj.v, monkeypatch)


def _two_view_bundler(path, src):
    """Balbianello (Bundler v0.3, extdata) cut to its first two views: the other cameras all
    zeros (as Bundler writes cameras it did not reconstruct), points seen by both views kept."""
    lines = src.read_text().split("\n")
    ncam, npt = map(int, lines[1].split())
    out = []
    for i in range(ncam):
        out += lines[2 + 5 * i: 7 + 5 * i] if i < 2 else ["0 0 0"] * 5
    rest, pts = lines[2 + 5 * ncam:], []
    for k in range(npt):
        view = rest[3 * k + 2].split()
        v = [view[1 + 4 * j: 5 + 4 * j] for j in range(int(view[0]))]
        v = [e for e in v if int(e[0]) < 2]
        if len(v) == 2:
            pts += [rest[3 * k], rest[3 * k + 1], " ".join(["2"] + [" ".join(e) for e in v])]
    path.write_text("\n".join(["# Bundle file v0.3", f"{ncam} {len(pts) // 3}"] + out + pts) + "\n")


def test_two_view_bundler_block_with_zero_cameras_converges(tmp_path):
    """A two-view Bundler block (f, k1, k2 of both cameras free: a long curved valley) stopped
    unconverged; now the trust region and the end game reach the fixed point: converged, and
    one more undamped step from it is round-off."""
    require_extdata(BAL)
    path = tmp_path / "two-view.out"
    _two_view_bundler(path, BAL / "Balbianello.out")
    problem = read_problem(path)
    adj = adjust(problem, Options())              # the default iteration limit suffices
    assert adj.converged, adj.termination
    again = adjust(problem, Options(method="gauss-newton", max_iter=1), x0=adj.x)
    assert again.history[0] < 1e-4
    assert main(["analyze", str(path), "--quiet"]) == 0


def test_gauge_switches_reuse_small_layouts(monkeypatch):
    """A free block switches between the free gauge of its damped steps and the held gauge of
    its undamped ones: the held gauge's elimination layout is kept, not analysed again
    (KEEP_LAYOUTS_BYTES), and the adjustment is the same, bit for bit, as with one layout at a
    time."""
    from baarda.model.bundle import build_block_problem
    from baarda.simulate import simulate_block

    block, _ = simulate_block(strips=2, images_per_strip=5, seed=4, datum="free")
    problem = build_block_problem(block)
    calls = []
    real = iteration_mod.schur_structure

    def counted(*a, **k):
        calls.append(a[2].size)
        return real(*a, **k)

    monkeypatch.setattr(iteration_mod, "schur_structure", counted)
    x0 = problem.params.x0.copy()
    x0[problem.params.kind == "k"] += 0.5                 # far enough from the solution to damp
    kept = adjust(problem, Options(solver="schur"), x0=x0)
    n_kept = len(calls)
    calls.clear()
    monkeypatch.setattr(iteration_mod, "KEEP_LAYOUTS_BYTES", 0)
    one = adjust(problem, Options(solver="schur"), x0=x0)
    assert kept.damped and len(set(calls)) == 2                 # both gauges were used
    assert n_kept < len(calls)
    assert kept.iterations == one.iterations and np.array_equal(kept.x, one.x)
    assert kept.schur_structure is not None and kept.schur_structure.matches(kept.Ar)
