"""GNSS projection centres of a simulated block (:func:`baarda.simulate.simulate_block` with
``gnss_sigma``): observed antenna positions X0 + R e + noise per image, a planted bad centre
(error kind ``gnss``) or a shift of a whole strip, a cycle slip (``gnss-strip``).

Recipe keys: ``gnss_sigma`` (m, σ of each component; None = no GNSS), ``gnss_lever`` (e, m,
camera frame), ``gnss_shift`` / ``gnss_drift`` (the block models a shift / drift per strip);
``imu_sigma`` (degrees, σ of each IMU angle; None = no IMU) and ``imu_boresight`` (degrees): IMU
attitudes angles(R(ω, φ, κ) R_b) + noise (:mod:`baarda.observations.imu`), error kind ``imu``
(``{"size": σ-multiple, "image", "angle": omega|phi|kappa}``), written to ``OUT.imu.csv``.
Errors: ``{"kind": "gnss", "size": σ-multiple, "image", "axis"}`` and ``{"kind": "gnss-strip",
"size": σ-multiple, "strip", "axis"}`` (axis x, y or z; default x). Times: image j of a strip at
t = j (one time unit per image).

The GNSS file is written beside the block (``OUT.gnss.csv``, docs/formats.md); the truth lists
each planted error with its rows in the problem of the block and that file.
"""

from __future__ import annotations

import numpy as np

from .errors import OptionError
from .model.gnss import GnssCentre, GnssSpec
from .model.gnss import ImuAttitude, ImuSpec
from .observations.imu import angles_of
from .observations.rotation import R_opk


def add_gnss(block, truth_images: dict, r: dict, errors: list) -> tuple:
    """``(block with GNSS, truth errors)``: the centres of every image observed with σ
    ``r["gnss_sigma"]``, the recipe's GNSS errors planted (module docstring)."""
    sigma = float(r["gnss_sigma"])
    lever = np.asarray(r["gnss_lever"], dtype=float)
    rng = np.random.default_rng([int(r["seed"]), 28])      # its own stream: the block is unchanged
    ids = [im.id for im in block.images]
    strips = [im.strip for im in block.images]
    pos = {}
    for iid in ids:
        X0, Y0, Z0, om, ph, ka = truth_images[iid]
        pos[iid] = np.array([X0, Y0, Z0]) + R_opk(om, ph, ka) @ lever
        if not r["design"]:
            pos[iid] = pos[iid] + rng.normal(0, sigma, 3)
    out = []
    ctrl_rows = sum(len(p.axes) for p in block.points if p.status == "control")   # the datum becomes "control"
    row0 = 2 * block.obs.size + ctrl_rows

    def rows_of(images, axis):
        return [row0 + 3 * ids.index(i) + "xyz".index(axis) for i in images]

    for spec in errors:
        kind = spec["kind"]
        axis = spec.get("axis") or "x"
        size = float(spec.get("size", 20.0))
        val = size * sigma * (spec.get("sign") or 1.0)
        if kind == "gnss":
            image = spec.get("image") or str(rng.choice(ids))
            if image not in pos:
                raise OptionError("image", image, (), f"error gnss: no image {image!r} in the block")
            pos[image][("xyz").index(axis)] += val
            hit, what = [image], {"image": image, "axis": axis}
        elif kind == "gnss-strip":
            strip = spec.get("strip") or str(rng.choice(sorted(set(strips))))
            hit = [i for i, s in zip(ids, strips) if s == strip]
            if not hit:
                raise OptionError("strip", strip, (), f"error gnss-strip: no strip {strip!r} in the block")
            for i in hit:
                pos[i]["xyz".index(axis)] += val
            what = {"strip": strip, "axis": axis, "images": hit}
        else:
            raise OptionError("errors.kind", kind, (), f"unknown error kind '{kind}'")
        out.append({"kind": kind, "ids": what, "vector": [val], "unit": "m", "size_sigma": size,
                    "class": "small" if size <= 50 else "medium", "rows": rows_of(hit, axis)})
    cov = tuple(map(tuple, (sigma ** 2 * np.eye(3)).tolist()))
    t, seen = {}, {}
    for i, s in zip(ids, strips):          # image j of its strip at t = j
        t[i] = float(seen.get(s, 0))
        seen[s] = seen.get(s, 0) + 1
    centres = tuple(GnssCentre(i, tuple(float(v) for v in pos[i]), cov, strips[k], t[i])
                    for k, i in enumerate(ids))
    spec = GnssSpec(centres, tuple(float(v) for v in lever), False, bool(r["gnss_shift"]), bool(r["gnss_drift"]))
    return block.replace(gnss=spec, datum="control"), out


def gnss_csv(spec: GnssSpec) -> str:
    """The GNSS file of a simulated block (``image,x,y,z,sx,sy,sz,strip,time``)."""
    lines = ["image,x,y,z,sx,sy,sz,strip,time"]
    for c in spec.centres:
        sd = np.sqrt(np.diag(np.asarray(c.cov)))
        lines.append(",".join([c.image, *(repr(float(v)) for v in c.xyz), *(repr(float(v)) for v in sd),
                               c.strip, repr(float(c.time))]))
    return "\n".join(lines) + "\n"


def add_imu(block, truth_images: dict, r: dict, errors: list) -> tuple:
    """``(block with IMU attitudes, truth errors)``: angles(R R_b) of every image observed with σ
    ``r["imu_sigma"]`` degrees, the recipe's ``imu`` errors planted (module docstring)."""
    sd = float(r["imu_sigma"])
    rng = np.random.default_rng([int(r["seed"]), 29])
    Rb = R_opk(*np.radians(np.asarray(r["imu_boresight"], dtype=float)))
    ids = [im.id for im in block.images]
    deg = {}
    for iid in ids:
        ang = np.degrees(angles_of(R_opk(*truth_images[iid][3:]) @ Rb))
        deg[iid] = ang if r["design"] else ang + rng.normal(0, sd, 3)
    out = []
    row0 = 2 * block.obs.size + sum(len(p.axes) for p in block.points if p.status == "control") \
        + (3 * len(block.gnss.centres) if block.gnss is not None else 0)
    for spec in errors:
        angle = spec.get("angle") or "omega"
        if angle not in ("omega", "phi", "kappa"):
            raise OptionError("angle", angle, ("omega", "phi", "kappa"))
        image = spec.get("image") or str(rng.choice(ids))
        if image not in deg:
            raise OptionError("image", image, (), f"error imu: no image {image!r} in the block")
        size = float(spec.get("size", 20.0))
        val = size * sd * (spec.get("sign") or 1.0)
        c = ("omega", "phi", "kappa").index(angle)
        deg[image][c] += val
        out.append({"kind": "imu", "ids": {"image": image, "angle": angle}, "vector": [val], "unit": "deg",
                    "size_sigma": size, "class": "small" if size <= 50 else "medium",
                    "rows": [row0 + 3 * ids.index(image) + c]})
    cov = tuple(map(tuple, (np.radians(sd) ** 2 * np.eye(3)).tolist()))
    att = tuple(ImuAttitude(i, tuple(float(a) for a in np.radians(deg[i])), cov, tuple(float(a) for a in deg[i]),
                            (sd, sd, sd)) for i in ids)
    return block.replace(imu=ImuSpec(att), datum="control"), out


def imu_csv(spec: ImuSpec) -> str:
    """The IMU file of a simulated block (``image,omega,phi,kappa,somega,sphi,skappa``, degrees)."""
    lines = ["image,omega,phi,kappa,somega,sphi,skappa"]
    for a in spec.attitudes:
        lines.append(",".join([a.image, *(repr(float(v)) for v in a.values_file),
                               *(repr(float(v)) for v in a.sigma_file)]))
    return "\n".join(lines) + "\n"
