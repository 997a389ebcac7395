"""The reduced camera system S once its values are summed: its order for the block-tridiagonal
factor (reverse Cuthill-McKee or the spectral order of the supernode graph), its factor — the
one place where both :class:`baarda.solve.schur.factor.SchurFactor` and
:class:`baarda.solve.schur.step.StepFactor` make and factor S from the values their kernels
scatter — the diagonal of N over every unknown, and a factor kept in another order.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import laplacian, reverse_cuthill_mckee
from scipy.sparse.linalg import eigsh

from ...errors import SingularError
from ..linalg import SPDFactor, block_partition


def _partition_cost(Smat, perm) -> float:
    """Flops (∝ Σ s_K³) of the block-tridiagonal factor of S in the order ``perm``."""
    ip = np.empty_like(perm)
    ip[perm] = np.arange(perm.size)
    C = Smat.tocoo()
    size = np.diff(block_partition(ip[C.row], ip[C.col], perm.size))
    return float((size.astype(float) ** 3).sum())


def camera_order(Smat, st) -> np.ndarray:
    """Order of S for the block-tridiagonal factor: reverse Cuthill-McKee, or the spectral order
    of the supernode graph (sorted Fiedler vector; Barnard, Pothen & Simon 1995) when its blocks
    are cheaper — strip blocks are ordered along the block rather than in RCM's diagonal fronts.
    It depends on the pattern only, so it is computed once per structure (kept in its cache)."""
    if st.cache.order is None:
        st.cache.order = _compute_order(Smat, st)
    return st.cache.order


def _compute_order(Smat, st) -> np.ndarray:
    rcm = np.asarray(reverse_cuthill_mckee(Smat, symmetric_mode=True), dtype=np.int64)
    nsn = st.sn_t.size
    if nsn < 50:
        return rcm
    Pat = sp.csr_matrix((np.ones(st.bcol.size), st.bcol, st.bptr), shape=(nsn, nsn))
    try:
        vals, vecs = eigsh(laplacian(Pat) + 1e-8 * sp.identity(nsn), k=2, sigma=-1e-3, which="LM")
    except Exception:          # no convergence: keep RCM
        return rcm
    fiedler = vecs[:, np.argsort(vals)[1]]
    sn_order = np.argsort(fiedler, kind="stable")
    size = np.diff(st.sn_ptr)
    spec = (np.repeat(st.sn_ptr[sn_order], size[sn_order])
            + np.arange(st.sn_ptr[-1]) - np.repeat(np.cumsum(size[sn_order]) - size[sn_order], size[sn_order]))
    return spec if _partition_cost(Smat, spec) < _partition_cost(Smat, rcm) else rcm


class Permuted:
    """A factor kept in another order: unknown k of the caller is unknown perm[k] of the factor."""

    def __init__(self, factor: SPDFactor, perm: np.ndarray):
        self.factor, self.perm, self.m = factor, perm, perm.size

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        y = np.empty_like(b)
        y[self.perm] = b
        return self.factor.solve(y)[self.perm]


def singular_error(st, col: int) -> SingularError:
    """The error naming reduced unknown ``col`` (its label where the structure has labels)."""
    name = st.labels[col] if st.labels is not None else f"unknown {col}"
    return SingularError(unknown=name, index=col)


def check_dense(Smat, dense_limit: int) -> None:
    """MemoryError when S has more than ``dense_limit`` unknowns and a band after reverse
    Cuthill-McKee of at least half its size (its factor would be dense)."""
    nc_ = Smat.shape[0]
    if nc_ <= dense_limit:
        return
    perm = reverse_cuthill_mckee(Smat, symmetric_mode=True)
    iperm = np.empty_like(perm)
    iperm[perm] = np.arange(nc_)
    Cm = Smat.tocoo()
    band = int(np.abs(iperm[Cm.row] - iperm[Cm.col]).max(initial=0))
    if 2 * band >= nc_:
        raise MemoryError(f"the reduced camera system ({nc_} unknowns) has a band of {band}: "
                          f"its factor would be dense beyond DENSE_LIMIT = {dense_limit}")


def factor_reduced(st, S: np.ndarray, pivot_tol: float, dense_limit: int | None = None) -> SPDFactor:
    """S, its values ``S`` on the block pattern of ``st`` (rows and columns ``st.flat_r``,
    ``st.flat_c``), as a sparse matrix factored in :func:`camera_order` (first
    :func:`check_dense` against ``dense_limit`` unless None). Raises the SingularError of
    :func:`singular_error` naming the reduced unknown at the failing pivot."""
    nc_ = st.cam.size
    Smat = sp.csr_matrix((S, (st.flat_r, st.flat_c)), shape=(nc_, nc_))
    if dense_limit is not None:
        check_dense(Smat, dense_limit)
    try:
        return SPDFactor(Smat, labels=None if st.labels is None else st.labels[st.cam],
                         pivot_tol=pivot_tol, perm=camera_order(Smat, st))
    except SingularError as err:
        raise singular_error(st, int(st.cam[err.index])) from None


def unknown_diagonal(st, diag_c: np.ndarray, dC: np.ndarray) -> np.ndarray:
    """diag(N) over the reduced unknowns from diag(U) by S index (``diag_c``) and the
    diagonals of the point blocks C_j (``dC``, (entities, 3))."""
    diag = np.empty(st.u)
    diag[st.cam] = diag_c
    okc = st.ent_cols >= 0
    diag[st.ent_cols[okc]] = dC[okc]
    return diag


def point_places(st) -> tuple[np.ndarray, np.ndarray]:
    """(places in the (entities · 3) point layout that hold a coordinate, the reduced unknown of
    each): how the factors' solves move point values between the two."""
    pflat = np.flatnonzero(st.ent_cols.ravel() >= 0)
    return pflat, st.ent_cols.ravel()[pflat]
