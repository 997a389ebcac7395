"""Separability of hypotheses (M84 §3.3, F80 §7.4): the correlation of two test statistics, checked
against a dense computation of P C_vv P (F80 eq. 8) on the demo block."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import scipy.linalg as la
import scipy.sparse as sp
from tests.oracle import pcp

from baarda.adjust import adjust
from baarda.errors import OptionError
from baarda.stats import separability
from baarda.stats.hypotheses import h_point_transfer, selection
from baarda.stats.snooping import iterate
from baarda.stats.reliability import reliability_of

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def demo(demo_problem, demo_adjustment):
    return demo_problem, demo_adjustment, pcp(demo_adjustment)        # D(Pv) with σ0 absorbed (F80 eq. 8)


def _row(p, **ids):
    return next(i for i, x in enumerate(p.info.ids) if all(x.get(k) == v for k, v in ids.items()))


def _dense_groups(S, ok, threshold):
    """Connected components of |ρ_ij| ≥ threshold over all pairs of controlled observations."""
    s = np.sqrt(np.diag(S))
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = S / np.outer(s, s)
    link = (np.abs(rho) >= threshold) & ok[:, None] & ok[None, :]
    np.fill_diagonal(link, False)
    _, lab = sp.csgraph.connected_components(sp.csr_matrix(link), directed=False)
    groups = {}
    for i in np.flatnonzero(link.any(axis=1)):
        groups.setdefault(lab[i], []).append(int(i))
    return sorted(tuple(g) for g in groups.values()), rho


def test_w_correlation_of_two_observations_against_dense(demo):
    p, adj, S = demo
    i, j = _row(p, image="101", point="P00001", component="x"), _row(p, image="102", point="P00001", component="y")
    k = _row(p, image="302", point="P05003", component="y")
    for a, b in ((i, j), (i, k), (j, k)):
        expected = S[a, b] / np.sqrt(S[a, a] * S[b, b])
        got = separability.correlation(adj, selection(p.n, [a]), selection(p.n, [b]))
        assert got == pytest.approx(expected, abs=1e-7)


def test_two_ray_point_images_are_inseparable(demo):
    """A 2-ray point has one condition: its four residuals move together, so the w-tests of both
    images are perfectly correlated and give the same |w| (F80 §7.4)."""
    p, adj, S = demo
    rows = [_row(p, image=im, point="P00001", component=c) for im in ("101", "102") for c in "xy"]
    groups = separability.inseparable_pairs(adj)
    g = next(g for g in groups if rows[0] in g.members)
    assert set(rows) <= set(g.members) and g.rho > 0.9999
    assert np.allclose(np.abs(adj.w[rows]), abs(adj.w[rows[0]]), rtol=1e-6)
    tw = separability.twins(adj, rows[2])
    assert {j for j, _ in tw} == {rows[0], rows[1], rows[3]}
    for j, rho in tw:
        assert rho == pytest.approx(S[rows[2], j] / np.sqrt(S[j, j] * S[rows[2], rows[2]]), abs=1e-7)


def test_all_inseparable_w_tests_against_dense(demo):
    """Every group the sparse search finds (pairs sharing parameters, redundancy bound) is the dense
    search over all n² pairs."""
    p, adj, S = demo
    expected, _ = _dense_groups(S, ~adj.uncontrolled, 0.99)
    got = separability.inseparable_pairs(adj, threshold=0.99)
    assert [g.members for g in got] == expected
    assert len(expected) > 10


def test_transfer_hypotheses_in_the_two_strips_are_inseparable(demo):
    """The planted transfer error of P04004 in images 203-205 and one in 303-305 (the next strip) have
    canonical correlations ≈ 1 (T = 32.4 and 31.8): one offset in all six images is nearly a shift of
    the point, so an offset in one strip's images looks like the opposite offset in the other's.
    203-205 vs 204-205 is separable (0.86, 0.32). Reference: cosines of the
    principal angles between Lᵀ H1 and Lᵀ H2, S = L Lᵀ (dense)."""
    p, adj, S = demo
    lam, V = np.linalg.eigh(S)
    L = V[:, lam > 1e-9 * lam.max()] * np.sqrt(lam[lam > 1e-9 * lam.max()])
    H = {k: h_point_transfer(p, "P04004", ims) for k, ims in
         (("203-205", ["203", "204", "205"]), ("303-305", ["303", "304", "305"]), ("204-205", ["204", "205"]))}

    def ref(a, b):
        return np.sort(np.cos(la.subspace_angles(L.T @ H[a].toarray(), L.T @ H[b].toarray())))[::-1]

    for a, b in (("203-205", "303-305"), ("203-205", "204-205")):
        got = separability.canonical_correlations(adj, H[a], H[b])
        assert got == pytest.approx(ref(a, b), abs=1e-6)
        assert separability.correlation(adj, H[a], H[b]) == pytest.approx(ref(a, b).min(), abs=1e-6)
    assert ref("203-205", "303-305").min() > 0.999 and ref("203-205", "204-205").min() < 0.5
    groups = separability.inseparable_pairs(adj, list(H.items()))
    assert [g.members for g in groups] == [("203-205", "303-305")]
    tests = [reliability_of(adj).test(h, label=k) for k, h in H.items()]
    assert [g.members for g in separability.inseparable_pairs(adj, tests)] == [("203-205", "303-305")]


def test_snooping_names_the_twins_of_a_removed_observation(demo):
    """Data snooping on the demo removes one image coordinate of the 2-ray point P00001 (planted in
    image 101); the step names the other three as twins (ρ = ±1)."""
    p, adj, _ = demo
    steps = iterate(p).steps
    rows = {_row(p, image=im, point="P00001", component=c) for im in ("101", "102") for c in "xy"}
    step = next(s for s in steps if s.removed in rows)
    assert set(step.twins) == rows - {step.removed}
    assert np.allclose(np.abs(step.twin_rho), 1.0, atol=1e-6)
    first = steps[0]                                  # the 20σ image error: a well-controlled point
    assert first.twins == ()


def test_bad_threshold(demo):
    _, adj, _ = demo
    with pytest.raises(OptionError):
        separability.inseparable_pairs(adj, threshold=1.5)


def test_suspects_only(demo):
    """``tests`` as observation indices: the groups linked to those observations only."""
    p, adj, _ = demo
    rows = [_row(p, image="101", point="P00001", component="x"), _row(p, image="302", point="P05003", component="y")]
    groups = separability.inseparable_pairs(adj, np.array(rows))
    full = separability.inseparable_pairs(adj)
    assert [g.members for g in groups] == [g.members for g in full if set(g.members) & set(rows)]
    assert len(groups) == 1


def test_baarda_test_names_inseparable_hypotheses(tmp_path, capsys):
    from baarda.cli import main

    out = tmp_path / "t.json"
    specs = ["transfer:P04004:203,204,205", "transfer:P04004:303,304,305", "transfer:P04004:204,205"]
    assert main(["test", str(DATA / "demo-block.json"), *[a for s in specs for a in ("--hypothesis", s)],
                 "--json", str(out)]) == 0
    assert "the data cannot tell these hypotheses apart" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, json.loads(resources.files("baarda").joinpath("schema/test.schema.json").read_text()))
    (g,) = doc["inseparable"]
    assert g["hypotheses"] == specs[:2] and g["rho"] > 0.999


def test_partly_inseparable_image_points_of_a_three_ray_point(tmp_path, capsys):
    """Issue 27 item 8 (F80 §7.4, M84 §3.3): two image points of a 3-ray point have canonical
    correlations (1, ~0.6): inseparable along one direction, separable along the other. The
    smallest alone (what :func:`inseparable_pairs` judges) hid it. Reference: the canonical
    correlations of the dense P C_vv P (tests.oracle.pcp); ``baarda test`` names the pair."""
    import json

    from baarda.cli import main
    from baarda.io.native import write_native
    from baarda.model.bundle import build_block_problem
    from baarda.simulate import simulate_block
    from baarda.stats.hypotheses import h_image_point
    from tests.oracle import pcp

    blk, _ = simulate_block(seed=3, strips=2, images_per_strip=4)
    p = build_block_problem(blk)
    adj = adjust(p)
    hs = [(im, h_image_point(p, im, "P00003")) for im in ("102", "103", "104")]
    S = pcp(adj)

    def dense_cc(H1, H2):
        H1, H2 = H1.toarray(), H2.toarray()
        W11, W12, W22 = H1.T @ S @ H1, H1.T @ S @ H2, H2.T @ S @ H2
        r1 = np.linalg.inv(np.linalg.cholesky(W11))
        r2 = np.linalg.inv(np.linalg.cholesky(W22))
        return np.linalg.svd(r1 @ W12 @ r2.T, compute_uv=False)

    partly = separability.partly_inseparable(adj, hs)
    flagged = {g.members for g in partly}
    for a in range(3):
        for b in range(a + 1, 3):
            c = dense_cc(hs[a][1], hs[b][1])
            expect = bool(c.max() >= separability.THRESHOLD > c.min())
            assert ((hs[a][0], hs[b][0]) in flagged) is expect
    assert partly and not separability.inseparable_pairs(adj, hs)
    g = partly[0]
    c = dense_cc(dict(hs)[g.members[0]], dict(hs)[g.members[1]])
    assert (g.largest, g.smallest) == pytest.approx((c.max(), c.min()), abs=1e-6)
    assert np.linalg.norm(g.direction) == pytest.approx(1.0)
    path = tmp_path / "b.json"
    write_native(blk, path)
    out = tmp_path / "t.json"
    assert main(["test", str(path), "-H", "image-point:102:P00003", "-H", "image-point:103:P00003",
                 "--json", str(out)]) == 0
    assert "partly inseparable" in capsys.readouterr().out
    (pp,) = json.loads(out.read_text())["partly_inseparable"]
    assert pp["largest"] > 0.99 > pp["smallest"]


def test_shared_part_against_dense(demo):
    """separability.shared_part: the canonical correlations of two image points' tests at a 3-ray
    point and the part of the first test's statistic T1 = g1ᵀ W11⁻¹ g1 along the first canonical
    direction (F80 §7.4, M84 §3.3), against a dense computation: W_jk = H_jᵀ (P C_vv P) H_k from the
    oracle's P C_vv P (F80 eq. 8), g = Hᵀ P v, whitening by the symmetric inverse square root."""
    p, adj, S = demo
    rays: dict = {}
    for i, d in enumerate(p.info.ids):
        if "image" in d:
            rays.setdefault(d["point"], {}).setdefault(d["image"], []).append(i)
    pt = next(k for k, v in rays.items() if len(v) == 3)
    (a, ra), (b, rb), _ = sorted(rays[pt].items())
    H1, H2 = selection(p.n, ra), selection(p.n, rb)
    cc, part = separability.shared_part(adj, H1, H2)
    h1, h2 = H1.toarray(), H2.toarray()
    W11, W12, W22 = h1.T @ S @ h1, h1.T @ S @ h2, h2.T @ S @ h2
    X1, X2 = la.inv(la.sqrtm(W11)).real, la.inv(la.sqrtm(W22)).real
    U, c, _ = np.linalg.svd(X1 @ W12 @ X2)
    z = X1 @ (h1.T @ np.asarray(adj.Pv))
    assert cc == pytest.approx(c, abs=1e-6)
    assert part == pytest.approx((U[:, 0] @ z) ** 2 / (z @ z), abs=1e-6)
    assert 0.0 <= part <= 1.0
