"""``baarda test`` and the group quantities of ``baarda analyze --json`` against the dense oracle
(F80 eq. 10-18 written out with numpy matrices), and the command's error paths (one line, exit 2,
naming the argument or the file, line and field)."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import jsonschema

import numpy as np
import pytest
import scipy.linalg as la
from scipy import optimize
from scipy import stats as sps

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.cli import main
from baarda.io.hypothesis import parse_hypothesis
from baarda.errors import BaardaError
from baarda.stats.hypotheses import hypothesis_matrix
from baarda.stats.reliability import reliability_of

from tests.oracle import dense, pcp, reduced_design
from tests.io.test_colmap import duplicate_model

DATA = Path(__file__).resolve().parents[1] / "data"
DEMO = DATA / "demo-block.json"
SCHEMA = json.loads(resources.files("baarda").joinpath("schema/test.schema.json").read_text())
ANALYSIS = json.loads(resources.files("baarda").joinpath("schema/analysis.schema.json").read_text())
SPECS = ["transfer:P04004:203,204,205", "image-point:302:P05003", "control:P04009", "observation:5", "group:100"]


@pytest.fixture(scope="module")
def demo(demo_adjustment):
    adj = demo_adjustment
    ref = dense(adj)
    kind = adj.problem.params.kind[adj.problem.params.free]
    t, k = np.flatnonzero(kind == "t"), np.flatnonzero(kind == "k")
    Cbar = reduced_design(ref.A, ref.P, t, k)
    Qkk = np.linalg.pinv(Cbar.T @ ref.P @ Cbar, rcond=1e-12, hermitian=True)
    return adj, ref, k, Cbar, Qkk


@pytest.fixture(scope="module")
def tested(tmp_path_factory):
    out = tmp_path_factory.mktemp("test") / "t.json"
    args = ["test", str(DEMO), "--json", str(out), "--quiet"]
    for s in SPECS:
        args += ["--hypothesis", s]
    assert main(args) == 0
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    jsonschema.validate(doc["summary"], ANALYSIS["properties"]["summary"])
    return doc


def _dense_test(adj, ref, H):
    """F80 eq. 10-14 with dense matrices: W_s, ∇ŝ, σ∇ŝ, T, R, the semi-axes and δ0′max. P C_vv P
    from the SVD of the whitened design (oracle.pcp): through N⁻¹ the control point's T of the
    demo block loses 1e-7 of its value to the squared condition."""
    P, v = ref.P, ref.v
    W = H.T @ pcp(adj) @ H
    g = H.T @ P @ v
    Winv = np.linalg.inv(W)
    T = g @ Winv @ g
    q, r = H.shape[1], adj.dof
    R = (T / q) / ((v @ P @ v - T) / (r - q))
    return W, -Winv @ g, np.sqrt(np.diag(Winv)), T, R, la.eigh(H.T @ P @ H, W, eigvals_only=True).max()


@pytest.mark.parametrize("k", range(len(SPECS)))
def test_every_json_quantity_of_a_test_equals_the_dense_formulas(demo, tested, k):
    adj, ref, kcols, Cbar, Qkk = demo
    t = tested["tests"][k]
    spec = parse_hypothesis(SPECS[k])
    H = hypothesis_matrix(adj, spec).toarray()
    assert t["rows"] == np.flatnonzero(np.abs(H).sum(axis=1)).tolist()
    W, nabla, sig, T, R, mu = _dense_test(adj, ref, H)
    q = H.shape[1]
    a, b = 0.001, 0.80
    crit_T, crit_R = sps.chi2.isf(a, q), sps.f.isf(a, q, adj.dof - q)
    c1 = sps.chi2.isf(a, q)
    d0 = np.sqrt(optimize.brentq(lambda lam: sps.ncx2.sf(c1, q, lam) - b, 1e-6, 400.0, xtol=1e-13))
    assert t["dimension"] == q
    assert t["T"] == pytest.approx(T, rel=1e-7) and t["R"] == pytest.approx(R, rel=1e-7)
    assert t["critical_T"] == pytest.approx(crit_T, rel=1e-10) and t["critical_R"] == pytest.approx(crit_R, rel=1e-10)
    assert t["rejected"] == bool(T > crit_T) and t["decided_on"] == "T"
    np.testing.assert_allclose(t["nabla"], nabla, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(t["nabla_sigma"], sig, rtol=1e-6)
    assert t["delta0"] == pytest.approx(d0, rel=1e-8)
    lam = np.linalg.eigvalsh(W)
    np.testing.assert_allclose(sorted(t["ellipse_axes"]), sorted(d0 / np.sqrt(lam)), rtol=1e-6)
    for axis, direction in zip(t["ellipse_axes"], t["ellipse_directions"]):      # on the ellipse, eq. 13
        s = axis * np.asarray(direction)
        assert s @ W @ s == pytest.approx(d0 ** 2, rel=1e-6)
    assert t["delta0_prime_max"] == pytest.approx(d0 * np.sqrt(mu), rel=1e-6)
    # F80 eq. 17: M = HᵀP C̄ Q_kk C̄ᵀ P H, δ̄0max = δ0 √λmax(M, W_s)
    G = Cbar.T @ ref.P @ H
    M = G.T @ Qkk @ G
    assert t["delta_bar0_max"] == pytest.approx(d0 * np.sqrt(la.eigh(M, W, eigvals_only=True).max()), rel=1e-6)
    assert t["lambda_bar_max"] == pytest.approx(t["delta_bar0_max"] ** 2, rel=1e-12)
    s = np.asarray(t["delta_bar0_direction"])
    assert d0 * np.sqrt((s @ M @ s) / (s @ W @ s)) == pytest.approx(t["delta_bar0_max"], rel=1e-6)
    # F80 eq. 16: the deformation of ∇0s = s δ0/√(sᵀW s) is N⁻¹AᵀP H ∇0s (weighted control: N regular)
    nabla0 = np.asarray(t["deformation"]["nabla0_s"])
    np.testing.assert_allclose(nabla0, s * d0 / np.sqrt(s @ W @ s), rtol=1e-6)
    dx = np.linalg.solve(ref.A.T @ ref.P @ ref.A, ref.A.T @ ref.P @ (H @ nabla0))
    shifts = adj.point_shifts(dx)
    pts = t["deformation"]["points"]
    ids = list(adj.problem.points.ids)
    assert len(pts) == int((np.abs(shifts).sum(axis=1) > 0).sum())
    for p in pts[:10]:
        np.testing.assert_allclose([p["dx"], p["dy"], p["dz"]], shifts[ids.index(p["id"])], rtol=1e-5,
                                   atol=1e-9 * np.abs(shifts).max())
    assert [p["norm"] for p in pts] == sorted((p["norm"] for p in pts), reverse=True)


def test_group_quantities_of_analyze_equal_the_dense_formulas(demo, tmp_path):
    """groups[] of analyze --json: T, R, critical values, ∇ŝ ± σ∇ŝ, semi-axes, δ0′max
    (F80 eq. 10-14) against dense matrices for every group the test sees in full."""
    adj, ref, *_ = demo
    out = tmp_path / "a.json"
    assert main(["analyze", str(DEMO), "--json", str(out), "--quiet"]) == 0
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, ANALYSIS)
    groups = doc["groups"]
    checked = 0
    for g in groups[::7]:
        H = np.zeros((adj.n, len(g["members"])))
        H[g["members"], np.arange(len(g["members"]))] = 1.0
        if g["dimension"] < H.shape[1]:
            assert g["delta0_prime_max"] is None                    # q below the group's size: unbounded
            continue
        W, nabla, sig, T, R, mu = _dense_test(adj, ref, H)
        q = g["dimension"]
        d0 = doc["summary"]["delta0"] if q == 1 else None
        assert g["T"] == pytest.approx(T, rel=1e-7) and g["R"] == pytest.approx(R, rel=1e-7)
        assert g["critical_R"] == pytest.approx(sps.f.isf(0.001, q, adj.dof - q), rel=1e-10)
        np.testing.assert_allclose(g["nabla"], nabla, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(g["nabla_sigma"], sig, rtol=1e-6)
        axes = np.asarray(g["ellipse_axes"])
        lam = np.linalg.eigvalsh(W)
        delta0 = axes[0] * np.sqrt(lam.min())                       # the same δ0 for every axis
        np.testing.assert_allclose(axes, delta0 / np.sqrt(lam), rtol=1e-6)
        if d0 is not None:
            assert delta0 == pytest.approx(d0, rel=1e-8)
        assert g["delta0_prime_max"] == pytest.approx(delta0 * np.sqrt(mu), rel=1e-6)
        checked += 1
    assert checked > 10


def test_a_hypothesis_file_gives_the_same_test(tmp_path, tested):
    """H from a file (docs/formats.md) equals the builder's: the point transfer written out."""
    adj = adjust(read_problem(DEMO))
    H = hypothesis_matrix(adj, parse_hypothesis(SPECS[0])).tocoo()
    f = tmp_path / "h.txt"
    f.write_text("# observation column value\n" + "".join(f"{i}, {j}, {v}\n" for i, j, v in zip(H.row, H.col, H.data)))
    out = tmp_path / "f.json"
    assert main(["test", str(DEMO), "-H", f"file:{f}", "--json", str(out), "--quiet"]) == 0
    t = json.loads(out.read_text())["tests"][0]
    assert t["T"] == pytest.approx(tested["tests"][0]["T"], rel=1e-12)
    assert t["delta_bar0_max"] == pytest.approx(tested["tests"][0]["delta_bar0_max"], rel=1e-10)


def test_text_output_names_every_quantity(capsys):
    assert main(["test", str(DEMO), "-H", SPECS[0], "--top", "2"]) == 0
    text = capsys.readouterr().out
    for needle in ("T = ", "R = ", "REJECTED on T", "∇ŝ = ", "lower-bound ellipse", "δ0′max", "δ̄0max",
                   "λ̄ = ", "deformation", "2 largest of"):
        assert needle in text, needle


@pytest.mark.parametrize("spec, needle", [
    ("pixel:1", "--hypothesis 'pixel:1': unknown kind 'pixel'"),
    ("image-point:302", "--hypothesis 'image-point:302': expected image-point:IMAGE:POINT[:KEYPOINT]"),
    ("observation:x", "INDEX must be an integer"),
    ("observation:99999", "--hypothesis 'observation:99999': no observation 99999"),
    ("image-point:999:P05003", "--hypothesis 'image-point:999:P05003': no measurement of point P05003 in image 999"),
    ("transfer:P04004:203,999", "no measurement of point P04004 in image 999"),
    ("control:NOPE", "no id NOPE"),
    ("ap-group:RC30:nope", "unknown AP group 'nope'"),
    ("ap-group:XX:brown", "no camera XX"),
    ("group:-5", "no test group -5"),
])
def test_bad_spec_is_one_line_exit_2(spec, needle, capsys):
    assert main(["test", str(DEMO), "-H", spec]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("baarda: error: ") and needle in err, err


@pytest.mark.parametrize("text, where", [
    ("0 0 1\n1 0 x\n", ":2: value: not a finite number: 'x'"),
    ("0 0 1\n1 0 nan\n", ":2: value: not a finite number"),
    ("0 0 1\n1.5 0 1\n", ":2: observation: not an integer: '1.5'"),
    ("0 0 1\n99999 0 1\n", ":2: observation: 99999 is not an observation index"),
    ("0 0 1\n# c\n3 -1 1\n", ":3: column: must not be negative"),
    ("0 0 1 4\n", ":1: expected 3 fields"),
    ("0 0 1\n0 0 2\n", ":2: observation 0, column 0 given twice (first at line 1)"),
    ("0 0 1\n1 2 1\n", ":0: column(s) 1 have no entry"),
    ("# nothing\n", ":0: no entries"),
])
def test_bad_hypothesis_file_names_file_line_and_field(tmp_path, capsys, text, where):
    f = tmp_path / "h.txt"
    f.write_text(text)
    assert main(["test", str(DEMO), "-H", f"file:{f}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{f}{where}" in err, err


def test_missing_hypothesis_file(tmp_path, capsys):
    assert main(["test", str(DEMO), "-H", f"file:{tmp_path / 'none.txt'}"]) == 2
    err = capsys.readouterr().err
    assert "none.txt:0: cannot read: No such file" in err and err.count("\n") == 1, err


def test_estimated_ap_group_gets_its_ap_test(tmp_path, capsys):
    """An AP group the model estimates is tested as F80 §7.2-7.3 do (significance, determinability,
    reliability); one not in the model as H = ∂f/∂s."""
    blk = tmp_path / "ap.json"
    rec = tmp_path / "r.json"
    rec.write_text(json.dumps({"strips": 2, "images_per_strip": 4, "ap": ["brown"], "seed": 4}))
    assert main(["simulate", str(blk), "--recipe", str(rec), "--quiet"]) == 0
    out = tmp_path / "t.json"
    assert main(["test", str(blk), "-H", "ap-group:RC30:brown", "-H", "ap-group:RC30:ebner", "--json", str(out),
                 "--quiet"]) == 0
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    tests = doc["tests"]
    assert {"T", "critical", "significant", "reliability_max", "delta0_prime_max"} <= set(tests[0]["ap_test"])
    assert tests[1]["dimension"] > 0 and tests[1]["delta_bar0_max"] > 0
    with pytest.raises(BaardaError):
        parse_hypothesis("file:")


def test_image_point_with_several_keypoints_is_named_by_its_keypoint(tmp_path, capsys):
    """A COLMAP image observing a point by two keypoints: image-point:IMAGE:POINT is ambiguous
    (one line naming the keypoints), image-point:IMAGE:POINT:KEYPOINT tests that one (its
    group's T)."""
    txt, _, _, added = duplicate_model(tmp_path)
    iid, pid, kp = added[0]
    assert main(["test", str(txt), "-H", f"image-point:{iid}:{pid}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "by keypoints" in err and str(kp) in err
    out = tmp_path / "k.json"
    assert main(["test", str(txt), "-H", f"image-point:{iid}:{pid}:{kp}", "--json", str(out), "--quiet"]) == 0
    t = json.loads(out.read_text())["tests"][0]
    adj = adjust(read_problem(txt))
    rows = [i for i, d in enumerate(adj.problem.info.ids)
            if d["image"] == str(iid) and d["point"] == str(pid) and d["keypoint"] == kp]
    assert t["rows"] == sorted(rows)
    g = next(g for g in reliability_of(adj).groups if sorted(g["members"].tolist()) == sorted(rows))
    assert t["T"] == pytest.approx(g["T"], rel=1e-8)
    assert main(["test", str(txt), "-H", f"image-point:{iid}:{pid}:999999"]) == 2
    assert "by keypoint 999999" in capsys.readouterr().err


def test_observation_quantities_of_analyze_equal_the_dense_formulas(demo, tmp_path):
    """observations[] of analyze --json: u_k = (C̄ Q_kk C̄ᵀ P)_ii, u_t = 1 − r − u_k (F80 eq. 16),
    δ̄0 = δ0 √(u_k,i / r_i) for these uncorrelated observations (F80 eq. 18) and λ̄ = δ̄0² (M84 §3.2),
    and the rejection flags by w and by τ."""
    adj, ref, _, Cbar, Qkk = demo
    out = tmp_path / "o.json"
    assert main(["analyze", str(DEMO), "--json", str(out), "--quiet"]) == 0
    doc = json.loads(out.read_text())
    obs = doc["observations"]
    r = ref.r
    uk = np.diag(Cbar @ Qkk @ Cbar.T @ ref.P)
    d0 = doc["summary"]["delta0"]
    tc = np.sqrt(adj.dof * sps.beta.isf(0.001, 0.5, (adj.dof - 1) / 2.0))
    checked = 0
    for o, ri, uki in zip(obs, r, uk):
        assert o["u_k"] == pytest.approx(uki, abs=1e-7) and o["u_t"] == pytest.approx(1 - ri - uki, abs=1e-7)
        assert o["rejected_w"] == (o["w"] is not None and abs(o["w"]) > 3.2905267314919255)
        assert o["rejected_tau"] == (o["tau"] is not None and abs(o["tau"]) > tc)
        if ri > 1e-3:
            assert o["external"] == pytest.approx(d0 * np.sqrt(max(uki, 0.0) / ri), rel=1e-6, abs=1e-9)
            assert o["lambda_bar"] == pytest.approx(o["external"] ** 2, rel=1e-12)
            checked += 1
    assert checked > 300
