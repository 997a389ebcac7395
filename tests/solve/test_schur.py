"""The reduced-camera-system path (baarda.solve.schur) against the generic path and dense references."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda.adjust import Options, adjust
from baarda.errors import DatumDefectError
from baarda.exclusion import exclude
from baarda.model.bundle import build_block_problem
from baarda.model.problem import subset
from baarda.simulate import simulate_block
from baarda.solve import schur
from baarda.solve.compiled import NUMBA
from baarda.solve.linalg import LowRankUpdate
from baarda.stats.hypotheses import h_point_transfer
from baarda.stats.reliability import reliability_of

from tests.oracle import nuisance_share, redundancy

BACKENDS = ["numpy"] + (["numba"] if NUMBA else [])
QUANTITIES = ("r", "u_k", "u_t")
SCALED = ("w", "mdb", "external", "external_all", "tau")


def _block(**kw):
    block, _ = simulate_block(strips=2, images_per_strip=5, seed=3, **kw)
    return block, build_block_problem(block)


def _as(adj, solver, backend=None):
    """The same adjustment (same x, same linearisation point) computed by another path."""
    opts = dataclasses.replace(adj.options, backend=backend)
    return dataclasses.replace(adj, solver=solver, options=opts, timings={})


def _measure(adj, q):
    """w and τ of the result, MDB and δ̄0 of its reliability under its options' policy."""
    return getattr(adj, q) if q in ("w", "tau") else getattr(reliability_of(adj), q)


def _agree(a, b, tol):
    for q in QUANTITIES:
        assert np.abs(getattr(a, q) - getattr(b, q)).max() <= tol, q
    ok = b.r > 0.01
    for q in SCALED:
        x, y = _measure(a, q)[ok], _measure(b, q)[ok]
        floor = 1.0 if q in ("w", "tau") else 1e-12      # test statistics: relative to max(|w|, 1)
        assert np.nanmax(np.abs(x - y) / np.maximum(np.abs(y), floor)) <= tol, q


def _dense_reference(adj):
    """r and u_t of the dense oracle (F80 §5, §6) over the kept unknowns."""
    kind = adj.problem.params.kind[adj.problem.params.free][adj.keep]
    return redundancy(adj.Ar, adj.P), nuisance_share(adj.Ar, adj.P, np.flatnonzero(kind == "t"))


CASES = {
    "control": {},
    "free": {"datum": "free"},
    "brown": {"ap": ["brown"]},
    "correlated": {"rho": 0.3, "control": "dense"},
}
#: cond(N) ≈ 1e13 with Brown's APs in a 2 × 5 block: both paths carry round-off of ~1e-9 there
#: (against a QR oracle the Schur path is the closer one). The free block's S-transformed point
#: covariances carry a few 1e-10 in either path (test_schur_point_covariance_against_qr_oracle)
TOL = {"control": 1e-9, "free": 2e-9, "brown": 1e-8, "correlated": 1e-9}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("case", list(CASES))
def test_schur_equals_generic_at_the_same_point(case, backend):
    _, pr = _block(**CASES[case])
    g = adjust(pr, Options(solver="generic"))
    s = _as(g, "schur", backend)
    assert s.schur_structure is not None and s.schur_structure.n_eliminated > 0
    assert isinstance(s.factor, schur.SchurFactor)
    _agree(s, g, TOL[case])
    assert np.abs(s.point_cov - g.point_cov).max() <= TOL[case] * np.abs(g.point_cov).max()


def _qr_covariance(adj):
    """Σ of the free parameters, S-transformed, from a dense QR of the whitened design matrix
    (no normal matrix is formed: the oracle of the square-root elimination)."""
    import scipy.linalg as la

    A = adj.Ar.toarray()
    W = la.cholesky(adj.P.toarray())                   # P = WᵀW
    R = np.linalg.qr(W @ A, mode="r")
    Ri = la.solve_triangular(R, np.eye(R.shape[0]))
    u = adj.plan.G.shape[0]
    Sig = np.zeros((u, u))
    Sig[np.ix_(adj.keep, adj.keep)] = Ri @ Ri.T
    T = np.eye(u) - adj.plan.G @ adj.plan.K
    return T @ Sig @ T.T


@pytest.mark.parametrize("backend", BACKENDS)
def test_schur_point_covariance_against_qr_oracle(backend):
    """The square-root point elimination (QR of each point's whitened rows) and the generic
    Cholesky of N are both within 1e-9 of a dense QR oracle on the free block (S-transformed
    covariances of a free block carry round-off of a few 1e-10 in either path)."""
    _, pr = _block(**CASES["free"])
    g = adjust(pr, Options(solver="generic"))
    s = _as(g, "schur", backend)
    ref = _qr_covariance(g)
    u = ref.shape[0]
    I, J = np.meshgrid(np.arange(u), np.arange(u), indexing="ij")
    err = {k: np.abs(a.cov_entries(I.ravel(), J.ravel()).reshape(u, u) - ref).max() / np.abs(ref).max()
           for k, a in (("schur", s), ("generic", g))}
    assert err["schur"] < 1e-9 and err["generic"] < 1e-9, err


def test_schur_against_dense_reference():
    _, pr = _block()
    s = adjust(pr, Options(solver="schur"))
    assert s.solver == "schur"
    r, ut = _dense_reference(s)
    assert np.abs(s.r - r).max() <= 1e-10
    assert np.abs(s.u_t - ut).max() <= 1e-10
    assert abs(s.r.sum() - s.dof) <= 1e-8


def test_backends_agree():
    if len(BACKENDS) < 2:
        pytest.skip("numba not installed")
    _, pr = _block(datum="free", rho=0.2)
    a = adjust(pr, Options(solver="schur", backend="numpy"))
    b = _as(a, "schur", "numba")
    Ha, Hta = a.hat_blocks
    Hb, Htb = b.hat_blocks
    assert np.abs(Ha - Hb).max() <= 1e-10 * np.abs(Ha).max()        # summation order only
    assert np.abs(Hta - Htb).max() <= 1e-10 * np.abs(Hta).max()      # cancellation in a Σ_t aᵀ
    _agree(a, b, 1e-9)
    assert np.array_equal(a.factor.Svals != 0, b.factor.Svals != 0)
    assert np.abs(a.factor.Svals - b.factor.Svals).max() <= 1e-12 * np.abs(a.factor.Svals).max()


@pytest.mark.parametrize("case", ["control", "free"])
def test_gauss_newton_through_schur(case):
    _, pr = _block(**CASES[case])
    g = adjust(pr, Options(solver="generic"))
    s = adjust(pr, Options(solver="schur"))
    assert s.solver == "schur" and s.converged
    assert np.abs(s.x - g.x).max() <= 1e-8
    assert s.defect == g.defect


def test_datum_coordinates_make_smaller_point_blocks():
    """Free block: the d coordinates held by the datum plan leave 2 × 2 / 1 × 1 point blocks."""
    _, pr = _block(datum="free")
    s = adjust(pr, Options(solver="schur"))
    st = s.schur_structure
    assert s.defect == 7
    sizes = st.ent_size[: st.n_points]
    assert sizes.sum() == st.n_eliminated and (sizes < 3).any()
    assert sizes.sum() + st.n_cameras == s.keep.size


def test_structure_caches_live_in_its_cache_field():
    """The structure stays frozen: what the factors keep with it (the order of S, the cluster
    weights of P, the step factor's diagonal blocks and applicability, col_S) is in its
    StructureCache, no attribute is added to it; nbytes counts the cached arrays too."""
    _, pr = _block(datum="free")
    s = adjust(pr, Options(solver="schur"))
    st = s.schur_structure
    s.factor.solve(np.ones(st.u))
    fields = {f.name for f in dataclasses.fields(st)}
    assert set(vars(st)) == fields
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.M = 3
    cache = st.cache
    assert isinstance(cache, schur.StructureCache)
    assert cache.order is not None and cache.weights is not None and cache.col_S is not None
    assert st.col_S is cache.col_S
    assert st.nbytes() >= sum(a.nbytes for a in cache.arrays()) + st.src_a.nbytes
    if NUMBA:
        cache.sn_diag = None
        before = st.nbytes()
        assert schur.StepFactor.applicable(st, s.P) and cache.step_applicable[0] is s.P
        schur.StepFactor(st, s.Ar, s.P)
        assert cache.sn_diag is not None and st.nbytes() == before + cache.sn_diag.nbytes
        assert set(vars(st)) == fields


def test_solve_and_entries_match_the_dense_inverse():
    _, pr = _block(control="dense")
    s = adjust(pr, Options(solver="schur"))
    Nd = (s.Ar.T @ s.P @ s.Ar).toarray()
    Ninv = np.linalg.inv(Nd)
    rng = np.random.default_rng(0)
    b = rng.normal(size=(Nd.shape[0], 2))
    x = s.factor.solve(b)
    assert np.abs(Nd @ x - b).max() <= 1e-7 * np.abs(b).max()
    i, j = rng.integers(0, Nd.shape[0], (2, 400))
    assert np.abs(s.factor.entries(i, j) - Ninv[i, j]).max() <= 1e-7 * np.abs(Ninv).max()
    assert s.factor.logdet() == pytest.approx(np.linalg.slogdet(Nd)[1], rel=1e-9)


def test_hypothesis_test_uses_the_schur_factor():
    block, pr = _block()
    s = adjust(pr, Options(solver="schur"))
    g = _as(s, "generic")
    pts = np.bincount(block.obs.point)
    p = int(np.flatnonzero(pts >= 3)[0])
    images = [block.images[i].id for i in block.obs.image[block.obs.point == p][:3]]
    H = h_point_transfer(pr, block.points[p].id, images)
    hs, hg = reliability_of(s).test(H), reliability_of(g).test(H)
    assert hs.T == pytest.approx(hg.T, rel=1e-9, abs=1e-12)
    assert np.allclose(hs.W, hg.W, rtol=1e-9, atol=1e-12 * np.abs(hg.W).max())


def test_local_defect_is_diagnosed():
    block, pr = _block()
    counts = np.bincount(block.obs.point)
    p = int(np.flatnonzero(counts == 2)[0])
    k = int(np.flatnonzero(block.obs.point == p)[0])
    reduced = subset(pr, np.setdiff1d(np.arange(pr.n), [2 * k, 2 * k + 1]))
    with pytest.raises(DatumDefectError):
        adjust(reduced, Options(solver="schur"))


def test_auto_choice():
    _, pr = _block()
    assert adjust(pr).solver == "generic"           # a small block: not worth eliminating
    big, _ = simulate_block(strips=4, images_per_strip=40, design=True, pattern=[5, 3])
    a = adjust(build_block_problem(big))
    assert a.solver == "schur" and a.schur_structure.worthwhile()


# ------------------------------------------------------------------------------------------
# leaving observations out (Woodbury)
# ------------------------------------------------------------------------------------------
def _rows_to_drop(block):
    counts = np.bincount(block.obs.point)
    ms = np.flatnonzero(counts[block.obs.point] >= 4)
    return [2 * ms[0], 2 * ms[0] + 1, 2 * ms[5]]        # a whole image point and half of one


@pytest.mark.parametrize("solver", ["generic", "schur"])
def test_exclude_woodbury_equals_refactoring(solver):
    block, pr = _block()
    adj = adjust(pr, Options(solver=solver))
    rows = _rows_to_drop(block)
    w = exclude(adj, rows, method="woodbury")
    f = exclude(adj, rows, method="refactor")
    assert isinstance(w.factor, LowRankUpdate) and not isinstance(f.factor, LowRankUpdate)
    assert w.n == adj.n - 3
    assert np.abs(w.x - f.x).max() <= 1e-10
    _agree(w, f, 1e-9)
    # dense reference of the reduced problem at the same linearisation point
    r, ut = _dense_reference(f)
    assert np.abs(w.r - r).max() <= 1e-9
    assert np.abs(w.u_t - ut).max() <= 1e-9
    # a full readjustment started at x̂: its first step is the same linear update
    one = adjust(subset(pr, np.setdiff1d(np.arange(pr.n), rows)), Options(solver=solver, max_iter=1), x0=adj.x)
    assert np.abs(one.x - w.x).max() <= 1e-9


def test_exclude_free_datum_and_chained():
    block, pr = _block(datum="free")
    adj = adjust(pr, Options(solver="schur"))
    rows = _rows_to_drop(block)
    a = exclude(exclude(adj, rows[:2]), [rows[2] - 2])
    b = exclude(adj, rows, method="refactor")
    _agree(a, b, 1e-8)


def test_memory_bounds_keep_the_numbers(monkeypatch):
    """SchurFactor.solve in groups of right-hand sides (SOLVE_BYTES), E_c made again for every
    solve instead of kept (KEEP_E_BYTES) and the point covariances in chunks of points
    (result.POINT_CHUNK): the same numbers as all at once."""
    import baarda.result as result_mod

    _, pr = _block(datum="free")
    adj = adjust(pr, Options(solver="schur"))
    f = adj.factor
    B = np.random.default_rng(0).standard_normal((f.m, 9))
    ref = f.solve(B)
    ref_cov = adj.point_cov.copy()
    monkeypatch.setattr(schur.factor, "SOLVE_BYTES", 1)
    monkeypatch.setattr(schur.factor, "KEEP_E_BYTES", 0)
    f2 = schur.SchurFactor(adj.schur_structure, adj.Ar, adj.P)
    assert np.allclose(f2.solve(B), ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
    assert f2._E is None                                          # made for each solve, not kept
    monkeypatch.setattr(result_mod, "POINT_CHUNK", 3)
    again = dataclasses.replace(adj, timings={})
    assert np.abs(again.point_cov - ref_cov).max() <= 1e-12 * np.abs(ref_cov).max()   # (Z by groups: round-off)
