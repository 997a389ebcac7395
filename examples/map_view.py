"""The dashboard's maps of an analysis, as in a notebook (``analysis.view()``), saved here to a
standalone HTML file so that the script runs outside Jupyter too.

Run from the repository root:  .venv/bin/python examples/map_view.py [OUT.html]
"""

import sys
from pathlib import Path

import panel as pn

import baarda

ROOT = Path(__file__).resolve().parents[1]
out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("demo-maps.html")

pn.extension("tabulator")
analysis = baarda.analyze(ROOT / "data" / "demo-block.json")
view = analysis.view("maps")          # in Jupyter: just `analysis.view()` as the cell's last line
view.save(out, embed=False, resources="inline")
print(f"wrote {out}")
