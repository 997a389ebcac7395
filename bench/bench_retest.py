"""Live retests on the dashboard's State without views (issue 29 item 1): median and largest
milliseconds of

- toggle: a 2D point-transfer hypothesis switched off and on;
- α0: 0.001 ↔ 0.01, and α0+tables: the same with the observations/points tables and the summary
  read afterwards (what the views read);
- exclude: one image coordinate excluded and re-included, until the exact adjustment is shown;
- exclude (first answer): the exclusion shown from the downdate of the factor
  (:meth:`State.downdate`), before the exact re-adjustment replaces it.

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_retest [--blocks demo aerial-1000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from baarda.dashboard.state import State
from bench.bench_dashboard import problem_for, transfer_spec


def timed(steps, repeat: int) -> tuple[float, float]:
    ts = []
    for _ in range(repeat):
        for step in steps:
            t0 = time.perf_counter()
            step()
            ts.append(time.perf_counter() - t0)
    return statistics.median(ts), max(ts)


def bench(name: str, repeat: int) -> list[tuple[str, float, float]]:
    st = State(problem=problem_for(name))
    k = st.add_hypothesis(transfer_spec(st))
    st.selected_hypothesis = k
    st.frames()
    r = np.where(np.char.startswith(np.asarray(st.problem.info.kind, dtype=str), "image"), st.expand(st.results.r), -1.0)
    i = int(np.nanargmax(r))

    def tables():
        st.frames()
        st.summary()

    rows = [("toggle", *timed([lambda: st.toggle_hypothesis(k, False), lambda: st.toggle_hypothesis(k, True)], repeat)),
            ("α0", *timed([lambda: setattr(st, "alpha0", 0.01), lambda: setattr(st, "alpha0", 0.001)], repeat)),
            ("α0+tables", *timed([lambda: (setattr(st, "alpha0", 0.01), tables()),
                                  lambda: (setattr(st, "alpha0", 0.001), tables())], repeat)),
            ("exclude", *timed([lambda: st.exclude(i), lambda: st.include(i)], max(1, repeat // 2)))]
    first = []
    for _ in range(max(1, repeat // 2)):
        t0 = time.perf_counter()
        st.downdate({i})
        first.append(time.perf_counter() - t0)
        st.refine({i})
        st.include(i)
    rows.append(("exclude (first answer)", statistics.median(first), max(first)))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blocks", nargs="+", default=["demo", "aerial-1000"])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"load average {os.getloadavg()[0]:.2f}, repeat {args.repeat}")
    for name in args.blocks:
        for action, med, most in bench(name, args.repeat):
            print(f"{name:<12} {action:<24} median {med * 1000:9.1f} ms   max {most * 1000:9.1f} ms", flush=True)


if __name__ == "__main__":
    main()
