"""Time from a user action to updated plot data, server side (issue 4).

For each block every view of the dashboard is built as a Bokeh model (no browser: the maps,
the image-residual view, the hypothesis panel, the tests table, the sidebar, the summary and the
teaching plots, each in its own Bokeh document, as if every tab had been opened). Then each
action is timed until its callbacks have returned, i.e. until the Bokeh ColumnDataSources hold
the new data (median of repeats):

- toggle: a 2D point-transfer hypothesis (the selected one: its lower-bound ellipse and
  deformation field are drawn) switched off and on;
- α0: 0.001 ↔ 0.01 (new δ0, MDBs, δ̄0; the hypotheses retested);
- exclude: one image coordinate excluded and re-included (a new adjustment);
- select: a point selected on the map.

Columns: ``core`` is the same action on a state without views (the core's share), ``views``
the action with every view live, ``naive`` a full re-render of the views after the action
(new views, new Bokeh models: what rebuilding instead of updating in place would cost) and
``ratio`` = views / (core + naive).

The maps not on screen are not redrawn until shown (:meth:`MapView.set_shown`): by default the
first map tab is on screen and the other maps are hidden, as in the app; ``--all-shown`` times
every map on screen.

Blocks: the demo block (``data/demo-block.json``) and the 1,000-image aerial block of
``bench/bench_blocks.py`` (``aerial-1000``: 20 strips × 50 images, design mode, seed 1).

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_dashboard [--blocks demo aerial-1000] [--repeat 5]   # (from the repository root)
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import holoviews as hv
import numpy as np
import panel as pn
from bokeh.document import Document

from baarda.build import read_problem
from baarda.dashboard import geometry
from baarda.dashboard import views as V
from baarda.dashboard.state import State
from baarda.model.bundle import build_block_problem
from baarda.simulate import simulate_block
from bench.bench_blocks import AERIAL        # the recipe of the 1,000-image block

ROOT = Path(__file__).resolve().parent.parent


def problem_for(name: str):
    if name == "demo":
        return read_problem(ROOT / "data" / "demo-block.json")
    strips, per_strip = AERIAL[name]
    block, _ = simulate_block(strips=strips, images_per_strip=per_strip, design=True, seed=1)
    return build_block_problem(block)


def all_views(st: State) -> list:
    out = [cls(state=st) for cls in V.MAP_VIEWS]
    out += [V.ImageResidualView(state=st), V.HypothesisPanel(state=st), V.TestsTable(state=st),
            V.Controls(state=st), V.SelectionPanel(state=st), V.SummaryHeader(state=st),
            V.TeachingView(state=st)]
    return out


def render(views) -> list:
    return [pn.panel(v).get_root(Document()) for v in views]


def transfer_spec(st: State) -> dict:
    """A point-transfer hypothesis: the tie point seen in most images, its first three images."""
    by_point: dict = {}
    for ids in st.problem.info.ids:
        if "point" in ids and "image" in ids:
            by_point.setdefault(str(ids["point"]), set()).add(str(ids["image"]))
    pid = max(by_point, key=lambda p: (len(by_point[p]), p))
    return {"kind": "transfer", "point": pid, "images": sorted(by_point[pid])[:3]}


def actions(st: State) -> dict:
    """Per action a list of zero-argument steps (each timed on its own)."""
    k = st.add_hypothesis(transfer_spec(st))
    st.selected_hypothesis = k
    r = np.where(np.char.startswith(np.asarray(st.problem.info.kind, dtype=str), "image"),
                 st.expand(st.results.r), -1.0)
    i = int(np.nanargmax(r))
    _, pts = st.frames()
    a, b = int(np.argmax(pts["n_obs"])), int(np.argmin(pts["n_obs"]))
    return {
        "toggle": [lambda: st.toggle_hypothesis(k, False), lambda: st.toggle_hypothesis(k, True)],
        "α0": [lambda: setattr(st, "alpha0", 0.01), lambda: setattr(st, "alpha0", 0.001)],
        "exclude": [lambda: st.exclude(i), lambda: st.include(i)],
        "select": [lambda: setattr(st, "selected_point", a), lambda: setattr(st, "selected_point", b)],
    }


def timed(steps, repeat: int, after=None) -> tuple[float, float]:
    """Median seconds of the steps, and of ``after`` run after each step (if given)."""
    t_step, t_after = [], []
    for _ in range(repeat):
        for step in steps:
            t0 = time.perf_counter()
            step()
            t_step.append(time.perf_counter() - t0)
            if after is not None:
                t0 = time.perf_counter()
                after()
                t_after.append(time.perf_counter() - t0)
    return statistics.median(t_step), statistics.median(t_after) if t_after else float("nan")


def bench(name: str, repeat: int, all_shown: bool = False) -> list[dict]:
    t0 = time.perf_counter()
    problem = problem_for(name)
    t_build = time.perf_counter() - t0
    bare = State(problem=problem)
    live = State(problem=problem)
    t0 = time.perf_counter()
    views = all_views(live)
    render(views)
    if not all_shown:           # as the app: the first map tab on screen, the other maps hidden
        for v in views[1:len(V.MAP_VIEWS)]:
            v.set_shown(False)
    t_open = time.perf_counter() - t0
    n_img = len(geometry.images(live.problem))
    head = {"block": name, "images": n_img, "points": len(problem.points.ids), "n": problem.n,
            "build": t_build, "open": t_open}
    core_actions, live_actions = actions(bare), actions(live)
    rows = []
    for act in core_actions:
        reps = max(2, repeat // 2) if act == "exclude" else repeat
        core, _ = timed(core_actions[act], reps)
        naive_st = State(problem=problem)
        naive_steps = actions(naive_st)[act]
        _, naive = timed(naive_steps, max(1, reps // 2), after=lambda: render(all_views(naive_st)))
        views_t, _ = timed(live_actions[act], reps)
        rows.append({**head, "action": act, "core": core, "views": views_t, "naive": naive,
                     "ratio": views_t / (core + naive)})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blocks", nargs="+", default=["demo", "aerial-1000"])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--all-shown", action="store_true",
                    help="every map on screen (default: the first map tab shown, the others hidden, as in the app)")
    args = ap.parse_args(argv)
    pn.extension("tabulator")
    hv.extension("bokeh", logo=False)
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"load average {os.getloadavg()[0]:.2f}, repeat {args.repeat}")
    head = (f"{'block':<12} {'images':>6} {'points':>6} {'obs':>6} {'action':<8} {'core s':>7} "
            f"{'views s':>8} {'naive s':>8} {'ratio':>6}")
    print(head)
    print("-" * len(head))
    for name in args.blocks:
        for r in bench(name, args.repeat, args.all_shown):
            print(f"{r['block']:<12} {r['images']:>6} {r['points']:>6} {r['n']:>6} {r['action']:<8} "
                  f"{r['core']:>7.3f} {r['views']:>8.3f} {r['naive']:>8.3f} {r['ratio']:>6.2f}", flush=True)
        print(f"{'':<12} build {r['build']:.1f} s, all views opened in {r['open']:.1f} s", flush=True)
    print("core: the action on a state without views; views: with every view live (median, the data of "
          "the Bokeh sources updated); naive: every view built again after the action; "
          "ratio = views / (core + naive).")


if __name__ == "__main__":
    main()
