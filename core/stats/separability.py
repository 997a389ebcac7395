"""Separability of alternative hypotheses: the correlation of their test statistics (M84 §3.3, F80 §7.4).

Two hypotheses H1 (n × q1) and H2 (n × q2) are tested through g_k = H_kᵀ P v, whose joint
covariance (σ0 absorbed in P) is

    D(g1, g2) = [W11 W12; W21 W22],   W_jk = H_jᵀ P C_vv P H_k = H_jᵀPH_k − (AᵀPH_j)ᵀ Σ (AᵀPH_k)

(F80 eq. 8, 10; W_kk is the W_s of :mod:`baarda.stats.hypotheses`). For two one-dimensional tests
(q1 = q2 = 1, e.g. Baarda's w-tests of observations i and j, H = e_i, e_j) the correlation of the
test statistics is

    ρ12 = W12 / √(W11 W22),   for w-tests ρ_ij = (P C_vv P)_ij / √((P C_vv P)_ii (P C_vv P)_jj).

For q > 1 the statistics T_k = g_kᵀ W_kk⁻¹ g_k are the squared lengths of the projections of one
standard normal vector onto two subspaces; their cosines are the canonical correlations of g1 and g2,
the singular values of W11^(−½) W12 W22^(−½). T1 ≡ T2 for every data set exactly when the subspaces
coincide (q1 = q2 and every canonical correlation 1): then the data cannot tell the two hypotheses
apart (F80 §7.4: "identical test statistics T or R"; F80 §7.5). The same happens when a gross error
in one observation has the effect of a gross error in another (the two image points of a 2-ray
point: |ρ| = 1), and M84 §3.3 notes that strongly correlated test variates make the rejection of one
alternative involve the rejection of others.

Functions: :func:`canonical_correlations`, :func:`correlation` (one number per pair: the signed ρ
for two 1D tests, else the smallest canonical correlation — 1 iff one test space contains the
other), :func:`twins` (the w-tests perfectly correlated with one observation's, one solve) and
:func:`inseparable_pairs` (groups of hypotheses whose statistics are (near-)perfectly correlated,
for all w-tests of a result or for given hypotheses).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import HypothesisError, OptionError

#: default threshold on |ρ| above which two tests are reported as not separable
THRESHOLD = 0.99


@dataclass(frozen=True)
class PartialPair:
    """Two hypotheses whose test spaces share a direction (largest canonical correlation ≥ the
    threshold) but not all (smallest below it): along that direction the data cannot tell them
    apart — an error there is seen by both tests alike — while the other directions separate them
    (F80 §7.4, M84 §3.3). ``members``: the two labels; ``largest``, ``smallest``: the canonical
    correlations; ``direction``: the shared direction in the first hypothesis' parameters (unit)."""

    members: tuple
    largest: float
    smallest: float
    direction: tuple


@dataclass(frozen=True)
class InseparableGroup:
    """Hypotheses whose test statistics are pairwise linked by |ρ| ≥ threshold (connected
    components of that graph). ``members``: observation indices (w-tests) or the labels of the given
    hypotheses; ``rho``: the smallest |ρ| on the links that join them."""

    members: tuple
    rho: float


def _as_matrix(adj, H) -> sp.csc_matrix:
    H = sp.csc_matrix(H) if not sp.issparse(H) else H.tocsc()
    if H.shape[0] != adj.n:
        raise HypothesisError(f"H has {H.shape[0]} rows for {adj.n} observations", rows=H.shape[0], n=adj.n)
    return H


class _Reduced:
    """P H, AᵀPH and Σ AᵀPH of one hypothesis (q solves with the cached factor)."""

    def __init__(self, adj, H):
        self.H = _as_matrix(adj, H)
        PH = adj.P @ self.H
        self.PH = PH.toarray() if sp.issparse(PH) else np.asarray(PH)
        self.AtPH = np.asarray(adj.Ar.T @ self.PH)
        self.Y = np.asarray(adj.factor.solve(self.AtPH)).reshape(self.AtPH.shape)

    def w_with(self, other: "_Reduced") -> np.ndarray:
        """W_jk = H_jᵀPH_k − (AᵀPH_j)ᵀ Σ (AᵀPH_k) (module docstring)."""
        return np.asarray(self.H.T @ other.PH) - self.AtPH.T @ other.Y


def _inverse_sqrt(W: np.ndarray) -> np.ndarray:
    """W^(−½) on the space of the eigenvalues of W the test counts (the tolerance of
    :func:`baarda.stats.hypotheses.test`), q × rank."""
    W = 0.5 * (W + W.T)
    lam, V = np.linalg.eigh(W)
    pos = lam > 1e-10 * max(lam.max(initial=0.0), 1e-300)
    return V[:, pos] / np.sqrt(lam[pos])


def _canonical(W11, W12, W22) -> np.ndarray:
    X1, X2 = _inverse_sqrt(W11), _inverse_sqrt(W22)
    if X1.shape[1] == 0 or X2.shape[1] == 0:
        return np.zeros(0)
    return np.clip(np.linalg.svd(X1.T @ W12 @ X2, compute_uv=False), 0.0, 1.0)


def _single(W11, W12, W22) -> float:
    """The pair's one number (see :func:`correlation`)."""
    if W11.shape == (1, 1) and W22.shape == (1, 1):
        d = float(W11[0, 0] * W22[0, 0])
        return float(np.clip(W12[0, 0] / np.sqrt(d), -1.0, 1.0)) if d > 0 else float("nan")
    c = _canonical(W11, W12, W22)
    return float(c.min()) if c.size else float("nan")


def canonical_correlations(adj, H1, H2) -> np.ndarray:
    """The canonical correlations of g1 = H1ᵀPv and g2 = H2ᵀPv, descending (F80 §7.4, M84 §3.3).

    The singular values of W11^(−½) W12 W22^(−½) (module docstring; F80 eq. 8, 10): the cosines of
    the angles between the two test spaces. Their number is the smaller rank of W11, W22; empty when a
    hypothesis is not testable (W = 0).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    H1, H2 : numpy.ndarray or scipy.sparse matrix
        n × q1 and n × q2 hypothesis matrices, dimensionless.

    Returns
    -------
    numpy.ndarray
        The canonical correlations in [0, 1], dimensionless.
    """
    a, b = _Reduced(adj, H1), _Reduced(adj, H2)
    return _canonical(a.w_with(a), a.w_with(b), b.w_with(b))


def shared_part(adj, H1, H2, g1=None) -> tuple[np.ndarray, float]:
    """How much of one hypothesis' statistic lies along the direction it shares with another (F80 §7.4).

    The canonical correlations of H1's and H2's tests, and the part of H1's statistic
    T1 = g1ᵀ W11⁻¹ g1 along the first canonical direction, (u1ᵀ W11^(−½) g1)² / T1 ∈ [0, 1]
    (F80 eq. 10: W11 ∇ is the signature of an error ∇). Where the largest canonical correlation
    is 1, H2's test sees that direction alike: the larger the part, the less the data tell H1
    from H2.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    H1, H2 : scipy.sparse matrix
        n × q1 and n × q2 hypothesis matrices, dimensionless.
    g1 : numpy.ndarray, optional
        The misclosure of H1's test (q1,), default H1ᵀ P v of ``adj``; P v in units⁻¹ of the observations.

    Returns
    -------
    numpy.ndarray
        The canonical correlations, descending, in [0, 1].
    float
        The part of T1 along the first canonical direction, in [0, 1] (0 when T1 = 0).
    """
    a, b = _Reduced(adj, H1), _Reduced(adj, H2)
    W11, W12, W22 = a.w_with(a), a.w_with(b), b.w_with(b)
    X1, X2 = _inverse_sqrt(W11), _inverse_sqrt(W22)
    if X1.shape[1] == 0 or X2.shape[1] == 0:
        return np.zeros(0), 0.0
    U, c, _ = np.linalg.svd(X1.T @ W12 @ X2)
    z = X1.T @ (np.asarray(a.H.T @ adj.Pv).ravel() if g1 is None else np.asarray(g1, dtype=float).ravel())
    T = float(z @ z)
    part = float((U[:, 0] @ z) ** 2 / T) if T > 0 else 0.0
    return np.clip(c, 0.0, 1.0), min(part, 1.0)


def correlation(adj, H1, H2) -> float:
    """Correlation of the test statistics of two hypotheses (M84 §3.3, F80 §7.4).

    For two one-dimensional hypotheses (columns h1, h2; w-tests: h = e_i) the signed
    ρ = h1ᵀ P C_vv P h2 / √(h1ᵀ P C_vv P h1 · h2ᵀ P C_vv P h2) ∈ [−1, 1]. For q > 1 the smallest
    canonical correlation over the smaller test space (module docstring) ∈ [0, 1]: 1 when that
    space lies in the other one — for q1 = q2 the two tests then give the same T on any data.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    H1, H2 : numpy.ndarray or scipy.sparse matrix
        n × q1 and n × q2 hypothesis matrices (dense or sparse), dimensionless.

    Returns
    -------
    float
        ρ, dimensionless; NaN when a hypothesis is not testable at all (W = 0).
    """
    a, b = _Reduced(adj, H1), _Reduced(adj, H2)
    return _single(a.w_with(a), a.w_with(b), b.w_with(b))


def twins(adj, i: int, threshold: float = THRESHOLD) -> list[tuple[int, float]]:
    """The observations j ≠ i whose w-test has |ρ_ij| ≥ ``threshold`` with observation i's (F80 §7.4).

    ρ_ij = (P C_vv P)_ij / √((P C_vv P)_ii (P C_vv P)_jj). One solve: the column
    P C_vv P e_i = P e_i − P A Σ AᵀP e_i. Uncontrolled observations (no w) are never twins.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    i : int
        Observation index.
    threshold : float
        Smallest |ρ| reported, in (0, 1].

    Returns
    -------
    list of tuple
        (j, ρ_ij) with ρ dimensionless, largest |ρ| first.
    """
    P = adj.P
    pe = np.asarray(P[:, [i]].toarray() if sp.issparse(P) else P[:, [i]]).ravel()
    y = np.asarray(adj.factor.solve(np.asarray(adj.Ar.T @ pe))).ravel()
    s = pe - np.asarray(P @ (adj.Ar @ y)).ravel()
    qpp = adj.qvv_pp
    if not qpp[i] > 0 or adj.uncontrolled[i]:
        return []
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = s / np.sqrt(qpp[i] * qpp)
    ok = (~adj.uncontrolled) & (np.abs(rho) >= threshold)
    ok[i] = False
    js = np.flatnonzero(ok)
    js = js[np.argsort(-np.abs(rho[js]), kind="stable")]
    return [(int(j), float(np.clip(rho[j], -1.0, 1.0))) for j in js]


def _components(n: int, I: np.ndarray, J: np.ndarray, rho: np.ndarray) -> list[tuple[list[int], float]]:
    """Connected components (size ≥ 2) of the graph on n nodes with edges (I, J): node lists and
    the smallest |ρ| on their edges."""
    if I.size == 0:
        return []
    g = sp.coo_matrix((np.ones(I.size), (I, J)), shape=(n, n))
    _, label = sp.csgraph.connected_components(g, directed=False)
    out = {}
    for a, b, r in zip(I.tolist(), J.tolist(), np.abs(rho).tolist()):
        nodes, low = out.get(label[a], (set(), 1.0))
        out[label[a]] = (nodes | {a, b}, min(low, r))
    return sorted(((sorted(nodes), low) for nodes, low in out.values()), key=lambda t: t[0])


def _incidence(adj, columns=None) -> sp.csr_matrix:
    """Rows: observations; columns: the parameters of ``adj.Ar`` (all, or the ``columns``) and the
    covariance clusters, 1 where the observation touches them."""
    n = adj.n
    M = sp.csr_matrix(adj.Ar if columns is None else adj.Ar[:, columns], copy=True)
    M.data = np.ones_like(M.data)
    cl = adj.problem.cov.cluster
    K = sp.csr_matrix((np.ones(n), (np.arange(n), cl)), shape=(n, int(cl.max()) + 1 if n else 0))
    return sp.hstack([M, K]).tocsr()


def _sharing_pairs(inc: sp.csr_matrix, rows: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs i < j (i or j in ``rows``, both ``ok``) whose rows of ``inc`` share a column."""
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    C = (inc[rows] @ inc.T).tocoo()
    I, J = rows[C.row], C.col.astype(np.int64)
    keep = (I != J) & ok[I] & ok[J]
    I, J = np.minimum(I[keep], J[keep]), np.maximum(I[keep], J[keep])
    if I.size == 0:
        return I, J
    pairs = np.unique(np.stack([I, J], axis=1), axis=0)
    return pairs[:, 0], pairs[:, 1]


def _diagonal_clusters(cov) -> np.ndarray:
    """Per observation: its covariance cluster is diagonal (the observation is uncorrelated)."""
    out = np.ones(cov.cluster.size, dtype=bool)
    for m, _, members, C in cov.groups if cov.groups is not None else ():
        if m > 1:
            off = np.abs(C - C * np.eye(m)).max(axis=(1, 2)) > 0
            out[members[off].ravel()] = False
    if cov.groups is None:
        for mem, C in zip(cov.members, cov.blocks):
            C = np.asarray(C)
            if C.shape[0] > 1 and np.abs(C - np.diag(np.diag(C))).max() > 0:
                out[np.asarray(mem)] = False
    return out


def _w_pairs(adj, threshold: float, among=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs i < j of controlled observations with |ρ_ij| ≥ threshold and their ρ (``among``: at
    least one of the pair in these observations). P C_vv P vanishes between observations that share
    no parameter and no covariance cluster, so only pairs that do are computed, in two stages:

    1. pairs that share a coordinate (or a cluster);
    2. pairs that share only nuisance parameters (an image's orientation), where every observation
       is uncorrelated, only if the redundancy bound allows: from P C_vv P C P C_vv P = P C_vv P
       (C_vv P C_vv = C_vv) the diagonal reads Σ_{j≠i} ρ_ij² r_j = 1 − r_i, so beyond the stage-1
       partners an observation j can reach ρ² only where ρ² r_j ≤ 1 − r_i − Σ_stage1 ρ_ij² r_j
       (and the same with i, j exchanged).
    """
    n = adj.n
    ok = ~adj.uncontrolled
    rows = np.flatnonzero(ok) if among is None else np.intersect1d(np.asarray(among, dtype=np.int64), np.flatnonzero(ok))
    kind = adj.problem.params.kind[adj.problem.params.free][adj.keep]
    I1, J1 = _sharing_pairs(_incidence(adj, np.flatnonzero(kind != "t")), rows, ok)
    rho1 = _w_correlations(adj, I1, J1)
    I2, J2 = _sharing_pairs(_incidence(adj), rows, ok)
    if I2.size and I1.size:                  # stage 2: the pairs not in stage 1
        new = ~np.isin(I2 * n + J2, I1 * n + J1)
        I2, J2 = I2[new], J2[new]
    if I2.size and _diagonal_clusters(adj.problem.cov).all():
        r = adj.r
        rest = 1.0 - r
        np.subtract.at(rest, I1, rho1 ** 2 * r[J1])
        np.subtract.at(rest, J1, rho1 ** 2 * r[I1])
        rest = np.maximum(rest, 0.0)
        rho2, tol = threshold ** 2, 1e-9
        keep = (rho2 * r[J2] <= rest[I2] + tol) & (rho2 * r[I2] <= rest[J2] + tol)
        I2, J2 = I2[keep], J2[keep]
    rho2_ = _w_correlations(adj, I2, J2)
    I, J, rho = np.r_[I1, I2], np.r_[J1, J2], np.r_[rho1, rho2_]
    hit = np.abs(rho) >= threshold
    return I[hit], J[hit], rho[hit]


def _w_correlations(adj, I: np.ndarray, J: np.ndarray, chunk: int = 512) -> np.ndarray:
    """ρ_ij of the w-tests for the pairs (I, J): (P C_vv P)_ij = P_ij − Σ_kl P_ik (A Σ Aᵀ)_kl P_lj
    over the covariance clusters of i and j (one cluster member for an uncorrelated observation).
    a_k Σ a_lᵀ = a_l · y_k with y_k = Σ a_kᵀ: one solve per distinct k, in chunks of ``chunk``."""
    if I.size == 0:
        return np.zeros(0)
    cov = adj.problem.cov
    cl = cov.cluster
    P = sp.csr_matrix(adj.P)
    diag = _diagonal_clusters(cov)
    ci, cj = cl[I], cl[J]
    members = {int(c): np.asarray(cov.members[int(c)]) for c in np.unique(np.r_[ci[~diag[I]], cj[~diag[J]]])}
    # expand each pair over the members k of cluster(i) and l of cluster(j) (i, j themselves if uncorrelated)
    ma = [members[int(c)] if not d else np.array([i]) for i, c, d in zip(I.tolist(), ci.tolist(), diag[I].tolist())]
    mb = [members[int(c)] if not d else np.array([j]) for j, c, d in zip(J.tolist(), cj.tolist(), diag[J].tolist())]
    sizes = np.array([x.size * y.size for x, y in zip(ma, mb)])
    pk = np.repeat(np.arange(I.size), sizes)
    kk = np.concatenate([np.repeat(x, y.size) for x, y in zip(ma, mb)])
    ll = np.concatenate([np.tile(y, x.size) for x, y in zip(ma, mb)])
    Ar = sp.csr_matrix(adj.Ar)
    uniq, pos = np.unique(kk, return_inverse=True)
    h = np.empty(kk.size)
    order = np.argsort(pos, kind="stable")
    bounds = np.searchsorted(pos[order], np.arange(0, uniq.size + chunk, chunk))
    for c, start in enumerate(range(0, uniq.size, chunk)):
        Y = np.asarray(adj.factor.solve(Ar[uniq[start:start + chunk]].T.toarray())).reshape(Ar.shape[1], -1)
        sel = order[bounds[c]:bounds[c + 1]]
        M = Ar[ll[sel]]
        row = np.repeat(np.arange(sel.size), np.diff(M.indptr))
        h[sel] = np.bincount(row, weights=M.data * Y[M.indices, pos[sel][row] - start], minlength=sel.size)
    pik = np.asarray(P[I[pk], kk]).ravel()
    plj = np.asarray(P[ll, J[pk]]).ravel()
    s = np.asarray(P[I, J]).ravel() - np.bincount(pk, weights=pik * h * plj, minlength=I.size)
    qpp = adj.qvv_pp
    return np.clip(s / np.sqrt(qpp[I] * qpp[J]), -1.0, 1.0)


def _hypothesis(adj, t, k):
    """(label, H) of an item of ``tests``: a HypothesisTest, a (label, H) pair or a matrix."""
    if hasattr(t, "H") and hasattr(t, "label"):
        return t.label or str(k), t.H
    if isinstance(t, tuple) and len(t) == 2:
        return t
    return str(k), t


def inseparable_pairs(adj, tests=None, threshold: float = THRESHOLD) -> list[InseparableGroup]:
    """Groups of hypotheses whose test statistics are (near-)perfectly correlated (M84 §3.3, F80 §7.4).

    |ρ| ≥ threshold (module docstring): the data cannot tell the members of a group apart.
    ``tests`` None: Baarda's w-tests of all observations of ``adj`` (members are observation
    indices); an integer array: the w-tests linked to these observations (a suspects list). Only
    pairs that share a parameter or a covariance cluster, and that the redundancy bound of
    :func:`_w_pairs` allows, are computed (one solve per observation involved). Otherwise a sequence
    of hypotheses — :class:`baarda.stats.hypotheses.HypothesisTest` objects, (label, H) pairs or
    n × q matrices (labelled by position) — compared pairwise by :func:`correlation`; members are
    their labels.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    tests : None, numpy.ndarray of int or sequence, optional
        What to compare (above).
    threshold : float
        Smallest |ρ| that links two tests, in (0, 1].

    Returns
    -------
    list of InseparableGroup
        Sorted by their first member; ρ dimensionless.

    Raises
    ------
    baarda.errors.OptionError
        For a threshold outside (0, 1].
    """
    if not 0 < threshold <= 1:
        raise OptionError("threshold", threshold, (), "the threshold on |ρ| must lie in (0, 1]")
    if tests is None or (isinstance(tests, np.ndarray) and tests.dtype.kind in "iu"):
        I, J, rho = _w_pairs(adj, threshold, among=tests)
        return [InseparableGroup(tuple(m), float(r)) for m, r in _components(adj.n, I, J, rho)]
    items = [_hypothesis(adj, t, k) for k, t in enumerate(tests)]
    red = [_Reduced(adj, H) for _, H in items]
    W = [x.w_with(x) for x in red]
    support = [set(np.flatnonzero(np.asarray(abs(adj.Ar[x.H.indices]).sum(axis=0)).ravel()).tolist())
               | {("row", i) for i in x.H.indices.tolist()} for x in red]
    I, J, R = [], [], []
    for a in range(len(red)):
        for b in range(a + 1, len(red)):
            if not support[a] & support[b]:
                continue
            rho = _single(W[a], red[a].w_with(red[b]), W[b])
            if abs(rho) >= threshold:
                I.append(a), J.append(b), R.append(rho)
    comps = _components(len(red), np.asarray(I, dtype=np.int64), np.asarray(J, dtype=np.int64), np.asarray(R))
    return [InseparableGroup(tuple(items[k][0] for k in m), float(r)) for m, r in comps]


def partly_inseparable(adj, tests, threshold: float = THRESHOLD) -> list[PartialPair]:
    """Pairs of hypotheses that are partly inseparable (F80 §7.4, M84 §3.3).

    Their largest canonical correlation reaches ``threshold``, their smallest does not (module
    docstring; :func:`inseparable_pairs` reports the pairs where every one does). Two image points of
    one 3-ray point, say, with canonical correlations (1.0, 0.52): an error along the shared direction
    cannot be attributed to either image.

    Parameters
    ----------
    adj : baarda.result.Adjustment
        The adjustment.
    tests : sequence
        Hypotheses as :func:`inseparable_pairs` takes them.
    threshold : float
        In (0, 1].

    Returns
    -------
    list of PartialPair
        Canonical correlations (dimensionless) and the shared unit direction.

    Raises
    ------
    baarda.errors.OptionError
        For a threshold outside (0, 1].
    """
    if not 0 < threshold <= 1:
        raise OptionError("threshold", threshold, (), "the threshold on |ρ| must lie in (0, 1]")
    items = [_hypothesis(adj, t, k) for k, t in enumerate(tests)]
    red = [_Reduced(adj, H) for _, H in items]
    W = [x.w_with(x) for x in red]
    support = [set(np.flatnonzero(np.asarray(abs(adj.Ar[x.H.indices]).sum(axis=0)).ravel()).tolist())
               | {("row", i) for i in x.H.indices.tolist()} for x in red]
    out = []
    for a in range(len(red)):
        for b in range(a + 1, len(red)):
            if not support[a] & support[b] or (W[a].shape == (1, 1) and W[b].shape == (1, 1)):
                continue
            X1, X2 = _inverse_sqrt(W[a]), _inverse_sqrt(W[b])
            if X1.shape[1] == 0 or X2.shape[1] == 0:
                continue
            U, c, _ = np.linalg.svd(X1.T @ red[a].w_with(red[b]) @ X2)
            c = np.clip(c, 0.0, 1.0)
            if c.size and c.max() >= threshold and c.min() < threshold:
                d = X1 @ U[:, 0]
                d = d / np.linalg.norm(d)
                out.append(PartialPair((items[a][0], items[b][0]), float(c.max()), float(c.min()),
                                       tuple(float(x) for x in d)))
    return out
