"""Bundle blocks: collinearity Jacobians, reliability against an OLS oracle, datum invariance,
block hypotheses (point transfer), AP tests (F80 §7.2) and the native file format."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp
import statsmodels.api as sm
from statsmodels.stats.outliers_influence import OLSInfluence

from baarda import InputError, Options, adjust
from baarda.io.native import read_native, write_native
from baarda.model.bundle import Camera, build_block_problem, check_points, image_rows
from baarda.simulate import simulate_block
from baarda.stats.ap_tests import ap_test
from baarda.stats.hypotheses import (h_ap_group, h_control_point, h_exchanged, h_image_coordinate, h_image_point,
                                     h_point_transfer)
from baarda.stats.reliability import reliability_of

from tests.oracle import reduced_design

# ------------------------------------------------------------------------------------------
# collinearity Jacobian
# ------------------------------------------------------------------------------------------
def test_jacobian_matches_finite_differences():
    cam = {"id": "C", "c": 153.0, "width": 230.0, "height": 230.0, "unit": "mm",
           "k1": 2e-8, "k2": -1e-12, "p1": 1e-6, "p2": -2e-6}
    block, _ = simulate_block(seed=2, strips=2, images_per_strip=4, camera=cam,
                              ap=["io", "brown", "ebner"])
    pr = build_block_problem(block)
    rng = np.random.default_rng(1)
    x = pr.params.x0.copy()
    is_ap = np.array([lab.count(".") == 2 for lab in pr.params.labels])
    x[is_ap] = rng.normal(0, 0.01, is_ap.sum())
    _, J = pr.evaluate(x)
    J = J.toarray()
    for j in range(pr.params.size):
        h = 1e-6 if (pr.params.kind[j] == "t" and not is_ap[j] and pr.params.labels[j].split(".")[-1]
                     in ("omega", "phi", "kappa")) else 1e-4
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        fd = (pr.evaluate(xp)[0] - pr.evaluate(xm)[0]) / (2 * h)
        assert np.abs(fd - J[:, j]).max() <= 1e-6 * max(1.0, np.abs(J[:, j]).max()), pr.params.labels[j]


# ------------------------------------------------------------------------------------------
# reliability against an independent oracle
# ------------------------------------------------------------------------------------------
def _whitened_hat(adj):
    """1 − h_ii of the whitened design matrix (statsmodels OLSInfluence), each 2×2 cluster
    whitened with its Cholesky factor."""
    A = adj.A.toarray()
    Aw = np.empty_like(A)
    for idx, C in zip(adj.problem.cov.members, adj.problem.cov.blocks):
        Aw[idx] = np.linalg.solve(np.linalg.cholesky(C), A[idx])
    res = sm.OLS(np.zeros(A.shape[0]) + np.arange(A.shape[0]) % 3, Aw).fit()
    return 1.0 - OLSInfluence(res).hat_matrix_diag


@pytest.fixture(scope="module")
def block_adj():
    block, truth = simulate_block(seed=11, strips=2, images_per_strip=5)
    return block, truth, adjust(build_block_problem(block))


def test_redundancy_numbers_equal_ols_leverage(block_adj):
    _, _, adj = block_adj
    assert adj.converged
    assert np.abs(adj.r - _whitened_hat(adj)).max() <= 1e-8
    assert abs(adj.r.sum() - adj.dof) < 1e-8


def test_redundancy_of_correlated_image_points():
    """With correlated 2×2 clusters (C_vv P)_ii and the whitened leverage differ per
    component (they are similar matrices, not equal); their trace per cluster agrees.

    A component of (C_vv P)_ii can be negative for correlated observations; ``Adjustment.r``
    clips only uncorrelated observations to [0, 1], so these are the values as computed."""
    block, _ = simulate_block(seed=12, strips=2, images_per_strip=4, rho=0.4)
    adj = adjust(build_block_problem(block))
    one_minus_h = _whitened_hat(adj)
    r_raw = adj.r
    for idx in adj.problem.cov.members:
        assert abs(r_raw[idx].sum() - one_minus_h[idx].sum()) <= 1e-8
    assert abs(r_raw.sum() - adj.dof) < 1e-8


def test_redundancy_is_datum_invariant():
    block, _ = simulate_block(seed=5, control="minimal")
    tight = Options(tol=1e-8)           # all three linearised at the same geometry
    a_ctrl = adjust(build_block_problem(block), tight)
    a_free = adjust(build_block_problem(block.replace(datum="free")), tight)
    base = tuple(p.id for p in block.points[::5])      # an S-base spread over the block
    a_base = adjust(build_block_problem(block.replace(datum="free", sbase=base)), tight)
    m = 2 * block.obs.size
    assert a_free.defect == 7 and a_ctrl.defect == 0
    assert a_ctrl.dof == a_free.dof == a_base.dof
    assert np.abs(a_ctrl.r[:m] - a_free.r).max() <= 1e-9
    assert np.abs(a_base.r - a_free.r).max() <= 1e-9
    assert np.abs(a_ctrl.r[m:]).max() <= 1e-9          # a minimum datum has no redundancy
    ok = a_free.r > 0.01                # w of nearly uncontrolled observations is round-off
    assert np.abs(a_base.w[ok] - a_free.w[ok]).max() <= 1e-6
    # coordinate precision depends on the S-base, reliability not (M84 §2)
    assert np.abs(a_base.point_sigma - a_free.point_sigma).max() > 1e-3


# ------------------------------------------------------------------------------------------
# hypotheses
# ------------------------------------------------------------------------------------------
def test_single_hypotheses_agree_with_data_snooping(block_adj):
    block, _, adj = block_adj
    pr = adj.problem
    track = np.bincount(block.obs.point)
    k = int(np.flatnonzero(track[block.obs.point] >= 4)[0])    # both coordinates controlled
    im, pt = block.images[block.obs.image[k]].id, block.points[block.obs.point[k]].id
    rows = image_rows(pr, im, pt)
    h = reliability_of(adj).test(h_image_coordinate(pr, im, pt, "y"))
    assert np.isclose(h.T, adj.w[rows[1]] ** 2)
    h2 = reliability_of(adj).test(h_image_point(pr, im, pt))
    g = next(g for g in reliability_of(adj).groups if g["group"] == k)
    assert h2.q == 2 and np.isclose(h2.T, g["T"])
    ctrl = next(p.id for p in block.points if p.status == "control")
    hc = reliability_of(adj).test(h_control_point(pr, ctrl))
    assert hc.q == 3 and hc.H.shape == (pr.n, 3)


def test_point_transfer_error_is_found_by_its_own_hypothesis():
    block, truth = simulate_block(seed=0, errors=[{"kind": "transfer", "size": 10, "images": 3}])
    adj = adjust(build_block_problem(block))
    e = truth["errors"][0]
    assert len(e["ids"]["images"]) == 3 and e["class"] == "small"
    h = reliability_of(adj).test(h_point_transfer(adj.problem, e["ids"]["point"], e["ids"]["images"]))
    single = [g["T"] for g in reliability_of(adj).groups if g["dimension"] == 2]
    assert h.rejected_T
    assert h.T > max(single)
    assert np.all(np.abs(h.nabla - e["vector"]) < h.nabla_sigma)
    H = h.H.toarray()
    assert set(np.flatnonzero(H.any(axis=1))) == set(e["rows"])


def test_exchange_hypothesis_column(block_adj):
    block, _, adj = block_adj
    im = block.images[3].id
    k = np.flatnonzero(block.obs.image == 3)[:2]
    a, b = (block.points[block.obs.point[i]].id for i in k)
    H = h_exchanged(adj, im, a, b).toarray().ravel()
    ra, rb = image_rows(adj.problem, im, a), image_rows(adj.problem, im, b)
    assert np.allclose(H[ra], adj.f[rb] - adj.f[ra]) and np.allclose(H[rb], -H[ra])
    h = reliability_of(adj).test(sp.csc_matrix(H[:, None]))
    assert h.q == 1 and abs(h.nabla[0]) < 0.05          # no exchange planted


# ------------------------------------------------------------------------------------------
# additional parameters (F80 §7.2)
# ------------------------------------------------------------------------------------------
def test_ap_group_significant_only_with_radial_distortion():
    with_rad, _ = simulate_block(seed=4, ap=["brown"], radial=0.010)
    without, _ = simulate_block(seed=4, ap=["brown"])
    t1 = ap_test(adjust(build_block_problem(with_rad)), "RC30", "brown")
    t0 = ap_test(adjust(build_block_problem(without)), "RC30", "brown")
    assert t1.significant and t1.T > 2 * t1.critical
    assert not t0.significant
    assert np.allclose(t0.determinability, t0.delta0_1 * t0.sigma)
    assert np.all(t0.reliability > 0) and t0.reliability_max > 0


def test_ap_reliability_matches_dense_oracle():
    """δ̄0(s) of the AP group (F80 eq. 17) against the hypothesis H = ∂f/∂a in the model
    without APs, with Q_kk⁻¹ = C̄ᵀPC̄ formed densely (design mode: both linearised at the truth)."""
    blk, _ = simulate_block(seed=6, strips=2, images_per_strip=4, ap=["ebner"], design=True)
    adj = adjust(build_block_problem(blk))
    t = ap_test(adj, "RC30", "ebner")
    adj0 = adjust(build_block_problem(blk.replace(cameras=(Camera(**{**blk.cameras[0].__dict__, "ap": ()}),))))
    H = h_ap_group(adj0, "RC30", "ebner")
    h = reliability_of(adj0).test(H)
    assert np.allclose(np.linalg.inv(h.W), t.cov, rtol=1e-6, atol=1e-12)
    kind = adj0.problem.params.kind[adj0.problem.params.free]
    k, tt = kind == "k", kind == "t"
    P = adj0.P.toarray()
    Cbar = reduced_design(adj0.A, P, tt, k)
    dK = np.column_stack([adj0.deformation(H[:, [j]].toarray().ravel())[k] for j in range(H.shape[1])])
    M = dK.T @ Cbar.T @ P @ Cbar @ dK
    lam = np.linalg.eigvals(np.linalg.solve(h.W, M)).real.max()
    assert np.isclose(t.reliability_max, t.delta0_q * np.sqrt(lam), rtol=1e-5)


@pytest.mark.slow
def test_ap_test_rejection_rate_is_alpha():
    """Monte Carlo: without systematic errors the AP group test rejects at rate ≈ α."""
    alpha, n = 0.05, 300
    rejected = 0
    for seed in range(n):
        blk, _ = simulate_block(seed=1000 + seed, strips=2, images_per_strip=4, ap=["brown"])
        t = ap_test(adjust(build_block_problem(blk), Options(alpha0=alpha, tol=1e-10)), "RC30", "brown")
        rejected += t.significant
    se = np.sqrt(alpha * (1 - alpha) / n)
    assert abs(rejected / n - alpha) < 3 * se


def test_check_points_are_reported_not_adjusted():
    blk, truth = simulate_block(seed=8, check=3)
    adj = adjust(build_block_problem(blk))
    rep = check_points(adj, blk)
    assert len(rep["points"]) == 3
    assert not any(k.startswith("control") and ids["id"] in {p["id"] for p in rep["points"]}
                   for k, ids in zip(adj.problem.info.kind, adj.problem.info.ids))
    assert max(rep["rms"]) < 1.0


def test_problem_layout_and_geometry(block_adj):
    block, _, adj = block_adj
    pr = adj.problem
    m = block.obs.size
    assert pr.info.kind[0] == "image-x" and pr.info.kind[1] == "image-y"
    assert all(len(pr.cov.members[k]) == 2 for k in range(m))
    assert set(pr.info.group[:2 * m]) == set(range(m))
    geo = pr.geometry.as_dict()
    assert len(geo["images"]) == len(block.images) and len(geo["images"][0]["footprint"]) == 4
    assert 1400 < geo["flying_height"] < 1600
    fp = np.array(geo["images"][0]["footprint"])
    side = np.linalg.norm(fp[1] - fp[0])
    assert abs(side - 230 * geo["flying_height"] / 153) < 0.1 * side
    assert set(pr.points.status) == {"tie", "control"}
    json.dumps(geo)


# ------------------------------------------------------------------------------------------
# native format
# ------------------------------------------------------------------------------------------
def test_native_round_trip(tmp_path):
    blk, _ = simulate_block(seed=9, strips=2, images_per_strip=3, ap=["brown"], rho=0.2, check=1)
    path = tmp_path / "b.json"
    write_native(blk, path)
    back = read_native(path)
    assert np.array_equal(back.obs.xy, blk.obs.xy) and np.allclose(back.obs.cov, blk.obs.cov, rtol=1e-15)
    assert [p.__dict__ | {"line": 0} for p in back.points] == [p.__dict__ | {"line": 0} for p in blk.points]
    assert [i.__dict__ | {"line": 0} for i in back.images] == [i.__dict__ | {"line": 0} for i in blk.images]
    assert back.cameras[0].ap == ("brown",)
    text = path.read_text().splitlines()
    k = 5
    assert f'"point": "{back.points[back.obs.point[k]].id}"' in text[back.obs.line[k] - 1]
    write_native(back, tmp_path / "c.json")
    assert (tmp_path / "c.json").read_text() == path.read_text()


def _small_text(tmp_path):
    blk, _ = simulate_block(seed=9, strips=2, images_per_strip=3)
    path = tmp_path / "ok.json"
    write_native(blk, path)
    return path.read_text()


def _line_of(text, needle, nth=0):
    hits = [i + 1 for i, line in enumerate(text.splitlines()) if needle in line]
    return hits[nth]


MALFORMED = [
    # (name, transform(text) -> text, needle locating the expected line or an int)
    ("syntax", lambda t: t.replace('"c": 153.0,', '"c": 153.0,,', 1), '"c": 153.0'),
    ("format", lambda t: t.replace('"baarda-block"', '"other"', 1), '"format"'),
    ("version", lambda t: t.replace('"version": 1', '"version": 7', 1), '"version"'),
    ("c <= 0", lambda t: t.replace('"c": 153.0', '"c": -153.0', 1), '"c": -153.0'),
    ("not a number", lambda t: t.replace('"X0": ', '"X0": "abc", "x": ', 1), '"X0": "abc"'),
    ("nan", lambda t: t.replace('"Z0": ', '"Z0": NaN, "z": ', 1), '"Z0": NaN'),
    ("infinity", lambda t: _nth_obs(t, 4, '"x": ', '"x": Infinity, "q": '), '"x": Infinity'),
    ("sigma <= 0", lambda t: _nth_obs(t, 6, '"sigma": 0.005', '"sigma": 0.0'), '"sigma": 0.0}'),
    ("duplicate image", lambda t: t.replace('"id": "102"', '"id": "101"', 1), ('"id": "101"', 1)),
    ("unknown image", lambda t: _nth_obs(t, 3, '"image": "', '"image": "9'), '"image": "9'),
    ("unknown camera", lambda t: t.replace('"camera": "RC30"', '"camera": "XX"', 1), '"camera": "XX"'),
    ("cov shape", lambda t: _nth_obs(t, 2, '"sigma": 0.005', '"cov": [[1e-5, 0], [0, 1e-5, 0]]'), '"cov"'),
    ("ref count", lambda t: _first_control(t), '"ref": [1.0, 2.0]'),
    ("bad status", lambda t: t.replace('"status": "tie"', '"status": "bridge"', 1), '"status": "bridge"'),
    ("empty block", lambda t: _empty_observations(t), '"observations"'),
]


def _nth_obs(text, n, old, new):
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(' "observations"'))
    lines[start + 1 + n] = lines[start + 1 + n].replace(old, new, 1)
    return "\n".join(lines) + "\n"


def _first_control(text):
    lines = text.splitlines()
    i = next(i for i, line in enumerate(lines) if '"status": "control"' in line)
    j0 = lines[i].index('"ref": [')
    j1 = lines[i].index("]", j0)
    lines[i] = lines[i][:j0] + '"ref": [1.0, 2.0]' + lines[i][j1 + 1:]
    return "\n".join(lines) + "\n"


def _empty_observations(text):
    doc = json.loads(text)
    doc["observations"] = []
    return json.dumps(doc, indent=1)


@pytest.mark.parametrize("name,transform,where", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_native_files(tmp_path, name, transform, where):
    bad = transform(_small_text(tmp_path))
    path = tmp_path / "bad.json"
    path.write_text(bad)
    with pytest.raises(InputError) as info:
        read_native(path)
    needle, nth = where if isinstance(where, tuple) else (where, 0)
    assert info.value.line == _line_of(bad, needle, nth), str(info.value)
    assert info.value.path == str(path)


def test_point_seen_by_one_image_is_a_local_defect(tmp_path, capsys):
    """A tie point on one ray is read, named as a local defect and left out; --strict refuses it at
    the file (tests/test_local_defects.py checks the rest against the block without it)."""
    from baarda.cli import main

    blk, _ = simulate_block(seed=9, strips=2, images_per_strip=3)
    path = tmp_path / "b.json"
    write_native(blk, path)
    doc = json.loads(path.read_text())
    pid = next(p["id"] for p in doc["points"] if p.get("status") == "tie")
    seen = [i for i, o in enumerate(doc["observations"]) if o["point"] == pid]
    doc["observations"] = [o for i, o in enumerate(doc["observations"]) if i not in seen[1:]]
    path.write_text(json.dumps(doc, indent=1))
    assert len(read_native(path).points) == len(blk.points)
    out = tmp_path / "r.json"
    assert main(["analyze", str(path), "--quiet", "--json", str(out)]) == 0, capsys.readouterr().err
    named = [(d["entity"], d["id"]) for d in json.loads(out.read_text())["summary"]["local_defects"]]
    assert named == [("point", pid)]
    assert main(["analyze", str(path), "--quiet", "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"point {pid} " in err


@pytest.mark.parametrize("cal", [(0.0, 0.0, 0.0, 0.0, 0.0), (2e-5, -3e-9, 1e-13, 4e-6, -5e-6)])
def test_compiled_collinearity_equals_the_numpy_formulas(cal):
    """The numba kernel of CollinearitySet.evaluate (cameras without APs) against the vectorised
    numpy formulas: same f and Jacobian, with and without a calibrated distortion."""
    import dataclasses

    import scipy.sparse as sp

    from baarda.observations.collinearity import CollinearitySet

    pytest.importorskip("numba", reason="numba not installed: only the numpy path exists")
    block, _ = simulate_block(strips=2, images_per_strip=4, seed=5)
    pr = build_block_problem(block)
    s = next(s for s in pr.sets if isinstance(s, CollinearitySet))
    s = dataclasses.replace(s, cal=cal, x0=0.01, y0=-0.02)
    x = pr.params.x0 + 1e-4 * np.random.default_rng(1).normal(size=pr.params.size)
    a, b = s.evaluate(x), s.evaluate_numpy(x)
    shape = (2 * s.ipt.shape[0], pr.params.size)
    Ja = sp.csr_matrix((a[3], (a[1], a[2])), shape=shape)
    Jb = sp.csr_matrix((b[3], (b[1], b[2])), shape=shape)
    assert np.abs(a[0] - b[0]).max() <= 1e-12 * np.abs(b[0]).max()
    assert abs(Ja - Jb).max() <= 1e-12 * abs(Jb).max()


def test_block_geometry_is_typed_and_its_dictionary_is_the_drawn_one():
    """Problem.geometry (baarda.model.geometry): the statistics read typed fields; as_dict() is
    the JSON-able form the dashboard draws — the same values, per image and camera."""
    block, _ = simulate_block(strips=2, images_per_strip=4, seed=3)
    geo = build_block_problem(block).geometry
    d = geo.as_dict()
    assert [im.id for im in geo.images] == [im["id"] for im in d["images"]] == [im.id for im in block.images]
    for im, di, src in zip(geo.images, d["images"], block.images):
        assert (im.X0, im.Y0, im.Z0, im.strip, im.camera) == (di["X0"], di["Y0"], di["Z0"], di["strip"], di["camera"])
        assert (im.X0, im.Y0, im.Z0) == (src.X0, src.Y0, src.Z0)
    cam = block.cameras[0]
    assert (geo.camera.c, geo.camera.x0, geo.camera.y0, geo.camera.ap_scale) == (cam.c, cam.x0, cam.y0, cam.scale)
    assert d["camera"]["c"] == cam.c and geo.camera_of(block.images[0].id) is geo.camera
    assert geo.images_of(cam.id) == {im.id for im in block.images if im.camera == cam.id}
    Zm = np.mean([p.Z for p in block.points])
    assert geo.terrain_height == pytest.approx(Zm) and d["flying_height"] == geo.flying_height


def test_image_rows_come_from_the_one_image_point_index():
    """image_rows looks image points up in model.problem.image_point_index (the index the
    hypotheses and the dashboard use): x before y whatever the file order; a point measured by
    several keypoints of one image (COLMAP) is not silently one of them but named."""
    from types import SimpleNamespace

    from baarda.errors import NotFoundError
    from baarda.model.problem import image_point_index

    ids = [{"image": "1", "point": "7", "component": "y"}, {"image": "1", "point": "7", "component": "x"},
           {"image": "1", "point": "8", "keypoint": 3, "component": "x"},
           {"image": "1", "point": "8", "keypoint": 3, "component": "y"},
           {"image": "1", "point": "8", "keypoint": 5, "component": "x"},
           {"image": "1", "point": "8", "keypoint": 5, "component": "y"}]
    p = SimpleNamespace(info=SimpleNamespace(ids=ids))
    assert image_point_index(p)[("1", "7", None)] == [0, 1]
    assert image_rows(p, "1", "7").tolist() == [1, 0]
    with pytest.raises(NotFoundError, match="keypoints 3, 5"):
        image_rows(p, "1", "8")
    with pytest.raises(NotFoundError, match="no measurement of point 9"):
        image_rows(p, "1", "9")
