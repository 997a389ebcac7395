"""Every real block in ../shared/extdata read as it is (compressed BAL included), adjusted to
convergence and analysed with exit status 0; the optimum against pycolmap's Ceres where the
extdata README gives it (independent program, same camera model)."""

from __future__ import annotations

import json

import pytest

from baarda.cli import main
from tests.extdata import EXTDATA, require_extdata

BAL = EXTDATA / "bal"
COLMAP = EXTDATA / "colmap"

# file, ½Σr² at Ceres's optimum (extdata README) or None where no common optimum is published
BLOCKS = [
    ("bal/Balbianello.out", None),
    ("bal/dubrovnik-3-7-pre.txt", None),          # intrinsics undetermined: held (local defect)
    ("bal/dubrovnik-3-7-18-pre.txt", None),
    ("bal/problem-49-7776-pre.txt", None),        # Ladybug: Ceres stops at its iteration limit
    ("bal/problem-21-11315-pre.txt.bz2", 30378.635796),
    ("bal/problem-16-22106-pre.txt.bz2", 18033.903479),
    ("colmap/test_colmap-sparse0", 3637.780514),  # pycolmap's Ceres with intrinsics fixed
]


@pytest.mark.slow
@pytest.mark.parametrize("name,optimum", BLOCKS, ids=[b[0].split("/")[-1] for b in BLOCKS])
def test_real_block_analyses_and_converges(name, optimum, tmp_path, capsys):
    path = require_extdata(EXTDATA / name)
    out = tmp_path / "r.json"
    code = main(["analyze", str(path), "--quiet", "--json", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    s = json.loads(out.read_text())["summary"]
    assert s["converged"] is True, s["termination"]
    if optimum is not None:
        assert abs(s["omega"] / 2 - optimum) / optimum < 1e-6, s["omega"] / 2


def test_every_real_block_is_listed():
    """A new real file in extdata must be added above (dubrovnik-1-1, one image point, is the one
    file with nothing to adjust: tests/io/test_readers.py checks its error)."""
    require_extdata(BAL)
    present = {f"bal/{p.name}" for p in BAL.iterdir() if p.name not in ("SHA256SUMS",)}
    present |= {f"colmap/{p.name}" for p in COLMAP.iterdir()}
    assert present - {b[0] for b in BLOCKS} == {"bal/dubrovnik-1-1-pre.txt"}
