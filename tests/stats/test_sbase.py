"""Baarda's 3D S-base (two points and the normal direction, M84 §2.2) and criterion matrices for
heights and 3D blocks (M84 §2.3): S-transformation against a refit in that datum, and the
comparison |G − λH| = 0 the same in every S-base (d = 1, d = 7; d = 3, 4 in test_precision)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from tests.networks import problem

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.cli import main
from baarda.datum import Datum
from baarda.model.bundle import build_block_problem
from baarda.model.network import Cluster, NetObservation, NetPoint, Network
from baarda.simulate import simulate_block, simulate_to_files
from baarda.stats import analyses, precision

DATA = Path(__file__).resolve().parents[2] / "data"
RECIPE = dict(strips=2, images_per_strip=4, datum="free", seed=3)


def dense_ratio(G, H, Gnull):
    """λmax/λmin of |G − λH| = 0 on the complement of the null space with numpy alone: P projects
    onto it, the pencil is eig(pinv(P H P) P G P) on its non-zero part (M84 eq. 3)."""
    Q, _ = np.linalg.qr(Gnull)
    P = np.eye(G.shape[0]) - Q @ Q.T
    lam = np.linalg.eigvals(np.linalg.pinv(P @ H @ P, rcond=1e-12, hermitian=True) @ (P @ G @ P)).real
    lam = np.sort(lam)[Gnull.shape[1]:]
    return lam[-1] / lam[0]


@pytest.fixture(scope="module")
def free_block():
    block, _ = simulate_block(**RECIPE)
    return adjust(build_block_problem(block))


def _blocks(cc, ids, names):
    out = []
    for name in names:
        sel = np.flatnonzero(cc.point == ids.index(name))
        out.append(cc.cov[np.ix_(sel, sel)])
    return out


def test_two_point_sbase_in_3d_is_the_refit_in_that_datum(free_block):
    """Two points fix translations, scale and two rotations; the normal of the plane through them and
    a third point C fixes the rotation about their line (M84 §2.2). Σ S-transformed to that base
    equals Σ of the free block adjusted with that S-base (inner constraints over it)."""
    adj = free_block
    assert adj.plan.defect == 7
    ids = list(adj.problem.points.ids)
    a, b = ids[0], ids[3]
    cc = precision.covariance(adj, sbase=[a, b])
    third = next(s for s in cc.sbase if s.startswith("normal="))[len("normal="):]
    refit = adjust(dataclasses.replace(adj.problem, datum=Datum("free", (a, b, f"normal={third}"))), x0=adj.x)
    assert refit.plan.normal.size == 3
    scale = np.abs(cc.cov).max()
    for name in ids[:: max(1, len(ids) // 8)] + [third]:
        k = ids.index(name)
        np.testing.assert_allclose(refit.point_cov[k], _blocks(cc, ids, [name])[0], atol=1e-7 * scale)
    for Sb in _blocks(cc, ids, [a, b]):                         # the base points are non-stochastic
        assert np.abs(Sb).max() < 1e-9 * scale
    n = refit.plan.normal
    Sc = _blocks(cc, ids, [third])[0]
    assert n @ Sc @ n < 1e-9 * np.trace(Sc)                      # C does not move along the normal
    assert np.trace(Sc) > 1e-6 * scale                           # but does move in its plane
    # the normal point named explicitly gives the same transformation
    named = precision.covariance(adj, sbase=[a, b, f"normal={third}"])
    np.testing.assert_allclose(named.cov, cc.cov, atol=1e-9 * scale)


def test_criterion_same_in_every_3d_sbase(free_block):
    """A 3D free block (d = 7): λmax/λmin of the chaotic criterion (axes = 3, l_ij in space) is the
    same for a two-point base with either normal, three points and eight points — and equals the dense
    projector computation; the fit (M84 §2.3) too."""
    adj = free_block
    ids = list(adj.problem.points.ids)
    bases = ([ids[0], ids[3]], [ids[0], ids[3], f"normal={ids[-1]}"], [ids[1], ids[5], ids[9]], ids[2:10])
    ratios, fits = [], []
    for base in bases:
        setup = analyses.criterion_setup(adj, base)
        assert setup.axes == 3 and setup.xy.shape[1] == 3
        c = analyses.criterion_compare(setup, "logarithmic", 1e-6, 500.0)
        H = precision.sbase_transform(precision.criterion_matrix(setup.xy, "logarithmic", 0.0, 1e-6, 500.0, axes=3),
                                      setup.G, setup.in_base)
        ratios.append(c.lam_max / c.lam_min)
        assert ratios[-1] == pytest.approx(dense_ratio(setup.cov.cov, H, setup.G), rel=1e-6)
        fits.append(analyses.criterion_fit(setup, "logarithmic"))
    np.testing.assert_allclose(ratios, ratios[0], rtol=1e-7)
    np.testing.assert_allclose([f["ratio"] for f in fits], fits[0]["ratio"], rtol=1e-5)
    np.testing.assert_allclose([f["C1"] for f in fits], fits[0]["C1"], rtol=1e-5)


def test_criterion_matrix_in_3d_and_for_heights_gives_d2_for_differences():
    """M84 eq. 2: a coordinate difference has variance d_ij² (3D: l_ij the spatial distance, every
    axis; heights: one coordinate per point, l_ij planimetric)."""
    rng = np.random.default_rng(2)
    xyz = rng.uniform(0, 1000, size=(5, 3))
    for pos, axes in ((xyz, 3), (xyz[:, :2], 1)):
        H = precision.criterion_matrix(pos, "linear", 1e-6, 2e-6, axes=axes)
        for i, j in ((0, 1), (2, 4)):
            l = np.linalg.norm(pos[i] - pos[j])
            for k in range(axes):
                e = np.zeros(H.shape[0])
                e[i * axes + k], e[j * axes + k] = 1.0, -1.0
                assert e @ H @ e == pytest.approx(1e-6 + 2e-6 * l, rel=1e-12)


def _height_network():
    """Six benchmarks with positions, a levelling ring and two diagonals, point A fixed."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 3000, size=(6, 2))
    names = "ABCDEF"
    pts = tuple(NetPoint(n, x=float(p[0]), y=float(p[1]), z=100.0 + k, fixed="z" if k == 0 else "",
                         adjusted="" if k == 0 else "z") for k, (n, p) in enumerate(zip(names, xy)))
    pairs = [(k, (k + 1) % 6) for k in range(6)] + [(0, 3), (1, 4)]
    obs = tuple(NetObservation("height-diff", (names[i], names[j]), (j - i) + rng.normal(0, 1e-3)) for i, j in pairs)
    sig = [1e-3 * np.sqrt(np.linalg.norm(xy[i] - xy[j]) / 1000) for i, j in pairs]
    return Network(pts, obs, tuple(Cluster((k,), np.array([[s * s]])) for k, s in enumerate(sig)),
                   sigma_act="apriori")


def test_height_criterion_same_in_every_sbase():
    """Heights (d = 1 once the fixed point is released): the S-base is one point (M84 §2.2); the
    criterion comparison is the same for A (the adjustment's datum), C and three points."""
    adj = adjust(problem(_height_network()))
    assert analyses.criterion_axes(adj) == (1, "")
    ratios = []
    for base in (["A"], ["C"], ["B", "D", "E"]):
        setup = analyses.criterion_setup(adj, base)
        assert setup.G.shape[1] == 1 and setup.axes == 1
        c = analyses.criterion_compare(setup, "linear", 1e-6)
        H = precision.sbase_transform(precision.criterion_matrix(setup.xy, "linear", 0.0, 1e-6, axes=1),
                                      setup.G, setup.in_base)
        ratios.append(c.lam_max / c.lam_min)
        assert ratios[-1] == pytest.approx(dense_ratio(setup.cov.cov, H, setup.G), rel=1e-7)
        assert analyses.criterion_fit(setup, "linear")["ratio"] == pytest.approx(ratios[0], rel=1e-6)
    np.testing.assert_allclose(ratios, ratios[0], rtol=1e-8)


def test_cli_two_point_sbase_and_criteria(tmp_path, capsys):
    blk, truth = tmp_path / "free.json", tmp_path / "free.truth.json"
    simulate_to_files(RECIPE, str(blk), str(truth))
    ids = list(read_problem(blk).points.ids)
    out = tmp_path / "r.json"
    assert main(["analyze", str(blk), "--sbase", f"{ids[0]},{ids[3]}", "--criterion", "logarithmic",
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"S-base {ids[0]}, {ids[3]}, normal=" in text and "criterion matrix (logarithmic" in text
    doc = json.loads(out.read_text())
    assert doc["summary"]["sbase"][2].startswith("normal=") and doc["criterion"]["C1"] > 0
    assert main(["analyze", str(DATA / "demo-block.json"), "--criterion", "exponential", "--quiet"]) == 0
    assert main(["analyze", str(DATA / "demo-levelling.gkf"), "--criterion", "linear", "--quiet"]) == 2
    assert "--criterion: a criterion matrix for heights needs" in capsys.readouterr().err
    assert main(["analyze", str(blk), "--sbase", f"{ids[0]},{ids[3]},normal=NOPE", "--quiet"]) == 2
    assert "unknown point id(s) NOPE" in capsys.readouterr().err
