"""Tests of the gama-local XML reader and of the approximate coordinates.

Oracles: gama-local 2.33's own adjustment results (``NAME.xml`` beside ``NAME.gkf`` in the shared
extdata folder). See ``../shared/extdata/README.md`` for what the result files contain.
"""

from __future__ import annotations

import collections
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from baarda.approx import approximate_coordinates
from baarda.errors import InputError
from baarda.io.gama import ARCSEC, CC, GON, MM, read_gama

from tests.extdata import GAMA, require_extdata
from tests.gama_result import read_gama_result


def _gama_files():
    d = GAMA
    if not d.is_dir():
        return [pytest.param(None, id="extdata-missing")]
    return [pytest.param(p, id=str(p.relative_to(d))) for p in sorted(d.rglob("*.gkf"))]


def _with_result():
    return [p for p in _gama_files() if p.values[0] is not None
            and p.values[0].with_suffix(".xml").exists()]


GKF = _gama_files()
GKF_XML = _with_result()

#: gama-local silently ignores observations to points no <point> defines; baarda refuses them
#: unless asked to mimic gama (``unknown_points="drop"``).
UNDEFINED_POINTS = {"2021-talapkova.gkf": 315}


def _read(path: Path):
    if path.name in UNDEFINED_POINTS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return read_gama(path, unknown_points="drop")
    return read_gama(path)


def _path(path):
    require_extdata(GAMA)
    assert path is not None
    return path


# ------------------------------------------------------------------------------------------
# helpers computing gama's observables from coordinates


def _wrap(a):
    return math.remainder(a, 2 * math.pi)


def _coords(res):
    P = {}
    for d in (res.fixed, res.adjusted):
        for k, v in d.items():
            P.setdefault(k, {}).update(v)
    return P


def _compute(net, P, o, with_heights=True):
    """Observable of ``o`` from coordinates ``P`` in the network's conventions (SI)."""
    s, off = net.angle_sign, net.azimuth_offset
    p = o.points

    def brg(a, b):
        return s * math.atan2(P[b]["y"] - P[a]["y"], P[b]["x"] - P[a]["x"]) + off

    def hd():
        return math.hypot(P[p[1]]["x"] - P[p[0]]["x"], P[p[1]]["y"] - P[p[0]]["y"])

    def dz():
        h = (o.to_dh - o.from_dh) if with_heights else 0.0
        return P[p[1]]["z"] + h - P[p[0]]["z"]

    k = o.kind
    if k in ("direction", "azimuth"):
        return brg(*p)
    if k == "angle":
        return (brg(p[0], p[2]) - brg(p[0], p[1])) % (2 * math.pi)
    if k == "distance":
        return hd()
    if k == "slope-distance":
        return math.hypot(hd(), dz())
    if k == "zenith-angle":
        return math.atan2(hd(), dz())
    if k == "height-diff":
        return P[p[1]]["z"] - P[p[0]]["z"]
    if k in ("dx", "dy", "dz"):
        return P[p[1]][k[1]] - P[p[0]][k[1]]
    if k.startswith("coordinate-"):
        return P[p[0]][k[-1]]
    raise AssertionError(k)


def _match(net, res):
    """Pairs (baarda observation, gama observation) in order; unmatched baarda ones apart."""
    pairs, extra, j = [], [], 0
    obs = net.observations
    for g in res.observations:
        while True:
            assert j < len(obs), f"gama observation {g.kind} {g.ids} not found in the input"
            o = obs[j]
            j += 1
            if o.kind == g.kind and tuple(o.points) == g.ids:
                pairs.append((o, g))
                break
            extra.append(o)
    extra.extend(obs[j:])
    return pairs, extra


# ------------------------------------------------------------------------------------------
# every file parses


@pytest.mark.parametrize("path", GKF)
def test_every_gkf_parses(path):
    path = _path(path)
    if path.name in UNDEFINED_POINTS:
        with pytest.raises(InputError) as e:
            read_gama(path)
        assert e.value.line == UNDEFINED_POINTS[path.name]
    net = _read(path)
    assert net.observations
    # every observation is in exactly one cluster, with a symmetric positive definite cov
    seen = collections.Counter(i for c in net.clusters for i in c.indices)
    assert sorted(seen) == list(range(len(net.observations)))
    assert set(seen.values()) == {1}
    for c in net.clusters:
        assert c.cov.shape == (len(c.indices),) * 2
        np.testing.assert_allclose(c.cov, c.cov.T)
        assert np.all(np.linalg.eigvalsh(c.cov) > 0)
    for o in net.observations:
        assert o.line > 0 and math.isfinite(o.value) and o.sigma_file > 0
    # direction sets numbered 0..n-1, one station each
    sets = collections.defaultdict(set)
    for o in net.observations:
        if o.kind == "direction":
            sets[o.set_id].add(o.points[0])
    assert sorted(sets) == list(range(len(sets)))
    assert all(len(v) == 1 for v in sets.values())
    assert net.tol_abs > 0 and net.sigma0 > 0


def test_units_and_defaults(tmp_path):
    d = require_extdata(GAMA)
    net = read_gama(d / "bug" / "tst-tetrahedron-3-deg.gkf")
    a_deg, a_gon = [o for o in net.observations if o.kind == "angle"]
    assert a_deg.unit == "deg" and a_deg.sigma_unit == "arcsec"
    assert a_gon.unit == "gon" and a_gon.sigma_unit == "cc"
    assert a_deg.value == pytest.approx((59 + 59 / 60 + 59.62847999998132 / 3600) * math.pi / 180)
    assert a_deg.value == pytest.approx(a_gon.value, abs=2e-6)
    assert a_deg.sigma_file == 1.296  # = 4 cc · 0.324
    k = net.observations.index(a_deg)
    c = next(c for c in net.clusters if k in c.indices)
    assert math.sqrt(c.cov[0, 0]) == pytest.approx(1.296 * ARCSEC)
    assert net.sigma0 == 10 and net.conf_pr == 0.95 and net.tol_abs == pytest.approx(1.0)
    assert net.sigma_act == "aposteriori"
    # distance-stdev="a b c": σ = a + b·D[km]^c mm, for horizontal and slope distances
    f = tmp_path / "abc.gkf"
    f.write_text(HEAD.replace('distance-stdev="5"', 'distance-stdev="2 3 0.5"') + """<obs from="A">
 <distance to="B" val="100"/> <s-distance to="C" val="2500"/> <distance to="C" val="70" stdev="4"/>
</obs>""" + TAIL)
    sig = [o.sigma_file for o in read_gama(f).observations]
    assert sig == pytest.approx([2 + 3 * 0.1 ** 0.5, 2 + 3 * 2.5 ** 0.5, 4])
    f.write_text(HEAD.replace('distance-stdev="5"', 'distance-stdev="5 5"') + """<obs from="A">
 <distance to="B" val="200"/></obs>""" + TAIL)
    assert read_gama(f).observations[0].sigma_file == pytest.approx(5 + 5 * 0.2)


@pytest.mark.parametrize("path", GKF_XML)
def test_sigmas_match_gama(path):
    """σ_i of uncorrelated observations = σ0·√(qrr/r), r = 1 − (1 − f/100)² (README)."""
    path = _path(path)
    net, res = _read(path), read_gama_result(path.with_suffix(".xml"))
    size = {i: len(c.indices) for c in net.clusters for i in c.indices}
    cov = {i: c.cov[k, k] for c in net.clusters for k, i in enumerate(c.indices)}
    index = {id(o): i for i, o in enumerate(net.observations)}
    for o, g in _match(net, res)[0]:
        i = index[id(o)]
        if size[i] > 1 or g.f is None or g.qrr is None:
            continue
        r = 1 - (1 - g.f / 100) ** 2
        if r < 0.1 or g.qrr < 0.1:  # too few printed digits to compare
            continue
        unit = MM if o.kind in ("distance", "slope-distance", "height-diff") else CC
        sigma_gama = res.apriori * math.sqrt(g.qrr / r) * unit
        assert math.sqrt(cov[i]) == pytest.approx(sigma_gama, rel=0.01), (o.kind, o.line)


# ------------------------------------------------------------------------------------------
# counts per kind


def _single_direction_sets(net):
    n = collections.Counter(o.set_id for o in net.observations if o.kind == "direction")
    return {s for s, c in n.items() if c == 1}


@pytest.mark.parametrize("path", GKF_XML)
def test_observation_counts_match_gama(path):
    """Counts per kind equal gama's, except what gama itself removes, each explained here:

    - a direction set with a single direction (no information, e.g. knin_* traverses);
    - observations whose residual exceeds tol-abs (gama's blunder rejection, the
      ``tst-tetrahedron-{1,2}`` 1500 m height difference): checked from gama's adjusted
      coordinates;
    - observations to undefined points (only with ``unknown_points="drop"``, talapkova).
    """
    path = _path(path)
    net, res = _read(path), read_gama_result(path.with_suffix(".xml"))
    pairs, extra = _match(net, res)
    singles = _single_direction_sets(net)
    P = _coords(res)
    for o in extra:
        if o.kind == "direction" and o.set_id in singles:
            continue
        v = _compute(net, P, o) - o.value
        if o.kind in ("direction", "azimuth", "angle", "zenith-angle"):
            a, b = o.points[0], o.points[-1]  # angular residual as a lateral offset
            v = _wrap(v) * math.hypot(P[b]["x"] - P[a]["x"], P[b]["y"] - P[a]["y"])
        assert abs(v) > net.tol_abs, f"{o.kind} at line {o.line} missing from gama's result"
    ours = collections.Counter(o.kind for o, _ in pairs)
    theirs = collections.Counter(g.kind for g in res.observations)
    assert ours == theirs
    # gama's summary counts vectors and coordinates per component
    assert res.summary.get("distances", 0) == theirs["distance"]
    assert res.summary.get("directions", 0) == theirs["direction"]
    assert res.summary.get("h-diffs", 0) == theirs["height-diff"]


# ------------------------------------------------------------------------------------------
# conventions: gama's adjusted values recomputed from gama's adjusted coordinates


@pytest.mark.parametrize("path", GKF_XML)
def test_conventions_reproduce_gama_adjusted_values(path):
    """Bearings, angles, distances, zenith angles, dh, vectors from Gama's coordinates.

    Tolerance 1e-6 of the unit (gon, m); 1e-5 for slope distances and zenith angles, whose
    printed adjusted values are gama's linearised ones (second-order terms ~ 1e-6 m, e.g.
    ``tst-tetrahedron-1``). gama prints slope distances and zenith angles reduced to the
    marks (instrument/target heights removed), so those are compared without from_dh/to_dh;
    with them, the residual at the adjusted coordinates equals gama's adj − obs (to second-order
    terms of the reduction).
    Directions are compared as differences within their set (the orientation is free).
    """
    path = _path(path)
    net, res = _read(path), read_gama_result(path.with_suffix(".xml"))
    P = _coords(res)
    first = {}
    for o, g in _match(net, res)[0]:
        c = _compute(net, P, o, with_heights=False)
        angular = o.kind in ("direction", "azimuth", "angle", "zenith-angle")
        tol = 1e-5 if o.kind in ("slope-distance", "zenith-angle") else 1e-6
        if o.kind == "direction":
            if o.set_id not in first:
                first[o.set_id] = (c, g.adj * GON)
                continue
            c0, a0 = first[o.set_id]
            err = _wrap((c - c0) - (g.adj * GON - a0)) / GON
        elif angular:
            err = _wrap(c - g.adj * GON) / GON
        else:
            err = c - g.adj
        assert abs(err) < tol, f"{o.kind} {o.points} line {o.line}: {err:.3g}"
        if o.kind in ("slope-distance", "zenith-angle") and (o.from_dh or o.to_dh):
            v = _compute(net, P, o) - o.value
            v_gama = (g.adj - g.obs) * (GON if angular else 1.0)
            # gama reduces to the marks at its own linearisation (ctu/2019-prager: 25 m sights,
            # 0.1 m target heights, differences up to 5e-6 rad): loose tolerance, but a sign
            # error in from_dh/to_dh would be ~4e-3 rad there
            assert abs(v - v_gama) < (3e-5 if angular else 1e-4)


def test_azimuth_conventions_cover_sw_and_en():
    """The bearing convention is pinned by azimuths in both axes-xy families."""
    d = require_extdata(GAMA)
    for name, axes in (("azimuth-azimuth", "sw"), ("krumm/2D/Ghilani16_2_DistanceAngleAzimuth_fix", "en")):
        net = read_gama(d / f"{name}.gkf")
        res = read_gama_result(d / f"{name}.xml")
        assert net.axes_xy == axes
        P = _coords(res)
        n = 0
        for o, g in _match(net, res)[0]:
            if o.kind == "azimuth":
                assert abs(_wrap(_compute(net, P, o) - g.adj * GON)) < 1e-6 * GON
                n += 1
        assert n


# ------------------------------------------------------------------------------------------
# approximate coordinates


@pytest.mark.parametrize("path", GKF)
def test_approximate_coordinates(path):
    path = _path(path)
    net = _read(path)
    approx = approximate_coordinates(net)
    for p0, p in zip(net.points, approx.points):
        for a in "xyz":
            if getattr(p0, a) is not None:
                assert getattr(p, a) == getattr(p0, a)  # given coordinates untouched
            if a in p.fixed + p.adjusted:
                assert getattr(p, a) is not None, f"{p.id}.{a}"
    xml = path.with_suffix(".xml")
    if not xml.exists():
        return
    res = read_gama_result(xml)
    P = _coords(res)
    xy = np.array([[v["x"], v["y"]] for v in P.values() if "x" in v and "y" in v])
    extent = float(np.ptp(xy, axis=0).max()) if len(xy) > 1 else 0.0
    tol = max(1.0, 2e-5 * extent)  # 1 m, or 2e-5 of the network size (krasovsky: 170 km)
    for p0, p in zip(net.points, approx.points):
        for a in "xyz":
            if getattr(p0, a) is None and getattr(p, a) is not None:
                assert abs(getattr(p, a) - P[p.id][a]) < tol, f"{p.id}.{a}"


def test_approximate_coordinates_reports_undetermined_points(tmp_path):
    f = tmp_path / "island.gkf"
    f.write_text("""<?xml version="1.0" ?>
<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">
<network>
<points-observations distance-stdev="5" direction-stdev="10">
<point id="A" x="0" y="0" fix="xy"/>
<point id="B" x="100" y="0" fix="xy"/>
<point id="C" adj="xy"/>
<point id="D" adj="xy"/>
<point id="E" adj="xy"/>
<obs from="A"> <direction to="B" val="0"/> <direction to="C" val="50"/> </obs>
<obs from="D"> <distance to="E" val="10"/> </obs>
</points-observations>
</network>
</gama-local>
""")
    net = read_gama(f)
    with pytest.raises(InputError) as e:
        approximate_coordinates(net)
    assert e.value.line == 7
    assert "C" in str(e.value) and "D" in str(e.value) and "E" in str(e.value)


# ------------------------------------------------------------------------------------------
# malformed inputs

HEAD = """<?xml version="1.0" ?>
<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">
<network>
<points-observations distance-stdev="5" direction-stdev="10">
<point id="A" x="0" y="0" fix="xy"/>
<point id="B" x="100" y="0" fix="xy"/>
<point id="C" x="50" y="50" adj="xy"/>
"""
TAIL = """</points-observations>
</network>
</gama-local>
"""
GOOD = """<obs from="A"> <direction to="B" val="0"/> <direction to="C" val="50"/> </obs>
"""

BAD = {
    # name: (body inserted at line 8, expected line, words in the message)
    "malformed-xml": ('<obs from="A"> <direction to="B" val="0"> </obs>\n', 8, "malformed XML"),
    "not-a-number": ('<obs from="A"> <direction to="B" val="abc"/> </obs>\n', 8, "not a number"),
    "nan": ('<obs from="A">\n <distance to="B" val="nan"/> </obs>\n', 9, "finite"),
    "inf": (GOOD + '<obs from="A"> <distance to="C" val="70" stdev="inf"/> </obs>\n', 9, "finite"),
    "zero-sigma": (GOOD + '<obs from="A"> <distance to="C" val="70" stdev="0"/> </obs>\n', 9,
                   "positive"),
    "negative-sigma": ('<obs from="A">\n\n <direction to="B" val="0" stdev="-3"/> </obs>\n', 10,
                       "positive"),
    "unknown-point": (GOOD + '<obs from="A"> <distance to="Q" val="70"/> </obs>\n', 9,
                      "unknown point id 'Q'"),
    "conflicting-point": ('<point id="B" x="101" y="0"/>\n' + GOOD, 8, "conflicting"),
    "cov-mat-count": ('<obs from="A">\n <distance to="B" val="100"/>\n <distance to="C" val="70"/>\n'
                      '<cov-mat dim="2" band="1">\n 25 1\n</cov-mat>\n</obs>\n', 11, "needs 3 numbers"),
    "cov-mat-not-pd": ('<obs from="A">\n <distance to="B" val="100"/>\n <distance to="C" val="70"/>\n'
                       '<cov-mat dim="2" band="1">\n 25 30 25\n</cov-mat>\n</obs>\n', 11,
                       "not positive definite"),
    "cov-mat-dim": ('<obs from="A">\n <distance to="B" val="100"/>\n'
                    '<cov-mat dim="2" band="0">\n 25 25\n</cov-mat>\n</obs>\n', 10, "holds 1"),
    "cov-mat-bad-number": ('<obs from="A">\n <distance to="B" val="100"/>\n <distance to="C" val="70"/>\n'
                           '<cov-mat dim="2" band="1">\n 25 1\n x\n</cov-mat>\n</obs>\n', 13,
                           "not a number"),
    "unknown-element": (GOOD + '<obs from="A">\n <distanse to="B" val="100"/> </obs>\n', 10,
                        "unknown element <distanse>"),
    "unknown-attribute": (GOOD + '<obs from="A"> <distance to="B" value="100"/> </obs>\n', 9,
                          "unknown attribute"),
    "no-sigma": ('<obs from="A"> <angle bs="B" fs="C" val="50"/> </obs>\n', 8,
                 "no standard deviation"),
    "bad-dms": ('<obs from="A"> <direction to="B" val="10-70-00"/> </obs>\n', 8, "d-m-s"),
    # angles no double can hold (issue 26.4): d-m-s degrees of 400 digits are inf, not a crash
    "dms-degrees-overflow": ('<obs from="A"> <direction to="B" val="1' + "0" * 399 + '-52-12.0108"/> </obs>\n',
                             8, "400 digits of degrees"),
    "dms-degrees-huge": ('<obs from="A">\n <direction to="B" val="-' + "9" * 25 + '-0-0"/> </obs>\n',
                         9, "outside ±1e+20"),
    "dms-zenith-overflow": ('<obs from="A"> <z-angle to="B" val="' + "7" * 330 + '-00-00"/> </obs>\n', 8,
                            "digits of degrees"),
    "gon-overflow": ('<obs from="A"> <direction to="B" val="1' + "0" * 400 + '"/> </obs>\n', 8, "finite"),
    "gon-inf": ('<obs from="A"> <angle bs="B" fs="C" val="-inf" stdev="3"/> </obs>\n', 8, "finite"),
    "no-standpoint": ('<obs> <distance to="B" val="100"/> </obs>\n', 8, "standpoint"),
    "empty-network": ("", 4, "no observations"),
    "fixed-without-coordinates": ('<point id="F" fix="xy"/>\n' + GOOD, 8, "fixed point F"),
    "bad-adj-letters": ('<point id="G" adj="xq"/>\n' + GOOD, 8, "axis letters"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_malformed_input(tmp_path, name):
    body, line, words = BAD[name]
    f = tmp_path / f"{name}.gkf"
    f.write_text(HEAD + body + TAIL)
    with pytest.raises(InputError) as e:
        read_gama(f)
    assert e.value.line == line, str(e.value)
    assert words in str(e.value)
    assert str(e.value).startswith(f"{f}:{line}: ")


def test_good_minimal_input(tmp_path):
    f = tmp_path / "good.gkf"
    f.write_text(HEAD + GOOD + TAIL)
    net = read_gama(f)
    assert [o.line for o in net.observations] == [8, 8]
    assert [o.set_id for o in net.observations] == [0, 0]
    assert net.observations[1].value == pytest.approx(50 * GON)


def test_two_sets_at_one_station_and_cov_mat_units(tmp_path):
    f = tmp_path / "sets.gkf"
    f.write_text(HEAD + GOOD + """<obs from="A">
 <direction to="B" val="10-00-00" />
 <distance to="C" val="70.7" />
 <direction to="C" val="55-00-00" />
 <cov-mat dim="3" band="1"> 1.0 0.5 25 2 4 </cov-mat>
</obs>
<vectors>
 <vec from="A" to="C" dx="50" dy="50" dz="0" />
 <vec from="B" to="C" dx="-50" dy="50" dz="0" />
 <cov-mat dim="6" band="0"> 1 1 1 4 4 4 </cov-mat>
</vectors>
<height-differences> <dh from="A" to="C" val="1.0" dist="4" /> </height-differences>
""" + TAIL)
    net = read_gama(f)
    sets = [o.set_id for o in net.observations if o.kind == "direction"]
    assert sets == [0, 0, 1, 1]
    c = next(c for c in net.clusters if len(c.indices) == 3)
    s = np.array([ARCSEC, MM, ARCSEC])
    expected = np.array([[1.0, 0.5, 0], [0.5, 25, 2], [0, 2, 4]]) * np.outer(s, s)
    np.testing.assert_allclose(c.cov, expected)
    vec = next(c for c in net.clusters if len(c.indices) == 6)
    assert vec.group
    keys = [net.observations[i].group_key for i in vec.indices]
    assert len(set(keys)) == 2 and keys[0] == keys[2] != keys[3]
    dh = next(o for o in net.observations if o.kind == "height-diff")
    assert dh.sigma_file == pytest.approx(10 * math.sqrt(4))  # sigma-apr·√dist, mm


def test_dms_overflow_is_one_line_from_the_cli(tmp_path, capsys):
    """Issue 26.4 / 25.5: a d-m-s angle whose degrees overflow is exit 2 with one line naming
    file, line and field — not an internal error in the approximate coordinates."""
    from baarda.cli import main

    f = tmp_path / "overflow.gkf"
    f.write_text(HEAD + GOOD + '<obs from="C"> <direction to="A" val="0-0-0"/>\n <direction to="B" val="1'
                 + "0" * 399 + '-52-12.0108"/> </obs>\n' + TAIL)
    assert main(["analyze", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"baarda: error: {f}:10:"), err
    assert "<direction val>" in err and "digits of degrees" in err


@pytest.mark.parametrize("value", [float("inf"), float("nan"), -1e300])
def test_absurd_angle_from_any_reader_is_refused_before_the_approximation(tmp_path, value):
    """The class of issue 26.4 whatever the reader: a network whose observed angle is not
    finite or beyond ±1e20 is an InputError at its line (validate.check_model_range), before
    approx._circular_mean would meet it."""
    from dataclasses import replace

    from baarda.validate import check_model_range

    f = tmp_path / "net.gkf"
    f.write_text(HEAD + GOOD + TAIL)
    net = read_gama(f)
    bad = replace(net, observations=(net.observations[0], replace(net.observations[1], value=value)))
    with pytest.raises(InputError, match="direction A C: value") as e:
        check_model_range(bad, f)
    assert e.value.line == 8
