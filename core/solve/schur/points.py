"""The point blocks and small dense helpers: square roots R_j of the 3 × 3 point blocks (Givens
rotations compiled, beside their numpy twin: stacked Householder QR), inverses of triangular
3 × 3 blocks, stacked small products and segment sums.
"""

from __future__ import annotations

import numpy as np

from ..compiled import NUMBA, njit, prange

_KERNELS = {}


def _givens_kernel(Bw, ent_ptr, extra, R):
    """R_e of the rows of entity e (whitened cluster rows, then the rows diag(extra_e)), one
    Givens rotation per non-zero: the upper triangular factor of a QR decomposition."""
    M = Bw.shape[1]
    for e in prange(ent_ptr.size - 1):
        r00 = r01 = r02 = r11 = r12 = r22 = 0.0
        last = ent_ptr[e + 1] * M
        for k in range(ent_ptr[e] * M, last + 3):
            if k < last:
                v0, v1, v2 = Bw[k // M, k % M, 0], Bw[k // M, k % M, 1], Bw[k // M, k % M, 2]
            else:
                v0 = extra[e, 0] if k == last else 0.0
                v1 = extra[e, 1] if k == last + 1 else 0.0
                v2 = extra[e, 2] if k == last + 2 else 0.0
            if v0 != 0.0:
                rr = np.hypot(r00, v0)
                cs, sn = r00 / rr, v0 / rr
                r00 = rr
                t = cs * r01 + sn * v1
                v1 = cs * v1 - sn * r01
                r01 = t
                t = cs * r02 + sn * v2
                v2 = cs * v2 - sn * r02
                r02 = t
            if v1 != 0.0:
                rr = np.hypot(r11, v1)
                cs, sn = r11 / rr, v1 / rr
                r11 = rr
                t = cs * r12 + sn * v2
                v2 = cs * v2 - sn * r12
                r12 = t
            if v2 != 0.0:
                r22 = np.hypot(r22, v2)
        R[e, 0, 0], R[e, 0, 1], R[e, 0, 2] = r00, r01, r02
        R[e, 1, 1], R[e, 1, 2], R[e, 2, 2] = r11, r12, r22


def point_roots(b: np.ndarray, Pc: np.ndarray, ent_ptr: np.ndarray, ent_size: np.ndarray,
                 damping: float, tol: float, backend: str = "numpy", diagonal: bool | None = None):
    """Square roots R_j (upper triangular, C_j = R_jᵀR_j) of the point blocks, from a QR
    decomposition of each point's whitened rows — never from C_j itself.

    A point near infinity has a 3 × 3 block of condition 1e12 (its depth along the rays is
    hardly determined): a Cholesky factor of C_j loses ε·cond(C_j) ≈ 1e-4 of its weakest
    direction, and every product E C_j⁻¹ Eᵀ of the elimination loses as much to cancellation
    (r_i < 0 came out). The QR of the whitened rows [L_cᵀ b_c; √(λ diag C_j)] loses only
    ε·cond(B_j) = ε·√cond(C_j), and with p̃ = R_j p as the point unknowns the point blocks are the
    identity, so no product in the elimination is formed through C_j⁻¹ (the "square-root"
    elimination: Demmel, N. et al. (2021), Square root bundle adjustment for large-scale
    reconstruction, CVPR). Givens rotations row by row (numba) or stacked Householder QR per
    track length (numpy) give the same R to round-off.

    A padded coordinate gets a unit row, ``damping`` λ adds the rows √(λ C_ii) of
    Levenberg-Marquardt. Returns (R, bad, dC): bad the first coordinate whose pivot
    R_ii² ≤ tol · C_ii (−1 where all pass), dC the diagonals of C_j (padded: 1).
    """
    nc, M, _ = b.shape
    ne = ent_size.size
    eyeM = np.eye(M)
    d = np.diagonal(Pc, axis1=1, axis2=2)
    if diagonal is None:
        diagonal = M == 1 or not np.any(Pc - d[:, :, None] * eyeM)
    if diagonal:                                                # uncorrelated rows: √p_r
        Bw = np.sqrt(np.maximum(d, 0.0))[:, :, None] * b
    else:
        L = np.linalg.cholesky(Pc + eyeM * (d <= 0)[:, None, :])       # padded rows: unit weight
        Bw = np.matmul(mT(L), b)                                      # whitened rows (nc, M, 3)
    pad = np.arange(3)[None, :] >= ent_size[:, None]
    dC = segment_sum((Bw * Bw).sum(axis=1), ent_ptr)                 # diag C_j = Σ rows²
    dC[pad] = 1.0
    extra = np.where(pad, 1.0, np.sqrt(damping * np.maximum(dC, 0.0)))  # (ne, 3)
    R = np.zeros((ne, 3, 3))
    if backend == "numba" and NUMBA:
        if "givens" not in _KERNELS:
            _KERNELS["givens"] = njit(cache=True, parallel=True)(_givens_kernel)
        _KERNELS["givens"](np.ascontiguousarray(Bw), ent_ptr, extra, R)
    else:
        count = np.diff(ent_ptr)
        for n in np.unique(count):
            ents = np.flatnonzero(count == n)
            pos = ent_ptr[ents][:, None] + np.arange(n)[None, :]
            X = np.concatenate([Bw[pos].reshape(ents.size, n * M, 3),
                                extra[ents][:, :, None] * np.eye(3)[None]], axis=1)
            R[ents] = np.linalg.qr(X, mode="r")[:, :3, :]
        sign = np.where(np.diagonal(R, axis1=1, axis2=2) < 0, -1.0, 1.0)
        R *= sign[:, :, None]                                         # positive diagonal
    piv = np.diagonal(R, axis1=1, axis2=2) ** 2
    fail = ~(piv > tol * np.where(pad, 1.0, np.maximum(dC, 1e-300)))
    bad = np.where(fail.any(axis=1), fail.argmax(axis=1), -1)
    return R, bad, dC


def upper3_inverse(R: np.ndarray) -> np.ndarray:
    """Inverses of a stack of upper triangular 3 × 3 matrices by back-substitution."""
    Ri = np.zeros_like(R)
    d = np.diagonal(R, axis1=1, axis2=2)
    Ri[:, 0, 0], Ri[:, 1, 1], Ri[:, 2, 2] = 1.0 / d[:, 0], 1.0 / d[:, 1], 1.0 / d[:, 2]
    Ri[:, 0, 1] = -R[:, 0, 1] * Ri[:, 1, 1] / d[:, 0]
    Ri[:, 1, 2] = -R[:, 1, 2] * Ri[:, 2, 2] / d[:, 1]
    Ri[:, 0, 2] = -(R[:, 0, 1] * Ri[:, 1, 2] + R[:, 0, 2] * Ri[:, 2, 2]) / d[:, 0]
    return Ri


def mT(X: np.ndarray) -> np.ndarray:
    """The transposes of a stack of matrices (a view; numpy's ``.mT``)."""
    return np.swapaxes(X, 1, 2)


def _bmm_loops(X, Y, out):
    """out[p] = X[p] @ Y[p] (pure loops, compiled by numba)."""
    for p in range(X.shape[0]):
        for i in range(X.shape[1]):
            for k in range(Y.shape[2]):
                acc = 0.0
                for j in range(X.shape[2]):
                    acc += X[p, i, j] * Y[p, j, k]
                out[p, i, k] = acc


def bmm(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """X[p] @ Y[p] for stacks of small matrices: compiled loops when numba is installed (numpy's
    stacked matmul pays a call per tiny matrix), numpy's matmul otherwise."""
    if not NUMBA:
        return np.matmul(X, Y)
    if "bmm" not in _KERNELS:
        _KERNELS["bmm"] = njit(cache=True)(_bmm_loops)
    out = np.empty((X.shape[0], X.shape[1], Y.shape[2]))
    _KERNELS["bmm"](X, Y, out)
    return out


def segment_sum(X: np.ndarray, ptr: np.ndarray) -> np.ndarray:
    """Sums of X over consecutive segments ptr[e]:ptr[e+1] (empty segments give 0)."""
    ne = ptr.size - 1
    out = np.zeros((ne,) + X.shape[1:])
    nonempty = np.flatnonzero(np.diff(ptr) > 0)
    if nonempty.size:
        out[nonempty] = np.add.reduceat(X, ptr[:-1][nonempty], axis=0)
    return out
