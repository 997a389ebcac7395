"""A real COLMAP model with GNSS centres in a CSV (issue 28, "What it must show"): read, converted
to a native block, georeferenced, adjusted, with GNSS tests. The GNSS positions are the model's
own centres moved by a known similarity (scale 37) with σ 5 cm noise and a 1 m error at one
image, named by file name: the similarity is recovered, the bad centre left out of the fit, and
its x component is the largest |w| among the GNSS observations and rejected."""

from __future__ import annotations

import numpy as np
import pytest

import baarda
from baarda.io import read_model
from baarda.io.gnss import GnssOptions
from baarda.model.sfm import to_block
from baarda.observations.rotation import R_opk
from tests.extdata import EXTDATA, require_extdata

MODEL = EXTDATA / "colmap" / "test_colmap-sparse0"


@pytest.mark.slow
def test_real_colmap_model_georeferenced_and_tested(tmp_path):
    require_extdata(MODEL)
    blk = to_block(read_model(MODEL))
    names = blk.extra["image_names"]
    C = np.array([[im.X0, im.Y0, im.Z0] for im in blk.images])
    G = 37.0 * C @ R_opk(0.2, -0.4, 1.0).T + [5000.0, 2000.0, 300.0]
    G += np.random.default_rng(0).normal(0, 0.05, G.shape)
    bad = blk.images[3].id
    G[3, 0] += 1.0
    rows = ["image,x,y,z,sx,sy,sz"] + [f"{names[im.id]},{float(G[k, 0])!r},{float(G[k, 1])!r},{float(G[k, 2])!r},"
                                       f"0.05,0.05,0.05" for k, im in enumerate(blk.images)]
    csv = tmp_path / "gnss.csv"
    csv.write_text("\n".join(rows) + "\n")
    a = baarda.analyze(MODEL, gnss=GnssOptions(csv, georeference=True))
    geo = a.to_dict()["georeference"]
    assert geo["scale"] == pytest.approx(37.0, rel=1e-3) and geo["left_out"] == [bad]
    assert a.summary()["datum"] == f"GNSS projection centres ({len(blk.images)}), no control points"
    adj, problem = a.adjustment, a.adjustment.problem
    g = np.array([i for i, k in enumerate(problem.info.kind) if k.startswith("gnss-")])
    worst = g[np.argmax(np.abs(adj.w[g]))]
    assert problem.info.ids[worst] == {"image": bad, "component": "x"} and a.reliability.rejected[worst]
