"""The order of the reduced camera system S for its block-tridiagonal factor (reverse
Cuthill-McKee or the spectral order of the supernode graph), and a factor kept in another order.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import laplacian, reverse_cuthill_mckee
from scipy.sparse.linalg import eigsh

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
