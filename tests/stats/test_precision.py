"""S-transformations, criterion matrices (M84 §2) and risk minimisation (M84 §3.3)."""

from __future__ import annotations

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.stats import precision, risk
from baarda.stats.reliability import reliability_of

from tests.networks import grid_network, problem
from tests.oracle import reduced_design


@pytest.fixture(scope="module")
def pair():
    fixed = adjust(problem(grid_network(3, 3, noise_seed=8)))
    free = adjust(problem(grid_network(3, 3, noise_seed=8, datum="free")))
    return fixed, free


def test_s_transformation_to_all_points_is_the_pseudo_inverse(pair):
    """Σ of the fixed-datum adjustment carried to the S-base of all points (inner constraints,
    E = G) is N⁺ of the released network (M84 §2) — computed here densely at the same solution."""
    fixed, _ = pair
    ids = fixed.problem.points.ids
    a = precision.covariance(fixed, sbase=ids)
    params = fixed.problem.params
    k = np.flatnonzero(params.kind == "k")
    t = np.flatnonzero(params.kind == "t")
    _, J = fixed.problem.evaluate(fixed.x)
    A = J.toarray()
    P = fixed.P.toarray()
    Cbar = reduced_design(A, P, t, k)                                # F80 eq. 16
    Nplus = np.linalg.pinv(Cbar.T @ P @ Cbar, rcond=1e-12, hermitian=True)
    np.testing.assert_allclose(a.cov, Nplus, atol=1e-12 + 1e-7 * np.abs(Nplus).max())


def test_s_base_changes_ellipses_but_not_tests(pair):
    fixed, free = pair
    ids = fixed.problem.points.ids
    c1 = precision.covariance(fixed, sbase=ids[:2])
    c2 = precision.covariance(fixed, sbase=ids[-3:])
    e1, e2 = c1.ellipses(), c2.ellipses()
    assert np.nanmax(np.abs(e1[:, 0] - e2[:, 0])) > 1e-5          # the ellipses change
    # the S-base points are the most precise in their own base (the 3 free transformations of a
    # distance-direction network leave one degree of freedom on two points' 4 coordinates)
    assert (e1[:2, 0] < e2[:2, 0]).all() and (e2[-3:, 0] < e1[-3:, 0]).all()
    # r_i, w, and Baarda's λ̄ are the same in every datum
    np.testing.assert_allclose(fixed.r, free.r, atol=1e-9)
    for i in (0, 7):
        err = np.zeros(fixed.n)
        err[i] = reliability_of(fixed).mdb[i]
        lf = precision.lambda_bar(fixed, err)
        lr = precision.lambda_bar(free, err)
        assert abs(lf - lr) < 1e-6 * lf
        # λ̄ = δ̄0² for a single observation (M84 §3.2), counting all coordinates
        assert abs(lf - reliability_of(fixed).external[i] ** 2) < 1e-6 * lf


def test_generalised_eigenvalues_hand_checkable(pair):
    fixed, _ = pair
    ids = fixed.problem.points.ids
    cc = precision.covariance(fixed, sbase=ids[:2])
    in_base = np.isin(np.array(ids)[cc.point], ids[:2])
    Gk = precision.release_null_space(fixed)[1][: cc.params.size]
    G = cc.cov
    c = precision.compare(G, G, Gk, in_base)
    np.testing.assert_allclose(c.lam, 1.0, atol=1e-8)
    c2 = precision.compare(G, 2 * G, Gk, in_base)
    np.testing.assert_allclose(c2.lam, 0.5, atol=1e-8)
    assert c2.satisfied and not c.satisfied


def test_fitted_criterion_has_lambda_max_one(pair):
    fixed, _ = pair
    ids = fixed.problem.points.ids
    base = ids[:2]
    cc = precision.covariance(fixed, sbase=base)
    cols, Gnull, _ = precision.release_null_space(fixed)
    Gk = Gnull[: cc.params.size]
    in_base = np.isin(np.array(ids)[cc.point], base)
    xy = fixed.coordinates[:, :2]
    for kind in ("linear", "logarithmic", "exponential"):
        fit = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind=kind)
        H = precision.sbase_transform(precision.criterion_matrix(xy, kind, 0.0, fit["C1"], fit["C2"]), Gk, in_base)
        c = precision.compare(cc.cov, H, Gk, in_base)
        assert abs(c.lam_max - 1.0) < 1e-8
        assert c.lam_min > 0 and abs(c.lam_max / c.lam_min - fit["ratio"]) < 1e-6 * fit["ratio"]
        pattern = c.worst_pattern()
        # in the S-base: no similarity transformation of the base points (Eᵀ S = 0, M84 §2)
        assert np.abs(pattern).max() == pytest.approx(1.0)
        np.testing.assert_allclose(Gk[in_base].T @ pattern[in_base], 0.0, atol=1e-9 * np.abs(Gk).max())


def test_chaotic_structure_gives_difference_variance_d2():
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 300.0]])
    H = precision.criterion_matrix(xy, "linear", 0.0, 1e-6)
    # var(x1 − x2) = H11 + H22 − 2 H12 = d12² = C1 · 100
    v = H[0, 0] + H[2, 2] - 2 * H[0, 2]
    assert v == pytest.approx(1e-4)


@pytest.mark.parametrize("p,L1,L2,lam", [(0.01, 1.0, 10.0, 17.0), (0.05, 2.0, 1.0, 9.0), (0.001, 1.0, 100.0, 25.0)])
def test_risk_critical_value_closed_form_minimises_risk(p, L1, L2, lam):
    C = risk.critical_value(p, L1, L2, lam)
    Cn = risk.critical_value_numeric(p, L1, L2, lam)
    assert abs(C - Cn) < 1e-6
    for d in (-0.1, 0.1):
        assert risk.risk(C, p, L1, L2, lam) < risk.risk(C + d, p, L1, L2, lam)


def test_standard_ellipses_and_their_points_follow_the_closed_form():
    """a², b² = (sxx + syy)/2 ± √(((sxx − syy)/2)² + sxy²), bearing ½ atan2(2 sxy, sxx − syy)
    (the textbook closed form), and every drawn point lies on xᵀC⁻¹x = 1."""
    from baarda.stats.precision import ellipse_points, standard_ellipses

    rng = np.random.default_rng(5)
    L = rng.normal(size=(20, 2, 2))
    C = L @ np.swapaxes(L, 1, 2) + 0.01 * np.eye(2)
    e = standard_ellipses(C, scale=2.0)
    sxx, syy, sxy = C[:, 0, 0], C[:, 1, 1], C[:, 0, 1]
    root = np.sqrt(((sxx - syy) / 2) ** 2 + sxy ** 2)
    np.testing.assert_allclose(e[:, 0], 2.0 * np.sqrt((sxx + syy) / 2 + root), rtol=1e-12)
    np.testing.assert_allclose(e[:, 1], 2.0 * np.sqrt((sxx + syy) / 2 - root), rtol=1e-10)
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    d = np.mod(e[:, 2] - theta, np.pi)                      # a direction: modulo π
    np.testing.assert_allclose(np.minimum(d, np.pi - d), 0.0, atol=1e-9)
    pts = ellipse_points(standard_ellipses(C), n=17)
    q = np.einsum("mni,mij,mnj->mn", pts, np.linalg.inv(C), pts)
    np.testing.assert_allclose(q, 1.0, rtol=1e-9)


# -- M84 §2.2-2.3: the judgement in any S-base, and the fit at its true minimum (issue 14, items 2-3)

def free_network(directions_only=False):
    """A free 4 × 3 grid: distances and directions (d = 3), or directions only (d = 4)."""
    net = grid_network(4, 3, datum="free", jitter=0.5)
    if directions_only:
        keep = [i for i, o in enumerate(net.observations) if o.kind == "direction"]
        clusters = tuple(type(c)((k,), c.cov) for k, c in enumerate(net.clusters[i] for i in keep))
        net = type(net)(net.points, tuple(net.observations[i] for i in keep), clusters,
                        sigma0=net.sigma0, sigma_act=net.sigma_act)
    return adjust(problem(net))


def dense_ratio(G, H, Gnull):
    """λmax/λmin of |G − λH| = 0 on the complement of the null space, written out with numpy
    alone: P projects orthogonally onto that complement, and the pencil is solved there as
    eig(pinv(P H P) P G P) on its non-zero part (M84 eq. 3)."""
    Q, _ = np.linalg.qr(Gnull)
    P = np.eye(G.shape[0]) - Q @ Q.T
    lam = np.linalg.eigvals(np.linalg.pinv(P @ H @ P, rcond=1e-12, hermitian=True) @ (P @ G @ P)).real
    lam = np.sort(lam)[Gnull.shape[1]:]              # the d zeros of the null space dropped
    return lam[-1] / lam[0]


def first_two_points_base(adj):
    """The coordinate covariance in the S-base of the first two points, the null space over the
    coordinates, the S-base flags and the point positions."""
    ids = list(adj.problem.points.ids)
    cc = precision.covariance(adj, sbase=ids[:2])
    Gk = precision.release_null_space(adj)[1][: cc.params.size]
    return cc, Gk, np.isin(np.array(ids)[cc.point], ids[:2]), adj.coordinates[:, :2]


@pytest.mark.parametrize("directions_only", [False, True], ids=["d=3", "d=4"])
def test_criterion_judgement_same_in_every_sbase(directions_only):
    adj = free_network(directions_only)
    ids = list(adj.problem.points.ids)
    _, Gnull, _ = precision.release_null_space(adj)
    d = Gnull.shape[1]
    assert d == (4 if directions_only else 3)
    xy = adj.coordinates[:, :2]
    ratios, fits = [], []
    for base in (ids[:2], [ids[1], ids[5], ids[10]], ids[3:8]):      # minimal, 3 points, 5 points
        cc = precision.covariance(adj, sbase=base)
        Gk = Gnull[: cc.params.size]
        in_base = np.isin(np.array(ids)[cc.point], base)
        H = precision.sbase_transform(precision.criterion_matrix(xy, "logarithmic", 0.0, 1e-6, 50.0), Gk, in_base)
        c = precision.compare(cc.cov, H, Gk, in_base)
        ratios.append(c.lam_max / c.lam_min)
        # independent: the same pencil through a projector and a pseudo-inverse
        assert ratios[-1] == pytest.approx(dense_ratio(cc.cov, H, Gk), rel=1e-7)
        fits.append(precision.fit_criterion(cc.cov, xy, in_base, Gk, kind="exponential"))
        pattern = c.worst_pattern()
        assert np.abs(pattern).max() == pytest.approx(1.0)
    np.testing.assert_allclose(ratios, ratios[0], rtol=1e-8)
    np.testing.assert_allclose([f["ratio"] for f in fits], fits[0]["ratio"], rtol=1e-6)
    np.testing.assert_allclose([f["C1"] for f in fits], fits[0]["C1"], rtol=1e-6)


@pytest.mark.parametrize("kind", ["logarithmic", "exponential"])
def test_fitted_c2_is_the_minimum_over_a_fine_scan(kind):
    """M84 §2.3: C2 makes λmax/λmin smallest. A brute-force scan of 400 values over six decades
    either side of the network's distances finds nothing smaller than the fit."""
    cc, Gk, in_base, xy = first_two_points_base(free_network())
    fit = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind=kind)
    lo, hi = fit["C2_range"]
    scan = []
    for C2 in np.geomspace(lo, hi, 400):
        H = precision.sbase_transform(precision.criterion_matrix(xy, kind, 0.0, 1.0, C2), Gk, in_base)
        scan.append(dense_ratio(cc.cov, H, Gk))
    assert fit["ratio"] <= min(scan) * (1 + 1e-6)
    if kind == "exponential":
        # the network's distances are 100-180 m: a C2 in m^-½ well below 1, not at a bound in metres
        assert fit["C2"] < 1.0


def test_c0_chosen_first_keeps_lambda_max_one():
    """M84 §2.3: C0 first, then C1 so that λmax = 1 (a root, since H no longer scales with C1)."""
    cc, Gk, in_base, xy = first_two_points_base(free_network())
    free = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind="linear")
    C0 = 0.3 * free["C1"] * 100.0          # a constant part worth 30 m of the C0 = 0 fit
    fit = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind="linear", C0=C0)
    H = precision.sbase_transform(precision.criterion_matrix(xy, "linear", C0, fit["C1"]), Gk, in_base)
    c = precision.compare(cc.cov, H, Gk, in_base)
    assert fit["C0"] == C0 and 0 < fit["C1"] < free["C1"]
    assert c.lam_max == pytest.approx(1.0, rel=1e-9)


def test_compare_refuses_a_covariance_singular_on_the_compared_coordinates():
    """A function of the coordinates without variance leaves λmax/λmin undefined: refused with a
    reason (the ratio came out as −1e16), not returned."""
    from baarda.errors import BaardaError

    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    G = A @ A.T
    G[:, 0] = G[0, :] = 0.0                  # coordinate 0 fixed: left out, the rest compared
    H = np.eye(6)
    cmp_ = precision.compare(G, H, np.zeros((6, 0)), np.zeros(6, dtype=bool))
    assert cmp_.lam_min > 0 and np.isfinite(cmp_.lam_max / cmp_.lam_min)
    v = rng.normal(size=6)
    v[0] = 0.0
    S = G - np.outer(G @ v, G @ v) / (v @ G @ v)     # now G v = 0 on the compared coordinates
    with pytest.raises(BaardaError, match="singular on the coordinates compared"):
        precision.compare(S, H, np.zeros((6, 0)), np.zeros(6, dtype=bool))


def test_cli_criterion_on_fixed_points_and_on_a_singular_covariance(capsys):
    """Gama's knin traverse (fixed points outside the S-base): a finite, positive ratio; a
    network whose covariance is singular on its coordinates: exit 2 with one line saying why."""
    from baarda.cli import main
    from tests.extdata import GAMA, require_extdata

    bug = require_extdata(GAMA / "bug")
    assert main(["analyze", str(bug / "2019-08-13-traverse-knin_male.gkf"), "--criterion", "logarithmic"]) == 0
    line = next(l for l in capsys.readouterr().out.splitlines() if "criterion matrix" in l)
    ratio = float(line.split("λmax/λmin = ")[1].split()[0])
    assert 1.0 <= ratio < 1e6
    assert main(["analyze", str(bug / "test-linearization-angle.gkf"), "--criterion", "logarithmic"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("baarda: error: --criterion: the coordinate covariance is singular")


def dense_lam_max(G, H, Gnull):
    """λmax of |G − λH| = 0 on the complement of the null space (the projector and pseudo-inverse
    of :func:`dense_ratio`, numpy alone; M84 eq. 3)."""
    Q, _ = np.linalg.qr(Gnull)
    P = np.eye(G.shape[0]) - Q @ Q.T
    lam = np.linalg.eigvals(np.linalg.pinv(P @ H @ P, rcond=1e-12, hermitian=True) @ (P @ G @ P)).real
    return float(np.sort(lam)[-1])


def exponential_H(xy, C0, C1, C2):
    """M84 eq. 2 written out: d_ij² = C0² + C1 (1 − exp(−C2² l_ij)) for i ≠ j, 0 for i = j;
    cov(x_i, x_j) = cov(y_i, y_j) = d² − ½ d_ij² (d² = max d_ij², cancels in the S-base)."""
    L = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    D2 = np.where(L > 0, C0 ** 2 + C1 * (1 - np.exp(-C2 ** 2 * L)), 0.0)
    return np.kron(D2.max() - 0.5 * D2, np.eye(2))


@pytest.mark.parametrize("directions_only", [False, True], ids=["d=3", "d=4"])
def test_exponential_fit_with_c0_meets_lambda_max_one_or_says_why_not(directions_only):
    """Issue 27 item 5 (M84 §2.3): ``--criterion exponential --criterion-c0 C0`` was an internal
    error (the root of λmax(C1) = 1 was bracketed by λmax at C1 = 1 *with* C0). C0_crit: the C0
    whose nugget alone gives λmax = 1. Below it the fit has C1 > 0 and λmax = 1 in a dense
    reference H (M84 eq. 2 written out); above it C1 = 0, λmax < 1, ``C1_zero`` and a note."""
    adj = free_network(directions_only)
    cc, Gk, in_base, xy = first_two_points_base(adj)
    lam_unit = dense_lam_max(cc.cov, precision.sbase_transform(exponential_H(xy, 1.0, 0.0, 1.0), Gk, in_base), Gk)
    c0_crit = np.sqrt(lam_unit)                     # H of the nugget scales with C0²
    for f in (0.2, 0.7, 0.95):
        fit = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind="exponential", C0=f * c0_crit)
        assert fit["C1"] > 0 and not fit["C1_zero"] and fit["note"] == ""
        H = precision.sbase_transform(exponential_H(xy, f * c0_crit, fit["C1"], fit["C2"]), Gk, in_base)
        assert dense_lam_max(cc.cov, H, Gk) == pytest.approx(1.0, rel=1e-7)
        assert fit["lam_max"] == pytest.approx(1.0, rel=1e-9)
    fit = precision.fit_criterion(cc.cov, xy, in_base, Gk, kind="exponential", C0=1.5 * c0_crit)
    assert fit["C1"] == 0.0 and fit["C1_zero"] and "cannot be met" in fit["note"]
    assert fit["lam_max"] == pytest.approx(1 / 1.5 ** 2, rel=1e-7)


def test_cli_exponential_with_c0_on_wolf(tmp_path, capsys):
    """Wolf's free network: every C0 gives a fit (it was exit 3, "f(a) and f(b) must have different
    signs"); a C0 that alone bounds G is named in the text and the JSON."""
    import json

    from baarda.cli import main
    from tests.extdata import GAMA, require_extdata

    wolf = require_extdata(GAMA / "krumm" / "2D" / "Wolf_DistanceDirectionAngle_free.gkf")
    out = tmp_path / "w.json"
    for c0, zero in ((0.001, False), (0.01, False), (1.0, True), (30.0, True)):
        assert main(["analyze", str(wolf), "--criterion", "exponential", "--criterion-c0", str(c0), "--top", "1",
                     "--json", str(out)]) == 0
        text = capsys.readouterr().out
        fit = json.loads(out.read_text())["criterion"]
        assert fit["C1_zero"] is zero and (fit["lam_max"] == pytest.approx(1.0, rel=1e-9)) is (not zero)
        assert ("C0 alone bounds the covariance" in text) is zero and f"C0 = {c0:.4g} m (given)" in text
