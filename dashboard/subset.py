"""A problem without some of its observations, for the dashboard's exclude / re-include.

The reduced problem is built properly (not by giving the excluded observations a huge variance):
every observation set is wrapped so that it evaluates the original equations and keeps only the
rows still in use, renumbered, and the covariance, observation vector and observation info are
cut to the same rows. The redundancy r = n − rank(A), the global test and σ̂0 of the reduced
problem are therefore those of a fresh adjustment without the excluded observations (a
"weight zero" variance inflation would leave them counted in r).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from baarda.model.problem import ObservationInfo


@dataclass(frozen=True, eq=False)
class RowSubset:
    """An observation set restricted to some of its rows.

    base: the original set; local: which of its local rows (0..n_base-1) are kept, sorted;
    rows: their new global row indices in the reduced problem.
    """

    base: object
    local: np.ndarray
    rows: np.ndarray

    @property
    def kind(self) -> str:
        return getattr(self.base, "kind", "")

    @property
    def angular(self) -> np.ndarray:
        return np.asarray(self.base.angular)[self.local]

    def evaluate(self, x):
        f, jr, jc, jv = self.base.evaluate(x)
        new_local = np.full(np.asarray(self.base.rows).size, -1, dtype=np.int64)
        new_local[self.local] = np.arange(self.local.size)
        m = new_local[jr] >= 0
        return f[self.local], new_local[jr[m]], jc[m], jv[m]


def without(problem, excluded) -> tuple[object, np.ndarray]:
    """``(reduced_problem, kept)``: ``problem`` without the observations ``excluded``.

    kept: the original indices of the reduced problem's observations (sorted), so that reduced
    index k is original observation ``kept[k]``.
    """
    n = problem.n
    excluded = np.unique(np.asarray(sorted(excluded), dtype=np.int64))
    if excluded.size and (excluded.min() < 0 or excluded.max() >= n):
        raise IndexError(f"observation index out of range 0..{n - 1}")
    if excluded.size == 0:
        return problem, np.arange(n)
    kept = np.setdiff1d(np.arange(n), excluded)
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[kept] = np.arange(kept.size)
    sets = []
    for s in problem.sets:
        rows = np.asarray(s.rows)
        local = np.flatnonzero(new_index[rows] >= 0)
        if local.size:
            sets.append(RowSubset(s, local, new_index[rows[local]]))
    info = problem.info
    new_info = ObservationInfo(
        kind=tuple(info.kind[i] for i in kept), ids=tuple(info.ids[i] for i in kept),
        value_file=np.asarray(info.value_file)[kept], unit=tuple(info.unit[i] for i in kept),
        sigma_file=np.asarray(info.sigma_file)[kept],
        sigma_unit=tuple(info.sigma_unit[i] for i in kept),
        line=np.asarray(info.line)[kept], group=np.asarray(info.group)[kept])
    reduced = replace(problem, sets=tuple(sets), l=np.asarray(problem.l)[kept],
                      cov=problem.cov.subset(kept), info=new_info)
    return reduced, kept
