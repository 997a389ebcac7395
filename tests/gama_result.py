"""Parser of gama-local's adjustment output XML (``gama-local NAME.gkf --xml NAME.xml``).

Only what the test suite compares with baarda is read. The document is in the namespace
``http://www.gnu.org/software/gama/gama-local-adjustment``; the tags are matched on their
local names so that the namespace does not matter. Values are kept in the file's units:
coordinates and linear observations in metres, angular observations in gon (``obs``/``adj``),
standard deviations in mm or cc, ``qrr`` and ``f`` as printed (see extdata README).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Observation elements that carry point ids, in the order the output writes them.
ID_TAGS = ("from", "to", "left", "right", "id")
NUMBER_TAGS = ("obs", "adj", "stdev", "qrr", "f", "std-residual", "err-obs", "err-adj")


@dataclass
class GamaObservation:
    kind: str  # element name: distance, direction, angle, dx, coordinate-x, ...
    ids: tuple[str, ...]  # from/to, from/left/right or id, as present
    obs: float
    adj: float
    stdev: float
    qrr: float | None = None
    f: float | None = None
    std_residual: float | None = None
    err_obs: float | None = None
    err_adj: float | None = None


@dataclass
class GamaResult:
    path: Path
    axes_xy: str = "ne"
    angles: str = "left-handed"
    version: str = ""
    equations: int = 0
    unknowns: int = 0
    dof: int = 0
    defect: int = 0
    sum_of_squares: float = float("nan")
    apriori: float = float("nan")
    aposteriori: float = float("nan")
    used: str = ""
    probability: float = float("nan")
    ratio: float = float("nan")
    lower: float = float("nan")
    upper: float = float("nan")
    failed: bool = False
    summary: dict = field(default_factory=dict)  # observations-summary counts
    fixed: dict = field(default_factory=dict)  # id -> {"x": .., "y": .., "z": ..}
    approximate: dict = field(default_factory=dict)
    adjusted: dict = field(default_factory=dict)
    constrained: dict = field(default_factory=dict)  # id -> axes written in capitals
    orientations: dict = field(default_factory=dict)  # set index -> (station id, approx, adj) gon
    cov: np.ndarray | None = None
    original_index: list = field(default_factory=list)
    observations: list = field(default_factory=list)

    def count(self, kind: str) -> int:
        return sum(1 for o in self.observations if o.kind == kind)


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _child(el, name):
    for c in el:
        if _local(c.tag) == name:
            return c
    return None


def _float(el, name, default=None):
    c = _child(el, name)
    if c is None or c.text is None:
        return default
    return float(c.text)


def _points(el) -> tuple[dict, dict]:
    out, caps = {}, {}
    if el is None:
        return out, caps
    for p in el:
        if _local(p.tag) != "point":
            continue
        pid = _child(p, "id").text.strip()
        d = {}
        for c in p:
            name = _local(c.tag)
            if name.lower() in ("x", "y", "z"):
                d[name.lower()] = float(c.text)
                if name.isupper():
                    caps[pid] = caps.get(pid, "") + name.lower()
        out[pid] = d
    return out, caps


def read_gama_result(path) -> GamaResult:
    """Parse a gama-local adjustment XML file into a :class:`GamaResult`."""
    path = Path(path)
    root = ET.parse(path).getroot()
    res = GamaResult(path)
    gp = _child(root, "network-general-parameters")
    if gp is not None:
        res.axes_xy = gp.get("axes-xy", "ne")
        res.angles = gp.get("angles", "left-handed")
        res.version = gp.get("gama-local-version", "")
    summ = _child(root, "network-processing-summary")
    if summ is not None:
        osum = _child(summ, "observations-summary")
        if osum is not None:
            res.summary = {_local(c.tag): int(c.text) for c in osum}
        pe = _child(summ, "project-equations")
        if pe is not None:
            res.equations = int(_float(pe, "equations", 0))
            res.unknowns = int(_float(pe, "unknowns", 0))
            res.dof = int(_float(pe, "degrees-of-freedom", 0))
            res.defect = int(_float(pe, "defect", 0))
            res.sum_of_squares = _float(pe, "sum-of-squares", float("nan"))
        sd = _child(summ, "standard-deviation")
        if sd is not None:
            res.apriori = _float(sd, "apriori")
            res.aposteriori = _float(sd, "aposteriori")
            u = _child(sd, "used")
            res.used = u.text.strip() if u is not None and u.text else ""
            res.probability = _float(sd, "probability", float("nan"))
            res.ratio = _float(sd, "ratio", float("nan"))
            res.lower = _float(sd, "lower", float("nan"))
            res.upper = _float(sd, "upper", float("nan"))
            res.failed = _child(sd, "failed") is not None
    coords = _child(root, "coordinates")
    if coords is not None:
        res.fixed, _ = _points(_child(coords, "fixed"))
        res.approximate, _ = _points(_child(coords, "approximate"))
        res.adjusted, res.constrained = _points(_child(coords, "adjusted"))
        osh = _child(coords, "orientation-shifts")
        if osh is not None:
            for k, o in enumerate(c for c in osh if _local(c.tag) == "orientation"):
                res.orientations[k] = (_child(o, "id").text.strip(), _float(o, "approx"),
                                       _float(o, "adj"))
        cm = _child(coords, "cov-mat")
        if cm is not None:
            dim, band = int(_float(cm, "dim")), int(_float(cm, "band"))
            vals = [float(c.text) for c in cm if _local(c.tag) == "flt"]
            m = np.zeros((dim, dim))
            k = 0
            for i in range(dim):
                for j in range(i, min(dim, i + band + 1)):
                    m[i, j] = m[j, i] = vals[k]
                    k += 1
            res.cov = m
        oi = _child(coords, "original-index")
        if oi is not None:
            res.original_index = [int(c.text) for c in oi]
    obs = _child(root, "observations")
    if obs is not None:
        for o in obs:
            ids = tuple(_child(o, t).text.strip() for t in ID_TAGS if _child(o, t) is not None)
            nums = {t: _float(o, t) for t in NUMBER_TAGS}
            res.observations.append(GamaObservation(
                kind=_local(o.tag), ids=ids, obs=nums["obs"], adj=nums["adj"],
                stdev=nums["stdev"], qrr=nums["qrr"], f=nums["f"],
                std_residual=nums["std-residual"], err_obs=nums["err-obs"],
                err_adj=nums["err-adj"]))
    return res
