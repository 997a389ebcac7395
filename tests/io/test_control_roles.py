"""Check points in the control CSV (issue 28 item 4): a ``role`` column (control | check), unknown
columns refused with their name, check points never in the adjustment, their differences and
RMSE per axis in the text and the JSON document."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import baarda
from baarda.cli import main
from baarda.io.control import read_control

VALID = Path(__file__).resolve().parents[1] / "malformed" / "valid"
BAL = VALID / "bal-valid.txt"
CONTROL = (VALID / "control-valid.csv").read_text().splitlines()


def _write(tmp_path, text: str, name: str = "cp.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _with_checks(tmp_path, known) -> Path:
    """The valid control CSV with a role column and points 4 and 5 as check points at ``known``."""
    rows = [CONTROL[0] + ",role"] + [r + ",control" for r in CONTROL[1:]]
    for pid, xyz in zip(("4", "5"), known):
        rows.append(f"{pid},{float(xyz[0])!r},{float(xyz[1])!r},{float(xyz[2])!r},,,,check")
    return _write(tmp_path, "\n".join(rows) + "\n")


def test_role_column_is_read_and_check_sigmas_may_be_empty(tmp_path):
    cps = read_control(_with_checks(tmp_path, [(0.0, 1.0, 2.0), (3.0, 4.0, 5.0)]))
    assert [c.role for c in cps] == ["control"] * 4 + ["check"] * 2
    assert cps[4].xyz == (0.0, 1.0, 2.0) and np.isnan(cps[4].sigma).all()


def test_check_points_never_enter_the_adjustment(tmp_path):
    plain = baarda.analyze(BAL, control=VALID / "control-valid.csv")
    pts = plain.records("points")
    truth_xyz = np.column_stack([pts["x"], pts["y"], pts["z"]])
    known = [truth_xyz[4] + [0.01, -0.02, 0.03], truth_xyz[5] + [-0.01, 0.0, 0.05]]
    a = baarda.analyze(BAL, control=_with_checks(tmp_path, known))
    # the same observations and the same estimate as without the check rows
    assert a.adjustment.n == plain.adjustment.n
    assert not any(ids.get("id") in ("4", "5") for ids in a.problem.info.ids)
    np.testing.assert_allclose(a.adjustment.x, plain.adjustment.x, rtol=0, atol=1e-12)
    assert a.problem.points.status[4:6] == ("check", "check")
    rep = a.check_points()
    assert rep["n"] == 2
    # the difference is adjusted − known, the RMSE the root mean square per axis
    d = np.array([p["diff"] for p in rep["points"]])
    np.testing.assert_allclose(d, -np.array([[0.01, -0.02, 0.03], [-0.01, 0.0, 0.05]]), atol=1e-9)
    np.testing.assert_allclose(rep["rms"], np.sqrt((d ** 2).mean(axis=0)), rtol=1e-12)
    assert "check points (not in the adjustment): 2; RMSE X 0.01" in a.text()


def test_check_points_in_cli_text_and_json(tmp_path, capsys):
    a = baarda.analyze(BAL, control=VALID / "control-valid.csv")
    pts = a.records("points")
    xyz = np.column_stack([pts["x"], pts["y"], pts["z"]])
    csv = _with_checks(tmp_path, [xyz[4] + 0.1, xyz[5] - 0.1])
    out = tmp_path / "out.json"
    assert main(["analyze", str(BAL), "--control", str(csv), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "check points (not in the adjustment): 2; RMSE X 0.1, Y 0.1, Z 0.1" in text
    doc = json.loads(out.read_text())
    assert doc["check_points"]["n"] == 2
    np.testing.assert_allclose(doc["check_points"]["rms"], [0.1] * 3, rtol=1e-6)
    assert {p["id"] for p in doc["check_points"]["points"]} == {"4", "5"}


def test_only_check_points_leave_a_free_block(tmp_path):
    csv = _write(tmp_path, "id,X,Y,Z,sx,sy,sz,role\n4,0,0,0,,,,check\n")
    a = baarda.analyze(BAL, control=csv)
    assert a.problem.datum.kind == "free" and a.check_points()["n"] == 1


@pytest.mark.parametrize("text,line,needle", [
    ("id,X,Y,Z,sx,sy,sz,rol\n0,0,0,0,1,1,1,check\n", 1, "unknown column(s) 'rol'"),
    ("id,X,Y,Z,sx,sy,sz,name\n0,0,0,0,1,1,1,a\n", 1, "unknown column(s) 'name'"),
    ("id,X,Y,Z,sx,sy,sz,role\n0,0,0,0,1,1,1,control\n1,0,0,0,1,1,1,chek\n", 3, "role = 'chek' is not one of control, check"),
    ("id,X,Y,Z,sx,sy,sz,role\n0,0,0,0,,1,1,control\n", 2, "sx = '' is not a number"),
])
def test_bad_roles_and_columns_are_refused(tmp_path, capsys, text, line, needle):
    csv = _write(tmp_path, text)
    before = csv.read_bytes()
    assert main(["analyze", str(BAL), "--control", str(csv)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {csv}:{line}: ") and err.count("\n") == 1, err
    assert needle in err, err
    assert csv.read_bytes() == before


def test_check_role_on_a_native_block(tmp_path):
    from baarda.io.control import add_control
    from baarda.simulate import simulate_block
    blk, _ = simulate_block(seed=3)
    ctrl = [p for p in blk.points if p.status == "control"]
    tie = [p for p in blk.points if p.status == "tie"][0]
    rows = ["id,X,Y,Z,sx,sy,sz,role"] + [f"{p.id},{p.ref[0]},{p.ref[1]},{p.ref[2]},0.05,0.05,0.05,control"
                                          for p in ctrl]
    rows.append(f"{tie.id},{tie.X},{tie.Y},{tie.Z},,,,check")
    out = add_control(blk, _write(tmp_path, "\n".join(rows) + "\n"))
    p = {q.id: q for q in out.points}[tie.id]
    assert p.status == "check" and p.ref == (tie.X, tie.Y, tie.Z) and out.datum == "control"
