"""Point elimination: the reduced camera system of bundle blocks and its selected inverse.

A bundle block has many point unknowns k in 3 × 3 blocks (2 × 2 or 1 × 1 where the datum holds
some coordinates) that no observation couples with each other: every image point, every control
point sees one point and some nuisance parameters t (orientations, APs; F80 eq. 1). Order the
unknowns as "cameras" c (all unknowns that are not eliminated) and points p:

.. math::

    N = \\begin{pmatrix} U & W \\\\ W^T & V \\end{pmatrix},\\quad
    V = \\operatorname{diag}(C_j),\\quad S = U - W V^{-1} W^T

(S the reduced camera system, the Schur complement of V). With Z_j = C_j⁻¹ W_jᵀ the blocks of
Σ = N⁻¹ are (the block inverse of N; TFC73 for S)

.. math::

    Σ_{cc} = S^{-1},\\quad Σ_{c p_j} = -Σ_{cc} Z_j^T,\\quad
    Σ_{p_j p_j} = C_j^{-1} + Z_j Σ_{cc} Z_j^T .

Z_j has non-zero columns only for the cameras K_j that observe point j, and every pair of them is
a non-zero block of S; so the selected inverse of S on its own pattern (Takahashi,
:class:`baarda.solve.linalg.SPDFactor`) gives every block that a_i Σ a_iᵀ of an observation of point j
needs. Per covariance cluster c (one image point, one control point) of point j, with a_c its
camera columns, b_c its point columns, P_c its weight, E_c = a_cᵀ P_c b_c and E_c C_j⁻¹ = Q_c:

    W_j = Σ_c E_c,           G_c = Σ_{k_c, p_j} = −Σ_{c' ∈ j} Σ_{k_c k_c'} Q_c',
    Σ_{p_j p_j} = C_j⁻¹ − Σ_c Q_cᵀ G_c,
    a_c Σ a_cᵀ (the cluster's block of A Σ Aᵀ) = a Σ_{kk} aᵀ + a G bᵀ + b Gᵀ aᵀ + b Σ_pp bᵀ.

The two loops over pairs of clusters of one point — scattering −Q_c E_c'ᵀ into S, and gathering
Σ_{k_c k_c'} Q_c' — are kernels compiled by numba when it is installed; a chunked numpy version
of the same formulas gives the same numbers to round-off (``backend="numpy"``).

Cameras are grouped into *supernodes*, columns that the same observation rows touch (the six
orientation unknowns of one image, the APs of one camera), and S is stored as dense blocks
between supernodes on the pattern of point-sharing (a block-sparse matrix). S is then factored by
:class:`baarda.solve.linalg.SPDFactor` (reverse Cuthill-McKee, block tridiagonal; a small or densely
connected S becomes one dense LAPACK Cholesky). Nothing larger than the band of S is ever dense;
:data:`DENSE_LIMIT` bounds the size of a dense S.

Solving N x = b goes through the same elimination: y_p = V⁻¹ b_p,
S x_c = b_c − W y_p, x_p = y_p − V⁻¹ Wᵀ x_c, with W applied as A_cᵀ P A_p (sparse products).

The nuisance split u_t (F80 eq. 16) needs (BᵀPB)⁻¹ over the nuisance columns B; that matrix is
U restricted to the nuisance supernodes (block diagonal per image without APs, coupled through
shared APs otherwise) and is factored and selected-inverted the same way.

Datum: eliminated points are whatever coordinates remain after the datum plan
(:mod:`baarda.datum`) holds d coordinates of S-base points: a point with a held coordinate simply
has a 2 × 2 or 1 × 1 block. The regularised system is the one the generic path solves, so x̂, the
generalised inverse and every statistic agree with it.

Reference: Takahashi, K., Fagan, J., Chen, M.-S. (1973), Formation of a sparse bus impedance
matrix and its application to short circuit study, PICA; Triggs, B. et al. (2000), Bundle
adjustment — a modern synthesis, §6.1 (reduced camera system).

The package, by concept: :mod:`.structure` (the elimination layout, :func:`schur_structure`),
:mod:`.kernels` (the pair loops, each compiled kernel beside its numpy twin), :mod:`.points`
(square roots of the point blocks, small stacked helpers), :mod:`.ordering` (the order of S),
:mod:`.factor` (:class:`SchurFactor`) and :mod:`.step` (:class:`StepFactor`, the iterations'
fused factor). numba is imported only by :mod:`baarda.solve.compiled`.
"""

from __future__ import annotations

from .factor import (BACKENDS, DENSE_LIMIT, KEEP_E_BYTES, PIVOT_TOL, POINT_PIVOT_TOL, SOLVE_BYTES,
                     SchurFactor, default_backend)
from .kernels import CHUNK, SCATTER_CHUNKS
from .points import bmm
from .step import StepFactor
from .structure import (MAX_CLUSTER, MIN_ELIMINATED, MIN_SHARE, SOLVERS, Structure, StructureCache,
                        analyse, schur_structure)

__all__ = ["BACKENDS", "CHUNK", "DENSE_LIMIT", "KEEP_E_BYTES", "MAX_CLUSTER", "MIN_ELIMINATED", "MIN_SHARE",
           "PIVOT_TOL", "POINT_PIVOT_TOL", "SCATTER_CHUNKS", "SOLVERS", "SOLVE_BYTES", "SchurFactor",
           "StepFactor", "Structure", "StructureCache", "analyse", "bmm", "default_backend", "schur_structure"]
