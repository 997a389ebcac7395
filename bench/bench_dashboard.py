"""Time from a hypothesis toggle (and an α0 change) to updated plot data, server side.

For each available problem the layout map and the hypothesis panel are built as Bokeh models
(no browser); then a hypothesis is switched off and on again and the time until the Bokeh
ColumnDataSources hold the new data is measured (median of repeats). Prints a table.

    python bench/bench_dashboard.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import holoviews as hv
import numpy as np
import panel as pn
from bokeh.document import Document

from baarda.dashboard.state import State
from baarda.dashboard.views import HypothesisPanel, LayoutMap, MDBMap

ROOT = Path(__file__).resolve().parents[1]
GAMA = ROOT.parent / "shared" / "extdata" / "gama"
CANDIDATES = [ROOT / "data" / "demo-block.json", *sorted((ROOT / "data").glob("*.gkf")),
              GAMA / "gama-local.gkf", GAMA / "krumm" / "1D" / "Niemeier_Height_free.gkf",
              GAMA / "tetrahedron.gkf", GAMA / "krumm" / "2D" / "Grossmann_Direction_fix.gkf"]


def hypothesis_for(st: State) -> dict:
    """A 2D hypothesis where the problem has one (image point, control point), else one observation."""
    p = st.problem
    kinds = set(p.info.kind)
    if any(k.startswith("image-") for k in kinds):
        i = int(np.nanargmax(st.results.r * np.char.startswith(np.asarray(p.info.kind, dtype=str), "image")))
        ids = p.info.ids[i]
        return {"kind": "image-point", "image": ids["image"], "point": ids["point"]}
    if (np.asarray(p.info.group) >= 0).any():
        return {"kind": "group", "group": int(np.max(p.info.group))}
    return {"kind": "observation", "index": int(np.nanargmax(np.abs(st.results.w)))}


def bench(path: Path, repeat: int) -> dict:
    st = State(path)
    if st.results is None:
        return {"problem": path.name, "error": st.error}
    views = [LayoutMap(state=st), HypothesisPanel(state=st), MDBMap(state=st)]
    for v in views:
        pn.panel(v).get_root(Document())
    k = st.add_hypothesis(hypothesis_for(st))
    st.selected_hypothesis = k
    toggle = []
    for _ in range(repeat):
        for active in (False, True):
            t0 = time.perf_counter()
            st.toggle_hypothesis(k, active)
            toggle.append(time.perf_counter() - t0)
    alpha = []
    for a in [0.01, 0.001] * ((repeat + 1) // 2):
        t0 = time.perf_counter()
        st.alpha0 = a
        alpha.append(time.perf_counter() - t0)
    h = st.hyp_results[k]
    return {"problem": path.name, "n": st.problem.n, "u": st.results.n_unknowns,
            "hypothesis": st.hypotheses[k]["kind"], "q": h.q,
            "test_ms": 1000 * st.timings.get("hypotheses", float("nan")),
            "toggle_ms": 1000 * statistics.median(toggle), "alpha_ms": 1000 * statistics.median(alpha)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)
    pn.extension("tabulator")
    hv.extension("bokeh", logo=False)
    rows = [bench(p, args.repeat) for p in CANDIDATES if p.exists()]
    print(f"{'problem':<34s} {'n':>6s} {'u':>5s} {'hypothesis':<13s} {'q':>2s} {'core test':>10s} "
          f"{'toggle→data':>12s} {'α0→data':>9s}")
    for r in rows:
        if "error" in r:
            print(f"{r['problem']:<34s} {r['error']}")
            continue
        print(f"{r['problem']:<34s} {r['n']:6d} {r['u']:5d} {r['hypothesis']:<13s} {r['q']:2d} "
              f"{r['test_ms']:8.1f}ms {r['toggle_ms']:10.1f}ms {r['alpha_ms']:7.1f}ms")
    print("toggle→data: hypothesis switched off/on until the layout map, hypothesis table and ellipse "
          "plot sources hold the new data (server side, median); α0→data: the same views after an α0 "
          "change (new δ0, MDBs, hypothesis retested).")


if __name__ == "__main__":
    main()
