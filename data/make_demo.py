"""Regenerate the demo files of this folder deterministically (see README.md).

    python data/make_demo.py            # writes next to this script

Everything is drawn from fixed seeds; the same numpy gives byte-identical files.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from baarda.io.native import write_native
from baarda.simulate import simulate_imodel, simulate_to_files

HERE = Path(__file__).resolve().parent

BLOCK_RECIPE = {
    "title": "demo: 3 × 8 aerial block, RC30 153 mm, 1:10 000, four planted errors",
    "strips": 3, "images_per_strip": 8, "camera": "aerial", "flying_height": 1530.0,
    "forward_overlap": 0.6, "side_overlap": 0.25, "pattern": [3, 3], "relief": 0.03,
    "control": "perimeter", "control_spacing": 2, "check": 2,
    "sigma_image": 0.005, "sigma_control_h": 0.05, "sigma_control_v": 0.05,
    "errors": [
        {"kind": "transfer", "size": 10, "images": 3},
        {"kind": "image", "size": 20},
        {"kind": "control", "size": 20, "axis": "z"},
        {"kind": "image-point", "size": 6},
    ],
    "seed": 2024,
}

LEVELLING_POINTS = ["A", "B", "C", "D", "E", "F", "G", "H"]
LEVELLING_LINES = [("A", "B"), ("B", "C"), ("C", "D"), ("D", "E"), ("E", "F"), ("F", "G"), ("G", "H"),
                   ("H", "A"), ("A", "E"), ("B", "G"), ("C", "F"), ("D", "H")]


def make_block():
    return simulate_to_files(BLOCK_RECIPE, HERE / "demo-block.json", HERE / "demo-block.truth.json")


def make_imodel():
    blk, truth = simulate_imodel(strips=2, models_per_strip=5, errors=[{"kind": "model-point", "size": 25}],
                                 seed=7, title="demo: independent-model block 2 × 5 (PAT-M), one planted error")
    write_native(blk, HERE / "demo-imodel.json")
    (HERE / "demo-imodel.truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return blk, truth


def make_levelling():
    """A levelling network in GNU Gama's XML: 8 benchmarks, A fixed, 12 lines (a ring with
    four diagonals). σ = 1 mm/√km · √dist; a 6 mm blunder on line C → D (recorded in the file
    description)."""
    rng = np.random.default_rng(11)
    H = dict(zip(LEVELLING_POINTS, 100.0 + np.round(rng.uniform(-5, 15, len(LEVELLING_POINTS)), 4)))
    H["A"] = 100.0
    xy = {p: (np.cos(2 * np.pi * k / 8) * 2.0, np.sin(2 * np.pi * k / 8) * 2.0)
          for k, p in enumerate(LEVELLING_POINTS)}
    lines = []
    for a, b in LEVELLING_LINES:
        dist = float(np.hypot(xy[a][0] - xy[b][0], xy[a][1] - xy[b][1]))      # km
        sigma = 1.0 * np.sqrt(dist)                                           # mm
        dh = H[b] - H[a] + rng.normal(0, sigma) / 1000
        if (a, b) == ("C", "D"):
            dh += 0.006
        lines.append(f'<dh from="{a}" to="{b}" val="{dh:.5f}" stdev="{sigma:.2f}" />')
    pts = [f'<point id="A" z="{H["A"]:.4f}" fix="z" />']
    pts += [f'<point id="{p}" z="{H[p] + rng.normal(0, 0.05):.3f}" adj="z" />' for p in LEVELLING_POINTS[1:]]
    text = "\n".join([
        '<?xml version="1.0" ?>',
        '<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">',
        '<network angles="left-handed" axes-xy="ne">',
        "<description>",
        "demo: levelling network, 8 benchmarks, A fixed, 12 height differences (ring + diagonals);",
        "sigma 1 mm per sqrt(km); planted blunder of 6 mm on the line C - D (baarda data/make_demo.py)",
        "</description>",
        '<parameters sigma-apr="1" conf-pr="0.95" tol-abs="1000" sigma-act="apriori" />',
        "<points-observations>",
        *pts,
        "<height-differences>",
        *lines,
        "</height-differences>",
        "</points-observations>",
        "</network>",
        "</gama-local>",
        ""])
    (HERE / "demo-levelling.gkf").write_text(text)


if __name__ == "__main__":
    make_block()
    make_imodel()
    make_levelling()
    for f in sorted(HERE.glob("demo-*")):
        print(f"{f.name:28s} {f.stat().st_size:8d} bytes")
