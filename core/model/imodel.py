"""Planimetric independent-model blocks (the PAT-M teaching case).

Each model (a stereo pair's relative orientation) carries its own plane coordinate system. The
model coordinates (x, y) of the points are the observations; a 2D similarity per model relates
them to the ground (X, Y):

.. math::

    x = a X - b Y + c, \\qquad y = b X + a Y + d,

with four nuisance parameters (a, b, c, d) per model (kind ``"t"``; a = m cos θ, b = m sin θ
for scale m and rotation θ ground → model) and the ground coordinates X, Y of every point
(kind ``"k"``). The equations are bilinear; Gauss-Newton linearises them. Residuals
v = f(x̂) − l are in model units. Each point's (x, y) in one model is a 2 × 2 covariance
cluster and one test group (like an image point of a bundle block, F80 §2.2); each control
point's (X, Y) observations are one cluster and group.

Units: ground coordinates and control σ in metres; model coordinates and their σ in the
model's unit (e.g. mm at photo scale), given per block.

Layout: parameters per model (a, b, c, d), then per point (X, Y); observations x, y of
measurement k at rows 2k, 2k + 1, then the control coordinates point by point.

Datum: ``"control"`` — weighted control points; ``"free"`` — the 4-parameter defect
(two translations, rotation, scale) removed by inner constraints over ``sbase`` (empty = all
points); control observations are then not used.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..datum import Datum
from ..observations.geodetic import LinearSet
from .problem import Covariance, ObservationInfo, ParameterList, PointInfo, Problem, ProblemNotes

SIM_NAMES = ("a", "b", "c", "d")


@dataclass(frozen=True)
class Model:
    """An independent model with approximate similarity ground → model (x = aX − bY + c,
    y = bX + aY + d; a, b dimensionless model-unit per metre, c, d in model units)."""

    id: str
    a: float = 1.0
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0
    strip: str = ""
    line: int = 0


@dataclass(frozen=True)
class PlanPoint:
    """A ground point: approximate X, Y (m), status tie/control/check, reference coordinates
    ``ref`` (m) and σ (m) of the control coordinates."""

    id: str
    X: float
    Y: float
    status: str = "tie"
    ref: tuple[float, float] | None = None
    sigma: float = 0.0
    line: int = 0


@dataclass(frozen=True, eq=False)
class ModelObservations:
    """Model coordinates: model and point indices, ``xy`` (m × 2), ``cov`` (m × 2 × 2), line."""

    model: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    cov: np.ndarray
    line: np.ndarray

    @property
    def size(self) -> int:
        return int(self.model.size)


@dataclass(frozen=True, eq=False)
class IModelBlock:
    """A planimetric independent-model block (module docstring). ``unit``: model units."""

    models: tuple[Model, ...]
    points: tuple[PlanPoint, ...]
    obs: ModelObservations
    unit: str = "mm"
    datum: str = "control"
    sbase: tuple[str, ...] = ()
    sigma0: float = 1.0
    title: str = ""
    source: str = ""
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class SimilaritySet:
    """Model coordinates x = aX − bY + c, y = bX + aY + d (vectorised).

    rows: x of measurement k at local row 2k, y at 2k + 1; isim (m × 4) indices of a, b, c, d;
    ipt (m × 2) indices of X, Y.
    """

    rows: np.ndarray
    isim: np.ndarray
    ipt: np.ndarray

    @property
    def angular(self) -> np.ndarray:
        return np.zeros(self.rows.size, dtype=bool)

    def evaluate(self, x):
        m = self.ipt.shape[0]
        a, b = x[self.isim[:, 0]], x[self.isim[:, 1]]
        X, Y = x[self.ipt[:, 0]], x[self.ipt[:, 1]]
        f = np.empty(2 * m)
        f[0::2] = a * X - b * Y + x[self.isim[:, 2]]
        f[1::2] = b * X + a * Y + x[self.isim[:, 3]]
        o, z = np.ones(m), np.zeros(m)
        cols = np.column_stack([self.isim, self.ipt])
        vx = np.column_stack([X, -Y, o, z, a, -b])
        vy = np.column_stack([Y, X, z, o, b, a])
        lr = np.arange(m)
        jrows = np.concatenate([np.repeat(2 * lr, 6), np.repeat(2 * lr + 1, 6)])
        return f, jrows, np.concatenate([cols.ravel(), cols.ravel()]), np.concatenate([vx.ravel(), vy.ravel()])


def build_imodel_problem(block: IModelBlock) -> Problem:
    """Turn an :class:`IModelBlock` into an adjustment :class:`~baarda.model.problem.Problem`."""
    pl = ParameterList()
    add = pl.add

    isim = np.array([[add(f"{mo.id}.{nm}", getattr(mo, nm), "t") for nm in SIM_NAMES] for mo in block.models],
                    dtype=np.int64).reshape(-1, 4)
    index = np.full((len(block.points), 3), -1, dtype=np.int64)
    for i, p in enumerate(block.points):
        index[i, 0] = add(f"{p.id}.x", p.X, "k", i, 0)
        index[i, 1] = add(f"{p.id}.y", p.Y, "k", i, 1)
    params = pl.parameters()
    obs = block.obs
    m = obs.size
    sets = [SimilaritySet(np.arange(2 * m), isim[obs.model], index[obs.point, :2])] if m else []
    l = [obs.xy.ravel()]
    members = [np.array([2 * k, 2 * k + 1]) for k in range(m)]
    blocks = [obs.cov[k] for k in range(m)]
    kinds, ids, vfile, units, sfile, lines, group = [], [], [], [], [], [], []
    for k in range(m):
        mo, pt = block.models[obs.model[k]].id, block.points[obs.point[k]].id
        for comp in (0, 1):
            kinds.append("model-" + "xy"[comp])
            ids.append({"model": mo, "point": pt, "component": "xy"[comp]})
            vfile.append(obs.xy[k, comp])
            units.append(block.unit)
            sfile.append(np.sqrt(obs.cov[k, comp, comp]))
            lines.append(obs.line[k])
            group.append(k)
    row, g = 2 * m, m
    crow, cidx = [], []
    for i, p in enumerate(block.points):
        if block.datum == "free" or p.status != "control":
            continue
        rr = []
        for a in range(2):
            rr.append(row)
            crow.append(row)
            cidx.append(index[i, a])
            l.append(np.array([p.ref[a]]))
            kinds.append("control-" + "xy"[a])
            ids.append({"id": p.id})
            vfile.append(p.ref[a])
            units.append("m")
            sfile.append(p.sigma)
            lines.append(p.line)
            group.append(g)
            row += 1
        members.append(np.array(rr))
        blocks.append(np.eye(2) * p.sigma ** 2)
        g += 1
    if crow:
        sets.append(LinearSet("coordinate", np.array(crow, dtype=np.int64),
                              np.full(len(crow), -1, dtype=np.int64), np.array(cidx, dtype=np.int64)))
    cov = Covariance.from_blocks(row, members, blocks)
    info = ObservationInfo(kind=tuple(kinds), ids=tuple(ids), value_file=np.array(vfile, dtype=float),
                           unit=tuple(units), sigma_file=np.array(sfile, dtype=float), sigma_unit=tuple(units),
                           line=np.array(lines, dtype=np.int64), group=np.array(group, dtype=np.int64))
    pts = PointInfo(tuple(p.id for p in block.points), index, tuple(p.status for p in block.points), 2)
    datum = Datum("free", tuple(block.sbase)) if block.datum == "free" else Datum("fixed")
    geometry = {"models": [{"id": mo.id, "strip": mo.strip,
                            "points": sorted({block.points[p].id for p in obs.point[obs.model == j]})}
                           for j, mo in enumerate(block.models)], "unit": block.unit}
    return Problem(params=params, sets=tuple(sets), l=np.concatenate(l), cov=cov, info=info, points=pts,
                   datum=datum, sigma0=block.sigma0, sigma_act="apriori", source=block.source,
                   title=block.title, notes=ProblemNotes(imodel=geometry))
