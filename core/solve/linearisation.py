"""f(x) and the design matrix A = ∂f/∂x over the free parameters, on a CSR pattern found once
(:class:`Linearisation`, the linearisation step of :func:`baarda.adjust.adjust`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .linalg import compact, keep_columns

#: entries per chunk of :meth:`Linearisation._layout`'s temporaries
LAYOUT_CHUNK = 1 << 20


class Linearisation:
    """f(x) and the design matrix A = ∂f/∂x over the free parameters, on a pattern found once.

    The observation sets return their Jacobian entries as (row, column, value) triples in a
    fixed order; the CSR pattern of A (and of the reduced Ar, without the datum's held columns)
    and the place of every triple in it are computed at the first evaluation, so each later
    one is a single weighted bincount (duplicates summed as scipy's COO conversion does).
    A set that returns another pattern makes the layout be found again. :attr:`direct` tells
    whether the last :meth:`linearise` wrote the values straight into A's data.
    """

    def __init__(self, problem, free: np.ndarray):
        self.problem = problem
        self.u = free.size
        self.col = np.full(problem.params.size, -1, dtype=np.int64)
        self.col[free] = np.arange(free.size)
        self._key = self._take = self._first = self._dest = self._fixed = None

    @property
    def direct(self) -> bool:
        """True once :meth:`linearise` writes the set's Jacobian values straight into A's data
        (``evaluate_into``, on the layout found before): no array of the raw entries is made and
        their gathering order is dropped. False while A is gathered from the raw entries
        (:meth:`design`)."""
        return self._dest is not None and self._take is None

    def values(self, x: np.ndarray) -> np.ndarray:
        """f(x) alone (a trial point's: its Jacobian is made once the step is accepted)."""
        f = np.empty(self.problem.n)
        for s in self.problem.sets:
            f[s.rows] = s.values(x) if hasattr(s, "values") else s.evaluate(x)[0]
        return f

    def linearise(self, x: np.ndarray):
        """f(x) and A at x (:meth:`evaluate`, :meth:`design`). Once the layout is known, a set
        that writes its values in place (``evaluate_into``) writes them straight into A's data:
        no array of the raw entries besides it."""
        sets = self.problem.sets
        s = sets[0] if len(sets) == 1 else None
        if s is not None and (self._fixed is s or (
                hasattr(s, "evaluate_into") and self._key is not None and self._first is None
                and (self._take is not None or self._dest is not None) and self._same([(*s.pattern(), None)]))):
            self._direct(s)
            data = np.empty(self._indices.size + 1)
            f = np.empty(self.problem.n)
            f[s.rows] = s.evaluate_into(x, self._dest, data)
            return f, self._matrix(data[:-1])
        f, parts = self.evaluate(x)
        return f, self.design(parts)

    def first(self, x: np.ndarray):
        """f(x) and A at the first evaluation: the layout is found from the set's pattern alone,
        before any Jacobian value is made, and a set that writes its values in place
        (``evaluate_into``) writes them straight into A's data — no array of the raw entries
        beside the layout's temporaries. The same f and A as :meth:`evaluate` and :meth:`design`
        (the same kernel); otherwise those two."""
        sets = self.problem.sets
        s = sets[0] if len(sets) == 1 else None
        if s is not None and hasattr(s, "evaluate_into") and hasattr(s, "pattern"):
            self._layout([(*s.pattern(), None)])
            if self._first is None:
                return self.linearise(x)
        f, parts = self.evaluate(x)
        return f, self.design(parts)

    def _direct(self, s) -> None:
        """Make the place in A's data of every entry of the set ``s`` (the inverse of the gather
        order, which it replaces). A set whose pattern is fixed (``pattern_fixed``: a function of
        its own index arrays) is not compared with its entries again: their rows and columns are
        dropped here, by the set too (``release_entries``)."""
        if self._dest is None:
            nnz = self._indices.size
            dest = np.full(self._key[0][0].size, nnz, dtype=self._take.dtype)   # left out: a spare slot
            dest[self._take] = np.arange(nnz, dtype=self._take.dtype)
            self._dest, self._take = dest, None
        if getattr(s, "pattern_fixed", False) and self._fixed is not s:
            self._fixed, self._key = s, None
            getattr(s, "release_entries", lambda: None)()

    def evaluate(self, x: np.ndarray):
        """f(x) (n,) and the raw entries of the Jacobian (pass them to :meth:`design`)."""
        problem = self.problem
        f = np.empty(problem.n)
        parts = []
        for s in problem.sets:
            fs, jr, jc, jv = s.evaluate(x)
            f[s.rows] = fs
            parts.append((jr, jc, jv))
        return f, parts

    def _layout(self, parts):
        """The CSR pattern of A and the gathering order of the raw entries (their stable sort by
        (row, column), duplicates summed). Built in chunks of :data:`LAYOUT_CHUNK` entries: the
        int64 keys row·u + column are the only full-size int64 array besides the sort's order
        (no rows, columns or sorted keys of every entry beside them, ~0.4 KB per image point)."""
        problem = self.problem
        U = max(self.u, 1)
        n = problem.n
        sizes = [np.asarray(jr).size for jr, _, _ in parts]
        E = int(sum(sizes))
        itype = np.int32 if E < 2 ** 31 - 1 else np.int64
        m = np.empty(E, dtype=bool)         # entries of free columns
        o = 0
        for (_, jc, _), k in zip(parts, sizes):
            for s in range(0, k, LAYOUT_CHUNK):
                e = min(s + LAYOUT_CHUNK, k)
                m[o + s:o + e] = self.col[jc[s:e]] >= 0
            o += k
        nm = int(np.count_nonzero(m))
        key = np.empty(nm, dtype=np.int64)
        pos = 0
        rows = cols = mk = None
        for s_, (jr, jc, _), k in zip(problem.sets, parts, sizes):
            srows = np.asarray(s_.rows)
            for s in range(0, k, LAYOUT_CHUNK):
                e = min(s + LAYOUT_CHUNK, k)
                rows = srows[jr[s:e]].astype(np.int64)
                cols = self.col[jc[s:e]]
                mk = cols >= 0
                c = int(np.count_nonzero(mk))
                key[pos:pos + c] = rows[mk] * U + cols[mk]
                pos += c
        del rows, cols, mk
        order = np.argsort(key, kind="stable").astype(itype)
        # entries of the free columns in CSR order (the same stable order as before)
        self._take = order if nm == E else np.flatnonzero(m).astype(itype)[order]
        del m
        # duplicates (one parameter feeding two intrinsics) summed by reduceat over their runs;
        # the unique keys give A's row pointer and column indices, chunk by chunk
        small = self.u < 2 ** 31 - 1
        indices = np.empty(nm, dtype=np.int32 if small else np.int64)
        counts = np.zeros(n, dtype=np.int64)
        firsts, nu = [], 0
        ks = new = uk = None
        for s in range(0, nm, LAYOUT_CHUNK):
            e = min(s + LAYOUT_CHUNK, nm)
            ks = key[order[s:e]]
            new = np.empty(e - s, dtype=bool)
            new[0] = s == 0 or ks[0] != key[order[s - 1]]
            np.not_equal(ks[1:], ks[:-1], out=new[1:])
            if new.all():
                firsts.append((s, e))
                uk = ks
            else:
                firsts.append(np.flatnonzero(new) + s)
                uk = ks[new]
            indices[nu:nu + uk.size] = uk % U
            counts += np.bincount(uk // U, minlength=n)
            nu += uk.size
        del key, order, ks, new, uk
        self._key = tuple((jr, jc) for jr, jc, _ in parts)
        if nu == nm:
            self._first = None
        else:
            self._first = np.concatenate([np.arange(*f, dtype=np.int64) if isinstance(f, tuple) else f
                                          for f in firsts])
            indices = indices[:nu].copy()
        del firsts
        small = nu < 2 ** 31 - 1 and self.u < 2 ** 31 - 1       # int32 indices where they fit
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        self._indptr = indptr.astype(np.int32 if small else np.int64)
        self._indices = indices.astype(np.int32 if small else np.int64, copy=False)
        self._reduced = self._dest = self._fixed = None

    def release(self) -> None:
        """Forget the layout of A (kept for the next :meth:`design`); :meth:`reduced` still works."""
        self._key = self._take = self._first = self._dest = self._fixed = None

    def _same(self, parts) -> bool:
        if self._key is None or len(self._key) != len(parts):
            return False
        return all((jr is kr or np.array_equal(jr, kr)) and (jc is kc or np.array_equal(jc, kc))
                   for (jr, jc, _), (kr, kc) in zip(parts, self._key))

    def design(self, parts) -> sp.csr_matrix:
        """A (n × u_free, canonical CSR) from the entries of :meth:`evaluate`."""
        if self._take is None or not self._same(parts):
            self._layout(parts)
        jv = parts[0][2] if len(parts) == 1 else np.concatenate([jv for _, _, jv in parts])
        data = jv[self._take]
        if self._first is not None:
            data = np.add.reduceat(data, self._first)
        sets = self.problem.sets
        if (len(sets) == 1 and self._first is None and getattr(sets[0], "pattern_fixed", False)
                and hasattr(sets[0], "evaluate_into")):
            del jv, parts
            self._direct(sets[0])      # the next linearise writes into A: the entries' pattern goes now
        return self._matrix(data)

    def _matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """A on the layout's pattern with the values ``data`` (no copy)."""
        A = sp.csr_matrix((data, self._indices, self._indptr), shape=(self.problem.n, self.u), copy=False)
        A.has_canonical_format = True
        self._A_indices = A.indices
        return A

    def reduced(self, A: sp.csr_matrix, keep: np.ndarray, consume: bool = False) -> sp.csr_matrix:
        """A[:, keep] (:func:`keep_columns`), its pattern kept for the next A of this layout.
        consume: A is dropped afterwards; Ar's values are moved within A's data array (no second
        array of values while both exist)."""
        if A.indices is not getattr(self, "_A_indices", None):
            return keep_columns(A, keep, consume)
        if keep.size == self.u:
            self._reduced = None       # (the held gauge's pattern is made again when needed)
            return A                   # every column (the free gauge's steps): A itself, no copy
        if self._reduced is None or not np.array_equal(self._reduced[0], keep):
            self._reduced = None
            kept = np.zeros(self.u, dtype=bool)
            kept[keep] = True
            m = kept[A.indices]
            Ar = keep_columns(A, keep, consume)
            self._reduced = (keep.copy(), m, Ar.indices, Ar.indptr)
            Ar.has_canonical_format = True
            return Ar                  # (its values are A.data[m] already: not gathered twice)
        _, m, indices, indptr = self._reduced
        data = compact(A.data, m) if consume else A.data[m]
        Ar = sp.csr_matrix((data, indices, indptr), shape=(A.shape[0], keep.size), copy=False)
        Ar.has_canonical_format = True
        return Ar
