"""baarda against Krumm's published adjustments (krumm/{1D,2D,3D}/*.adj, computed by a program
other than Gama): adjusted coordinates within 0.1 mm for the networks Gama also matches.

An .adj line is ``id x . . y . . [z . .] ...`` (2D/3D) or ``id H ...`` (1D); the columns after
each coordinate are Krumm's corrections and standard deviations, not compared here.
"""

from __future__ import annotations

import pytest

from baarda.adjust import adjust
from baarda.build import read_problem

from tests.extdata import EXTDATA, GAMA, require_extdata

KRUMM = EXTDATA / "krumm"
#: differences of model named in the extdata README (Gama differs from these by 1.3-60 mm too)
MODEL_DIFFERENCES = {"Krumm_Traverse1", "Krumm_Traverse2", "Krumm_Traverse3", "Krumm_Traverse4",
                     "BlankenbachWillert3D_Distance_fix"}


def _cases():
    if not KRUMM.exists():
        return []
    out = []
    for adj in sorted(KRUMM.glob("*/*.adj")):
        gkf = GAMA / "krumm" / adj.parent.name / (adj.stem + ".gkf")
        if gkf.exists() and adj.stem not in MODEL_DIFFERENCES:
            out.append((adj, gkf))
    return out


def read_adj(path, dim):
    coords = {}
    for line in path.read_text(errors="replace").splitlines():
        parts = line.replace("\u2212", "-").split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            nums = [float(t) for t in parts[1:]]
        except ValueError:
            continue
        if dim == "1D":
            coords[parts[0]] = {"z": nums[0]}
        elif dim == "2D" and len(nums) >= 4:
            coords[parts[0]] = {"x": nums[0], "y": nums[3]}
        elif dim == "3D" and len(nums) >= 7:
            coords[parts[0]] = {"x": nums[0], "y": nums[3], "z": nums[6]}
    return coords


CASES = _cases()


def test_krumm_present():
    require_extdata(KRUMM)
    assert len(CASES) >= 25


@pytest.mark.parametrize("adj_path,gkf", CASES, ids=[c[0].stem for c in CASES])
def test_krumm_coordinates(adj_path, gkf):
    ref = read_adj(adj_path, adj_path.parent.name)
    problem = read_problem(gkf)
    result = adjust(problem)
    compared = []
    for i, pid in enumerate(problem.points.ids):
        if pid not in ref or problem.points.status[i] == "fixed":
            continue
        for a, name in enumerate("xyz"):
            if name in ref[pid] and problem.points.index[i, a] >= 0:
                compared.append(abs(result.coordinates[i, a] - ref[pid][name]))
    assert compared, "no coordinates compared"
    # Krumm prints 4 decimals (0.05 mm rounding) → 0.1 mm
    assert max(compared) <= 1.0e-4 + 1e-9, f"max difference {max(compared) * 1e3:.3f} mm"
