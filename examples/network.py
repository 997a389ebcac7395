"""A levelling network: the precision of its heights in an S-base and a criterion matrix fitted
to it (M84 §2.2-2.3), and the JSON document written as the CLI writes it.

Run from the repository root:  .venv/bin/python examples/network.py [OUT.json]
"""

import sys
from pathlib import Path

import baarda
from baarda.io.results import dump_json

ROOT = Path(__file__).resolve().parents[1]

analysis = baarda.analyze(ROOT / "data" / "demo-levelling.gkf")
print(analysis)
points = analysis.records("points", frame=True)
print(points.head())

extras = baarda.Extras(snooping=True)
doc = analysis.to_dict(extras)                       # what `baarda analyze --snoop --json` writes
print(f"data snooping removed {len(doc['snooping'])} observation(s)")
if len(sys.argv) > 1:
    dump_json(doc, sys.argv[1])
    print(f"wrote {sys.argv[1]}")
