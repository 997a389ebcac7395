"""Reader of GNU Gama's gama-local XML input (``.gkf``) into a :class:`baarda.model.network.Network`.

The format is documented in the GNU Gama manual, chapter "XML input data format for
gama-local" (https://www.gnu.org/software/gama/manual/). Conventions taken from it and
checked against gama-local 2.33's own results (``tests/io/test_gama.py``):

- Distances and coordinates in metres; their standard deviations in millimetres and
  covariances in mm².
- Angular values (directions, angles, azimuths, zenith angles) in gon, their standard
  deviations in cc (1 cc = 1e-4 gon), *or*, per value, in degrees written ``d-m-s`` (dashes,
  optional leading sign, e.g. ``"57-32-28.428"``); the standard deviation (explicit, default or
  covariance) of an observation written in d-m-s is in arc seconds (manual §2.1 "Angular units").
- ``<points-observations distance-stdev="a b c">``: the default σ of a horizontal or slope
  distance is ``a + b·D^c`` mm with D the observed distance in km (b = 0 and c = 1 when absent).
- ``<dh>`` without ``stdev`` but with ``dist`` (km): σ = sigma-apr·√dist mm (manual §2.15).
- Each ``<obs>`` element is one direction set (one orientation unknown); ``from`` of ``<obs>``
  is inherited by its children.
- A ``<cov-mat dim band>`` holds the upper band of a symmetric matrix, row by row
  (manual §2.8); it covers all observations of its ``<obs>``, ``<height-differences>``,
  ``<vectors>`` or ``<coordinates>`` element in document order (coordinates in x, y, z order).
- ``<point adj="xy">`` lowercase letters are adjusted coordinates, uppercase ones constrained
  (adjusted and part of the free-network datum); ``fix`` letters are fixed (either case).
- Parameter defaults: sigma-apr 10, conf-pr 0.95, tol-abs 1000 mm, sigma-act aposteriori.

Everything the file holds is either turned into the data model or kept in ``Network.extra``;
nothing is dropped silently and anything unknown is an :class:`baarda.errors.InputError`
carrying the file's line number.
"""

from __future__ import annotations

import math
import re
import warnings
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from baarda.errors import InputError, OptionError
from baarda.model.network import AXIS_NORTH_EAST, Cluster, NetObservation, NetPoint, Network
from baarda.validate import SIGMA0_MAX, SIGMA0_MIN, VALUE_LIMIT
from .source import open_binary

__all__ = ["read_gama", "bearing_convention", "UndefinedPointsWarning", "GON", "CC", "DEG", "ARCSEC", "MM"]

GON = math.pi / 200.0  #: radians per gon
CC = GON * 1e-4  #: radians per centicentigon (cc)
DEG = math.pi / 180.0  #: radians per degree
ARCSEC = DEG / 3600.0  #: radians per arc second
MM = 1e-3  #: metres per millimetre

class UndefinedPointsWarning(UserWarning):
    """Observations to points that no ``<point>`` defines were dropped (``unknown_points="drop"``)."""


_DMS = re.compile(r"^([+-]?)(\d+)-(\d+)-(\d+(?:\.\d*)?|\.\d+)$")

#: Elements that are direct observations, with the kind they get and their attributes.
_OBS_KINDS = {
    "direction": "direction",
    "distance": "distance",
    "angle": "angle",
    "azimuth": "azimuth",
    "s-distance": "slope-distance",
    "z-angle": "zenith-angle",
    "dh": "height-diff",
}
_ANGULAR = {"direction", "angle", "azimuth", "z-angle"}
_OBS_ATTRS = {
    "direction": {"from", "to", "val", "stdev", "from_dh", "to_dh", "extern"},
    "distance": {"from", "to", "val", "stdev", "from_dh", "to_dh", "extern"},
    "angle": {"from", "bs", "fs", "val", "stdev", "from_dh", "bs_dh", "fs_dh", "extern"},
    "azimuth": {"from", "to", "val", "stdev", "from_dh", "to_dh", "extern"},
    "s-distance": {"from", "to", "val", "stdev", "from_dh", "to_dh", "extern"},
    "z-angle": {"from", "to", "val", "stdev", "from_dh", "to_dh", "extern"},
    "dh": {"from", "to", "val", "stdev", "dist", "extern"},
}
_DEFAULT_STDEV_ATTR = {
    "direction": "direction-stdev",
    "angle": "angle-stdev",
    "azimuth": "azimuth-stdev",
    "z-angle": "zenith-angle-stdev",
}
_AXES_XY = ("ne", "sw", "es", "wn", "en", "nw", "se", "ws")
_PARAMETER_ATTRS = {
    "sigma-apr", "conf-pr", "tol-abs", "sigma-act", "update-constrained-coordinates",
    "algorithm", "cov-band", "ellipsoid", "latitude",
}


def bearing_convention(axes_xy: str, angles: str) -> tuple[float, float]:
    """``(angle_sign, azimuth_offset)`` reproducing gama-local's bearings in the file's axes.

    Gama measures bearings from north, clockwise for ``angles="left-handed"`` and
    counter-clockwise for ``"right-handed"`` (manual §2.3); ``axes-xy`` says where the file's
    x and y axes point. With the unit vectors of north and east expressed in the file's axes,
    the clockwise bearing from north is ``atan2(Δe, Δn)``, which is
    ``s·atan2(Δy, Δx) + θ`` with ``s = +1`` for left-handed axes (ne, sw, es, wn) and
    ``s = −1`` for right-handed ones (en, nw, se, ws), θ the clockwise bearing of the +x
    axis. Counter-clockwise angles negate both. Verified against gama-local's adjusted
    azimuths for ``sw`` and ``en`` (left-handed angles) and its adjusted directions and
    angles for every combination used in the test data.
    """
    ax, ay = AXIS_NORTH_EAST[axes_xy[0]], AXIS_NORTH_EAST[axes_xy[1]]  # (north, east) of +x and +y
    cross = ax[0] * ay[1] - ax[1] * ay[0]  # +1 when x→y turns clockwise (left-handed axes)
    sign = 1.0 if cross > 0 else -1.0
    theta = math.atan2(ax[1], ax[0])  # clockwise bearing of +x from north
    if angles == "right-handed":
        sign, theta = -sign, -theta
    return sign, theta % (2.0 * math.pi)


# ----------------------------------------------------------------------------------------
# A minimal DOM with line numbers (expat reports them; ElementTree does not).

#: The deepest nesting of elements read (gama-local's own files nest 4 deep); checked while parsing.
MAX_XML_DEPTH = 64
#: The most elements a file may hold (about 0.5 KB of memory each); checked while parsing.
MAX_XML_ELEMENTS = 2_000_000


@dataclass(slots=True)
class _Node:
    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)
    text: list = field(default_factory=list)  # (line, chunk) pairs

    def text_tokens(self):
        """Whitespace-separated tokens of the text with the line each starts on."""
        out = []
        for line, chunk in self.text:
            for m in re.finditer(r"\S+", chunk):
                out.append((line + chunk.count("\n", 0, m.start()), m.group()))
        return out


def _local(name: str) -> str:
    return name.rsplit(":", 1)[-1].rsplit("}", 1)[-1]


def _parse_xml(path: Path) -> _Node:
    """Parse the file with expat into :class:`_Node` objects carrying 1-based line numbers.

    The file (plain or compressed) is fed to expat in pieces as it is read, at most
    :func:`baarda.io.source.max_document_bytes` of it; nesting deeper than
    :data:`MAX_XML_DEPTH` or more than :data:`MAX_XML_ELEMENTS` elements are refused at the
    element where the bound is passed."""
    parser = xml.parsers.expat.ParserCreate()
    parser.buffer_text = False  # each chunk then reports its own starting line
    stack: list[_Node] = []
    root: list[_Node] = []
    count = [0]

    def start(name, attrs):
        count[0] += 1
        if len(stack) >= MAX_XML_DEPTH:
            raise InputError(path, parser.CurrentLineNumber,
                             f"elements nested more than {MAX_XML_DEPTH} deep")
        if count[0] > MAX_XML_ELEMENTS:
            raise InputError(path, parser.CurrentLineNumber, f"more than {MAX_XML_ELEMENTS:,} elements")
        node = _Node(_local(name), {_local(k): v for k, v in attrs.items()
                                    if not k.startswith("xmlns")}, parser.CurrentLineNumber)
        if stack:
            stack[-1].children.append(node)
        else:
            root.append(node)
        stack.append(node)

    def end(name):
        stack.pop()

    def chars(data):
        if stack:
            stack[-1].text.append((parser.CurrentLineNumber, data))

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        with open_binary(path, whole=True) as f:
            while True:
                piece = f.read(1 << 20)
                parser.Parse(piece, not piece)
                if not piece:
                    break
    except xml.parsers.expat.ExpatError as exc:
        msg = xml.parsers.expat.errors.messages.get(exc.code, str(exc))
        raise InputError(path, exc.lineno, f"malformed XML: {msg} (column {exc.offset + 1})") from exc
    except (LookupError, UnicodeError) as exc:      # <?xml encoding="..."?> unknown, or not that encoding
        raise InputError(path, 1, f"cannot decode the XML: {exc}") from None
    if not root:
        raise InputError(path, 1, "empty XML document")
    return root[0]


# ----------------------------------------------------------------------------------------


@dataclass
class _PointDef:
    id: str
    line: int
    coords: dict = field(default_factory=dict)  # axis -> (value, line)
    fixed: set = field(default_factory=set)
    adjusted: set = field(default_factory=set)
    constrained: set = field(default_factory=set)


@dataclass
class _Pending:
    """An observation before its σ is known (σ may depend on parameters read later)."""

    kind: str
    points: tuple
    value: float
    value_file: float
    unit: str
    line: int
    set_id: int = -1
    from_dh: float = 0.0
    to_dh: float = 0.0
    sigma_file: float | None = None  # explicit or default σ in sigma_unit
    sigma_unit: str = "mm"
    dist_km: float | None = None  # levelling section length for dh
    group_key: str = ""
    extern: str = ""


class _Reader:
    def __init__(self, path: Path, unknown_points: str = "error"):
        if unknown_points not in ("error", "drop"):
            raise OptionError("unknown_points", unknown_points, ("error", "drop"),
                              "unknown_points must be 'error' or 'drop'")
        self.unknown_points = unknown_points
        self.path = path
        self.points: dict[str, _PointDef] = {}
        self.pending: list[_Pending] = []
        self.blocks: list[tuple[list[int], _Node | None, bool]] = []  # (indices, cov-mat, group)
        self.params: dict[str, str] = {}
        self.param_lines: dict[str, int] = {}
        self.descriptions: list[str] = []
        self.extra: dict = {}
        self.n_sets = 0
        self.orientations: dict[int, float] = {}  # set id -> approximate orientation (rad)

    # -- errors and numbers ---------------------------------------------------------------
    def error(self, line, message, field=None):
        return InputError(self.path, line, message, field)

    def number(self, node: _Node, attr: str, what: str | None = None) -> float:
        text = node.attrs.get(attr)
        if text is None:
            raise self.error(node.line, f"<{node.tag}> needs attribute {attr}", attr)
        return self.parse_float(text, node.line, f"<{node.tag} {attr}>", attr)

    def opt_number(self, node: _Node, attr: str, default=None):
        if attr not in node.attrs:
            return default
        return self.number(node, attr)

    def parse_float(self, text: str, line: int, where: str, field=None) -> float:
        try:
            v = float(text.strip())
        except ValueError:
            raise self.error(line, f"{where}: not a number: {text.strip()!r}", field) from None
        if not math.isfinite(v):
            raise self.error(line, f"{where}: value must be finite, got {text.strip()!r}", field)
        if abs(v) > VALUE_LIMIT:        # squares of it overflow (baarda.validate)
            raise self.error(line, f"{where}: {v:g} is outside ±{VALUE_LIMIT:g}, too large to adjust in "
                             f"double precision", field)
        return v

    def angle(self, node: _Node, attr: str = "val") -> tuple[float, float, str]:
        """(radians, file value, unit) of an angular attribute: gon, or d-m-s in degrees."""
        text = node.attrs.get(attr)
        if text is None:
            raise self.error(node.line, f"<{node.tag}> needs attribute {attr}", attr)
        s = text.strip()
        m = _DMS.match(s)
        if m:
            sign = -1.0 if m.group(1) == "-" else 1.0
            d, mi, se = float(m.group(2)), float(m.group(3)), float(m.group(4))
            if mi > 60 or se > 60:  # gama-local accepts "187-33-60.00" (zoltan-test_2d_dms)
                raise self.error(node.line, f"<{node.tag} {attr}>: bad d-m-s angle {s!r} "
                                 "(minutes and seconds must not exceed 60)", attr)
            deg = sign * (d + mi / 60.0 + se / 3600.0)
            if not math.isfinite(deg) or abs(deg) > VALUE_LIMIT:
                # float() of a few hundred digits is inf: the same bound as a value in gon
                raise self.error(node.line, f"<{node.tag} {attr}>: d-m-s angle {s[:40]!r}"
                                 f"{'...' if len(s) > 40 else ''} has {len(m.group(2))} digits of degrees: "
                                 f"outside ±{VALUE_LIMIT:g}, too large to adjust in double precision", attr)
            return deg * DEG, deg, "deg"
        if "-" in s[1:]:
            raise self.error(node.line, f"<{node.tag} {attr}>: bad d-m-s angle {s!r}", attr)
        v = self.parse_float(s, node.line, f"<{node.tag} {attr}>", attr)
        return v * GON, v, "gon"

    def sigma(self, text: str, line: int, where: str, field="stdev") -> float:
        v = self.parse_float(text, line, where, field)
        if v <= 0:
            raise self.error(line, f"{where}: standard deviation must be positive, got {v:g}", field)
        return v

    def check_attrs(self, node: _Node, allowed: set):
        extra = sorted(set(node.attrs) - allowed)
        if extra:
            raise self.error(node.line, f"<{node.tag}>: unknown attribute(s) "
                             + ", ".join(extra), extra[0])

    def unknown_element(self, node: _Node, parent: str):
        raise self.error(node.line, f"unknown element <{node.tag}> in <{parent}>", node.tag)

    # -- document structure -------------------------------------------------------------
    def read(self) -> Network:
        root = _parse_xml(self.path)
        if root.tag != "gama-local":
            raise self.error(root.line, f"root element must be <gama-local>, found <{root.tag}>")
        self.check_attrs(root, {"version", "schemaLocation", "noNamespaceSchemaLocation"})
        if "version" in root.attrs:
            self.extra["version"] = root.attrs["version"]
        networks = [c for c in root.children if c.tag == "network"]
        for c in root.children:
            if c.tag != "network":
                self.unknown_element(c, "gama-local")
        if len(networks) != 1:
            raise self.error(root.line, f"<gama-local> must contain one <network>, found {len(networks)}")
        net = networks[0]
        self.check_attrs(net, {"axes-xy", "angles", "epoch"})
        axes = net.attrs.get("axes-xy", "ne").strip()
        if axes not in _AXES_XY:
            raise self.error(net.line, f"<network axes-xy>: unknown value {axes!r} "
                             f"(expected one of {', '.join(_AXES_XY)})", "axes-xy")
        angles = net.attrs.get("angles", "left-handed").strip()
        if angles not in ("left-handed", "right-handed"):
            raise self.error(net.line, f"<network angles>: unknown value {angles!r} "
                             "(expected left-handed or right-handed)", "angles")
        if "epoch" in net.attrs:
            self.extra["epoch"] = self.number(net, "epoch")
        sections = {"description": [], "parameters": [], "points-observations": []}
        for c in net.children:
            if c.tag not in sections:
                self.unknown_element(c, "network")
            sections[c.tag].append(c)
        for d in sections["description"]:
            self.descriptions.append("".join(t for _, t in d.text).strip())
            for c in d.children:
                self.unknown_element(c, "description")
        for p in sections["parameters"]:
            self.read_parameters(p)
        if not sections["points-observations"]:
            raise self.error(net.line, "<network> has no <points-observations>")
        for po in sections["points-observations"]:
            self.read_points_observations(po)
        return self.build(net, axes, angles, sections["points-observations"][0].line)

    def read_parameters(self, node: _Node):
        self.check_attrs(node, _PARAMETER_ATTRS)
        for c in node.children:
            self.unknown_element(c, "parameters")
        for k, v in node.attrs.items():
            self.params[k] = v.strip()
            self.param_lines[k] = node.line

    def param_float(self, name: str, default: float) -> float:
        if name not in self.params:
            return default
        return self.parse_float(self.params[name], self.param_lines[name], f"<parameters {name}>", name)

    # -- points ----------------------------------------------------------------------------
    def read_point(self, node: _Node, observed: bool = False):
        """Merge a ``<point>`` into the point list (``observed``: inside ``<coordinates>``)."""
        self.check_attrs(node, {"id", "x", "y", "z", "fix", "adj"})
        for c in node.children:
            self.unknown_element(c, "point")
        pid = node.attrs.get("id", "").strip()
        if not pid:
            raise self.error(node.line, "<point> needs a non-empty id", "id")
        p = self.points.setdefault(pid, _PointDef(pid, node.line))
        coords = {}
        for axis in "xyz":
            if axis in node.attrs:
                coords[axis] = self.number(node, axis)
        for axis, v in coords.items():
            if axis in p.coords:
                old, old_line = p.coords[axis]
                if not observed and old != v:
                    raise self.error(node.line, f"point {pid} redefined with {axis}={v!r}, "
                                     f"conflicting with {axis}={old!r} at line {old_line}", axis)
            else:
                p.coords[axis] = (v, node.line)
        fix = node.attrs.get("fix", "").strip()
        adj = node.attrs.get("adj", "").strip()
        for attr, letters in (("fix", fix), ("adj", adj)):
            bad = set(letters) - set("xyzXYZ")
            if bad or len(set(letters.lower())) != len(letters):
                raise self.error(node.line, f"<point {attr}>: bad axis letters {letters!r}", attr)
        for a in fix.lower():
            p.fixed.add(a)
        for a in adj:
            p.adjusted.add(a.lower())
            if a.isupper():
                p.constrained.add(a.lower())
        both = p.fixed & p.adjusted
        if both:
            raise self.error(node.line, f"point {pid}: coordinate(s) {''.join(sorted(both))} "
                             "both fixed and adjusted", "adj")
        return pid, coords

    # -- observations ----------------------------------------------------------------------
    def read_points_observations(self, po: _Node):
        self.check_attrs(po, {"distance-stdev", "direction-stdev", "angle-stdev",
                              "zenith-angle-stdev", "azimuth-stdev"})
        defaults = {}
        for k in ("direction-stdev", "angle-stdev", "zenith-angle-stdev", "azimuth-stdev"):
            if k in po.attrs:
                defaults[k] = self.sigma(po.attrs[k], po.line, f"<points-observations {k}>", k)
        if "distance-stdev" in po.attrs:
            toks = po.attrs["distance-stdev"].split()
            if not 1 <= len(toks) <= 3:
                raise self.error(po.line, "<points-observations distance-stdev>: expected 1 to 3 "
                                 "numbers 'a [b [c]]'", "distance-stdev")
            abc = [self.parse_float(t, po.line, "<points-observations distance-stdev>",
                                    "distance-stdev") for t in toks] + [0.0, 1.0][len(toks) - 1:]
            if abc[0] < 0 or abc[1] < 0 or abc[0] + abc[1] <= 0:
                raise self.error(po.line, "<points-observations distance-stdev>: model a + b·D^c "
                                 "needs a, b >= 0, not both zero", "distance-stdev")
            defaults["distance-stdev"] = tuple(abc)
        self.extra.setdefault("default_stdev", []).append(
            {k: v for k, v in defaults.items()})
        for c in po.children:
            if c.tag == "point":
                self.read_point(c)
            elif c.tag == "obs":
                self.read_obs(c, defaults)
            elif c.tag == "height-differences":
                self.read_block(c, defaults, {"dh"}, "height-differences")
            elif c.tag == "vectors":
                self.read_vectors(c)
            elif c.tag == "coordinates":
                self.read_coordinates(c)
            else:
                self.unknown_element(c, "points-observations")

    def split_cov(self, node: _Node, allowed_children: set, parent: str):
        """Children of an observation block, and its ``<cov-mat>`` (at most one, last)."""
        cov, items = None, []
        for c in node.children:
            if c.tag == "cov-mat":
                if cov is not None:
                    raise self.error(c.line, f"<{parent}> has more than one <cov-mat>")
                cov = c
            elif c.tag in allowed_children:
                if cov is not None:
                    raise self.error(c.line, f"<{c.tag}> after the <cov-mat> of its <{parent}>")
                items.append(c)
            else:
                self.unknown_element(c, parent)
        return items, cov

    def read_obs(self, node: _Node, defaults: dict):
        """One ``<obs>``: a direction set (own orientation) plus any other observations.

        Attributes (manual §2.8, gama-local.xsd): ``from`` (the standpoint, inherited by the
        observations), ``from_dh`` (the instrument height of every observation inside that
        does not give its own ``from_dh``) and ``orientation`` (an approximate value of the
        set's orientation unknown, an angle like the directions: gon or d-m-s; it only starts
        the iteration, the orientation is estimated).
        """
        self.check_attrs(node, {"from", "from_dh", "orientation"})
        items, cov = self.split_cov(node, set(_OBS_KINDS), "obs")
        station = node.attrs.get("from", "").strip() or None
        set_from_dh = self.opt_number(node, "from_dh", 0.0)
        set_id = -1
        if any(c.tag == "direction" for c in items):
            set_id = self.n_sets
            self.n_sets += 1
            if "orientation" in node.attrs:
                self.orientations[set_id] = self.angle(node, "orientation")[0]
        elif "orientation" in node.attrs:
            raise self.error(node.line, "<obs orientation> given but the <obs> holds no "
                             "<direction> (only direction sets have an orientation)",
                             "orientation")
        first = len(self.pending)
        for c in items:
            self.read_observation(c, defaults, station, set_id, set_from_dh, cov is not None)
        self.blocks.append((list(range(first, len(self.pending))), cov, False))

    def read_block(self, node: _Node, defaults: dict, allowed: set, parent: str):
        self.check_attrs(node, set())
        items, cov = self.split_cov(node, allowed, parent)
        if not items:
            raise self.error(node.line, f"<{parent}> contains no observations")
        first = len(self.pending)
        for c in items:
            self.read_observation(c, defaults, None, -1, 0.0, cov is not None)
        self.blocks.append((list(range(first, len(self.pending))), cov, False))

    def read_observation(self, node, defaults, station, set_id, set_from_dh, has_cov):
        tag = node.tag
        self.check_attrs(node, _OBS_ATTRS[tag])
        for c in node.children:
            self.unknown_element(c, tag)
        frm = node.attrs.get("from", "").strip() or station
        if tag == "direction" and station and frm != station:
            raise self.error(node.line, f"<direction from={frm!r}> differs from the standpoint "
                             f"{station!r} of its <obs>", "from")
        if not frm:
            raise self.error(node.line, f"<{tag}> has no standpoint: give from= in it or its <obs>",
                             "from")
        if tag == "angle":
            ids = (frm, self.req_id(node, "bs"), self.req_id(node, "fs"))
        else:
            ids = (frm, self.req_id(node, "to"))
        if len(set(ids)) != len(ids):
            raise self.error(node.line, f"<{tag}>: the same point used twice: {', '.join(ids)}")
        if tag in _ANGULAR:
            value, vfile, unit = self.angle(node)
            sunit = "arcsec" if unit == "deg" else "cc"
        else:
            value = vfile = self.number(node, "val")
            unit, sunit = "m", "mm"
            if tag in ("distance", "s-distance") and value <= 0:
                raise self.error(node.line, f"<{tag} val>: a distance must be positive, got {vfile:g}",
                                 "val")
        sigma = dist = None
        if "stdev" in node.attrs:
            sigma = self.sigma(node.attrs["stdev"], node.line, f"<{tag} stdev>")
        elif tag in _DEFAULT_STDEV_ATTR and _DEFAULT_STDEV_ATTR[tag] in defaults:
            sigma = defaults[_DEFAULT_STDEV_ATTR[tag]]
        elif tag in ("distance", "s-distance") and "distance-stdev" in defaults:
            a, b, c = defaults["distance-stdev"]
            sigma = a + b * (value / 1000.0) ** c
        if tag == "dh" and "dist" in node.attrs:
            dist = self.number(node, "dist")
            if dist <= 0:
                raise self.error(node.line, f"<dh dist>: levelling distance must be positive, "
                                 f"got {dist:g}", "dist")
        if sigma is None and dist is None and not has_cov:
            raise self.error(node.line, f"<{tag}> has no standard deviation (no stdev, no default "
                             "in <points-observations>, no <cov-mat>)", "stdev")
        from_dh = self.opt_number(node, "from_dh", set_from_dh if tag != "dh" else 0.0)
        to_dh = self.opt_number(node, "to_dh", 0.0)
        if tag == "angle":  # heights of the two targets: no effect on a horizontal angle
            to_dh = self.opt_number(node, "bs_dh", 0.0)
            self.opt_number(node, "fs_dh", 0.0)  # checked as a number, like gama-local
        self.pending.append(_Pending(
            kind=_OBS_KINDS[tag], points=ids, value=value, value_file=vfile, unit=unit,
            line=node.line, set_id=set_id if tag == "direction" else -1, from_dh=from_dh,
            to_dh=to_dh, sigma_file=sigma, sigma_unit=sunit, dist_km=dist,
            extern=node.attrs.get("extern", "")))

    def req_id(self, node: _Node, attr: str) -> str:
        v = node.attrs.get(attr, "").strip()
        if not v:
            raise self.error(node.line, f"<{node.tag}> needs attribute {attr}", attr)
        return v

    def read_vectors(self, node: _Node):
        """``<vectors>``: ``<vec from to dx dy dz>`` and one ``<cov-mat>`` (mm²) for them all."""
        self.check_attrs(node, set())
        items, cov = self.split_cov(node, {"vec"}, "vectors")
        if not items:
            raise self.error(node.line, "<vectors> contains no <vec>")
        if cov is None:
            raise self.error(node.line, "<vectors> needs a <cov-mat>")
        first = len(self.pending)
        for c in items:
            self.check_attrs(c, {"from", "to", "dx", "dy", "dz", "from_dh", "to_dh", "extern"})
            for cc in c.children:
                self.unknown_element(cc, "vec")
            ids = (self.req_id(c, "from"), self.req_id(c, "to"))
            if ids[0] == ids[1]:
                raise self.error(c.line, f"<vec>: the same point used twice: {ids[0]}")
            fdh, tdh = self.opt_number(c, "from_dh", 0.0), self.opt_number(c, "to_dh", 0.0)
            key = f"vec:{ids[0]}->{ids[1]}@{c.line}"
            for comp in ("dx", "dy", "dz"):
                v = self.number(c, comp)
                self.pending.append(_Pending(comp, ids, v, v, "m", c.line, from_dh=fdh, to_dh=tdh,
                                             group_key=key, extern=c.attrs.get("extern", "")))
        self.blocks.append((list(range(first, len(self.pending))), cov, True))

    def read_coordinates(self, node: _Node):
        """``<coordinates>``: observed coordinates (x, y, z order per point) and a ``<cov-mat>``."""
        self.check_attrs(node, {"extern"})
        items, cov = self.split_cov(node, {"point"}, "coordinates")
        if not items:
            raise self.error(node.line, "<coordinates> contains no <point>")
        if cov is None:
            raise self.error(node.line, "<coordinates> needs a <cov-mat>")
        first = len(self.pending)
        for c in items:
            pid, coords = self.read_point(c, observed=True)
            if not coords:
                raise self.error(c.line, f"<coordinates>: point {pid} has no coordinates")
            key = f"coord:{pid}@{c.line}"
            for axis in "xyz":
                if axis in coords:
                    v = coords[axis]
                    self.pending.append(_Pending(f"coordinate-{axis}", (pid,), v, v, "m", c.line,
                                                 group_key=key, extern=node.attrs.get("extern", "")))
        self.blocks.append((list(range(first, len(self.pending))), cov, True))

    # -- covariance matrices ---------------------------------------------------------------
    def read_cov(self, cov: _Node, n: int) -> np.ndarray:
        """The symmetric matrix of a ``<cov-mat dim band>`` (upper band by rows), file units."""
        self.check_attrs(cov, {"dim", "band"})
        for c in cov.children:
            self.unknown_element(c, "cov-mat")
        dim, band = self.number(cov, "dim"), self.number(cov, "band")
        if dim != int(dim) or band != int(band) or dim < 1 or band < 0:
            raise self.error(cov.line, f"<cov-mat>: bad dim={dim:g} or band={band:g}")
        dim, band = int(dim), int(band)
        if dim != n:
            raise self.error(cov.line, f"<cov-mat dim={dim}> but its element holds {n} observations",
                             "dim")
        band = min(band, dim - 1)
        toks = cov.text_tokens()
        expected = sum(min(band, dim - 1 - i) + 1 for i in range(dim))
        if len(toks) != expected:
            raise self.error(cov.line, f"<cov-mat dim={dim} band={band}> needs {expected} "
                             f"numbers, found {len(toks)}")
        m = np.zeros((dim, dim))
        k = 0
        for i in range(dim):
            for j in range(i, min(dim, i + band + 1)):
                line, t = toks[k]
                m[i, j] = m[j, i] = self.parse_float(t, line, "<cov-mat>")
                k += 1
        try:
            np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            raise self.error(cov.line, "<cov-mat> is not positive definite") from None
        return m

    # -- assembly -------------------------------------------------------------------------
    def build(self, net: _Node, axes: str, angles: str, po_line: int) -> Network:
        sigma_apr = self.param_float("sigma-apr", 10.0)
        conf_pr = self.param_float("conf-pr", 0.95)
        tol_abs = self.param_float("tol-abs", 1000.0)
        sigma_act = self.params.get("sigma-act", "aposteriori")
        if sigma_apr <= 0:
            raise self.error(self.param_lines["sigma-apr"], "<parameters sigma-apr> must be positive",
                             "sigma-apr")
        if not SIGMA0_MIN <= sigma_apr <= SIGMA0_MAX:
            raise self.error(self.param_lines["sigma-apr"], f"<parameters sigma-apr> = {sigma_apr:g} is outside "
                             f"[{SIGMA0_MIN:g}, {SIGMA0_MAX:g}]: too far from 1 to adjust in double precision",
                             "sigma-apr")
        if not 0 < conf_pr < 1:
            raise self.error(self.param_lines["conf-pr"], "<parameters conf-pr> must be in (0, 1)",
                             "conf-pr")
        if tol_abs <= 0:
            raise self.error(self.param_lines["tol-abs"], "<parameters tol-abs> must be positive",
                             "tol-abs")
        if sigma_act not in ("apriori", "aposteriori"):
            raise self.error(self.param_lines["sigma-act"], "<parameters sigma-act> must be apriori "
                             f"or aposteriori, got {sigma_act!r}", "sigma-act")
        if not self.pending:
            raise self.error(po_line, "empty network: no observations")
        keep = self.check_point_ids()
        new_index = {old: k for k, old in enumerate(i for i in range(len(self.pending)) if keep[i])}
        set_ids = sorted({self.pending[i].set_id for i in new_index if self.pending[i].set_id >= 0})
        set_map = {old: k for k, old in enumerate(set_ids)}
        observations, clusters = [None] * len(new_index), []
        for indices, cov, group in self.blocks:
            if not indices:
                continue
            scale = np.array([self.si_factor(self.pending[i]) for i in indices])
            kept = [k for k, i in enumerate(indices) if keep[i]]
            if cov is not None:
                c = self.read_cov(cov, len(indices))
                sig = np.sqrt(np.diag(c))
                for k in kept:
                    i = indices[k]
                    observations[new_index[i]] = self.finish(self.pending[i], sig[k], set_map)
                if kept:
                    sub = (c * np.outer(scale, scale))[np.ix_(kept, kept)]
                    clusters.append(Cluster(tuple(new_index[indices[k]] for k in kept), sub,
                                            group, cov.line))
            else:
                for k in kept:
                    i = indices[k]
                    ob = self.pending[i]
                    s = ob.sigma_file
                    if s is None:  # dh with dist only
                        s = sigma_apr * math.sqrt(ob.dist_km)
                    observations[new_index[i]] = self.finish(ob, s, set_map)
                    clusters.append(Cluster((new_index[i],), np.array([[(s * scale[k]) ** 2]]),
                                            False, ob.line))
        if not observations:
            raise self.error(po_line, "empty network: no observations left")
        for p in self.points.values():
            missing = [a for a in sorted(p.fixed) if a not in p.coords]
            if missing:
                raise self.error(p.line, f"fixed point {p.id} has no {'/'.join(missing)} coordinate",
                                 "fix")
        points = tuple(self.make_point(p) for p in self.points.values())
        sign, offset = bearing_convention(axes, angles)
        extra = dict(self.extra)
        extra["parameters"] = dict(self.params)
        extra["sigma_apr"] = sigma_apr
        extra["n_direction_sets"] = len(set_map)
        if self.orientations:
            extra["orientations"] = {set_map[s]: v for s, v in self.orientations.items()
                                     if s in set_map}
        return Network(points=points, observations=tuple(observations), clusters=tuple(clusters),
                       sigma0=sigma_apr, sigma_act=sigma_act, conf_pr=conf_pr,
                       tol_abs=tol_abs * MM, angle_sign=sign, azimuth_offset=offset, axes_xy=axes,
                       angles=angles, description="\n\n".join(d for d in self.descriptions if d),
                       source=str(self.path), extra=extra)

    def check_point_ids(self) -> list[bool]:
        """Which observations to keep: all, unless some refer to undefined points.

        gama-local silently removes observations whose points no ``<point>`` defines (e.g.
        ``ctu/2021-talapkova.gkf`` line 315); baarda raises :class:`InputError` instead, or,
        with ``unknown_points="drop"``, removes them too but records each one in
        ``Network.extra["dropped"]`` and warns.
        """
        keep = [True] * len(self.pending)
        dropped = []
        for i, ob in enumerate(self.pending):
            missing = [pid for pid in ob.points if pid not in self.points]
            if not missing:
                continue
            msg = f"{ob.kind} refers to unknown point id {missing[0]!r} (no <point> defines it)"
            if self.unknown_points == "error":
                raise self.error(ob.line, msg + "; --drop-undefined drops such observations "
                                 "as gama-local does")
            keep[i] = False
            dropped.append({"line": ob.line, "kind": ob.kind, "points": list(ob.points),
                            "undefined": missing, "reason": msg})
        if dropped:
            self.extra["dropped"] = dropped
            ids = sorted({pid for d in dropped for pid in d["undefined"]})
            warnings.warn(UndefinedPointsWarning(
                f"{self.path}: {len(dropped)} observation(s) to undefined point(s) "
                f"{', '.join(ids)} dropped (line(s) {', '.join(str(d['line']) for d in dropped)})"),
                stacklevel=4)
        return keep

    @staticmethod
    def si_factor(ob: _Pending) -> float:
        return {"mm": MM, "cc": CC, "arcsec": ARCSEC}[ob.sigma_unit]

    @staticmethod
    def finish(ob: _Pending, sigma_file: float, set_map: dict) -> NetObservation:
        return NetObservation(kind=ob.kind, points=ob.points, value=ob.value,
                              set_id=set_map.get(ob.set_id, -1),
                              from_dh=ob.from_dh, to_dh=ob.to_dh, line=ob.line,
                              value_file=ob.value_file, unit=ob.unit, sigma_file=float(sigma_file),
                              sigma_unit=ob.sigma_unit, group_key=ob.group_key, extern=ob.extern)

    @staticmethod
    def make_point(p: _PointDef) -> NetPoint:
        c = {a: v for a, (v, _) in p.coords.items()}
        order = lambda s: "".join(a for a in "xyz" if a in s)  # noqa: E731
        return NetPoint(id=p.id, x=c.get("x"), y=c.get("y"), z=c.get("z"), fixed=order(p.fixed),
                        adjusted=order(p.adjusted), constrained=order(p.constrained), line=p.line)


def read_gama(path, *, unknown_points: str = "error") -> Network:
    """Read a gama-local XML input file (``.gkf``) into a :class:`~baarda.model.network.Network`.

    Values are converted to SI (metres, radians) and every observation is put in exactly one
    :class:`~baarda.model.network.Cluster` with its covariance in SI². Raises
    :class:`baarda.errors.InputError` (with the line number) for malformed or inconsistent
    input. See the module docstring for the conventions.

    ``unknown_points="drop"`` mimics gama-local, which silently removes observations to
    points that no ``<point>`` defines: they are removed, listed in
    ``Network.extra["dropped"]`` (line, kind, points, reason) and a warning is issued. The
    default, ``"error"``, raises :class:`InputError` at the first such observation.
    """
    return _Reader(Path(path), unknown_points).read()
