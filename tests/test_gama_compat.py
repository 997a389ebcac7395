"""GNU Gama compatibility: the documented ``<obs>`` attributes, observations to undefined points,
local defects of networks, and the speed of the approximate coordinates.

References, independent of baarda's own arithmetic:

- ``from_dh``/``to_dh``, ``<obs from_dh>``, vector heights: noise-free networks computed here from
  known coordinates *between the instrument and target positions*; the adjustment must return
  those coordinates, and the same network with the heights folded into the observed values
  (observations between the marks, no heights) must agree with it;
- ``--drop-undefined``: gama-local's own result for ``ctu/2021-talapkova.gkf`` (it drops the
  observation to the undefined point 3021 silently);
- local defects: gama-local's own result for the real traverse ``bug/2019-08-13-traverse-knin_male``
  (2D), whose points are here declared ``adj="xyz"`` without any height information;
- approximate coordinates: the railway survey adjusted from the approximate coordinates its
  authors give (``extra/railway-survey-with-aproximate-xy.gkf``).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.cli import main
from baarda.errors import InputError
from baarda.io import read_model
from baarda.io.gama import GON, UndefinedPointsWarning, read_gama

from tests.extdata import GAMA, require_extdata
from tests.gama_result import read_gama_result

SCHEMA = json.loads((Path(__file__).parents[1] / "core" / "schema" / "analysis.schema.json").read_text())

TRUE = {"A": (0.0, 0.0, 100.0), "B": (400.0, 0.0, 150.0), "C": (0.0, 300.0, 200.0),
        "Z": (400.0, 300.0, 160.0)}
ORIENTATION = 0.3  # rad, of the direction set at Z
HI = 1.55          # instrument height at Z
HT = {"A": 1.30, "B": 2.10, "C": 0.00}   # target heights


def _obs_values(heights: bool):
    """Directions, slope distances and zenith angles from Z, computed from TRUE (gon, m)."""
    zx, zy, zz = TRUE["Z"]
    out = {}
    for t in "ABC":
        x, y, z = TRUE[t]
        dx, dy = x - zx, y - zy
        dz = (z + HT[t]) - (zz + HI) if heights else z - zz
        h = math.hypot(dx, dy)
        out[t] = {"dir": ((math.atan2(dy, dx) - ORIENTATION) % (2 * math.pi)) / GON,
                  "s": math.hypot(h, dz), "zen": math.atan2(h, dz) / GON}
    return out


def _gkf(obs_attrs: str, child, points=None) -> str:
    pts = points or (
        '<point id="A" x="0" y="0" z="100" fix="xyz"/>\n'
        '<point id="B" x="400" y="0" z="150" fix="xyz"/>\n'
        '<point id="C" x="0" y="300" z="200" fix="xyz"/>\n'
        '<point id="Z" x="401.3" y="298.2" z="161.1" adj="xyz"/>\n')
    body = "".join(child(t) for t in "ABC")
    return ('<?xml version="1.0"?>\n<gama-local><network>\n'
            '<parameters sigma-apr="1" sigma-act="apriori"/>\n'
            '<points-observations direction-stdev="10" zenith-angle-stdev="10" distance-stdev="2">\n'
            f'{pts}<obs from="Z"{obs_attrs}>\n{body}</obs>\n'
            '</points-observations></network></gama-local>\n')


def _children(values, explicit_from_dh: bool, heights: bool = True):
    def child(t):
        v = values[t]
        h = f' to_dh="{HT[t]}"' if heights else ""
        f = f' from_dh="{HI}"' if explicit_from_dh else ""
        return (f'<direction to="{t}" val="{v["dir"]:.12f}"/>\n'
                f'<s-distance to="{t}" val="{v["s"]:.9f}"{f}{h}/>\n'
                f'<z-angle to="{t}" val="{v["zen"]:.12f}"{f}{h}/>\n')
    return child


def _adjust_file(tmp_path, name, text):
    f = tmp_path / name
    f.write_text(text)
    problem = read_problem(f)
    adj = adjust(problem)
    assert adj.converged
    i = problem.points.ids.index("Z")
    return problem, adj, adj.coordinates[i]


# --------------------------------------------------------------------------------------------
# <obs from_dh>, <obs orientation>, <angle bs_dh fs_dh>, <vec from_dh to_dh>


def test_obs_from_dh_is_the_instrument_height_of_the_set(tmp_path):
    with_h = _obs_values(heights=True)
    # the height given once on <obs>, inherited by every observation inside
    p1, a1, z1 = _adjust_file(tmp_path, "set.gkf", _gkf(f' from_dh="{HI}"', _children(with_h, False)))
    assert all(o.from_dh == HI for o in read_gama(tmp_path / "set.gkf").observations)
    np.testing.assert_allclose(z1, TRUE["Z"], atol=1e-6)
    assert np.abs(a1.v).max() < 1e-7
    # the same heights on each observation: the same adjustment
    _, a2, z2 = _adjust_file(tmp_path, "each.gkf", _gkf("", _children(with_h, True)))
    np.testing.assert_allclose(z2, z1, atol=1e-9)
    np.testing.assert_allclose(a2.v, a1.v, atol=1e-9)
    # the heights folded into the observations (values between the marks, no heights)
    _, a3, z3 = _adjust_file(tmp_path, "marks.gkf",
                             _gkf("", _children(_obs_values(heights=False), False, heights=False)))
    np.testing.assert_allclose(z3, z1, atol=1e-6)
    # ignoring the set's height is visibly wrong (the test can fail)
    _, _, z4 = _adjust_file(tmp_path, "none.gkf", _gkf("", _children(with_h, False)))
    assert abs(z4[2] - TRUE["Z"][2]) > 0.5


def test_explicit_from_dh_wins_over_the_sets(tmp_path):
    f = tmp_path / "mixed.gkf"
    text = _gkf(' from_dh="9.99"', _children(_obs_values(heights=True), True))
    f.write_text(text)
    assert {o.from_dh for o in read_gama(f).observations if o.kind != "direction"} == {HI}
    # directions are horizontal: the set's height is kept on them but changes nothing
    assert {o.from_dh for o in read_gama(f).observations if o.kind == "direction"} == {9.99}


def test_obs_orientation_starts_the_orientation_unknown(tmp_path):
    values = _obs_values(heights=True)
    _, a0, z0 = _adjust_file(tmp_path, "plain.gkf", _gkf(f' from_dh="{HI}"', _children(values, False)))
    for text, expect in (("57.3", 57.3 * GON), ("-12-30-00", -12.5 * math.pi / 180)):
        p, a, z = _adjust_file(tmp_path, "ori.gkf",
                               _gkf(f' from_dh="{HI}" orientation="{text}"', _children(values, False)))
        k = [i for i, lab in enumerate(p.params.labels) if lab.startswith("orientation")]
        assert len(k) == 1 and p.params.x0[k[0]] == pytest.approx(expect)
        np.testing.assert_allclose(z, z0, atol=1e-8)          # only the start differs
        assert math.remainder(a.x[k[0]] - ORIENTATION, 2 * math.pi) == pytest.approx(0, abs=1e-9)
    # an orientation needs a direction set
    bad = tmp_path / "bad.gkf"
    bad.write_text(_gkf(' orientation="10"', lambda t: f'<distance to="{t}" val="100"/>\n'))
    with pytest.raises(InputError) as err:
        read_gama(bad)
    assert err.value.line == 9 and "orientation" in str(err.value)


def test_heights_of_horizontal_observations_change_nothing(tmp_path):
    """from_dh/to_dh of directions, distances, azimuths and bs_dh/fs_dh of angles are read
    (gama-local keeps bs_dh as the target height, fs_dh is checked only) and have no effect:
    these are horizontal quantities."""
    pts = ('<point id="A" x="0" y="0" fix="xy"/>\n<point id="B" x="400" y="0" fix="xy"/>\n'
           '<point id="C" x="0" y="300" fix="xy"/>\n<point id="Z" x="401" y="299" adj="xy"/>\n')
    vals = _obs_values(heights=False)
    zx, zy, _ = TRUE["Z"]

    def child(with_h):
        def make(t):
            x, y, _ = TRUE[t]
            h = ' from_dh="1.5" to_dh="2.5"' if with_h else ""
            return (f'<direction to="{t}" val="{vals[t]["dir"]:.10f}"{h}/>\n'
                    f'<distance to="{t}" val="{math.hypot(x - zx, y - zy) + 0.003:.6f}"{h}/>\n')
        return make

    extra = ('<obs><angle from="A" bs="B" fs="C" val="100.0021"{a} stdev="10"/>\n'
             '<azimuth from="Z" to="A" val="{az:.6f}"{h} stdev="10"/></obs>\n')
    az = (math.atan2(-zy, -zx) % (2 * math.pi)) / GON
    res = []
    for with_h in (False, True):
        text = _gkf("", child(with_h), pts).replace(
            "</points-observations>",
            extra.format(a=' from_dh="1.4" bs_dh="1.2" fs_dh="1.7"' if with_h else "",
                         h=' from_dh="1.5" to_dh="2"' if with_h else "", az=az + 0.0007)
            + "</points-observations>")
        res.append(_adjust_file(tmp_path, f"h{with_h}.gkf", text))
        if with_h:
            ang = [o for o in read_gama(tmp_path / "hTrue.gkf").observations if o.kind == "angle"]
            assert ang[0].from_dh == 1.4 and ang[0].to_dh == 1.2
    (_, a0, z0), (_, a1, z1) = res
    assert np.abs(a0.v).max() > 1e-5      # the data are not trivially consistent
    np.testing.assert_allclose(z1, z0, atol=1e-10)
    np.testing.assert_allclose(a1.v, a0.v, atol=1e-12)
    np.testing.assert_allclose(a1.w, a0.w, atol=1e-9)


def test_vectors_join_the_antennas(tmp_path):
    """<vec from_dh to_dh>: the vector is measured between antennas h_from, h_to above the marks,
    so Δz' = Δz + h_to − h_from (gama-local reads the heights but leaves them out)."""
    P = {"A": (0.0, 0.0, 100.0), "B": (500.0, 100.0, 120.0), "Q": (210.0, 330.0, 135.25)}
    hgt = {("A", "Q"): (1.6, 1.9), ("B", "Q"): (1.45, 1.9), ("A", "B"): (1.6, 1.45)}

    def vec(a, b, heights):
        ha, hb = hgt[(a, b)]
        dz = P[b][2] - P[a][2] + ((hb - ha) if heights else 0.0)
        h = f' from_dh="{ha}" to_dh="{hb}"' if heights else ""
        return (f'<vec from="{a}" to="{b}" dx="{P[b][0] - P[a][0]}" dy="{P[b][1] - P[a][1]}" '
                f'dz="{dz:.6f}"{h}/>\n')

    def text(heights, q_z=True):
        cov = " ".join(["4"] * 9)
        z = ' z="134"' if q_z else ""
        return ('<?xml version="1.0"?>\n<gama-local><network>\n<points-observations>\n'
                '<point id="A" x="0" y="0" z="100" fix="xyz"/>\n'
                '<point id="B" x="500" y="100" z="120" fix="xyz"/>\n'
                f'<point id="Q" x="209" y="331"{z} adj="xyz"/>\n<vectors>\n'
                + "".join(vec(a, b, heights) for a, b in hgt)
                + f'<cov-mat dim="9" band="0">\n{cov}\n</cov-mat>\n</vectors>\n'
                '</points-observations></network></gama-local>\n')

    for heights in (True, False):   # False: the heights folded into dz (reference)
        f = tmp_path / f"v{heights}.gkf"
        f.write_text(text(heights))
        problem = read_problem(f)
        adj = adjust(problem)
        q = adj.coordinates[problem.points.ids.index("Q")]
        np.testing.assert_allclose(q, P["Q"], atol=1e-9)
        assert np.abs(adj.v).max() < 1e-9
    # approximate height of Q from the vectors, reduced with the antenna heights
    f = tmp_path / "noz.gkf"
    f.write_text(text(True, q_z=False))
    net = read_model(f)
    assert [p.z for p in net.points if p.id == "Q"][0] == pytest.approx(P["Q"][2], abs=1e-9)


# --------------------------------------------------------------------------------------------
# observations to undefined points


TALAPKOVA = "ctu/2021-talapkova.gkf"


def test_undefined_points_default_error_names_file_and_line(capsys):
    path = require_extdata(GAMA) / TALAPKOVA
    with pytest.raises(InputError) as err:
        read_model(path)
    assert err.value.line == 315 and "'3021'" in str(err.value) and "--drop-undefined" in str(err.value)
    assert main(["analyze", str(path)]) == 2
    out = capsys.readouterr().err
    assert out.startswith(f"baarda: error: {path}:315: ") and out.count("\n") == 1


def test_undefined_points_dropped_on_request(tmp_path, capsys):
    path = require_extdata(GAMA) / TALAPKOVA
    with pytest.warns(UndefinedPointsWarning, match="3021"):
        net = read_model(path, drop_undefined=True)
    assert [(d["line"], d["undefined"]) for d in net.extra["dropped"]] == [(315, ["3021"])]
    out = tmp_path / "t.json"
    assert main(["analyze", str(path), "--drop-undefined", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("baarda: warning: ") and "3021" in err and "315" in err
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    dropped = doc["summary"]["dropped_observations"]
    assert [(d["line"], d["kind"], d["undefined"]) for d in dropped] == [(315, "direction", ["3021"])]
    # gama-local drops it too: the same observations remain, the same adjusted coordinates
    ref = read_gama_result(path.with_suffix(".xml"))
    assert doc["summary"]["n_observations"] == len(ref.observations)
    pts = {p["id"]: p for p in doc["points"]}
    diffs = [abs(pts[k][a] - v[a]) for k, v in ref.adjusted.items() for a in v if a in "xy"]
    assert diffs and max(diffs) < 1e-5
    # a file without undefined points: no warning, an empty list
    assert main(["analyze", str(GAMA / "gama-local.gkf"), "--drop-undefined", "--quiet",
                 "--json", str(out)]) == 0
    assert capsys.readouterr().err == ""
    assert json.loads(out.read_text())["summary"]["dropped_observations"] == []


# --------------------------------------------------------------------------------------------
# local defects of networks


KNIN = "bug/2019-08-13-traverse-knin_male.gkf"


def _knin3d(tmp_path, extra_points="", extra_obs=""):
    src = (require_extdata(GAMA) / KNIN).read_text()
    text = src.replace('adj="xy"', 'adj="xyz"')
    text = text.replace("</points-observations>", extra_points + extra_obs + "</points-observations>")
    f = tmp_path / "knin3d.gkf"
    f.write_text(text)
    return f


def _xy(problem, adj):
    return {pid: adj.coordinates[i, :2] for i, pid in enumerate(problem.points.ids)}


def test_traverse_without_heights_is_adjusted_in_xy(tmp_path, capsys):
    """A real traverse whose new points are declared adj="xyz" but have no height information:
    the heights are named as local defects and the points adjusted in x, y — exactly the 2D
    traverse, whose result gama-local gives."""
    f = _knin3d(tmp_path)
    p3 = read_problem(f)
    defects = p3.notes.local_defects
    assert [(d.id, d.components) for d in defects] == [(i, ("z",)) for i in ("4261", "4262", "4263")]
    assert all(d.action == "adjusted in x, y" and "height" in d.reason for d in defects)
    a3 = adjust(p3)
    p2 = read_problem(GAMA / KNIN)
    a2 = adjust(p2)
    xy3, xy2 = _xy(p3, a3), _xy(p2, a2)
    for pid in xy2:
        np.testing.assert_allclose(xy3[pid], xy2[pid], atol=1e-9)
    np.testing.assert_allclose(a3.r, a2.r, atol=1e-9)
    np.testing.assert_allclose(a3.w, a2.w, atol=1e-9, equal_nan=True)
    ref = read_gama_result((GAMA / KNIN).with_suffix(".xml"))
    for pid, c in ref.adjusted.items():
        assert abs(xy3[pid][0] - c["x"]) < 1e-5 and abs(xy3[pid][1] - c["y"]) < 1e-5
    # CLI: named in the text and the JSON; --strict refuses as before
    out = tmp_path / "k.json"
    assert main(["analyze", str(f), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "3 local defect(s)" in text and "point 4262 (z)" in text
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    assert [(d["id"], d["components"], d["action"]) for d in doc["summary"]["local_defects"]] == \
        [(i, ["z"], "adjusted in x, y") for i in ("4261", "4262", "4263")]
    assert main(["analyze", str(f), "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {f}:") and "4261" in err and err.count("\n") == 1


def test_undetermined_points_are_left_out_and_the_rest_analysed(tmp_path, capsys):
    """A point seen by one direction only (its position cannot be determined) and a point no
    observation involves: both named, left out with the observation that needs the first; the
    traverse is analysed exactly as without them."""
    f = _knin3d(tmp_path,
                extra_points='<point id="X9" adj="xy"/>\n<point id="Y9" x="1075200" y="758900" adj="xy"/>\n',
                extra_obs='<obs from="4262">\n<direction to="X9" val="33.3330"/>\n'
                          '<direction to="4261" val="0.0000"/>\n</obs>\n')
    line = next(k for k, s in enumerate(f.read_text().splitlines(), 1) if 'to="X9"' in s)
    p = read_problem(f)
    d = {x.id: x for x in p.notes.local_defects}
    assert set(d) == {"4261", "4262", "4263", "X9", "Y9"}
    assert d["X9"].components == ("x", "y") and d["X9"].action.startswith("left out")
    assert f"line(s) {line}" in d["X9"].action
    assert d["Y9"].components == ("x", "y") and "no observation involves its position" in d["Y9"].reason
    assert "X9" not in p.points.ids or p.points.index[p.points.ids.index("X9")].max() < 0
    a = adjust(p)
    a2 = adjust(read_problem(GAMA / KNIN))
    # the extra direction to 4261 stays (a set of one direction: no information, r = 0)
    assert p.n == a2.problem.n + 1
    np.testing.assert_allclose(np.sort(a.r)[1:], np.sort(a2.r), atol=1e-9)
    assert main(["analyze", str(f), "--strict"]) == 2
    assert "X9" in capsys.readouterr().err


def test_datum_defect_of_the_whole_network_is_still_diagnosed(tmp_path, capsys):
    f = _knin3d(tmp_path)
    f.write_text(f.read_text().replace('fix="XY"', 'adj="xy"'))
    assert main(["analyze", str(f)]) == 2
    err = capsys.readouterr().err
    assert "datum defect" in err and err.count("\n") == 1


# --------------------------------------------------------------------------------------------
# approximate coordinates of a real survey: fast and the same adjustment


def test_railway_survey_without_approximate_xy(capsys):
    """The railway survey (833 points, 3,694 observations) without its approximate xy gives
    the same adjustment as with them; the approximate coordinates take seconds, not minutes
    (they recomputed every bearing and distance after each located point)."""
    base = require_extdata(GAMA) / "extra"
    t0 = time.perf_counter()
    p_with = read_problem(base / "railway-survey-with-aproximate-xy.gkf")
    t_with = time.perf_counter() - t0
    t0 = time.perf_counter()
    net = read_model(base / "railway-survey.gkf")
    t_approx = time.perf_counter() - t0
    p_without = read_problem(base / "railway-survey.gkf")
    assert not p_without.notes.local_defects
    assert t_approx < 10.0 + 3 * t_with, (t_approx, t_with)
    assert sum(p.x is None for p in net.points) == 0
    a1, a2 = adjust(p_with), adjust(p_without)
    assert a1.converged and a2.converged
    c1 = dict(zip(p_with.points.ids, a1.coordinates[:, :2]))
    c2 = dict(zip(p_without.points.ids, a2.coordinates[:, :2]))
    assert set(c1) == set(c2)
    assert max(np.abs(c1[k] - c2[k]).max() for k in c1) < 1e-6
    key = lambda p, i: (p.info.kind[i], tuple(p.info.ids[i].values()), round(float(p.l[i]), 9))  # noqa: E731
    r1 = {key(p_with, i): (a1.r[i], a1.w[i]) for i in range(p_with.n)}
    r2 = {key(p_without, i): (a2.r[i], a2.w[i]) for i in range(p_without.n)}
    assert set(r1) == set(r2)
    for k, (r, w) in r1.items():
        assert abs(r - r2[k][0]) < 1e-6
        if r > 1e-6:   # w of observations without control (r ≈ 0) is noise
            assert abs(w - r2[k][1]) < 1e-4


def test_adjustment_safety_net_for_points_a_single_direction_leaves_open(tmp_path, capsys):
    """A point *with* approximate coordinates seen by a single direction: the structure looks
    fine, the normal equations are singular in its x, y only. adjust_network names it, sets it
    aside with its observation and adjusts the rest (the traverse as without it); --strict and
    the plain adjustment keep the datum-defect error."""
    from baarda.errors import DatumDefectError
    from baarda.network_defects import adjust_network

    f = _knin3d(tmp_path, extra_points='<point id="X8" x="1075200" y="758900" adj="xy"/>\n',
                extra_obs='<obs from="4262">\n<direction to="X8" val="33.3330"/>\n'
                          '<direction to="4261" val="0.0000"/>\n</obs>\n')
    line = next(k for k, s in enumerate(f.read_text().splitlines(), 1) if 'to="X8"' in s)
    p = read_problem(f)
    with pytest.raises(DatumDefectError):
        adjust(p)
    with pytest.raises(DatumDefectError):
        adjust_network(p, strict=True)
    a, p2 = adjust_network(p)
    d = {x.id: x for x in p2.notes.local_defects}
    assert set(d) == {"4261", "4262", "4263", "X8"}
    assert d["X8"].components == ("x", "y") and f"line(s) {line}" in d["X8"].action
    ref = adjust(read_problem(GAMA / KNIN))
    np.testing.assert_allclose(np.sort(a.r)[1:], np.sort(ref.r), atol=1e-9)
    out = tmp_path / "x8.json"
    assert main(["analyze", str(f), "--json", str(out), "--quiet"]) == 0
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    assert "X8" in [x["id"] for x in doc["summary"]["local_defects"]]
    assert main(["analyze", str(f), "--strict"]) == 2   # (refused at the heights already)
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {f}:") and err.count("\n") == 1


@pytest.mark.parametrize("attrs,words", [(' from_dh="1,5"', "not a number"),
                                         (' from_dh="inf"', "finite"),
                                         (' orientation="12-75-00"', "d-m-s"),
                                         (' station="Z"', "unknown attribute")])
def test_bad_obs_attributes_name_the_line(tmp_path, attrs, words):
    f = tmp_path / "bad.gkf"
    f.write_text(_gkf(attrs, _children(_obs_values(heights=True), False)))
    with pytest.raises(InputError) as err:
        read_gama(f)
    assert err.value.line == 9 and words in str(err.value)
