"""GNSS projection centres of a bundle block: the file-level model and its part of the Problem.

:class:`GnssSpec` is what a block carries (``Block.gnss``): the observed antenna positions of
its images (:class:`GnssCentre`, metres, with a 3 × 3 covariance each), the lever arm (given or
estimated) and whether each strip gets a shift and a drift. :func:`add_parameters` and
:func:`add_observations` put them into a bundle block's Problem
(:func:`baarda.model.bundle.build_block_problem`); the observation equation and its Jacobian
are :class:`baarda.observations.gnss.GnssSet`.

Parameters (kind ``"t"``): ``gnss.lever.x|y|z`` (fixed at the given lever arm unless it is
estimated); per strip s with a shift ``strip S.gnss-shift.x|y|z`` and with a drift
``strip S.gnss-drift.x|y|z`` (metres, metres per time unit). Each strip's shift and drift are
groups of additional parameters: ``problem.notes.ap_groups`` has ``"S:gnss-shift"`` and
``"S:gnss-drift"``, tested by :func:`baarda.stats.ap_tests.ap_test` (F80 §7.2).

Observations: kinds ``gnss-x|y|z`` (ids ``image``, ``strip`` where there is one, ``component``), after the image points and
control, centre by centre; one covariance cluster and one test group per centre (its group test
is the 3-D test of the centre, F80 eq. 10-12).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..observations.gnss import GnssSet
from ..observations.imu import ImuSet


@dataclass(frozen=True)
class GnssCentre:
    """A GNSS position of an image's antenna: ``xyz`` (m), covariance ``cov`` (3 × 3, m²),
    ``strip`` (the file's, "" = the image's strip), ``time`` (NaN = none), source ``line``."""

    image: str
    xyz: tuple[float, float, float]
    cov: tuple[tuple[float, float, float], ...]
    strip: str = ""
    time: float = float("nan")
    line: int = 0


@dataclass(frozen=True)
class GnssSpec:
    """The GNSS observations of a block and how they are modelled (module docstring).

    lever_arm: e (m, camera frame) given, or the start of its estimate when
    ``estimate_lever_arm``; shift, drift: per strip a_s, b_s estimated. source: the file.
    """

    centres: tuple[GnssCentre, ...]
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimate_lever_arm: bool = False
    shift: bool = False
    drift: bool = False
    source: str = ""
    extra: dict = field(default_factory=dict)

    def keep_images(self, ids) -> "GnssSpec":
        """The spec with only the centres of the images ``ids`` (a block reduced for its local defects)."""
        ids = set(ids)
        return GnssSpec(tuple(c for c in self.centres if c.image in ids), self.lever_arm, self.estimate_lever_arm,
                        self.shift, self.drift, self.source, self.extra)


@dataclass(frozen=True)
class GnssLayout:
    """Where a block's GNSS parameters are: lever (3,), per strip its shift and drift indices."""

    lever: np.ndarray
    shift: dict
    drift: dict


def strip_of(centre: GnssCentre, image_strip: dict) -> str:
    """The strip of a centre: the file's ``strip``, else the image's."""
    return centre.strip or image_strip.get(centre.image, "")


def add_parameters(pl, block) -> tuple[GnssLayout, dict]:
    """Add the GNSS parameters of ``block`` to the ParameterList ``pl``: ``(layout, ap_groups)``."""
    spec = block.gnss
    fix = not spec.estimate_lever_arm
    lever = np.array([pl.add(f"gnss.lever.{a}", v, "t", fixed=fix) for a, v in zip("xyz", spec.lever_arm)],
                     dtype=np.int64)
    image_strip = {im.id: im.strip for im in block.images}
    strips = list(dict.fromkeys(strip_of(c, image_strip) for c in spec.centres))
    shift, drift, groups = {}, {}, {}
    for s in strips:
        for on, what, out in ((spec.shift, "gnss-shift", shift), (spec.drift, "gnss-drift", drift)):
            if on:
                out[s] = np.array([pl.add(f"strip {s}.{what}.{a}", 0.0, "t") for a in "xyz"], dtype=np.int64)
                groups[f"{s}:{what}"] = [pl.labels[i] for i in out[s]]
    return GnssLayout(lever, shift, drift), groups


def time_offsets(spec: GnssSpec, image_strip: dict) -> np.ndarray:
    """t − t0_s per centre, t0_s the mean time of the strip's centres (0 where no time)."""
    strips = np.array([strip_of(c, image_strip) for c in spec.centres], dtype=object)
    t = np.array([c.time for c in spec.centres], dtype=float)
    dt = np.zeros(t.size)
    for s in set(strips.tolist()):
        m = (strips == s) & np.isfinite(t)
        if m.any():
            dt[m] = t[m] - t[m].mean()
    return dt


def add_observations(block, layout: GnssLayout, ieo_img: np.ndarray, row: int, group: int, out: dict):
    """Append the GNSS rows of ``block`` from ``row`` on, test groups from ``group`` on, to the
    builder's lists in ``out`` (``l``, ``kinds``, ``ids``, ``vfile``, ``units``, ``sfile``,
    ``lines``, ``group``, ``members``, ``blocks``, ``sets``). Returns (next row, next group)."""
    spec = block.gnss
    if not spec.centres:
        return row, group
    where = {im.id: k for k, im in enumerate(block.images)}
    image_strip = {im.id: im.strip for im in block.images}
    k = len(spec.centres)
    ieo = np.array([ieo_img[where[c.image]] for c in spec.centres], dtype=np.int64).reshape(k, 6)
    shift = np.full((k, 3), -1, dtype=np.int64)
    drift = np.full((k, 3), -1, dtype=np.int64)
    for j, c in enumerate(spec.centres):
        s = strip_of(c, image_strip)
        if s in layout.shift:
            shift[j] = layout.shift[s]
        if s in layout.drift:
            drift[j] = layout.drift[s]
    rows = row + np.arange(3 * k, dtype=np.int64)
    out["sets"].append(GnssSet(rows=rows, ieo=ieo, lever=layout.lever, shift=shift, drift=drift,
                               dt=time_offsets(spec, image_strip)))
    for j, c in enumerate(spec.centres):
        cov = np.asarray(c.cov, dtype=float)
        strip = strip_of(c, image_strip)
        out["members"].append(rows[3 * j:3 * j + 3])
        out["blocks"].append(cov)
        out["l"].append(np.asarray(c.xyz, dtype=float))
        for a, nm in enumerate("xyz"):
            out["kinds"].append(f"gnss-{nm}")
            out["ids"].append({"image": c.image, **({"strip": strip} if strip else {}), "component": nm})
            out["vfile"].append(c.xyz[a])
            out["units"].append("m")
            out["sfile"].append(float(np.sqrt(cov[a, a])))
            out["lines"].append(c.line)
            out["group"].append(group + j)
    return row + 3 * k, group + k


def datum_text(block) -> str:
    """How the datum of a block with GNSS centres or IMU attitudes is defined (the summary's
    ``datum``)."""
    n_ctrl = sum(1 for p in block.points if p.status == "control")
    parts = []
    gnss, imu = block.gnss, getattr(block, "imu", None)
    if gnss is not None and gnss.centres:
        extra = [w for w, on in (("per-strip shifts", gnss.shift), ("drifts", gnss.drift),
                                 ("lever arm estimated", gnss.estimate_lever_arm)) if on]
        parts.append(f"GNSS projection centres ({len(gnss.centres)}" + (f"; {', '.join(extra)}" if extra else "") + ")")
    if imu is not None and imu.attitudes:
        parts.append(f"IMU attitudes ({len(imu.attitudes)}; boresight {'held' if imu.boresight_fixed else 'estimated'})")
    what = " and ".join(parts)
    return f"{what} and control points ({n_ctrl})" if n_ctrl else f"{what}, no control points"


# --------------------------------------------------------------------------------------------
# IMU attitudes (:mod:`baarda.observations.imu`)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImuAttitude:
    """An IMU attitude of an image: ``angles`` ω, φ, κ (rad, the rotation R_ω R_φ R_κ of the
    IMU body frame), covariance ``cov`` (3 × 3, rad²), ``values_file`` and ``sigma_file`` as the
    file has them (degrees), source ``line``."""

    image: str
    angles: tuple[float, float, float]
    cov: tuple[tuple[float, float, float], ...]
    values_file: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_file: tuple[float, float, float] = (0.0, 0.0, 0.0)
    line: int = 0


@dataclass(frozen=True)
class ImuSpec:
    """The IMU attitudes of a block and the boresight (rad; estimated unless ``boresight_fixed``)."""

    attitudes: tuple[ImuAttitude, ...]
    boresight: tuple[float, float, float] = (0.0, 0.0, 0.0)
    boresight_fixed: bool = False
    source: str = ""

    def keep_images(self, ids) -> "ImuSpec":
        """The spec with only the attitudes of the images ``ids``."""
        ids = set(ids)
        return ImuSpec(tuple(a for a in self.attitudes if a.image in ids), self.boresight, self.boresight_fixed,
                       self.source)


def add_imu_parameters(pl, block) -> np.ndarray:
    """Add the boresight b_ω, b_φ, b_κ (``imu.boresight.omega|phi|kappa``, rad) to ``pl``."""
    spec = block.imu
    return np.array([pl.add(f"imu.boresight.{nm}", v, "t", fixed=spec.boresight_fixed)
                     for nm, v in zip(("omega", "phi", "kappa"), spec.boresight)], dtype=np.int64)


def add_imu_observations(block, boresight: np.ndarray, ieo_img: np.ndarray, row: int, group: int, out: dict):
    """Append the IMU rows of ``block`` (kinds ``imu-omega|phi|kappa``, ids ``image``, ``strip``,
    ``component``; one cluster and test group per image) as :func:`add_observations` does."""
    spec = block.imu
    if not spec.attitudes:
        return row, group
    where = {im.id: k for k, im in enumerate(block.images)}
    strip_of_image = {im.id: im.strip for im in block.images}
    k = len(spec.attitudes)
    ieo = np.array([ieo_img[where[a.image]] for a in spec.attitudes], dtype=np.int64).reshape(k, 6)
    rows = row + np.arange(3 * k, dtype=np.int64)
    out["sets"].append(ImuSet(rows=rows, ieo=ieo, boresight=boresight))
    for j, a in enumerate(spec.attitudes):
        out["members"].append(rows[3 * j:3 * j + 3])
        out["blocks"].append(np.asarray(a.cov, dtype=float))
        out["l"].append(np.asarray(a.angles, dtype=float))
        strip = strip_of_image.get(a.image, "")
        for c, nm in enumerate(("omega", "phi", "kappa")):
            out["kinds"].append(f"imu-{nm}")
            out["ids"].append({"image": a.image, **({"strip": strip} if strip else {}), "component": nm})
            out["vfile"].append(a.values_file[c])
            out["units"].append("deg")
            out["sfile"].append(a.sigma_file[c])
            out["lines"].append(a.line)
            out["group"].append(group + j)
    return row + 3 * k, group + k
