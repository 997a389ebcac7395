"""The adjustment result: residuals, tests and reliability measures, computed lazily.

Notation (F80): C = σ0²Q the a priori covariance of the observations,
P = C⁻¹, A the design matrix at the solution, Σ = N⁻¹ = (AᵀPA)⁻¹ (a generalised inverse for a
free network), H = AΣAᵀ, C_vv = C − H (F80 eq. 8). Per observation i:

- redundancy number r_i = (C_vv P)_ii (F80 §5), Σ r_i = r;
- Baarda's w_i = (Pv)_i / √(P C_vv P)_ii (σ0 a priori), Pope's τ_i = w_i σ0 / σ̂0;
- MDB ∇0l_i = δ0 / √(P C_vv P)_ii (F80 §5), σ_i δ0 / √r_i when uncorrelated;
- contribution to the coordinates u_k,i and to the nuisance parameters u_t,i = (B Σ_t Bᵀ P)_ii
  (F80 eq. 16), u_k,i = 1 − r_i − u_t,i;
- external reliability δ̄0,i = δ0 √((P H_k P)_ii / (P C_vv P)_ii), which is F80's
  δ0 √(u_k,i / r_i) for an uncorrelated observation (F80 eq. 18); ``external_all`` counts all
  unknowns, δ0 √((1 − r_i)/r_i).

Everything per observation needs only a_i Σ a_jᵀ for observations i, j of one covariance
cluster, i.e. entries of Σ on the pattern of N: the selected inverse of :mod:`baarda.solve.linalg`, or
for bundle blocks (``solver == "schur"``) the blocks of Σ that the reduced camera system of
:mod:`baarda.solve.schur` delivers without ever forming N.

:func:`baarda.exclusion.exclude` leaves observations out at the same linearisation point by a
low-rank (Woodbury) update of the factor and of these blocks (:class:`baarda.solve.linalg.LowRankUpdate`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from .model.problem import cluster_sizes, size_groups, size_weights
from .solve import heap
from .solve.linalg import SPDFactor, keep_columns
from .solve.pairs import cluster_blocks, cluster_pairs, pair_products
from .solve.schur import SchurFactor, bmm, schur_structure

R_EPS = 1e-10
#: clusters per chunk of the cluster passes (here and :func:`baarda.stats.groups.group_statistics`)
GROUP_CHUNK = 1 << 17
#: up to this many observations the cluster statistics are made in one pass (all five arrays at
#: once; a larger block makes (P H P)_ii and u_k,i in a second pass, when asked for)
ONE_PASS_N = 1 << 20
#: points per chunk of :attr:`Adjustment.point_cov`'s entries
POINT_CHUNK = 1 << 15


def _mm(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Stacked small-matrix products (compiled loops when numba is there)."""
    return bmm(np.ascontiguousarray(X), np.ascontiguousarray(Y))


class _Stats:
    """:attr:`Adjustment._cluster_stats`: items 0, 1 and 3 held, 2 and 4 from
    :attr:`Adjustment._cluster_extra` (made when first asked for)."""

    def __init__(self, adj, r, pcp, phkp):
        self._adj, self._held = adj, {0: r, 1: pcp, 3: phkp}

    def __getitem__(self, k):
        if k in self._held:
            return self._held[k]
        return self._adj._cluster_extra[{2: 0, 4: 1}[k]]


class HeldColumns:
    """The design matrix A (n × u) kept as its reduced copy Ar = A[:, keep] and the few entries
    of the held columns (the datum's d coordinates), so that a result does not hold A's values
    and pattern besides Ar's; :meth:`matrix` makes A again, the same values in the same canonical
    layout (:class:`Adjustment` does so when ``A`` is first asked for)."""

    def __init__(self, A: sp.csr_matrix, Ar: sp.csr_matrix, keep: np.ndarray):
        held = np.setdiff1d(np.arange(A.shape[1]), keep)
        H = sp.csr_matrix(A[:, held]).tocoo()
        self.rows, self.cols, self.vals = H.row.astype(np.int64), held[H.col], H.data.copy()
        self.Ar, self.keep, self.shape = Ar, np.asarray(keep), A.shape

    def matrix(self) -> sp.csr_matrix:
        Ar = self.Ar
        rows = np.concatenate([np.repeat(np.arange(Ar.shape[0], dtype=np.int64), np.diff(Ar.indptr)), self.rows])
        cols = np.concatenate([self.keep[Ar.indices], self.cols])
        data = np.concatenate([Ar.data, self.vals])
        A = sp.csr_matrix((data, (rows, cols)), shape=self.shape)
        A.sum_duplicates()         # (none: distinct columns) sorted, canonical
        return A


@dataclass(frozen=True, eq=False)
class Adjustment:
    """Result of :func:`baarda.adjust.adjust`; every derived quantity is a cached property."""

    problem: object
    options: object
    x: np.ndarray
    f: np.ndarray
    A: sp.csr_matrix          # n × u_free design matrix at the solution
    P: sp.csr_matrix          # weight matrix C⁻¹
    plan: object              # datum plan
    converged: bool
    iterations: int
    history: tuple = ()
    timings: dict = field(default_factory=dict)
    solver: str = "generic"   # "generic" (sparse Cholesky of N) or "schur" (baarda.solve.schur)
    # how the iterations ended (baarda.adjust: STATUS, its message, Levenberg-Marquardt used,
    # (λ, step, vᵀPv, gain ratio) per solved step, far points held in the end game)
    status: int = 0
    termination: str = ""
    damped: bool = False
    trace: tuple = ()
    far_held: int = 0
    #: what other layers derive from this result and keep with it (the reliability under a policy,
    #: the group statistics: :func:`baarda.stats.reliability.reliability_of`), keyed by them; never
    #: passed on by ``dataclasses.replace`` (a replaced result starts with an empty memo)
    memo: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        if isinstance(self.__dict__.get("A"), HeldColumns):
            # A is made from Ar and the held columns when first asked for (:class:`HeldColumns`)
            lazy = self.__dict__.pop("A")
            self.__dict__["_A_held"] = lazy
            self.__dict__.setdefault("Ar", lazy.Ar)

    def __getattr__(self, name):
        if name == "A":
            lazy = self.__dict__.get("_A_held")
            if lazy is not None:
                A = lazy.matrix()
                self.__dict__["A"] = A
                return A
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def _shape(self) -> tuple:
        """A's shape (without making A: :class:`HeldColumns`)."""
        A = self.__dict__.get("A")
        return A.shape if A is not None else self.__dict__["_A_held"].shape

    def seed(self, **values) -> "Adjustment":
        """Hand over values of cached properties computed elsewhere — the solver's own ``Ar``
        and ``schur_structure``, an exclusion's updated ``factor`` and ``hat_blocks`` — so
        they are not computed again. Only cached properties, each at most once; returns self."""
        for name, value in values.items():
            if not isinstance(getattr(type(self), name, None), cached_property):
                raise TypeError(f"Adjustment.seed: {name!r} is not a cached property")
            if name in self.__dict__:
                raise TypeError(f"Adjustment.seed: {name!r} is already computed")
            self.__dict__[name] = value
        return self

    def computed(self, *names: str) -> dict:
        """The cached properties among ``names`` that are already computed, name → value;
        nothing is computed here. With :meth:`seed`, another result built over the same
        linearisation takes what this one has (an exclusion's factor and hat blocks)."""
        out = {}
        for name in names:
            if not isinstance(getattr(type(self), name, None), cached_property):
                raise TypeError(f"Adjustment.computed: {name!r} is not a cached property")
            if name in self.__dict__:
                out[name] = self.__dict__[name]
        return out

    # -- basic quantities -------------------------------------------------------------------
    @cached_property
    def v(self) -> np.ndarray:
        """Residuals v = f(x̂) − l (adjusted minus observed), SI units."""
        return self.problem.misclosure(self.f)

    @cached_property
    def keep(self) -> np.ndarray:
        mask = np.ones(self._shape[1], dtype=bool)
        mask[self.plan.eliminate] = False
        return np.flatnonzero(mask)

    @cached_property
    def Ar(self) -> sp.csr_matrix:
        return keep_columns(self.A, self.keep)

    @cached_property
    def schur_structure(self):
        """The point-elimination layout (:mod:`baarda.solve.schur`), None for the generic solver."""
        if self.solver != "schur":
            return None
        return schur_structure(self.problem, self.Ar, self.keep, "schur")

    @cached_property
    def factor(self):
        """Factor of N = AᵀPA over the kept unknowns: :class:`baarda.solve.linalg.SPDFactor`, or
        :class:`baarda.solve.schur.SchurFactor` for the reduced camera system."""
        t0 = time.perf_counter()
        if self.schur_structure is not None:
            f = SchurFactor(self.schur_structure, self.Ar, self.P, backend=getattr(self.options, "backend", None))
        else:
            labels = np.asarray(self.problem.params.labels)[self.problem.params.free][self.keep]
            N = (self.Ar.T @ self.P @ self.Ar).tocsr()
            f = SPDFactor(N, labels=labels)
        self.timings.setdefault("factor", time.perf_counter() - t0)
        return f

    @property
    def n(self) -> int:
        return self.problem.n

    @property
    def n_unknowns(self) -> int:
        return int(self._shape[1])

    @property
    def defect(self) -> int:
        return self.plan.defect

    @cached_property
    def dof(self) -> int:
        """Redundancy r = n − rank(A) (F80 §1)."""
        return int(self.n - self.keep.size)

    @cached_property
    def Pv(self) -> np.ndarray:
        return self.P @ self.v

    @cached_property
    def vPv(self) -> float:
        """vᵀPv = Ω/σ0², the global test statistic (χ²(r) under H0)."""
        return float(self.v @ self.Pv)

    @property
    def sigma0(self) -> float:
        return float(self.problem.sigma0)

    @cached_property
    def omega(self) -> float:
        """Ω = vᵀ P_F v with the weights p = σ0²/σ² of F80 (Gama's [pvv])."""
        return self.vPv * self.sigma0 ** 2

    @cached_property
    def sigma0_post(self) -> float:
        """σ̂0 = √(Ω / r); NaN when r = 0."""
        return float(np.sqrt(self.omega / self.dof)) if self.dof > 0 else float("nan")

    # -- per-observation reliability ----------------------------------------------------------
    @cached_property
    def hat_blocks(self):
        """a_i Σ a_jᵀ and a_i Σ_t a_jᵀ (nuisance part) for the pairs of :func:`cluster_pairs`."""
        factor = self.factor
        t0 = time.perf_counter()
        if hasattr(factor, "hat_blocks"):
            out = factor.hat_blocks(self.problem.cov)
        else:
            I, J, _ = cluster_pairs(self.problem.cov)
            out = pair_products(self.Ar, factor, I, J), self._nuisance_products(I, J)
        out = self.repair_hat_blocks(*out, inplace=True)     # fresh arrays: no copies
        heap.trim(self.n)             # (the factor's freed temporaries)
        self.timings.setdefault("selected_inverse", time.perf_counter() - t0)
        return out

    def repair_hat_blocks(self, H, Ht, inplace: bool = False):
        """Recompute by direct solves the cluster blocks whose selected-inverse values betray
        round-off: a redundancy number outside [0, 1] or an asymmetric block.

        a Σ aᵀ from entries of Σ sums large terms of both signs when Σ is ill-conditioned (a
        camera that a near 2-ray point dominates); a solve N x = aᵀ followed by a x loses far
        less. Only the flagged clusters are solved for (few, if any); their number is kept in
        ``repaired_clusters``.
        """
        if not inplace:
            H, Ht = H.copy(), Ht.copy()
        pos, fixed = 0, 0
        cov = self.problem.cov
        for (m, _, members, C), Pc in zip(size_groups(cov), size_weights(cov)):
            k = members.shape[0]
            sl = slice(pos, pos + k * m * m)
            pos += k * m * m
            Hm, Htm = H[sl].reshape(k, m, m), Ht[sl].reshape(k, m, m)
            hr = np.diagonal(_mm(Hm, Pc), axis1=1, axis2=2)
            r = 1.0 - hr
            asym = np.abs(Hm - np.swapaxes(Hm, 1, 2)).max(axis=(1, 2)) if m > 1 else np.zeros(k)
            scale = np.abs(C).max(axis=(1, 2))
            if m == 1:
                out_of_range = (r[:, 0] < -1e-9) | (hr[:, 0] < -1e-9)
            else:      # single components of a correlated cluster may leave [0, 1]; the trace not
                out_of_range = (r.sum(axis=1) < -1e-9) | (hr.sum(axis=1) < -1e-9)
            bad = np.flatnonzero(out_of_range | (asym > 1e-9 * scale))
            if bad.size == 0:
                continue
            rows = members[bad].ravel()
            Ac = self.Ar[rows].toarray()
            X = self.factor.solve(Ac.T)
            Hm[bad] = np.einsum("kij,kjl->kil", Ac.reshape(bad.size, m, -1),
                                X.T.reshape(bad.size, m, -1).transpose(0, 2, 1))
            t = self.nuisance_columns
            if t.size:
                Bc = Ac[:, t]
                Xt = self.nuisance_factor.solve(Bc.T)
                Htm[bad] = np.einsum("kij,kjl->kil", Bc.reshape(bad.size, m, -1),
                                     Xt.T.reshape(bad.size, m, -1).transpose(0, 2, 1))
            H[sl], Ht[sl] = Hm.ravel(), Htm.ravel()
            fixed += bad.size
        self.__dict__["repaired_clusters"] = fixed
        return H, Ht

    @cached_property
    def nuisance_factor(self):
        """Factor of BᵀPB over the nuisance unknowns (ascending), None when there are none."""
        if hasattr(self.factor, "nuisance_factor"):
            return self.factor.nuisance_factor()
        t = self.nuisance_columns
        if t.size == 0:
            return None
        B = self.Ar[:, t].tocsr()
        return SPDFactor((B.T @ self.P @ B).tocsr())

    @cached_property
    def nuisance_columns(self) -> np.ndarray:
        kind = self.problem.params.kind[self.problem.params.free][self.keep]
        return np.flatnonzero(kind == "t")

    @cached_property
    def _cluster_stats(self):
        """Per observation: (C_vv P)_ii, (P C_vv P)_ii, (P H P)_ii, (P H_k P)_ii, u_k,i (see module
        doc), indexed 0-4. The first, second and fourth are made here; (P H P)_ii and u_k,i, which
        only :attr:`external_all`, :attr:`u_k` and :attr:`u_t` need, when first asked for (the same
        pass over the clusters: the same numbers; two arrays of n fewer held meanwhile) — in this
        pass up to :data:`ONE_PASS_N` observations (a small block's fixed cost: one pass, not two)."""
        t0 = time.perf_counter()
        one = self.n <= ONE_PASS_N and "_cluster_extra" not in self.__dict__
        out = self._cluster_pass(("r", "pcp", "phkp", "php", "uk") if one else ("r", "pcp", "phkp"))
        if one:
            self.__dict__["_cluster_extra"] = (out["php"], out["uk"])
        self.timings.setdefault("reliability", time.perf_counter() - t0)
        return _Stats(self, out["r"], out["pcp"], out["phkp"])

    @cached_property
    def _cluster_extra(self):
        out = self._cluster_pass(("php", "uk"))
        return out["php"], out["uk"]

    def _cluster_pass(self, names) -> dict:
        """The per-observation statistics ``names`` (of r, pcp, php, phkp, uk) from the cluster
        blocks of H and H_t, chunk by chunk of clusters."""
        cov = self.problem.cov
        H, Ht = self.hat_blocks
        n = self.n
        res = {name: np.empty(n) for name in names}
        r, pcp, php, phkp, uk = (res.get(name) for name in ("r", "pcp", "php", "phkp", "uk"))
        diag = lambda X: np.diagonal(X, axis1=1, axis2=2)  # noqa: E731
        for (m, members_all, C, Hc_all), (_, _, _, Htc_all), Pc_all in zip(
                cluster_blocks(cov, H), cluster_blocks(cov, Ht), size_weights(cov)):
            # in chunks of clusters (each cluster's products are its own: the same numbers), so
            # that the stacks of H P, H_k P and P H P are not made for every image point at once
            for s in range(0, members_all.shape[0], GROUP_CHUNK):
                sl = slice(s, s + GROUP_CHUNK)
                members, Hc, Htc, Pc = members_all[sl], Hc_all[sl], Htc_all[sl], Pc_all[sl]
                HP = _mm(Hc, Pc)
                HkP = HP - _mm(Htc, Pc)
                if r is not None:
                    r[members] = 1.0 - diag(HP)               # (C_vv P)_ii = 1 − (H P)_ii
                PHP = _mm(Pc, HP)
                if php is not None:
                    php[members] = diag(PHP)
                if pcp is not None:
                    pcp[members] = diag(Pc) - diag(PHP)       # P C_vv P = P − P H P
                if phkp is not None:
                    phkp[members] = diag(_mm(Pc, HkP))
                if uk is not None:
                    uk[members] = diag(HkP)
                del HP, HkP, PHP
        heap.trim(self.n)
        return res

    def cluster_cvv(self):
        """Cluster blocks of C_vv = C − A Σ Aᵀ (F80 eq. 8), as stacks per cluster size:
        a list of (members (k, m), C (k, m, m), C_vv (k, m, m))."""
        H, _ = self.hat_blocks
        return [(members, C, C - Hc) for m, members, C, Hc in cluster_blocks(self.problem.cov, H)]

    def _nuisance_products(self, I, J):
        t = self.nuisance_columns
        if t.size == 0:
            return np.zeros(len(I))
        return pair_products(self.Ar[:, t].tocsr(), self.nuisance_factor, I, J)

    @cached_property
    def r(self) -> np.ndarray:
        """Redundancy numbers r_i = (C_vv P)_ii (F80 §5), Σ r_i = r.

        For an uncorrelated observation 0 ≤ r_i ≤ 1 (round-off is clipped); a single component of a
        correlated cluster may fall outside [0, 1] — only the cluster's trace is bounded — and is
        reported as computed.
        """
        raw = self._cluster_stats[0]
        single = cluster_sizes(self.problem.cov)[self.problem.cov.cluster] == 1
        # clipped in place (no second array of n values): the few values the clip changes are
        # kept as computed for u_t = 1 − r_i − u_k,i (:attr:`u_t`)
        out = np.flatnonzero(single & ((raw < 0.0) | (raw > 1.0)))
        del single
        self.__dict__["_r_clipped"] = (out, raw[out].copy())
        raw[out] = np.clip(raw[out], 0.0, 1.0)
        return raw

    @property
    def weight_diagonal(self) -> np.ndarray:
        """P_ii per observation (the diagonal of the cluster inverses, :func:`size_weights`; made
        on demand, not kept)."""
        out = np.empty(self.n)
        for (_, _, members, _), Pc in zip(size_groups(self.problem.cov), size_weights(self.problem.cov)):
            out[members] = np.diagonal(Pc, axis1=1, axis2=2)
        return out

    @cached_property
    def uncontrolled(self) -> np.ndarray:
        """Observations whose (P C_vv P)_ii vanishes, relative to P_ii: w_i is undefined and an error
        in them cannot be detected at all (F80 §4). For an uncorrelated observation this is
        r_i ≤ R_EPS; a component of a correlated cluster can have r_i ≤ 0 while (P C_vv P)_ii > 0,
        and its w_i is defined. (The same with the clipped (P C_vv P)_ii of :attr:`qvv_pp`:
        P_ii > 0.)"""
        Pii = self.weight_diagonal
        Pii *= R_EPS
        return self._cluster_stats[1] <= Pii

    @cached_property
    def qvv_pp(self) -> np.ndarray:
        """(P C_vv P)_ii, the variance of (Pv)_i (clipped at 0 in place: the cluster statistics
        hold no second array of it)."""
        return np.maximum(self._cluster_stats[1], 0.0, out=self._cluster_stats[1])

    @cached_property
    def w(self) -> np.ndarray:
        """Baarda's w-test statistics (σ0 a priori, F80 §4); NaN where r_i = 0 (uncontrolled)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            w = self.Pv / np.sqrt(self.qvv_pp)
        w[self.uncontrolled] = np.nan
        return w

    @cached_property
    def tau(self) -> np.ndarray:
        """Pope's τ statistics (σ0 a posteriori): τ_i = w_i σ0 / σ̂0."""
        if self.dof <= 0 or self.sigma0_post == 0:
            return np.full(self.n, np.nan)
        return self.w * self.sigma0 / self.sigma0_post

    @cached_property
    def u_t(self) -> np.ndarray:
        """Contribution of each observation to the nuisance parameters (F80 eq. 16)."""
        u_k = self.u_k
        out = 1.0 - self._cluster_stats[0] - u_k
        idx, raw = self.__dict__.get("_r_clipped", (None, None))
        if idx is not None and idx.size:          # r_i as computed, not as clipped (:attr:`r`)
            out[idx] = 1.0 - raw - u_k[idx]
        return out

    @cached_property
    def u_k(self) -> np.ndarray:
        """Contribution of each observation to the coordinates u_k,i = (C̄ Q_kk C̄ᵀ P)_ii (F80 eq. 16)."""
        return self._cluster_stats[4]

    @cached_property
    def php_k(self) -> np.ndarray:
        """(P H_k P)_ii ≥ 0, H_k the coordinate part of H = A Σ Aᵀ (F80 eq. 18's numerator)."""
        return np.maximum(self._cluster_stats[3], 0.0, out=self._cluster_stats[3])   # (in place)

    @cached_property
    def php(self) -> np.ndarray:
        """(P H P)_ii ≥ 0 (the numerator of the external reliability over all unknowns)."""
        return np.maximum(self._cluster_stats[2], 0.0, out=self._cluster_stats[2])   # (in place)

    # -- covariance of the unknowns -----------------------------------------------------------
    def expand(self, vec_keep: np.ndarray) -> np.ndarray:
        """A vector (or columns) over the kept unknowns spread over all free ones (0 elsewhere)."""
        out = np.zeros((self._shape[1],) + vec_keep.shape[1:])
        out[self.keep] = vec_keep
        return out

    def solve_normal(self, b: np.ndarray) -> np.ndarray:
        """Σ b over the free parameters (with the datum's S-transformation applied)."""
        b = np.asarray(b, dtype=float)
        y = self.expand(self.factor.solve(b[self.keep]))
        return self.plan.transform(y)

    @cached_property
    def _sbase_Z(self):
        if self.plan.defect == 0:
            return None
        K = self.plan.K                                  # (EᵀG)⁻¹Eᵀ, d × u
        Z = self.expand(self.factor.solve(K.T[self.keep]))  # Σ Kᵀ, u × d
        return K, Z, K @ Z

    def cov_entries(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Entries of the a priori covariance σ0²Q_x̂x̂ (free-parameter positions), in the datum.

        For a free network the S-transformation Σ_S = S Σ Sᵀ (M84 §2) is applied entrywise.
        """
        i = np.asarray(i, dtype=np.int64)
        j = np.asarray(j, dtype=np.int64)
        pos = np.full(self._shape[1], -1)
        pos[self.keep] = np.arange(self.keep.size)
        pi, pj = pos[i], pos[j]
        ok = (pi >= 0) & (pj >= 0)
        out = np.zeros(np.broadcast(i, j).shape)
        out[ok] = self.factor.entries(pi[ok], pj[ok])
        if self._sbase_Z is not None:
            K, Z, KZ = self._sbase_Z
            G = self.plan.G
            out = (out - np.einsum("...d,...d->...", G[i], Z[j]) - np.einsum("...d,...d->...", Z[i], G[j])
                   + np.einsum("...d,de,...e->...", G[i], KZ, G[j]))
        return out

    @cached_property
    def variance_factor(self) -> float:
        """(σ0 used / σ0)²: 1 with σ0 a priori, (σ̂0/σ0)² when the problem asks for a posteriori."""
        if getattr(self.problem, "sigma_act", "apriori") == "aposteriori" and self.dof > 0:
            return (self.sigma0_post / self.sigma0) ** 2
        return 1.0

    @cached_property
    def point_cov(self) -> np.ndarray:
        """Covariance blocks of the points (m × 3 × 3, metres², σ0 as the problem asks; 0 for fixed)."""
        idx = self.problem.points.index
        fpos = np.full(self.problem.params.size, -1)
        fpos[self.problem.params.free] = np.arange(self.problem.params.free.size)
        loc = np.where(idx >= 0, fpos[np.maximum(idx, 0)], -1)
        m = len(idx)
        out = np.zeros((m, 3, 3))
        a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        # in chunks of points: each entry is computed on its own (the same numbers), and the
        # S-transformation's rows of G and Z per entry stay small (~0.1 KB each, 14 M entries at
        # 1.6 M points)
        for s in range(0, m, POINT_CHUNK):
            li, lj = loc[s:s + POINT_CHUNK, a], loc[s:s + POINT_CHUNK, b]
            both = (li >= 0) & (lj >= 0)
            out[s:s + POINT_CHUNK][both] = self.cov_entries(li[both], lj[both])
        out *= self.variance_factor
        return out

    @cached_property
    def point_sigma(self) -> np.ndarray:
        """Standard deviations of the point coordinates (m × 3, metres; 0 where fixed/absent)."""
        return np.sqrt(np.maximum(np.diagonal(self.point_cov, axis1=1, axis2=2), 0.0))

    @cached_property
    def coordinates(self) -> np.ndarray:
        """Adjusted coordinates of the points (m × 3, NaN for absent axes)."""
        idx = self.problem.points.index
        out = np.full(idx.shape, np.nan)
        out[idx >= 0] = self.x[idx[idx >= 0]]
        return out

    # -- deformations ---------------------------------------------------------------------------
    def deformation(self, error: np.ndarray) -> np.ndarray:
        """Effect ∇x = Σ AᵀP ∇l of an observation error vector ∇l on all free parameters (F80 §6).

        One solve with the cached factor; S-transformed to the problem's datum.
        """
        b = self.A.T @ (self.P @ np.asarray(error, dtype=float))
        return self.solve_normal(b)

    def point_shifts(self, dx_free: np.ndarray) -> np.ndarray:
        """A free-parameter vector as point displacements (m × 3, 0 where absent)."""
        full = np.zeros(self.problem.params.size)
        full[self.problem.params.free] = dx_free
        idx = self.problem.points.index
        out = np.zeros(idx.shape)
        out[idx >= 0] = full[idx[idx >= 0]]
        return out
