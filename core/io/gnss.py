"""GNSS projection centres from a CSV file: ``image,x,y,z,sx,sy,sz`` with a header line (and
IMU attitudes, ``image,omega,phi,kappa,somega,sphi,skappa`` in degrees: :func:`read_imu`).

Each row gives the observed antenna position of one image of the block (the ``image`` as the
block names it), in metres in the frame of the block's object coordinates, and its standard
deviations. Optional columns: ``strip`` (the strip of the shift/drift model; default: the
image's strip in the block), ``time`` (for the drift, any time unit; required for every row with
``--gnss-drift``), ``rxy``, ``rxz``, ``ryz`` (correlation coefficients, making a full 3 × 3
covariance per centre). Any other column is refused with its name. CSV as
:mod:`baarda.io.control` reads it (header names case-insensitive in any order, ``#`` and blank
lines skipped, spreadsheet BOM, line ends and quotes).

:func:`add_gnss` puts them into a native bundle block (:class:`baarda.model.gnss.GnssSpec`; a
BAL, Bundler or COLMAP model is converted to one first) with the lever arm and the strip model;
the datum is then defined by the GNSS centres and the control points together. An ``image`` is
the block's image id, or an SfM model's image file name, or that name without its extension
(:func:`image_matcher`).
"""

from __future__ import annotations

import dataclasses
import math
import sqlite3

import numpy as np

from ..errors import ConversionError, InputError
from ..georeference import georeference
from ..model.bundle import Block
from ..model.gnss import GnssCentre, GnssSpec, ImuAttitude, ImuSpec
from ..model.sfm import SfmBlock, to_block
from ..validate import SIGMA_MAX, SIGMA_MIN, VALUE_LIMIT
from .camera_positions import read_metashape, read_pix4d, sniff
from .control import csv_table

COLUMNS = ("image", "x", "y", "z", "sx", "sy", "sz")
OPTIONAL = ("strip", "time", "rxy", "rxz", "ryz")


@dataclasses.dataclass(frozen=True)
class GnssOptions:
    """How GNSS projection centres enter the adjustment (``baarda.analyze(gnss=...)``).

    path: the CSV (module docstring). lever_arm: e from the projection centre to the antenna in
    the camera frame (m). estimate_lever_arm: estimate e (starting at ``lever_arm``). shift,
    drift: a shift a_s and a drift b_s per strip (:mod:`baarda.observations.gnss`). georeference:
    bring the block into the frame of the centres first (:mod:`baarda.georeference`).
    """

    path: object
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimate_lever_arm: bool = False
    shift: bool = False
    drift: bool = False
    georeference: bool = False


def _number(path, ln, image, name, tok):
    try:
        v = float(tok)
    except ValueError:
        raise InputError(path, ln, f"image {image}: {name} = '{tok[:40]}' is not a number", field=name) from None
    if not math.isfinite(v):
        raise InputError(path, ln, f"image {image}: {name} = {tok[:40]} is not finite", field=name)
    if abs(v) > VALUE_LIMIT:
        raise InputError(path, ln, f"image {image}: {name} = {v:g} is outside ±{VALUE_LIMIT:g}: too large to "
                         f"adjust in double precision", field=name)
    return v


#: the first bytes of an SQLite 3 database (a COLMAP ``database.db``)
SQLITE_MAGIC = b"SQLite format 3\x00"


def read_pose_priors(path) -> list[GnssCentre]:
    """The position priors of a COLMAP ``database.db`` (sqlite, no COLMAP needed) as GNSS centres:
    table ``pose_priors`` as COLMAP 3.9-3.12 writes it (``image_id``, ``position``,
    ``coordinate_system``, ``position_covariance``) or COLMAP 4 (``corr_data_id`` = image id for
    ``corr_sensor_type`` 0, camera). ``position`` is 3 little-endian doubles, the covariance 9;
    only Cartesian priors (coordinate_system 1; -1, undefined, taken as Cartesian) are read — WGS84
    latitude/longitude (0) would need a map projection first. Image ids are COLMAP's IMAGE_IDs;
    "line" is the prior's row number. InputError naming the file for anything else."""
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            cols = [r[1] for r in con.execute("PRAGMA table_info(pose_priors)")]
            if not cols:
                raise InputError(path, 0, "a COLMAP database without a pose_priors table")
            if "image_id" in cols:
                rows = con.execute("SELECT image_id, position, coordinate_system, position_covariance "
                                   "FROM pose_priors ORDER BY image_id").fetchall()
            elif "corr_data_id" in cols:
                rows = con.execute("SELECT corr_data_id, position, coordinate_system, position_covariance "
                                   "FROM pose_priors WHERE corr_sensor_type = 0 ORDER BY corr_data_id").fetchall()
            else:
                raise InputError(path, 0, f"pose_priors has neither image_id nor corr_data_id (columns: "
                                 f"{', '.join(cols)})")
        finally:
            con.close()
    except sqlite3.Error as err:
        raise InputError(path, 0, f"cannot read the COLMAP database: {err}") from None
    out = []
    for k, (image, pos, system, cov) in enumerate(rows, 1):
        what = f"pose prior {k} (image {image})"
        if system == 0:
            raise InputError(path, 0, f"{what}: WGS84 latitude/longitude; baarda needs Cartesian positions "
                             f"(metres in a projected or local frame)")
        if not isinstance(pos, bytes) or len(pos) != 24:
            raise InputError(path, 0, f"{what}: position is not 3 doubles")
        xyz = np.frombuffer(pos, dtype="<f8")
        if not isinstance(cov, bytes) or len(cov) != 72:
            raise InputError(path, 0, f"{what}: position_covariance is not 9 doubles")
        C = np.frombuffer(cov, dtype="<f8").reshape(3, 3)
        if not (np.isfinite(xyz).all() and np.isfinite(C).all()):
            raise InputError(path, 0, f"{what}: position or covariance not finite (COLMAP stores NaN for an "
                             f"unknown covariance: give the σ in a CSV instead)")
        C = 0.5 * (C + C.T)
        sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
        if np.linalg.eigvalsh(C)[0] <= 0 or not ((sd >= SIGMA_MIN) & (sd <= SIGMA_MAX)).all():
            raise InputError(path, 0, f"{what}: the covariance is not positive definite with σ in "
                             f"[{SIGMA_MIN:g}, {SIGMA_MAX:g}]")
        if np.abs(xyz).max() > VALUE_LIMIT:
            raise InputError(path, 0, f"{what}: position beyond ±{VALUE_LIMIT:g}")
        out.append(GnssCentre(str(image), tuple(float(v) for v in xyz), tuple(map(tuple, C.tolist())), "",
                              float("nan"), k))
    if not out:
        raise InputError(path, 0, "the COLMAP database has no pose priors of images")
    return out


def read_gnss(path) -> list[GnssCentre]:
    """The GNSS centres of a CSV file (module docstring), of a Metashape or Pix4D camera-position
    export (:mod:`baarda.io.camera_positions`, recognised by its first lines), or the pose priors
    of a COLMAP ``database.db`` (:func:`read_pose_priors`); InputError naming file, line and field."""
    try:
        with open(path, "rb") as fh:
            if fh.read(16) == SQLITE_MAGIC:
                return read_pose_priors(path)
    except OSError:
        pass                                    # csv_table below says what is wrong
    layout, records = sniff(path)
    if layout == "metashape":
        return read_metashape(path, records)
    if layout == "pix4d":
        return read_pix4d(path, records)
    col, hline, rows = csv_table(path, COLUMNS, OPTIONAL)
    out, seen = [], {}
    for ln, r in rows:
        image = r[col["image"]].strip()
        if not image:
            raise InputError(path, ln, "empty image")
        if image in seen:
            raise InputError(path, ln, f"duplicate image {image} (first at line {seen[image]})")
        seen[image] = ln
        v = {c: _number(path, ln, image, c, r[col[c]].strip()) for c in COLUMNS[1:]}
        sd = np.array([v["sx"], v["sy"], v["sz"]])
        for c, s in zip(("sx", "sy", "sz"), sd):
            if not SIGMA_MIN <= s <= SIGMA_MAX:
                raise InputError(path, ln, f"image {image}: {c} = {s:g} must lie in [{SIGMA_MIN:g}, {SIGMA_MAX:g}]",
                                 field=c)
        corr = np.eye(3)
        for c, (i, j) in zip(("rxy", "rxz", "ryz"), ((0, 1), (0, 2), (1, 2))):
            tok = r[col[c]].strip() if c in col else ""
            if tok:
                rho = _number(path, ln, image, c, tok)
                if not -1 < rho < 1:
                    raise InputError(path, ln, f"image {image}: {c} = {rho:g} must lie in (-1, 1)", field=c)
                corr[i, j] = corr[j, i] = rho
        if np.linalg.eigvalsh(corr)[0] <= 1e-12:
            raise InputError(path, ln, f"image {image}: the correlations rxy, rxz, ryz make no positive definite "
                             f"covariance", field="rxy")
        cov = corr * np.outer(sd, sd)
        tok = r[col["time"]].strip() if "time" in col else ""
        t = _number(path, ln, image, "time", tok) if tok else float("nan")
        strip = r[col["strip"]].strip() if "strip" in col else ""
        out.append(GnssCentre(image, (v["x"], v["y"], v["z"]), tuple(map(tuple, cov.tolist())), strip, t, ln))
    if not out:
        raise InputError(path, hline, "no GNSS centres after the header")
    return out


def native_block(model, path, what: str):
    """``model`` as a native :class:`Block`: itself, or an SfM block (BAL, Bundler, COLMAP)
    converted as ``baarda convert`` does (intrinsics held at the file's values); InputError
    naming ``path`` otherwise."""
    if isinstance(model, Block):
        return model
    if isinstance(model, SfmBlock):
        try:
            return to_block(model)
        except ConversionError as err:
            raise InputError(path, 0, f"{what} need a native bundle block; this {model.convention} model cannot "
                             f"be converted to one: {err}") from None
    raise InputError(path, 0, f"{what} can be added to bundle blocks only, not to a {type(model).__name__}")


def image_matcher(block: Block):
    """A function label → image id of ``block``. The label, then the label without its extension,
    is looked up as the image's id, its file name (an SfM model's, ``extra["image_names"]``) and
    that name without its extension; then the same ignoring case. A file name or a case-folded
    match counts only where it names one image; None for no image."""
    ids = {im.id for im in block.images}
    names = dict(block.extra.get("image_names", {}) or {})
    tables = [{}, {}, {}, {}]                 # name, stem; then both case-folded
    for iid in ids:
        tables[2].setdefault(iid.casefold(), set()).add(iid)
        tables[3].setdefault(_stem(iid).casefold(), set()).add(iid)
    for iid, name in names.items():
        name = str(name)
        tables[0].setdefault(name, set()).add(iid)
        tables[1].setdefault(_stem(name), set()).add(iid)
        tables[2].setdefault(name.casefold(), set()).add(iid)
        tables[3].setdefault(_stem(name).casefold(), set()).add(iid)

    def match(text: str):
        keys = (text, _stem(text))
        for key in keys:
            if key in ids:
                return key
        for k, table in enumerate(tables):
            for key in keys:
                hit = table.get(key.casefold() if k >= 2 else key, ())
                if len(hit) == 1:
                    return next(iter(hit))
        return None
    return match


def _stem(name: str) -> str:
    """A file name without its extension (``IMG_01.JPG`` → ``IMG_01``); a name without one — or
    whose last dot is followed by anything but 1-5 letters and digits with a letter (``1.5``) — as it is."""
    head, dot, ext = name.rpartition(".")
    is_ext = 1 <= len(ext) <= 5 and ext.isalnum() and not ext.isdigit()
    return head if dot and head and is_ext else name


def add_gnss(model, options: GnssOptions):
    """The model with the GNSS centres of ``options.path`` (a new object; nothing the caller
    holds is changed). A BAL, Bundler or COLMAP model is converted to a native bundle block first
    (:func:`native_block`); every row must name an image of the block (:func:`image_matcher`);
    the datum becomes "control" (GNSS centres and control points define it)."""
    path = options.path
    centres = read_gnss(path)
    model = native_block(model, path, "GNSS projection centres")
    match = image_matcher(model)
    resolved = []
    for c in centres:
        iid = match(c.image)
        if iid is None:
            raise InputError(path, c.line, f"image {c.image} is not an image of the block", field="image")
        if options.drift and not math.isfinite(c.time):
            raise InputError(path, c.line, f"image {c.image}: --gnss-drift needs a time in every row", field="time")
        resolved.append(dataclasses.replace(c, image=iid))
    twice = {}
    for c in resolved:
        if c.image in twice:
            raise InputError(path, c.line, f"image {c.image} named twice (first at line {twice[c.image]})", field="image")
        twice[c.image] = c.line
    lever = tuple(float(v) for v in options.lever_arm)
    spec = GnssSpec(tuple(resolved), lever, bool(options.estimate_lever_arm), bool(options.shift),
                    bool(options.drift), source=str(path))
    model = model.replace(gnss=spec, datum="control")
    return georeference(model, path) if options.georeference else model


# --------------------------------------------------------------------------------------------
# IMU attitudes (--imu CSV)
# --------------------------------------------------------------------------------------------
IMU_COLUMNS = ("image", "omega", "phi", "kappa", "somega", "sphi", "skappa")


@dataclasses.dataclass(frozen=True)
class ImuOptions:
    """How IMU attitudes enter the adjustment (``baarda.analyze(imu=...)``): ``path`` the CSV
    ``image,omega,phi,kappa,somega,sphi,skappa`` (degrees; the rotation R_ω R_φ R_κ of the IMU
    body frame, as the block's images define theirs), ``boresight`` the start (or, with
    ``boresight_fixed``, the value) of the boresight rotation in degrees."""

    path: object
    boresight: tuple[float, float, float] = (0.0, 0.0, 0.0)
    boresight_fixed: bool = False


def read_imu(path) -> list[ImuAttitude]:
    """The IMU attitudes of a CSV file (:class:`ImuOptions`); InputError naming file, line and field."""
    col, hline, rows = csv_table(path, IMU_COLUMNS)
    out, seen = [], {}
    for ln, r in rows:
        image = r[col["image"]].strip()
        if not image:
            raise InputError(path, ln, "empty image")
        if image in seen:
            raise InputError(path, ln, f"duplicate image {image} (first at line {seen[image]})")
        seen[image] = ln
        v = {c: _number(path, ln, image, c, r[col[c]].strip()) for c in IMU_COLUMNS[1:]}
        for c in ("somega", "sphi", "skappa"):
            if not 1e-9 <= v[c] <= 180.0:
                raise InputError(path, ln, f"image {image}: {c} = {v[c]:g} must lie in [1e-09, 180] degrees", field=c)
        if abs(v["phi"]) >= 89.999:
            raise InputError(path, ln, f"image {image}: phi = {v['phi']:g}: ω, φ, κ are singular at |φ| = 90°",
                             field="phi")
        deg = (v["omega"], v["phi"], v["kappa"])
        sd = (v["somega"], v["sphi"], v["skappa"])
        cov = np.diag(np.radians(sd) ** 2)
        out.append(ImuAttitude(image, tuple(float(a) for a in np.radians(deg)), tuple(map(tuple, cov.tolist())),
                               deg, sd, ln))
    if not out:
        raise InputError(path, hline, "no IMU attitudes after the header")
    return out


def add_imu(model, options: ImuOptions):
    """The model with the IMU attitudes of ``options.path`` (a new object); an SfM model is
    converted first (:func:`native_block`), images matched by :func:`image_matcher`; the datum
    becomes "control"."""
    path = options.path
    attitudes = read_imu(path)
    model = native_block(model, path, "IMU attitudes")
    match = image_matcher(model)
    resolved, twice = [], {}
    for a in attitudes:
        iid = match(a.image)
        if iid is None:
            raise InputError(path, a.line, f"image {a.image} is not an image of the block", field="image")
        if iid in twice:
            raise InputError(path, a.line, f"image {iid} named twice (first at line {twice[iid]})", field="image")
        twice[iid] = a.line
        resolved.append(dataclasses.replace(a, image=iid))
    attitudes = resolved
    spec = ImuSpec(tuple(attitudes), tuple(float(b) for b in np.radians(options.boresight)),
                   bool(options.boresight_fixed), source=str(path))
    return model.replace(imu=spec, datum="control")
