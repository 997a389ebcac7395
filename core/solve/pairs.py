"""Entries a_i Σ a_jᵀ of the hat matrix H = A Σ Aᵀ for pairs of observations (rows of A) from the
selected entries of Σ = N⁻¹, and the pairs within each covariance cluster that the per-observation
reliability measures need (F80 eq. 8: C_vv = C − H on the clusters' blocks)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..model.problem import by_size, size_groups
from .linalg import SPDFactor


def _padded_rows(A: sp.csr_matrix):
    """Columns and values of each row of a CSR matrix, padded to the longest row.

    Padding repeats the row's first column with value 0, so that every (padded) pair of columns
    of one row stays inside the pattern of N and of the selected inverse.
    """
    A = sp.csr_matrix(A)
    A.sum_duplicates()
    counts = np.diff(A.indptr)
    K = max(int(counts.max(initial=0)), 1)
    n = A.shape[0]
    first = np.where(counts > 0, A.indices[np.minimum(A.indptr[:-1], max(A.nnz - 1, 0))] if A.nnz else 0, 0)
    cols = np.repeat(first[:, None], K, axis=1).astype(np.int64)
    vals = np.zeros((n, K))
    pos = np.arange(A.nnz) - np.repeat(A.indptr[:-1], counts)
    rows = np.repeat(np.arange(n), counts)
    cols[rows, pos] = A.indices
    vals[rows, pos] = A.data
    return cols, vals


def pair_products(A: sp.csr_matrix, factor: SPDFactor, I: np.ndarray, J: np.ndarray,
                  chunk: int = 200_000) -> np.ndarray:
    """a_i Σ a_jᵀ for row pairs (I[k], J[k]) with Σ = N⁻¹ from ``factor`` (selected entries)."""
    cols, vals = _padded_rows(A)
    out = np.empty(len(I))
    for s in range(0, len(I), chunk):
        i, j = I[s:s + chunk], J[s:s + chunk]
        ci, cj = cols[i], cols[j]
        S = factor.entries(ci[:, :, None] + 0 * cj[:, None, :], cj[:, None, :] + 0 * ci[:, :, None])
        out[s:s + chunk] = np.einsum("pa,pab,pb->p", vals[i], S, vals[j])
    return out


def cluster_pairs(cov) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All ordered pairs (i, j) of observations within each covariance cluster, and the cluster.

    Pairs are laid out cluster by cluster, m² consecutive entries for a cluster of m members
    (row-major), so that ``values[start:start + m*m].reshape(m, m)`` is the cluster's block.
    """
    I, J, Cl = [], [], []
    for m, clusters, members in by_size(cov):
        a = np.repeat(members, m, axis=1)            # (k, m*m): i index
        b = np.tile(members, (1, m))                 # (k, m*m): j index
        I.append(a.ravel())
        J.append(b.ravel())
        Cl.append(np.repeat(clusters, m * m))
    return np.concatenate(I), np.concatenate(J), np.concatenate(Cl)


def cluster_blocks(cov, values):
    """Split pair values laid out by :func:`cluster_pairs` into stacks (k, m, m) per size."""
    pos = 0
    for m, clusters, members, C in size_groups(cov):
        k = clusters.size
        block = values[pos:pos + k * m * m].reshape(k, m, m)
        pos += k * m * m
        yield m, members, C, block
