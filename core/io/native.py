"""baarda's native block format: versioned JSON (``docs/native-format.md``).

One document ``{"format": "baarda-block", "version": 1, "kind": ..., ...}`` holds a bundle
block (``"bundle"``), a planimetric independent-model block (``"imodel"``) or a levelling
network (``"levelling"``). :func:`read_native` validates everything and raises
:class:`baarda.errors.InputError` with the 1-based line of the offending entry: JSON syntax
errors carry the decoder's line; for a bad entry of a top-level list the reader knows where
each element starts, because it walks the top-level object with ``json.JSONDecoder.raw_decode``
(the writer puts one entry per line, but any layout works).
"""

from __future__ import annotations

import bisect
import json
import math
from pathlib import Path

import numpy as np

from ..errors import BaardaError, InputError
from ..model.bundle import AP_GROUPS, Block, Camera, Image, ImageObservations, ObjectPoint
from ..model.gnss import GnssCentre, GnssSpec, ImuAttitude, ImuSpec
from ..model.imodel import IModelBlock, Model, ModelObservations, PlanPoint
from ..model.network import Cluster, NetObservation, NetPoint, Network
from ..validate import SIGMA0_MAX, SIGMA0_MIN, SIGMA_MAX, SIGMA_MIN, VALUE_LIMIT
from .output import write_text
from .source import read_text

FORMAT = "baarda-block"
VERSIONS = (1,)
KINDS = ("bundle", "imodel", "levelling")


# --------------------------------------------------------------------------------------------
# locating entries
# --------------------------------------------------------------------------------------------
class _Locator:
    """Line numbers of the top-level keys and of the elements of top-level lists."""

    def __init__(self, text: str):
        self.newlines = [i for i, ch in enumerate(text) if ch == "\n"]
        self.keys: dict[str, int] = {}
        self.elements: dict[str, list[int]] = {}
        dec = json.JSONDecoder(parse_int=_parse_int)
        ws = " \t\r\n"
        pos = 0

        def skip(p):
            while p < len(text) and text[p] in ws:
                p += 1
            return p

        pos = skip(pos)
        if pos >= len(text) or text[pos] != "{":
            return
        pos = skip(pos + 1)
        while pos < len(text) and text[pos] != "}":
            key, pos = dec.raw_decode(text, pos)
            pos = skip(pos)
            pos = skip(pos + 1)        # ':'
            self.keys[key] = self.line(pos)
            if text[pos] == "[":
                starts = []
                pos = skip(pos + 1)
                while text[pos] != "]":
                    starts.append(self.line(pos))
                    _, pos = dec.raw_decode(text, pos)
                    pos = skip(pos)
                    if text[pos] == ",":
                        pos = skip(pos + 1)
                pos += 1
                self.elements[key] = starts
            else:
                _, pos = dec.raw_decode(text, pos)
            pos = skip(pos)
            if pos < len(text) and text[pos] == ",":
                pos = skip(pos + 1)

    def line(self, offset: int) -> int:
        return bisect.bisect_left(self.newlines, offset) + 1

    def of(self, key: str, index: int | None = None) -> int:
        if index is not None and key in self.elements and index < len(self.elements[key]):
            return self.elements[key][index]
        return self.keys.get(key, 1)


class _Reader:
    def __init__(self, path, text: str, doc: dict):
        self.path = str(path)
        self.doc = doc
        self.loc = _Locator(text)

    def fail(self, key, index, message, field=None):
        raise InputError(self.path, self.loc.of(key, index), message, field=field)

    def entries(self, key, required=True) -> list:
        val = self.doc.get(key)
        if val is None:
            if required:
                self.fail(key, None, f"missing '{key}' list", field=key)
            return []
        if not isinstance(val, list):
            self.fail(key, None, f"'{key}' must be a list", field=key)
        for i, e in enumerate(val):
            if not isinstance(e, dict):
                self.fail(key, i, f"{key}[{i}] must be an object", field=key)
        return val

    def number(self, e, name, key, i, default=None, positive=False, nonneg=False):
        if name not in e:
            if default is None:
                self.fail(key, i, f"{key}[{i}]: missing '{name}'", field=name)
            return float(default)
        v = e[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, i, f"{key}[{i}]: '{name}' is not a number ({v!r})", field=name)
        v = float(v)
        if math.isinf(v):
            self.fail(key, i, f"{key}[{i}]: '{name}' is not finite (beyond ±1.8e308, the range of double "
                      f"precision)", field=name)
        if not math.isfinite(v):
            self.fail(key, i, f"{key}[{i}]: '{name}' is not finite ({v})", field=name)
        if positive and v <= 0:
            self.fail(key, i, f"{key}[{i}]: '{name}' must be > 0 (got {v})", field=name)
        if nonneg and v < 0:
            self.fail(key, i, f"{key}[{i}]: '{name}' must be ≥ 0 (got {v})", field=name)
        if abs(v) > VALUE_LIMIT and name != "sigma0":     # its square overflows (baarda.validate)
            self.fail(key, i, f"{key}[{i}]: '{name}' = {v:g} is outside ±{VALUE_LIMIT:g}, too large to adjust "
                      f"in double precision", field=name)
        if name.startswith("sigma") and name != "sigma0" and not SIGMA_MIN <= v <= SIGMA_MAX:
            self.fail(key, i, f"{key}[{i}]: '{name}' = {v:g} is outside [{SIGMA_MIN:g}, {SIGMA_MAX:g}]: its "
                      f"weight 1/σ² cannot be formed in double precision", field=name)
        return v

    def vector(self, e, name, key, i, size, positive=False):
        v = e.get(name)
        if not isinstance(v, list) or len(v) != size:
            self.fail(key, i, f"{key}[{i}]: '{name}' must be a list of {size} numbers", field=name)
        return [self.number({name: x}, name, key, i, positive=positive) for x in v]

    def ident(self, e, name, key, i):
        v = e.get(name)
        if isinstance(v, bool) or not isinstance(v, (str, int)) or str(v) == "":
            self.fail(key, i, f"{key}[{i}]: missing or empty '{name}'", field=name)
        return str(v)

    def listed(self, key, empty: str) -> tuple[list, dict]:
        """The entries of the required, non-empty list ``key`` and their ids (id → index);
        ``empty`` is the message for an empty list."""
        items = self.entries(key)
        if not items:
            self.fail(key, None, empty)
        return items, self.unique(key, items)

    def choice(self, e, name, key, i, allowed: tuple[str, ...], default: str) -> str:
        """A field whose value is one of ``allowed``."""
        v = e.get(name, default)
        if v not in allowed:
            self.fail(key, i, f"{key}[{i}]: {name} must be {', '.join(allowed[:-1])} or {allowed[-1]} (got {v!r})",
                      field=name)
        return v

    def unique(self, key, items) -> dict:
        seen = {}
        for i, e in enumerate(items):
            pid = self.ident(e, "id", key, i)
            if pid in seen:
                self.fail(key, i, f"duplicate id '{pid}' in {key} (first at entry {seen[pid]})", field="id")
            seen[pid] = i
        return seen

    def covariance(self, e, key, i, size=2):
        if "cov" in e:
            c = e["cov"]
            if not (isinstance(c, list) and len(c) == size and all(isinstance(r, list) and len(r) == size for r in c)):
                self.fail(key, i, f"{key}[{i}]: 'cov' must be a {size} × {size} list of lists", field="cov")
            C = np.array([[self.number({"cov": x}, "cov", key, i) for x in r] for r in c])
            if not np.allclose(C, C.T) or np.linalg.eigvalsh(C).min() <= 0:
                self.fail(key, i, f"{key}[{i}]: 'cov' is not symmetric positive definite", field="cov")
            return C
        s = e.get("sigma")
        if isinstance(s, list):
            sig = self.vector(e, "sigma", key, i, size, positive=True)
        else:
            sig = [self.number(e, "sigma", key, i, positive=True)] * size
        return np.diag(np.square(sig))


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def read_native(path):
    """Read a native file: a :class:`baarda.model.bundle.Block`, :class:`baarda.model.imodel.IModelBlock`
    or (``kind: "levelling"``) a :class:`baarda.model.network.Network`. Raises InputError."""
    p = Path(path)
    text = read_text(p)                 # plain or compressed (gzip, bzip2, xz), UTF-8
    try:
        doc = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as err:
        raise InputError(path, err.lineno, f"JSON syntax error: {err.msg} (column {err.colno})") from None
    except RecursionError:
        line, depth = _too_deep(text)
        raise InputError(path, line, f"JSON nested too deeply (more than {depth} levels of [ or {{)") from None
    if not isinstance(doc, dict):
        raise InputError(path, 1, "the document must be a JSON object")
    rd = _Reader(p, text, doc)
    if doc.get("format") != FORMAT:
        rd.fail("format", None, f"not a {FORMAT} file (format = {doc.get('format')!r})", field="format")
    if doc.get("version") not in VERSIONS:
        rd.fail("version", None, f"unsupported version {doc.get('version')!r} (supported: "
                f"{', '.join(map(str, VERSIONS))})", field="version")
    kind = doc.get("kind", "bundle")
    if kind not in KINDS:
        rd.fail("kind", None, f"unknown kind {kind!r} (known: {', '.join(KINDS)})", field="kind")
    sigma0 = rd.number(doc, "sigma0", "sigma0", None, default=1.0, positive=True) if "sigma0" in doc else 1.0
    if not SIGMA0_MIN <= sigma0 <= SIGMA0_MAX:
        rd.fail("sigma0", None, f"'sigma0' = {sigma0:g} is outside [{SIGMA0_MIN:g}, {SIGMA0_MAX:g}]: too far from 1 "
                f"to adjust in double precision", field="sigma0")
    if kind == "bundle":
        return _read_bundle(rd, sigma0)
    if kind == "imodel":
        return _read_imodel(rd, sigma0)
    return _read_levelling(rd, sigma0)


def _parse_int(s: str):
    """A JSON integer: an int, or (beyond 300 digits, where Python's int-from-string limit and
    float conversion fail) the float it stands for — ``inf`` when it overflows, which the
    checks then refuse as not finite."""
    return int(s) if len(s) <= 300 else float(s)


def _too_deep(text: str, limit: int = 200) -> tuple[int, int]:
    """The line where ``text`` first nests deeper than ``limit`` arrays or objects (strings are
    skipped), and ``limit``; for the message after the decoder gave up with a RecursionError."""
    depth, line, in_str, esc = 0, 1, False, False
    for ch in text:
        if ch == "\n":
            line += 1
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            if depth > limit:
                return line, limit
        elif ch in "]}":
            depth -= 1
    return line, limit


def _datum(rd, point_ids):
    d = rd.doc.get("datum", {"kind": "control"})
    if not isinstance(d, dict) or d.get("kind", "control") not in ("control", "free"):
        rd.fail("datum", None, "datum must be {\"kind\": \"control\"} or {\"kind\": \"free\", \"sbase\": [...]}",
                field="datum")
    sbase = d.get("sbase", [])
    if not isinstance(sbase, list):
        rd.fail("datum", None, "datum.sbase must be a list of point ids", field="sbase")
    for s in sbase:
        if str(s) not in point_ids:
            rd.fail("datum", None, f"S-base point '{s}' is not a point of the block", field="sbase")
    return d.get("kind", "control"), tuple(str(s) for s in sbase)


def _plane_observations(rd, owner: str, owner_ids: dict, pt_ids: dict, empty: str, twice: str):
    """The ``observations`` list of a block: one (x, y) with its 2 × 2 covariance of one point in
    one ``owner`` (image or model) each, at most once per owner and point. Returns the owner and
    point indices, xy (m × 2), the covariances (m × 2 × 2) and the file lines.
    ``twice`` is the message for a repeated pair, formatted with ``point`` and ``owner``."""
    obs_in = rd.entries("observations")
    if not obs_in:
        rd.fail("observations", None, empty)
    m = len(obs_in)
    oi, op = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    xy, cov, line = np.empty((m, 2)), np.empty((m, 2, 2)), np.empty(m, dtype=np.int64)
    seen = set()
    for k, e in enumerate(obs_in):
        ow = rd.ident(e, owner, "observations", k)
        pt = rd.ident(e, "point", "observations", k)
        if ow not in owner_ids:
            rd.fail("observations", k, f"observations[{k}]: unknown {owner} '{ow}'", field=owner)
        if pt not in pt_ids:
            rd.fail("observations", k, f"observations[{k}]: unknown point '{pt}'", field="point")
        if (ow, pt) in seen:
            rd.fail("observations", k, f"observations[{k}]: " + twice.format(point=pt, owner=ow), field="point")
        seen.add((ow, pt))
        oi[k], op[k] = owner_ids[ow], pt_ids[pt]
        xy[k] = (rd.number(e, "x", "observations", k), rd.number(e, "y", "observations", k))
        cov[k] = rd.covariance(e, "observations", k)
        line[k] = rd.loc.of("observations", k)
    return oi, op, xy, cov, line


def _read_bundle(rd, sigma0):
    cams_in, cam_ids = rd.listed("cameras", "empty block: no cameras")
    cameras = []
    for i, e in enumerate(cams_in):
        unit = rd.choice(e, "unit", "cameras", i, ("mm", "px"), "mm")
        ap = e.get("ap", [])
        if not isinstance(ap, list) or any(g not in AP_GROUPS for g in ap):
            rd.fail("cameras", i, f"cameras[{i}]: 'ap' must list groups of {', '.join(AP_GROUPS)}", field="ap")
        ps = e.get("pixel_size")
        cameras.append(Camera(
            id=str(e["id"]), c=rd.number(e, "c", "cameras", i, positive=True),
            x0=rd.number(e, "x0", "cameras", i, 0.0), y0=rd.number(e, "y0", "cameras", i, 0.0), unit=unit,
            width=rd.number(e, "width", "cameras", i, positive=True),
            height=rd.number(e, "height", "cameras", i, positive=True),
            pixel_size=None if ps is None else rd.number(e, "pixel_size", "cameras", i, positive=True),
            **{k: rd.number(e, k, "cameras", i, 0.0) for k in ("k1", "k2", "k3", "p1", "p2")},
            ap=tuple(ap), ap_scale=rd.number(e, "ap_scale", "cameras", i, 0.0, nonneg=True),
            line=rd.loc.of("cameras", i)))
    imgs_in, img_ids = rd.listed("images", "empty block: no images")
    images = []
    for i, e in enumerate(imgs_in):
        cam = rd.ident(e, "camera", "images", i)
        if cam not in cam_ids:
            rd.fail("images", i, f"images[{i}]: unknown camera '{cam}'", field="camera")
        vals = {k: rd.number(e, k, "images", i) for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")}
        images.append(Image(id=str(e["id"]), camera=cam, strip=str(e.get("strip", "")),
                            line=rd.loc.of("images", i), **vals))
    pts_in, pt_ids = rd.listed("points", "empty block: no points")
    points = []
    for i, e in enumerate(pts_in):
        st = rd.choice(e, "status", "points", i, ("tie", "control", "check"), "tie")
        X, Y, Z = (rd.number(e, k, "points", i) for k in ("X", "Y", "Z"))
        ref, sh, sv, axes = None, 0.0, 0.0, "xyz"
        if st != "tie":
            ref = tuple(rd.vector(e, "ref", "points", i, 3)) if "ref" in e else (X, Y, Z)
        if st == "control":
            axes = e.get("axes", "xyz")
            if not isinstance(axes, str) or not axes or any(a not in "xyz" for a in axes) or len(set(axes)) != len(axes):
                rd.fail("points", i, f"points[{i}]: 'axes' must be letters of 'xyz'", field="axes")
            axes = "".join(a for a in "xyz" if a in axes)
            if "x" in axes or "y" in axes:
                sh = rd.number(e, "sigma_h", "points", i, positive=True)
            if "z" in axes:
                sv = rd.number(e, "sigma_v", "points", i, positive=True)
        points.append(ObjectPoint(id=str(e["id"]), X=X, Y=Y, Z=Z, status=st, ref=ref, sigma_h=sh, sigma_v=sv,
                                  axes=axes, line=rd.loc.of("points", i)))
    oi, op, xy, cov, line = _plane_observations(rd, "image", img_ids, pt_ids, "empty block: no image observations",
                                                "point '{point}' measured twice in image '{owner}'")
    # a point on fewer than two rays is a local defect (baarda.sfm_defects names it and leaves it
    # out, --strict refuses it), not bad input; a weighted control point on one ray is determined
    datum, sbase = _datum(rd, pt_ids)
    gnss, imu = _read_gnss(rd, img_ids), _read_imu(rd, img_ids)
    if gnss is not None or imu is not None:
        datum = "control"                  # GNSS centres (and control points) define it, as --gnss does
    extra = rd.doc.get("extra", {})
    return Block(cameras=tuple(cameras), images=tuple(images), points=tuple(points),
                 obs=ImageObservations(oi, op, xy, cov, line), datum=datum, sbase=sbase, sigma0=sigma0,
                 title=str(rd.doc.get("title", "")), source=rd.path, extra=extra if isinstance(extra, dict) else {},
                 gnss=gnss, imu=imu)


def _options(rd, key: str, allowed: dict) -> dict:
    """The optional object ``key`` of booleans and 3-vectors (``allowed``: name → default)."""
    d = rd.doc.get(key, {})
    if not isinstance(d, dict):
        rd.fail(key, None, f"'{key}' must be an object", field=key)
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        rd.fail(key, None, f"{key}: unknown field(s) {', '.join(map(repr, unknown))} (known: {', '.join(allowed)})",
                field=unknown[0])
    out = {}
    for name, default in allowed.items():
        v = d.get(name, default)
        if isinstance(default, bool):
            if not isinstance(v, bool):
                rd.fail(key, None, f"{key}.{name} must be true or false", field=name)
            out[name] = v
        elif name in d:
            ok = (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                              and math.isfinite(x) and abs(x) <= VALUE_LIMIT for x in v))
            if not ok:
                rd.fail(key, None, f"{key}.{name} must be a list of 3 finite numbers", field=name)
            out[name] = tuple(float(x) for x in v)
        else:
            out[name] = default
    return out


def _attached(rd, key, i, e, img_ids, seen) -> str:
    image = rd.ident(e, "image", key, i)
    if image not in img_ids:
        rd.fail(key, i, f"{key}[{i}]: unknown image '{image}'", field="image")
    if image in seen:
        rd.fail(key, i, f"{key}[{i}]: image '{image}' twice (first at entry {seen[image]})", field="image")
    seen[image] = i
    return image


def _read_gnss(rd, img_ids) -> GnssSpec | None:
    """``gnss_centres`` and the ``gnss`` options (docs/native-format.md), or None without centres."""
    items = rd.entries("gnss_centres", required=False)
    opts = _options(rd, "gnss", {"lever_arm": (0.0, 0.0, 0.0), "estimate_lever_arm": False, "shift": False,
                                 "drift": False})
    if not items:
        return None
    centres, seen = [], {}
    for i, e in enumerate(items):
        image = _attached(rd, "gnss_centres", i, e, img_ids, seen)
        xyz = rd.vector(e, "xyz", "gnss_centres", i, 3)
        C = rd.covariance(e, "gnss_centres", i, size=3)
        t = rd.number(e, "time", "gnss_centres", i) if "time" in e else float("nan")
        if opts["drift"] and not math.isfinite(t):
            rd.fail("gnss_centres", i, f"gnss_centres[{i}]: a drift needs a 'time' in every centre", field="time")
        centres.append(GnssCentre(image, tuple(xyz), tuple(map(tuple, C.tolist())), str(e.get("strip", "")), t,
                                  rd.loc.of("gnss_centres", i)))
    return GnssSpec(tuple(centres), opts["lever_arm"], opts["estimate_lever_arm"], opts["shift"], opts["drift"],
                    source=rd.path)


def _read_imu(rd, img_ids) -> ImuSpec | None:
    """``imu_attitudes`` and the ``imu`` options (docs/native-format.md), or None without attitudes."""
    items = rd.entries("imu_attitudes", required=False)
    opts = _options(rd, "imu", {"boresight": (0.0, 0.0, 0.0), "boresight_fixed": False})
    if not items:
        return None
    out, seen = [], {}
    for i, e in enumerate(items):
        image = _attached(rd, "imu_attitudes", i, e, img_ids, seen)
        ang = rd.vector(e, "angles", "imu_attitudes", i, 3)
        if abs(ang[1]) >= np.radians(89.999):
            rd.fail("imu_attitudes", i, f"imu_attitudes[{i}]: φ = {ang[1]:g} rad: ω, φ, κ are singular at |φ| = 90°",
                    field="angles")
        C = rd.covariance(e, "imu_attitudes", i, size=3)
        out.append(ImuAttitude(image, tuple(ang), tuple(map(tuple, C.tolist())),
                               tuple(float(v) for v in np.degrees(ang)),
                               tuple(float(v) for v in np.degrees(np.sqrt(np.diag(C)))), rd.loc.of("imu_attitudes", i)))
    return ImuSpec(tuple(out), opts["boresight"], opts["boresight_fixed"], source=rd.path)


def _read_imodel(rd, sigma0):
    mods_in, mod_ids = rd.listed("models", "empty block: no models")
    models = [Model(id=str(e["id"]), strip=str(e.get("strip", "")), line=rd.loc.of("models", i),
                    **{k: rd.number(e, k, "models", i, d) for k, d in (("a", 1.0), ("b", 0.0), ("c", 0.0), ("d", 0.0))})
              for i, e in enumerate(mods_in)]
    pts_in, pt_ids = rd.listed("points", "empty block: no points")
    points = []
    for i, e in enumerate(pts_in):
        st = rd.choice(e, "status", "points", i, ("tie", "control", "check"), "tie")
        X, Y = rd.number(e, "X", "points", i), rd.number(e, "Y", "points", i)
        ref = tuple(rd.vector(e, "ref", "points", i, 2)) if (st != "tie" and "ref" in e) else ((X, Y) if st != "tie" else None)
        sig = rd.number(e, "sigma", "points", i, positive=True) if st == "control" else 0.0
        points.append(PlanPoint(str(e["id"]), X, Y, st, ref, sig, line=rd.loc.of("points", i)))
    mi, mp, xy, cov, line = _plane_observations(rd, "model", mod_ids, pt_ids, "empty block: no model observations",
                                                "point '{point}' twice in model '{owner}'")
    counts = np.bincount(mp, minlength=len(points))
    for i, p in enumerate(points):
        if counts[i] < 1 and p.status != "control":
            rd.fail("points", i, f"point '{p.id}' is in no model", field="id")
    datum, sbase = _datum(rd, pt_ids)
    return IModelBlock(tuple(models), tuple(points), ModelObservations(mi, mp, xy, cov, line),
                       unit=str(rd.doc.get("unit", "mm")), datum=datum, sbase=sbase, sigma0=sigma0,
                       title=str(rd.doc.get("title", "")), source=rd.path)


def _read_levelling(rd, sigma0):
    pts_in, pt_ids = rd.listed("points", "empty network: no points")
    points = []
    for i, e in enumerate(pts_in):
        st = rd.choice(e, "status", "points", i, ("fixed", "adjusted"), "adjusted")
        H = rd.number(e, "H", "points", i)
        points.append(NetPoint(id=str(e["id"]), z=H, fixed="z" if st == "fixed" else "",
                               adjusted="z" if st == "adjusted" else "", line=rd.loc.of("points", i)))
    obs_in = rd.entries("observations")
    if not obs_in:
        rd.fail("observations", None, "empty network: no height differences")
    obs, clusters = [], []
    for k, e in enumerate(obs_in):
        a, b = rd.ident(e, "from", "observations", k), rd.ident(e, "to", "observations", k)
        for nm, pid in (("from", a), ("to", b)):
            if pid not in pt_ids:
                rd.fail("observations", k, f"observations[{k}]: unknown point '{pid}'", field=nm)
        if a == b:
            rd.fail("observations", k, f"observations[{k}]: from and to are the same point", field="to")
        dh = rd.number(e, "dh", "observations", k)
        s = rd.number(e, "sigma", "observations", k, positive=True)
        obs.append(NetObservation(kind="height-diff", points=(a, b), value=dh, line=rd.loc.of("observations", k),
                                  value_file=dh, unit="m", sigma_file=s, sigma_unit="m"))
        clusters.append(Cluster(indices=(k,), cov=np.array([[s * s]]), line=rd.loc.of("observations", k)))
    return Network(points=tuple(points), observations=tuple(obs), clusters=tuple(clusters), sigma0=sigma0,
                   sigma_act="apriori", description=str(rd.doc.get("title", "")), source=rd.path)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def _dump(doc: dict, lists: tuple[str, ...]) -> str:
    """JSON with one entry of each top-level list per line (exact float round trip)."""
    parts = []
    for key, val in doc.items():
        if key in lists:
            body = ",\n".join("  " + json.dumps(e, ensure_ascii=False, allow_nan=False) for e in val)
            parts.append(f" {json.dumps(key)}: [\n{body}\n ]")
        else:
            parts.append(f" {json.dumps(key)}: {json.dumps(val, ensure_ascii=False, allow_nan=False)}")
    return "{\n" + ",\n".join(parts) + "\n}\n"


def _cov_entry(C) -> dict:
    C = np.asarray(C, dtype=float)
    if C[0, 1] == 0 and C[1, 0] == 0:
        sx, sy = float(np.sqrt(C[0, 0])), float(np.sqrt(C[1, 1]))
        return {"sigma": sx if sx == sy else [sx, sy]}
    return {"cov": C.tolist()}


def _cov3_entry(C) -> dict:
    """``sigma`` [σx, σy, σz] of a diagonal 3 × 3 covariance, else ``cov``."""
    C = np.asarray(C, dtype=float)
    if not (C - np.diag(np.diag(C))).any():
        return {"sigma": [float(v) for v in np.sqrt(np.diag(C))]}
    return {"cov": C.tolist()}


def _f(v) -> float:
    return float(v)


def write_native(block, path) -> None:
    """Write a Block, IModelBlock or levelling Network in the native format (version 1)."""
    if isinstance(block, Block):
        doc = _bundle_doc(block)
        lists = ("cameras", "images", "points", "observations", "gnss_centres", "imu_attitudes")
    elif isinstance(block, IModelBlock):
        doc = _imodel_doc(block)
        lists = ("models", "points", "observations")
    else:
        other = sorted({o.kind for o in block.observations} - {"height-diff"})
        unknown_h = [p.id for p in block.points if p.z is None]
        if other or unknown_h:
            why = (f"it has {', '.join(other)} observations" if other
                   else f"point {unknown_h[0]} has no height")
            raise BaardaError(f"{block.source or 'input'}:0: the native format holds levelling networks "
                              f"only, and {why}; keep this network in GNU Gama's format")
        doc = _levelling_doc(block)
        lists = ("points", "observations")
    write_text(path, _dump(doc, lists))


def _plane_observation_docs(b, owner: str, owners, index) -> list[dict]:
    """The ``observations`` list of a block (the inverse of :func:`_plane_observations`)."""
    o = b.obs
    return [{owner: owners[index[k]].id, "point": b.points[o.point[k]].id,
             "x": _f(o.xy[k, 0]), "y": _f(o.xy[k, 1]), **_cov_entry(o.cov[k])} for k in range(o.size)]


def _datum_doc(b) -> dict:
    datum = {"kind": b.datum}
    if b.datum == "free":
        datum["sbase"] = list(b.sbase)
    return datum


def _bundle_doc(b) -> dict:
    cams = []
    for c in b.cameras:
        d = {"id": c.id, "c": c.c, "x0": c.x0, "y0": c.y0, "unit": c.unit, "width": c.width, "height": c.height}
        if c.pixel_size is not None:
            d["pixel_size"] = c.pixel_size
        d.update({k: getattr(c, k) for k in ("k1", "k2", "k3", "p1", "p2")})
        d["ap"] = list(c.ap)
        d["ap_scale"] = c.scale
        cams.append(d)
    imgs = [{"id": im.id, "camera": im.camera, "strip": im.strip,
             **{k: _f(getattr(im, k)) for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")}} for im in b.images]
    pts = []
    for p in b.points:
        d = {"id": p.id, "status": p.status, "X": _f(p.X), "Y": _f(p.Y), "Z": _f(p.Z)}
        if p.ref is not None:
            d["ref"] = [_f(v) for v in p.ref]
        if p.status == "control":
            d["axes"] = p.axes
            if p.sigma_h > 0:
                d["sigma_h"] = p.sigma_h
            if p.sigma_v > 0:
                d["sigma_v"] = p.sigma_v
        pts.append(d)
    obs = _plane_observation_docs(b, "image", b.images, b.obs.image)
    datum = _datum_doc(b)
    doc = {"format": FORMAT, "version": 1, "kind": "bundle", "title": b.title, "sigma0": b.sigma0,
           "units": {"object": "m", "angles": "rad", "image": "camera unit"}, "datum": datum,
           "cameras": cams, "images": imgs, "points": pts, "observations": obs}
    if b.gnss is not None and b.gnss.centres:
        g = b.gnss
        doc["gnss"] = {"lever_arm": [_f(v) for v in g.lever_arm], "estimate_lever_arm": bool(g.estimate_lever_arm),
                       "shift": bool(g.shift), "drift": bool(g.drift)}
        doc["gnss_centres"] = [{"image": c.image, "xyz": [_f(v) for v in c.xyz], **_cov3_entry(c.cov),
                                **({"strip": c.strip} if c.strip else {}),
                                **({"time": _f(c.time)} if math.isfinite(c.time) else {})} for c in g.centres]
    if b.imu is not None and b.imu.attitudes:
        doc["imu"] = {"boresight": [_f(v) for v in b.imu.boresight], "boresight_fixed": bool(b.imu.boresight_fixed)}
        doc["imu_attitudes"] = [{"image": a.image, "angles": [_f(v) for v in a.angles], **_cov3_entry(a.cov)}
                                for a in b.imu.attitudes]
    if b.extra:
        doc["extra"] = json.loads(json.dumps(b.extra, default=float))
    return doc


def _imodel_doc(b) -> dict:
    mods = [{"id": m.id, "strip": m.strip, "a": m.a, "b": m.b, "c": m.c, "d": m.d} for m in b.models]
    pts = []
    for p in b.points:
        d = {"id": p.id, "status": p.status, "X": _f(p.X), "Y": _f(p.Y)}
        if p.ref is not None:
            d["ref"] = [_f(v) for v in p.ref]
        if p.status == "control":
            d["sigma"] = p.sigma
        pts.append(d)
    obs = _plane_observation_docs(b, "model", b.models, b.obs.model)
    datum = _datum_doc(b)
    return {"format": FORMAT, "version": 1, "kind": "imodel", "title": b.title, "sigma0": b.sigma0,
            "unit": b.unit, "datum": datum, "models": mods, "points": pts, "observations": obs}


def _levelling_doc(net) -> dict:
    pts = [{"id": p.id, "status": "fixed" if "z" in p.fixed.lower() else "adjusted", "H": p.z} for p in net.points]
    obs = [{"from": o.points[0], "to": o.points[1], "dh": o.value, "sigma": float(np.sqrt(c.cov[0, 0]))}
           for o, c in zip(net.observations, net.clusters)]
    return {"format": FORMAT, "version": 1, "kind": "levelling", "title": net.description, "sigma0": net.sigma0,
            "units": {"height": "m", "sigma": "m"}, "points": pts, "observations": obs}
