"""2-D GNU Gama networks observed with zenith angles (issue 26, item 2).

Points ``adj="xy"`` without heights, observed per set with directions, horizontal distances and
zenith angles: gama-local adjusts them from the directions and distances, its revision of the
observations making every observation that needs a missing height passive. baarda reads them
the same way and says what it set aside.

The peer: gama-local's own result for ../shared/extdata/gama/zoltan-test_2d_gon (its .xml),
the network here with three zenith angles added to every set — a network gama-local adjusts
as if they were not there, so its result is the reference (gama-local itself is not installed
here: no Debian package of GNU Gama in this image's sources).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.cli import main

from tests.extdata import GAMA, require_extdata
from tests.gama_result import read_gama_result

SOURCE = GAMA / "zoltan-test_2d_gon.gkf"


def with_zenith_angles(text: str, slope: bool = False) -> str:
    """The network with z-angles to the first three targets of every set (and a slope distance
    to the first when ``slope``)."""
    def add(m):
        block = m.group(0)
        targets = re.findall(r'<direction to= "([^"]+)"', block)
        z = "".join(f' <z-angle to= "{t}" val= "{100.0123 + 0.001 * k:.4f}" stdev="20" />\n'
                    for k, t in enumerate(targets[:3]))
        if slope and targets:
            z += f' <s-distance to= "{targets[0]}" val= "1000.0" stdev="5" />\n'
        return block.replace("</obs>", z + "</obs>")
    return re.sub(r"<obs from=.*?</obs>", add, text, flags=re.S)


def _coordinates(problem, adj):
    return {pid: adj.coordinates[i, :2] for i, pid in enumerate(problem.points.ids)}


def test_zenith_angles_of_a_2d_network_are_set_aside_as_gama_local_does(tmp_path):
    require_extdata(SOURCE)
    path = tmp_path / "z2d.gkf"
    path.write_text(with_zenith_angles(SOURCE.read_text()))
    problem = read_problem(path)
    note = problem.notes.reader_notes[0]
    assert note.startswith("98 zenith angles set aside, as gama-local does")
    adj = adjust(problem)
    ref = read_gama_result(SOURCE.with_suffix(".xml"))
    assert adj.converged and adj.dof == ref.dof
    got = _coordinates(problem, adj)
    diffs = [abs(got[pid][a] - ref.adjusted[pid][name]) for pid in ref.adjusted
             for a, name in enumerate("xy") if name in ref.adjusted[pid]]
    assert len(diffs) == 2 * 21 and max(diffs) < 1e-5
    # the same as the file without them, observation by observation
    plain = read_problem(SOURCE)
    base = adjust(plain)
    assert problem.n == plain.n
    np.testing.assert_allclose(adj.v, base.v, rtol=0, atol=1e-9)


def test_slope_distances_and_the_cli_warning(tmp_path, capsys):
    """A slope distance to a point without height is set aside too; ``baarda analyze`` prints
    one warning line saying what and where, and analyses the rest (exit 0 or 1)."""
    require_extdata(SOURCE)
    path = tmp_path / "z2d.gkf"
    path.write_text(with_zenith_angles(SOURCE.read_text(), slope=True))
    assert main(["analyze", str(path), "--top", "1"]) in (0, 1)
    err = capsys.readouterr().err
    warn = [s for s in err.splitlines() if s.startswith("baarda: warning:")]
    assert len(warn) == 1
    assert "98 zenith angles, 33 slope distances set aside, as gama-local does" in warn[0]
    assert "line(s) 56, 57, 58" in warn[0]


def test_heights_that_can_be_computed_keep_their_zenith_angles(tmp_path):
    """Points adjusted in z (adj="xyz") keep their zenith angles: only heights no point can
    have make an observation passive."""
    text = """<?xml version="1.0" ?>
<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">
<network>
<points-observations distance-stdev="5" direction-stdev="10" zenith-angle-stdev="10">
<point id="A" x="0" y="0" z="100" fix="xyz"/>
<point id="B" x="100" y="0" z="101" fix="xyz"/>
<point id="C" x="50" y="60" adj="xyz"/>
<point id="D" x="50" y="-60" adj="xy"/>
<obs from="A"> <direction to="B" val="0"/> <direction to="C" val="55.7"/> <direction to="D" val="344.3"/>
 <distance to="C" val="78.1"/> <distance to="D" val="78.1"/>
 <z-angle to="C" val="99.2"/> <z-angle to="D" val="99.9"/> </obs>
<obs from="B"> <direction to="A" val="0"/> <direction to="C" val="344.3"/> <direction to="D" val="55.7"/>
 <distance to="C" val="78.1"/> <distance to="D" val="78.1"/> <z-angle to="C" val="99.0"/> </obs>
</points-observations>
</network>
</gama-local>
"""
    path = tmp_path / "mixed.gkf"
    path.write_text(text)
    problem = read_problem(path)
    kinds = list(problem.info.kind)
    assert kinds.count("zenith-angle") == 2
    assert list(problem.notes.reader_notes) == ["1 zenith angle set aside, as gama-local does: they need heights that "
                                             "point(s) D do not have (no z, not adjusted in z); the network is "
                                             "adjusted from its other observations (line(s) 11)"]


@pytest.mark.parametrize("flag", [[], ["--drop-undefined"]])
def test_not_refused_any_more(tmp_path, capsys, flag):
    """What the issue saw: "point 501 has no z coordinate" (and with --drop-undefined "nothing to
    adjust"); now analysed."""
    require_extdata(SOURCE)
    path = tmp_path / "z2d.gkf"
    path.write_text(with_zenith_angles(SOURCE.read_text()))
    assert main(["analyze", str(path), "--quiet", *flag]) in (0, 1)
    assert "error" not in capsys.readouterr().err
