"""The tests' oracle: the paper's formulas written out with dense numpy matrices.

The package never forms N⁻¹ or C_vv densely (../shared/STYLE.md principle 6); these functions do, for small
problems, so that every sparse path can be checked against the equation it implements. One copy
for the tests and the benchmarks (``bench/`` imports it too).

- F80 eq. 8: C_vv = C − A N⁻ Aᵀ, N = AᵀPA, P = C⁻¹;
- F80 §5: r_i = (C_vv P)_ii = 1 − (A N⁻ Aᵀ P)_ii;
- F80 §4 / M84 §3.1: w_i = (P v)_i / √(P C_vv P)_ii (σ0 = 1);
- F80 eq. 16: C̄ = (I − B (BᵀPB)⁻¹ BᵀP) C, the coordinate columns reduced for the nuisance
  unknowns; u_t,i = (B (BᵀPB)⁻¹ BᵀP)_ii their share of 1 − r_i.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as la


def _dense(M) -> np.ndarray:
    return M.toarray() if hasattr(M, "toarray") else np.asarray(M, dtype=float)


def normal_inverse(A, P, pinv: bool = False) -> np.ndarray:
    """N⁻¹ of N = AᵀPA (F80 eq. 3); the pseudo-inverse N⁺ when ``pinv`` (a datum defect)."""
    A = _dense(A)
    N = A.T @ (P @ A)
    if pinv:
        return np.linalg.pinv(N, rcond=1e-12, hermitian=True)
    return np.linalg.inv(N)


def redundancy(A, P, Ninv=None) -> np.ndarray:
    """r_i = 1 − (A N⁻¹ Aᵀ P)_ii (F80 §5) without forming an n × n matrix: for symmetric P,
    (A N⁻¹ Aᵀ P)_ii = Σ_k (A N⁻¹)_ik (P A)_ik. ``P`` may be sparse."""
    A = _dense(A)
    PA = _dense(P @ A)
    if Ninv is None:
        Ninv = np.linalg.inv(A.T @ PA)
    return 1.0 - ((A @ Ninv) * PA).sum(axis=1)


def nuisance_share(A, P, t) -> np.ndarray:
    """u_t,i = (B (BᵀPB)⁻¹ BᵀP)_ii with B = A[:, t], the nuisance columns (F80 §6)."""
    B = _dense(A)[:, t]
    P = _dense(P)
    return np.diag(B @ np.linalg.inv(B.T @ P @ B) @ B.T @ P)


def reduced_design(A, P, t, k) -> np.ndarray:
    """C̄ = C − B (BᵀPB)⁻¹ BᵀP C with B = A[:, t], C = A[:, k] (F80 eq. 16)."""
    A, P = _dense(A), _dense(P)
    B, C = A[:, t], A[:, k]
    return C - B @ np.linalg.solve(B.T @ P @ B, B.T @ P @ C)


@dataclass(frozen=True)
class Dense:
    """Dense C_vv and what follows from it for a design A, covariance C and residuals v."""

    A: np.ndarray
    C: np.ndarray
    P: np.ndarray
    Ninv: np.ndarray
    Cvv: np.ndarray
    v: np.ndarray

    @classmethod
    def of(cls, A, C, v) -> "Dense":
        """F80 eq. 8 with N⁻ the pseudo-inverse (any datum)."""
        A, C = _dense(A), _dense(C)
        P = np.linalg.inv(C)
        Ninv = normal_inverse(A, P, pinv=True)
        return cls(A, C, P, Ninv, C - A @ Ninv @ A.T, np.asarray(v, dtype=float))

    @property
    def r(self) -> np.ndarray:
        """Redundancy numbers (C_vv P)_ii (F80 §5)."""
        return np.diag(self.Cvv @ self.P)

    @property
    def w(self) -> np.ndarray:
        """Baarda's w_i = (P v)_i / √(P C_vv P)_ii with σ0 = 1 (F80 §4)."""
        return (self.P @ self.v) / np.sqrt(np.diag(self.P @ self.Cvv @ self.P))


def dense(adj) -> Dense:
    """The dense oracle of an adjustment: its design A, the problem's C and its residuals v."""
    return Dense.of(adj.A, adj.problem.cov.matrix(), adj.v)


def pcp(adj) -> np.ndarray:
    """P C_vv P (F80 eq. 8) without the normal equations: L⁻ᵀ (I − U Uᵀ) L⁻¹ with C = L Lᵀ and U an
    orthonormal basis of L⁻¹A (SVD). Squaring the condition in N = AᵀPA loses observations that are
    nearly uncontrolled (the x coordinates of a 2-ray point, r ≈ 1e-6) and hypotheses the unknowns
    nearly absorb to round-off; this keeps them."""
    A, C = _dense(adj.A), _dense(adj.problem.cov.matrix())
    Lc = np.linalg.cholesky(C)
    At = la.solve_triangular(Lc, A, lower=True)
    U, sv, _ = np.linalg.svd(At, full_matrices=False)
    U = U[:, sv > 1e-12 * sv[0]]
    Linv = la.solve_triangular(Lc, np.eye(C.shape[0]), lower=True)
    return Linv.T @ (np.eye(C.shape[0]) - U @ U.T) @ Linv
