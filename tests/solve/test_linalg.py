"""baarda.linalg: the block-tridiagonal Cholesky factor of a sparse SPD matrix, its selected
inverse (TFC73) and the Woodbury update, against dense numpy inverses and determinants."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from baarda.errors import SingularError
from baarda.solve.linalg import LowRankUpdate, SPDFactor, block_partition


def _banded_spd(m, band, seed=0):
    rng = np.random.default_rng(seed)
    A = sp.random(m, m, density=0.02, random_state=rng).toarray()
    i, j = np.indices((m, m))
    A[np.abs(i - j) > band] = 0.0
    N = A @ A.T + np.eye(m) * 0.1
    perm = rng.permutation(m)
    return sp.csr_matrix(N[np.ix_(perm, perm)])


def test_variable_block_selected_inverse():
    N = _banded_spd(400, 30)
    F = SPDFactor(N)
    assert F.nb > 1
    Ninv = np.linalg.inv(N.toarray())
    C = N.tocoo()
    assert np.abs(F.entries(C.row, C.col) - Ninv[C.row, C.col]).max() <= 1e-10 * np.abs(Ninv).max()
    i, j = np.random.default_rng(1).integers(0, 400, (2, 300))
    assert np.abs(F.entries(i, j) - Ninv[i, j]).max() <= 1e-10 * np.abs(Ninv).max()


def test_block_partition_is_tridiagonal():
    rng = np.random.default_rng(2)
    m = 500
    pi = rng.integers(0, m, 3000)
    pj = np.clip(pi + rng.integers(-40, 41, pi.size), 0, m - 1)
    starts = block_partition(pi, pj, m, 16)
    blk = np.searchsorted(starts, np.arange(m), side="right") - 1
    assert np.abs(blk[pi] - blk[pj]).max() <= 1


def test_low_rank_update():
    N = _banded_spd(120, 10, seed=3)
    F = SPDFactor(N)
    V = sp.random(4, 120, density=0.3, random_state=4).tocsr()
    M = np.diag([-0.5, 0.3, -0.2, 0.0])
    U = LowRankUpdate(F, V, M)
    N2 = N.toarray() + V.T.toarray() @ M @ V.toarray()
    inv2 = np.linalg.inv(N2)
    assert np.abs(U.dense_inverse() - inv2).max() <= 1e-9 * np.abs(inv2).max()
    assert U.logdet() == pytest.approx(np.linalg.slogdet(N2)[1], rel=1e-10)


def test_solve_logdet_and_far_entries_against_numpy():
    """N⁻¹ b for several right-hand sides, log det N, and entries of N⁻¹ outside the block
    pattern (computed by solves) equal numpy's dense results."""
    N = _banded_spd(300, 12, seed=5)
    F = SPDFactor(N)
    Nd = N.toarray()
    B = np.random.default_rng(6).normal(size=(300, 3))
    np.testing.assert_allclose(F.solve(B), np.linalg.solve(Nd, B), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(F.solve(B[:, 0]), np.linalg.solve(Nd, B[:, 0]), rtol=1e-9, atol=1e-12)
    assert F.logdet() == pytest.approx(np.linalg.slogdet(Nd)[1], rel=1e-12)
    Ninv = np.linalg.inv(Nd)
    i, j = F.perm[:5], F.perm[-5:]                        # first and last blocks: not neighbours
    assert F.nb > 2 and (F.iperm[j] - F.iperm[i] > 2 * F.bandwidth).all()
    np.testing.assert_allclose(F.entries(i, j), Ninv[i, j], rtol=1e-9, atol=1e-12 * np.abs(Ninv).max())


def test_update_removing_the_only_observation_of_an_unknown_is_singular():
    """N = AᵀA with unknown 0 in one row of A only: taking that row out (M = −1) leaves N'
    singular, which the update reports instead of returning a meaningless inverse."""
    rng = np.random.default_rng(7)
    A = rng.normal(size=(20, 6))
    A[1:, 0] = 0.0
    F = SPDFactor(sp.csr_matrix(A.T @ A))
    with pytest.raises(SingularError):
        LowRankUpdate(F, sp.csr_matrix(A[:1]), np.array([[-1.0]]))
    # the same row down-weighted by half keeps N' regular: Woodbury equals the dense inverse
    U = LowRankUpdate(F, sp.csr_matrix(A[:1]), np.array([[-0.5]]))
    N2 = A.T @ A - 0.5 * np.outer(A[0], A[0])
    np.testing.assert_allclose(U.dense_inverse(), np.linalg.inv(N2), rtol=1e-9, atol=1e-12)


def test_empty_matrix():
    F = SPDFactor(sp.csr_matrix((0, 0)))
    assert F.m == 0 and F.logdet() == 0.0 and F.solve(np.zeros(0)).shape == (0,)
