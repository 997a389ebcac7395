"""The generic adjustment problem: parameters in blocks, observations in sets and clusters.

Every model baarda adjusts — a levelling line, a 3D network, a bundle block — is turned into one
:class:`Problem`:

- a parameter vector ``x`` (all parameters, the fixed ones included, so that observation
  equations never need to know the datum); each parameter has a label, a kind (``"k"`` for
  coordinates, ``"t"`` for nuisance parameters such as orientations, F80 eq. 1) and, for
  coordinates, the point and axis it belongs to;
- observation sets, each a vectorised observation equation ``f(x)`` with its sparse Jacobian,
  writing into given rows of the global observation vector ``l``;
- a block-diagonal covariance matrix σ0² Q of the observations made of *clusters*
  (1 × 1 for an uncorrelated observation, 2 × 2 for an image point, 3 × 3 for a GNSS vector...);
- test *groups* (multi-dimensional observations tested together: image points, vectors);
- a :class:`baarda.datum.Datum`.

Residuals are ``v = f(x̂) − l`` (adjusted minus observed, F80 §1), wrapped to (−π, π] for
angular observations.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp

from ..errors import CovarianceError
from .geometry import BlockGeometry


# --------------------------------------------------------------------------------------------
# array-backed sequences: one entry per observation or parameter without one Python object each
# --------------------------------------------------------------------------------------------
class LazySequence(Sequence):
    """A read-only sequence whose items are made on demand from arrays.

    Behaves as the tuple it replaces (indexing, iteration, ``len``, ``==`` with a tuple or
    another sequence, ``np.asarray``); ``take(idx)`` is the sub-sequence of the indices
    ``idx`` (array-backed again). Subclasses implement ``__len__``, ``_item(i)`` and ``take``.
    """

    def __getitem__(self, i):
        if isinstance(i, slice):
            return self.take(np.arange(len(self))[i])
        if isinstance(i, (np.ndarray, list)):
            return self.take(np.asarray(i))
        n = len(self)
        i = int(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError("index out of range")
        return self._item(i)

    def __iter__(self):
        for i in range(len(self)):
            yield self._item(i)

    def __eq__(self, other):
        if not isinstance(other, Sequence) or isinstance(other, str) or len(other) != len(self):
            return NotImplemented if not isinstance(other, Sequence) else False
        return all(a == b for a, b in zip(self, other))

    __hash__ = None

    def __array__(self, dtype=None, copy=None):
        return np.array(list(self), dtype=dtype)

    def __repr__(self):
        n = len(self)
        head = ", ".join(repr(self._item(i)) for i in range(min(n, 3)))
        return f"{type(self).__name__}([{head}{', ...' if n > 3 else ''}], n={n})"


def take(seq, idx):
    """``seq`` at the indices ``idx``: array-backed for a :class:`LazySequence`, else a tuple."""
    if isinstance(seq, LazySequence):
        return seq.take(np.asarray(idx, dtype=np.int64))
    return tuple(seq[i] for i in np.asarray(idx).tolist())


class Categorical(LazySequence):
    """Strings from a few categories: ``categories[codes[i]]`` (kinds, units)."""

    def __init__(self, categories, codes):
        self.categories = tuple(categories)
        self.codes = np.asarray(codes)
        self.codes.setflags(write=False)

    def __len__(self):
        return self.codes.size

    def _item(self, i):
        return self.categories[self.codes[i]]

    def take(self, idx):
        return Categorical(self.categories, self.codes[idx])

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.categories, dtype=dtype if dtype is not None else str)[self.codes] \
            if self.categories else np.array([], dtype=dtype if dtype is not None else str)

    def startswith(self, prefix: str) -> np.ndarray:
        """Boolean per item: does it start with ``prefix``."""
        hit = np.array([c.startswith(prefix) for c in self.categories], dtype=bool)
        return hit[self.codes] if hit.size else np.zeros(len(self), dtype=bool)


class RecordIds(LazySequence):
    """Per observation the dict role → id of the reports, from index arrays.

    ``roles`` (r,), ``values`` (per role a sequence of ids), ``codes`` (n × r, int32): item i is
    ``{role: values[k][codes[i, k]]}`` over the roles with codes[i, k] ≥ 0, in the order of
    ``roles`` (the dicts the builders used to store, one per observation)."""

    def __init__(self, roles, values, codes):
        self.roles = tuple(roles)
        self.values = tuple(values)
        self.codes = np.asarray(codes)
        self.codes.setflags(write=False)

    def __len__(self):
        return self.codes.shape[0]

    def _item(self, i):
        row = self.codes[i].tolist()
        return {r: self.values[k][c] for k, (r, c) in enumerate(zip(self.roles, row)) if c >= 0}

    def take(self, idx):
        return RecordIds(self.roles, self.values, self.codes[idx])


class JoinedLabels(LazySequence):
    """Labels of the parameters: an explicit tuple followed by generated point coordinate labels
    ``f"{prefix}{point_ids[k]}.{axes[a]}"`` for (k, a) = divmod(j, len(axes)) (all points, all axes)."""

    def __init__(self, head, point_ids, prefix: str = "point ", axes: str = "xyz", sel=None):
        self.head = tuple(head)
        self.point_ids = point_ids
        self.prefix, self.axes = prefix, axes
        self.sel = sel                      # indices into the full sequence, or None for all

    def _full_len(self):
        return len(self.head) + len(self.point_ids) * len(self.axes)

    def __len__(self):
        return self._full_len() if self.sel is None else self.sel.size

    def _full_item(self, j):
        h = len(self.head)
        if j < h:
            return self.head[j]
        k, a = divmod(j - h, len(self.axes))
        return f"{self.prefix}{self.point_ids[k]}.{self.axes[a]}"

    def _item(self, i):
        return self._full_item(i if self.sel is None else int(self.sel[i]))

    def take(self, idx):
        idx = np.asarray(idx, dtype=np.int64)
        return JoinedLabels(self.head, self.point_ids, self.prefix, self.axes,
                            idx if self.sel is None else self.sel[idx])


class ObservationSet(Protocol):
    """A vectorised observation equation.

    ``rows`` are the global row indices the set writes to (length ``n``). ``evaluate(x)``
    returns ``(f, jrows, jcols, jvals)``: the predicted values (n,) and the Jacobian ∂f/∂x in
    COO form with *local* row indices (0..n-1) and global parameter indices.
    """

    rows: np.ndarray
    angular: np.ndarray

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        ...


@dataclass(frozen=True, eq=False)
class Parameters:
    """All parameters of a problem, fixed ones included.

    x0: initial values (u_all,). labels: a readable name per parameter ("P1.x", "ori 3").
    kind: "k" (coordinate) or "t" (nuisance) per parameter. fixed: True where the parameter is
    held at its value (fixed points). point: index of the point a coordinate belongs to (-1
    for other parameters); axis: 0, 1, 2 for x, y, z (-1 for others).
    """

    x0: np.ndarray
    labels: tuple[str, ...]
    kind: np.ndarray
    fixed: np.ndarray
    point: np.ndarray
    axis: np.ndarray

    @property
    def size(self) -> int:
        return self.x0.size

    @property
    def free(self) -> np.ndarray:
        """Indices of the estimated parameters."""
        return np.flatnonzero(~self.fixed)


class ParameterList:
    """The parameters of a problem collected one at a time by a model's builder (the one
    owner of that bookkeeping for networks, bundle, independent-model and SfM blocks);
    :meth:`parameters` makes the frozen :class:`Parameters`, with ``tail`` appended (a
    vectorised run of coordinates, as an SfM block's points)."""

    def __init__(self):
        self.labels: list[str] = []
        self.x0: list[float] = []
        self.kind: list[str] = []
        self.fixed: list[bool] = []
        self.point: list[int] = []
        self.axis: list[int] = []

    def __len__(self) -> int:
        return len(self.x0)

    def add(self, label: str, value, kind: str, point: int = -1, axis: int = -1, fixed: bool = False) -> int:
        """Append one parameter and return its index. kind "k" (coordinate of ``point`` on
        ``axis``) or "t" (nuisance)."""
        self.labels.append(label)
        self.x0.append(float(value))
        self.kind.append(kind)
        self.fixed.append(bool(fixed))
        self.point.append(int(point))
        self.axis.append(int(axis))
        return len(self.x0) - 1

    def parameters(self, tail: Parameters | None = None, labels=None) -> Parameters:
        """The frozen :class:`Parameters` (``labels``: a sequence to use instead of the list,
        e.g. :class:`baarda.model.problem.JoinedLabels` over ``tail``'s labels)."""
        head = Parameters(np.asarray(self.x0, dtype=float), tuple(self.labels), np.array(self.kind, dtype="<U1"),
                          np.array(self.fixed, dtype=bool), np.array(self.point, dtype=np.int64),
                          np.array(self.axis, dtype=np.int64))
        if tail is None:
            return head if labels is None else dataclasses.replace(head, labels=labels)
        return Parameters(np.concatenate([head.x0, tail.x0]),
                          labels if labels is not None else head.labels + tuple(tail.labels),
                          np.concatenate([head.kind, tail.kind]), np.concatenate([head.fixed, tail.fixed]),
                          np.concatenate([head.point, tail.point]), np.concatenate([head.axis, tail.axis]))


class _StackItems(LazySequence):
    """``members`` or ``blocks`` of a stacked :class:`Covariance`: item c is row ``pos[c]`` of
    the stack of size group ``grp[c]``."""

    def __init__(self, cov, which: int):
        self.cov, self.which = cov, which

    def __len__(self):
        return self.cov.cluster_count

    def _item(self, c):
        g, p = self.cov._locate()
        return self.cov.groups[g[c]][self.which][p[c]]

    def take(self, idx):
        return tuple(self._item(int(c)) for c in np.asarray(idx).tolist())

    def __iter__(self):
        g, p = self.cov._locate()
        stacks = [grp[self.which] for grp in self.cov.groups]
        for gc, pc in zip(g.tolist(), p.tolist()):
            yield stacks[gc][pc]


@dataclass(frozen=True, eq=False)
class Covariance:
    """Block-diagonal a priori covariance σ0²Q of the observations, by clusters.

    cluster: cluster id per observation (n,), clusters numbered 0..m-1.
    blocks: per cluster, the observation indices (sorted) and the covariance matrix (SI units²).

    A covariance made by :meth:`from_groups` keeps its clusters stacked by size — ``groups``:
    ((m, cluster ids (k,), members (k, m), C (k, m, m)), ...) ascending in m — and ``members``
    and ``blocks`` are read-only views of them (no array object per cluster; a block of a
    million image points with one σ holds one 2 × 2 matrix, broadcast).
    """

    cluster: np.ndarray
    members: tuple[np.ndarray, ...]
    blocks: tuple[np.ndarray, ...]
    groups: tuple | None = None

    @property
    def cluster_count(self) -> int:
        if self.groups is not None:
            return int(sum(g[1].size for g in self.groups))
        return len(self.members)

    @classmethod
    def from_blocks(cls, n: int, members, blocks) -> "Covariance":
        cluster = np.full(n, -1, dtype=np.int64)
        ms, bs = [], []
        for c, (idx, cov) in enumerate(zip(members, blocks)):
            idx = np.asarray(idx, dtype=np.int64)
            cov = np.atleast_2d(np.asarray(cov, dtype=float))
            if cov.shape != (idx.size, idx.size):
                raise CovarianceError(f"cluster {c}: covariance of shape {cov.shape} for {idx.size} observations",
                                      cluster=c)
            cluster[idx] = c
            ms.append(idx)
            bs.append(cov)
        if (cluster < 0).any():
            raise CovarianceError(f"observations without covariance: {np.flatnonzero(cluster < 0)[:10]}",
                                  observations=np.flatnonzero(cluster < 0)[:10])
        return cls(cluster, tuple(ms), tuple(bs))

    @classmethod
    def from_groups(cls, n: int, groups) -> "Covariance":
        """A stacked covariance from ((m, cluster ids (k,), members (k, m), C (k, m, m)), ...):
        the cluster ids of all groups together are 0..K-1, each once. Groups of one size are
        merged (cluster ids ascending in each); C may be a broadcast (read-only) view."""
        by_m: dict[int, list] = {}
        for m, cl, mem, C in groups:
            if np.asarray(cl).size:
                by_m.setdefault(int(m), []).append((np.asarray(cl, dtype=np.int64),
                                                    np.asarray(mem, dtype=np.int64).reshape(-1, int(m)),
                                                    np.asarray(C, dtype=float).reshape(-1, int(m), int(m))))
        out = []
        cluster = np.full(n, -1, dtype=np.int64)
        for m in sorted(by_m):
            parts = by_m[m]
            if len(parts) == 1:
                cl, mem, C = parts[0]
            else:
                cl = np.concatenate([p[0] for p in parts])
                mem = np.concatenate([p[1] for p in parts])
                C = np.concatenate([p[2] for p in parts])
            if cl.size > 1 and (np.diff(cl) <= 0).any():
                o = np.argsort(cl, kind="stable")
                cl, mem, C = cl[o], mem[o], C[o]
            if C.shape != (cl.size, m, m) or mem.shape != (cl.size, m):
                raise CovarianceError(f"clusters of size {m}: members {mem.shape}, covariances {C.shape}")
            cluster[mem] = cl[:, None]
            for a in (cl, mem, C):
                if a.flags.writeable:
                    a.setflags(write=False)
            out.append((m, cl, mem, C))
        if (cluster < 0).any():
            raise CovarianceError(f"observations without covariance: {np.flatnonzero(cluster < 0)[:10]}",
                                  observations=np.flatnonzero(cluster < 0)[:10])
        total = sum(g[1].size for g in out)
        if total and not np.array_equal(np.bincount(np.concatenate([g[1] for g in out]), minlength=total),
                                        np.ones(total, dtype=np.int64)):
            raise CovarianceError("cluster ids must be 0..K-1, each once")
        cov = cls(cluster, (), (), tuple(out))
        object.__setattr__(cov, "members", _StackItems(cov, 2))
        object.__setattr__(cov, "blocks", _StackItems(cov, 3))
        return cov

    def _locate(self):
        """(size group, row in its stack) of every cluster of a stacked covariance (cached)."""
        loc = self.__dict__.get("_loc")
        if loc is None:
            K = self.cluster_count
            g = np.empty(K, dtype=np.int8 if len(self.groups) < 128 else np.int32)
            p = np.empty(K, dtype=np.int64)
            for k, (_, cl, _, _) in enumerate(self.groups):
                g[cl] = k
                p[cl] = np.arange(cl.size)
            loc = (g, p)
            object.__setattr__(self, "_loc", loc)
        return loc

    @classmethod
    def diagonal(cls, sigma: np.ndarray) -> "Covariance":
        sigma = np.asarray(sigma, dtype=float)
        n = sigma.size
        return cls(np.arange(n), tuple(np.array([i]) for i in range(n)),
                   tuple(np.array([[s * s]]) for s in sigma))

    def matrix(self) -> sp.csr_matrix:
        """The sparse block-diagonal covariance matrix (n × n)."""
        if self.groups is not None:
            return _stack_diag([(mem, C) for _, _, mem, C in self.groups], self.cluster.size)
        return _block_diag(self.members, self.blocks, self.cluster.size)

    def weight(self, scale: np.ndarray | None = None) -> sp.csr_matrix:
        """P = C⁻¹, the inverse of each covariance block (:func:`size_weights`).

        ``scale`` (per cluster) divides each block's weight (variance-component factors).
        """
        parts = []
        for (m, clusters, members, _), W in zip(size_groups(self), size_weights(self)):
            if scale is not None:
                W = W / np.asarray(scale)[clusters][:, None, None]
            parts.append((m, clusters, members, W))
        if self.groups is not None:
            return _stack_diag([(members, W) for _, _, members, W in parts], self.cluster.size)
        inv = [None] * len(self.blocks)
        for _, clusters, _, W in parts:
            for k, c in enumerate(clusters):
                inv[c] = W[k]
        return _block_diag(self.members, inv, self.cluster.size)

    def _stack(self, clusters, m):
        if self.groups is not None:
            for mm, cl, _, C in self.groups:
                if mm == m:
                    return C
        return np.array([self.blocks[c] for c in clusters]).reshape(clusters.size, m, m)

    def sigma(self) -> np.ndarray:
        """Standard deviation of each observation (SI units)."""
        out = np.empty(self.cluster.size)
        for m, clusters, members in by_size(self):
            C = self._stack(clusters, m)
            out[members] = np.sqrt(np.diagonal(C, axis1=1, axis2=2))
        return out

    def scaled(self, factors: np.ndarray) -> "Covariance":
        """The covariance with each cluster multiplied by ``factors[cluster]``."""
        if self.groups is not None:
            f = np.asarray(factors, dtype=float)
            return Covariance.from_groups(self.cluster.size, [(m, cl, mem, C * f[cl][:, None, None])
                                                              for m, cl, mem, C in self.groups])
        return Covariance(self.cluster, self.members, tuple(b * f for b, f in zip(self.blocks, factors)))

    def subset(self, keep: np.ndarray) -> "Covariance":
        """The covariance of the observations ``keep`` (sorted indices), renumbered.

        Clusters kept whole keep their blocks (the usual case: a few observations left out of
        a large block); only clusters cut in part get a sub-block."""
        n = self.cluster.size
        keep = np.asarray(keep, dtype=np.int64)
        new_index = np.full(n, -1, dtype=np.int64)
        new_index[keep] = np.arange(keep.size)
        ncl = self.cluster_count
        kept = np.bincount(self.cluster[keep], minlength=ncl)
        renum = np.cumsum(kept > 0) - 1
        if self.groups is not None:
            groups = []
            for m, cl, mem, C in self.groups:
                kc = kept[cl]
                whole = kc == m
                groups.append((m, renum[cl[whole]], new_index[mem[whole]], C[whole]))
                for r in np.flatnonzero((kc > 0) & (kc < m)).tolist():
                    sel = new_index[mem[r]] >= 0
                    mm = int(sel.sum())
                    groups.append((mm, renum[cl[r:r + 1]], new_index[mem[r][sel]][None, :],
                                   C[r][np.ix_(sel, sel)][None]))
            return Covariance.from_groups(keep.size, groups)
        sizes = np.fromiter((idx.size for idx in self.members), dtype=np.int64, count=ncl)
        partial = set(np.flatnonzero((kept > 0) & (kept < sizes)).tolist())
        members, blocks = [], []
        for c in np.flatnonzero(kept > 0).tolist():
            idx, b = self.members[c], self.blocks[c]
            if c in partial:
                m = new_index[idx] >= 0
                members.append(new_index[idx[m]])
                blocks.append(b[np.ix_(m, m)])
            else:
                members.append(new_index[idx])
                blocks.append(b)
        return Covariance(renum[self.cluster[keep]], tuple(members), tuple(blocks))


# --------------------------------------------------------------------------------------------
# the clusters of a covariance grouped by size, their weights P_c = C_c⁻¹ and P
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=8)
def size_groups(cov) -> tuple:
    """Clusters grouped by their size: ((m, cluster ids (k,), members (k, m), C (k, m, m)), ...).

    Cached per (immutable) covariance object: the stacks are built once (a stacked covariance,
    :meth:`baarda.model.problem.Covariance.from_groups`, has them already).
    """
    if getattr(cov, "groups", None) is not None:
        return tuple((int(m), cl, members, C) for m, cl, members, C in cov.groups)
    sizes = np.array([idx.size for idx in cov.members])
    out = []
    for m in np.unique(sizes):
        cl = np.flatnonzero(sizes == m)
        members = np.array([cov.members[c] for c in cl]).reshape(cl.size, m)
        C = np.array([cov.blocks[c] for c in cl]).reshape(cl.size, m, m)
        for a in (cl, members, C):
            a.setflags(write=False)
        out.append((int(m), cl, members, C))
    return tuple(out)


@functools.lru_cache(maxsize=8)
def size_weights(cov) -> tuple:
    """P_c = C_c⁻¹ (symmetrised) of every cluster, stacked as :func:`size_groups` stacks C."""
    out = []
    for _, _, _, C in size_groups(cov):
        if C.ndim == 3 and C.shape[0] > 1 and C.strides[0] == 0:
            # one matrix broadcast over the clusters (a block's image points): its inverse,
            # broadcast likewise (the same numbers: the stack is inverted matrix by matrix)
            W1 = np.linalg.inv(C[:1])
            W1 = 0.5 * (W1 + np.swapaxes(W1, 1, 2))
            W = np.broadcast_to(W1[0], C.shape)
        else:
            W = np.linalg.inv(C)
            W = 0.5 * (W + np.swapaxes(W, 1, 2))
        W.setflags(write=False)
        out.append(W)
    return tuple(out)


@functools.lru_cache(maxsize=8)
def cluster_sizes(cov) -> np.ndarray:
    """Size of each cluster (observations), by cluster id."""
    sizes = np.zeros(sum(g[1].size for g in size_groups(cov)), dtype=np.int64)
    for m, cl, _, _ in size_groups(cov):
        sizes[cl] = m
    return sizes


def by_size(cov):
    """Clusters grouped by their size: yields (m, cluster ids (k,), members (k, m))."""
    for m, cl, members, _ in size_groups(cov):
        yield m, cl, members


def weight_matrix(cov) -> sp.csr_matrix:
    """P = C⁻¹ block by block from the stacks of :func:`size_weights` (the same batched inverses
    as :meth:`Covariance.weight`, so the same numbers), laid out as :func:`_stack_diag` lays them."""
    return _stack_diag([(members, W) for (_, _, members, _), W in zip(size_groups(cov), size_weights(cov))],
                       cov.cluster.size)


def _stack_diag(parts, n) -> sp.csr_matrix:
    """The block-diagonal matrix of stacks [(members (k, m), blocks (k, m, m)), ...]."""
    parts = [(mem, B) for mem, B in parts if mem.size]
    if not parts:
        return sp.csr_matrix((n, n))
    rows = np.concatenate([np.repeat(mem, mem.shape[1], axis=1).ravel() for mem, _ in parts])
    cols = np.concatenate([np.tile(mem, (1, mem.shape[1])).ravel() for mem, _ in parts])
    vals = np.concatenate([np.ascontiguousarray(B).ravel() for _, B in parts])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def _block_diag(members, blocks, n) -> sp.csr_matrix:
    if not len(members):
        return sp.csr_matrix((n, n))
    sizes = np.array([idx.size for idx in members])
    rows, cols, vals = [], [], []
    for m in np.unique(sizes):
        cl = np.flatnonzero(sizes == m)
        M = np.array([members[c] for c in cl]).reshape(cl.size, m)
        B = np.array([blocks[c] for c in cl]).reshape(cl.size, m, m)
        rows.append(np.repeat(M, m, axis=1).ravel())
        cols.append(np.tile(M, (1, m)).ravel())
        vals.append(B.ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


@dataclass(frozen=True, eq=False)
class ObservationInfo:
    """What the reports need to know of each scalar observation (n entries each).

    kind: e.g. "distance", "image-x". ids: per observation a dict of role → id (``from``,
    ``to``, ``image``, ``point``...). value_file/unit, sigma_file/sigma_unit: as the source
    file has them. line: source line (0 if unknown). group: test-group id (-1 for none).
    """

    kind: tuple[str, ...]
    ids: tuple[dict, ...]
    value_file: np.ndarray
    unit: tuple[str, ...]
    sigma_file: np.ndarray
    sigma_unit: tuple[str, ...]
    line: np.ndarray
    group: np.ndarray


@dataclass(frozen=True, eq=False)
class PointInfo:
    """The points of a problem: ids, parameter index per axis (-1 where none), status."""

    ids: tuple[str, ...]
    index: np.ndarray          # (m, 3) parameter index of x, y, z or -1
    status: tuple[str, ...]    # "fixed", "adjusted", "constrained", "control", "check", ...
    dim: int                   # 1 (levelling), 2 (planimetric) or 3


@dataclass(frozen=True, eq=False)
class ProblemNotes:
    """What a problem carries beyond its equations: where it came from and what was done to it
    on the way (typed, immutable; :meth:`Problem.with_notes` makes a problem with other notes).

    local_defects: the :class:`baarda.defects.LocalDefect` set aside (networks and blocks);
    local_model: the block model the local-defect analysis reduces further (:mod:`baarda.sfm_defects`);
    network_model: the :class:`~baarda.model.network.Network` a network's problem was built from
    (:mod:`baarda.network_defects`); kept_rows: for a subset (:func:`subset`), the rows of the
    problem it was taken from; ap_groups: "camera:group" → labels of the additional parameters a
    bundle block estimates; image_names: image id → file name (SfM blocks); duplicate_keypoints:
    COLMAP/Bundler points observed by several keypoints of one image (``{"points", "observations"}``);
    dropped_observations: Gama observations to undefined points dropped (``--drop-undefined``);
    reader_notes: lines of the reader on what it set aside or repaired; tol_abs, angles: a Gama
    network's ``tol-abs`` (mm) and angular unit; imodel: an independent-model block's geometry.
    """

    local_defects: tuple = ()
    local_model: object = None
    network_model: object = None
    kept_rows: np.ndarray | None = None
    ap_groups: dict = field(default_factory=dict)
    image_names: dict = field(default_factory=dict)
    duplicate_keypoints: dict | None = None
    dropped_observations: tuple = ()
    reader_notes: tuple = ()
    tol_abs: float | None = None
    angles: object = None
    imodel: object = None


@dataclass(frozen=True, eq=False)
class Problem:
    """An adjustment problem (see the module docstring)."""

    params: Parameters
    sets: tuple
    l: np.ndarray
    cov: Covariance
    info: ObservationInfo
    points: PointInfo
    datum: "object"
    sigma0: float = 1.0
    sigma_act: str = "apriori"
    conf_pr: float = 0.95
    source: str = ""
    title: str = ""
    notes: ProblemNotes = field(default_factory=ProblemNotes)
    geometry: BlockGeometry | None = None     # a photogrammetric block's images and cameras
    axes_xy: str | None = None                # a geodetic network's axes (Gama's axes-xy, "ne": x north)
    #: a geodetic network's planimetric positions as the file gives them (points × 2, metres, NaN
    #: where none): the distances of a height criterion matrix where x, y are not unknowns
    positions: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.l.size

    def with_notes(self, **changes) -> "Problem":
        """This problem with ``changes`` to its :class:`ProblemNotes` (nothing else copied)."""
        return dataclasses.replace(self, notes=dataclasses.replace(self.notes, **changes))

    @property
    def convention(self) -> str | None:
        """The structure-from-motion file convention (``"bal"``, ``"bundler"``, ``"colmap"``) of
        a block read from such a file, else None."""
        return self.geometry.convention if self.geometry is not None else None

    @property
    def angular(self) -> np.ndarray:
        a = np.zeros(self.n, dtype=bool)
        for s in self.sets:
            a[s.rows] = s.angular
        return a

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """f(x) (n,) and the Jacobian over all parameters (n × u_all, CSR)."""
        f = np.empty(self.n)
        R, C, V = [], [], []
        for s in self.sets:
            fs, jr, jc, jv = s.evaluate(x)
            f[s.rows] = fs
            R.append(s.rows[jr])
            C.append(jc)
            V.append(jv)
        J = sp.csr_matrix((np.concatenate(V), (np.concatenate(R), np.concatenate(C))),
                          shape=(self.n, self.params.size))
        return f, J

    def misclosure(self, f: np.ndarray) -> np.ndarray:
        """v = f − l, angular observations wrapped to (−π, π]."""
        d = f - self.l
        a = self.angular
        d[a] = wrap_angle(d[a])
        return d


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles (radians) to (−π, π]."""
    return -((-np.asarray(a) + np.pi) % (2 * np.pi) - np.pi)


@dataclass(frozen=True, eq=False)
class FilteredSet:
    """An observation set with some of its rows left out (excluded observations).

    Works for any set, whatever its internal layout (an image-point set may keep x and drop y):
    the inner set is evaluated whole and the kept rows are passed on, renumbered.
    """

    inner: object
    local_keep: np.ndarray    # positions (within the inner set's rows) that are kept
    rows: np.ndarray          # their new global rows

    @property
    def angular(self):
        return np.asarray(self.inner.angular)[self.local_keep]

    @property
    def kind(self):
        return getattr(self.inner, "kind", "")

    def evaluate(self, x):
        f, jr, jc, jv = self.inner.evaluate(x)
        pos = np.full(np.asarray(self.inner.rows).size, -1, dtype=np.int64)
        pos[self.local_keep] = np.arange(self.local_keep.size)
        m = pos[jr] >= 0
        return f[self.local_keep], pos[jr[m]], jc[m], jv[m]


def _subset_set(s, keep_mask: np.ndarray, new_index: np.ndarray):
    """The set with only the rows where ``keep_mask`` (global) is True (None if none is left)."""
    local = np.flatnonzero(keep_mask[s.rows])
    if local.size == 0:
        return None
    if local.size == s.rows.size:
        return dataclasses.replace(s, rows=new_index[s.rows]) if not isinstance(s, FilteredSet) else \
            FilteredSet(s.inner, s.local_keep, new_index[s.rows])
    if isinstance(s, FilteredSet):
        return FilteredSet(s.inner, s.local_keep[local], new_index[s.rows[local]])
    return FilteredSet(s, local, new_index[s.rows[local]])


def subset(problem: Problem, keep, observed: np.ndarray | None = None) -> Problem:
    """The problem with only the observations ``keep`` (indices or a boolean mask).

    Used to exclude observations (data snooping, the dashboard's exclude/re-include); the
    parameters and the datum stay as they are. ``observed`` (bool per parameter, optional):
    which parameters the kept observations determine, when the caller knows it (from a
    Jacobian); otherwise the kept observation sets are evaluated to find out.
    """
    mask = np.zeros(problem.n, dtype=bool)
    mask[np.asarray(keep)] = True
    idx = np.flatnonzero(mask)
    new_index = np.full(problem.n, -1, dtype=np.int64)
    new_index[idx] = np.arange(idx.size)
    sets = tuple(s2 for s2 in (_subset_set(s, mask, new_index) for s in problem.sets) if s2 is not None)
    info = problem.info
    info2 = ObservationInfo(
        kind=take(info.kind, idx), ids=take(info.ids, idx),
        value_file=info.value_file[idx], unit=take(info.unit, idx),
        sigma_file=info.sigma_file[idx], sigma_unit=take(info.sigma_unit, idx),
        line=info.line[idx], group=info.group[idx])
    # nuisance parameters left without any observation (e.g. the orientation of a direction set
    # whose directions were all excluded) are held at their values; coordinates are not, so that
    # an undetermined point is diagnosed rather than silently fixed
    params = problem.params
    if observed is None:
        observed = np.zeros(params.size, dtype=bool)
        x = params.x0
        for s2 in sets:
            _, _, jc, jv = s2.evaluate(x)
            observed[jc[jv != 0]] = True
    orphan = (params.kind == "t") & ~params.fixed & ~observed
    if orphan.any():
        params = dataclasses.replace(params, fixed=params.fixed | orphan)
    kept = idx if problem.notes.kept_rows is None else problem.notes.kept_rows[idx]
    return dataclasses.replace(problem, params=params, sets=sets, l=problem.l[idx], cov=problem.cov.subset(idx),
                               info=info2, notes=dataclasses.replace(problem.notes, kept_rows=kept))


def without(problem: Problem, excluded) -> tuple[Problem, np.ndarray]:
    """``(reduced, kept)``: ``problem`` without the observations ``excluded`` (indices).

    ``kept`` lists the original indices of the reduced problem's observations (sorted): reduced
    index k is original observation ``kept[k]``. The reduced problem is :func:`subset`'s, so its
    r, global test and σ̂0 are those of a fresh adjustment without the excluded observations, and
    a nuisance parameter left without observations (all directions of a set) is held.
    """
    n = problem.n
    excluded = np.unique(np.asarray(list(excluded), dtype=np.int64))
    if excluded.size and (excluded.min() < 0 or excluded.max() >= n):
        raise IndexError(f"observation index out of range 0..{n - 1}")
    if excluded.size == 0:
        return problem, np.arange(n)
    kept = np.setdiff1d(np.arange(n), excluded)
    return subset(problem, kept), kept


def image_point_index(problem) -> dict:
    """{(image, point, keypoint): [rows]} of every image observation, ids as text (keypoint None
    unless the image observes the point by several keypoints, COLMAP), rows in file order —
    one pass over the observations; the one place image points are found by their ids
    (:func:`baarda.model.bundle.image_rows`, :func:`baarda.stats.hypotheses.hypothesis_rows`, the dashboard)."""
    index: dict = {}
    for i, ids in enumerate(problem.info.ids):
        if "image" in ids and "point" in ids:
            kp = ids.get("keypoint")
            key = (str(ids["image"]), str(ids["point"]), None if kp is None else str(kp))
            index.setdefault(key, []).append(i)
    return index
