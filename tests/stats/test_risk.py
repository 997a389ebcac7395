"""Risk minimisation applied to the data (M84 §3.3): λtol, C and r_C per observation from a tolerance
on the coordinates, against the closed form and a dense computation of H_k (F80 eq. 16) and of the
coordinate effect Σ AᵀP e_i (F80 §6)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tests.oracle import dense, normal_inverse, pcp, reduced_design

from baarda.cli import main
from baarda.errors import OptionError
from baarda.stats import risk
from baarda.stats.reliability import reliability_of

DATA = Path(__file__).resolve().parents[2] / "data"
P_ERR, L1, L2 = 0.01, 1.0, 10.0


@pytest.fixture(scope="module")
def demo(demo_problem, demo_adjustment):
    return demo_problem, demo_adjustment, dense(demo_adjustment), pcp(demo_adjustment)


def _controlled(adj):
    return np.flatnonzero(adj.r > 0.05)


def test_general_purpose_tolerance_against_dense(demo):
    """λtol,i = λ̄tol (P C_vv P)_ii / (P H_k P)_ii with H_k = C̄ (C̄ᵀPC̄)⁻¹ C̄ᵀ (F80 eq. 16), dense; C_i the
    closed form and the numeric minimum of r_C; r_C the risk at C_i."""
    p, adj, d, S = demo
    kind = p.params.kind[p.params.free][adj.keep]
    t, k = np.flatnonzero(kind == "t"), np.flatnonzero(kind != "t")
    Cb = reduced_design(d.A, d.P, t, k)
    PC = d.P @ Cb
    PHkP = np.einsum("ij,ij->i", PC @ np.linalg.inv(Cb.T @ PC), PC)      # diag(P C̄ Q_kk C̄ᵀ P)
    res = risk.per_observation(adj, P_ERR, L1, L2, lambda_bar_tol=25.0)
    i = _controlled(adj)
    assert res.lam_tol[i] == pytest.approx(25.0 * np.diag(S)[i] / PHkP[i], rel=1e-6)
    for j in i[:: max(1, i.size // 6)]:
        C = risk.critical_value(P_ERR, L1, L2, res.lam_tol[j])
        assert res.C[j] == pytest.approx(C, rel=1e-12)
        assert res.C[j] == pytest.approx(risk.critical_value_numeric(P_ERR, L1, L2, res.lam_tol[j]), abs=1e-6)
        assert res.r_C[j] == pytest.approx(risk.risk(C, P_ERR, L1, L2, res.lam_tol[j]), rel=1e-12)
    assert np.array_equal(res.rejected, np.abs(np.nan_to_num(adj.w)) > res.C)


def test_coordinate_tolerance_against_dense(demo):
    """∇tol l_i = t / max_k |(N⁻¹AᵀP e_i)_k| over the point coordinates (dense); an error of that size in
    l_i moves the coordinates by at most t, reached."""
    p, adj, d, S = demo
    t = 0.1
    res = risk.per_observation(adj, P_ERR, L1, L2, coordinate_tol=t)
    kind = p.params.kind[p.params.free][adj.keep]
    coord = np.flatnonzero(kind != "t")
    G = normal_inverse(d.A, d.P) @ d.A.T @ d.P            # column i: the effect of a unit error in l_i
    i = _controlled(adj)
    effect = np.abs(G[coord][:, i]).max(axis=0)
    assert res.lam_tol[i] == pytest.approx((t / effect) ** 2 * np.diag(S)[i], rel=1e-6)
    j = i[0]
    tol_l = np.sqrt(res.lam_tol[j] / np.diag(S)[j])
    assert np.abs(G[coord, j] * tol_l).max() == pytest.approx(t, rel=1e-6)
    # the 20σ image error of the demo (obs 301) is rejected under both rules here
    assert res.rejected[301] and reliability_of(adj).rejected[301]


def test_arguments(demo):
    _, adj, _, _ = demo
    with pytest.raises(OptionError):
        risk.per_observation(adj, P_ERR, L1, L2)
    with pytest.raises(OptionError):
        risk.per_observation(adj, P_ERR, L1, L2, lambda_bar_tol=1.0, coordinate_tol=1.0)
    with pytest.raises(OptionError) as info:
        risk.per_observation(adj, 1.5, L1, L2, lambda_bar_tol=1.0)
    assert info.value.option == "p"


def test_cli_risk(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["analyze", str(DATA / "demo-block.json"), "--risk", "0.01,1,10", "--risk-lambda-bar", "25",
                 "--json", str(out), "--top", "3"]) == 0
    assert "risk minimisation (M84 §3.3" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["risk"]["tolerance"] == "lambda_bar=25"
    o = doc["observations"][301]["risk"]
    assert o["C"] == pytest.approx(risk.critical_value(0.01, 1, 10, o["lam_tol"]), rel=1e-12)
    assert doc["risk"]["rejected"] == sum(d["risk"]["rejected"] for d in doc["observations"])
    for args in (["--risk", "0.01,1"], ["--risk-coordinate", "0.1"], ["--risk", "0.01,1,10"],
                 ["--risk", "0.01,1,10", "--risk-coordinate", "-1"]):
        try:
            code = main(["analyze", str(DATA / "demo-block.json"), "--quiet", *args])
        except SystemExit as exc:             # a value out of range: a usage error of argparse
            code = exc.code
        assert code == 2
        err = capsys.readouterr().err
        assert err.startswith("baarda: error: ") and "--risk" in err and err.count("\n") == 1, err
