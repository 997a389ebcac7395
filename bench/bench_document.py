"""Benchmark: the cost of the result document beside the analysis (issue 29, item 2).

For each file: the CPU seconds (user + system, steadier than wall-clock on a loaded machine) of
the analysis (read, adjust, reliability: ``analyze`` and the document's summary), then of
writing the JSON document from the tables' columns (:mod:`baarda.io.columns`, what ``baarda
analyze --json`` does) and record by record (the reference path, ``Records.fields`` off), each
as a share of the analysis, and whether the two files are the same bytes.

    python -m bench.bench_document [FILE ...]     (default: the BAL files of ../shared/extdata/bal)
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
from pathlib import Path

from baarda.analysis import analyze
from baarda.io import results

EXTDATA = Path(__file__).resolve().parents[2] / "shared" / "extdata" / "bal"
FILES = [EXTDATA / "problem-49-7776-pre.txt", EXTDATA / "problem-21-11315-pre.txt.bz2",
         EXTDATA / "problem-16-22106-pre.txt.bz2"]


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path, default=FILES)
    args = ap.parse_args()
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
          f"load average {os.getloadavg()[0]:.2f}", flush=True)
    head = f"{'file':<30} {'analysis s':>10} {'columns s':>9} {'share':>6} {'records s':>9} {'share':>6} {'MB':>6}  same"
    print(head)
    print("-" * len(head), flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        new, old = Path(tmp) / "columns.json", Path(tmp) / "records.json"
        for path in args.files:
            if not path.exists():
                print(f"{path.name:<30} skipped: not found", flush=True)
                continue
            t0 = cpu()
            a = analyze(path)
            doc = a.to_dict()
            _ = a.reliability.groups.R               # (the derived group arrays: part of the analysis)
            t1 = cpu()
            results.write_json(a.adjustment, new, doc)
            t2 = cpu()
            fields = results.Records.fields
            results.Records.fields = lambda self: None
            try:
                doc = a.to_dict()
                t3 = cpu()
                results.write_json(a.adjustment, old, doc)
                t4 = cpu()
            finally:
                results.Records.fields = fields
            same = new.read_bytes() == old.read_bytes()
            base = t1 - t0
            print(f"{path.name:<30} {base:>10.2f} {t2 - t1:>9.2f} {(t2 - t1) / base:>6.0%} {t4 - t3:>9.2f} "
                  f"{(t4 - t3) / base:>6.0%} {new.stat().st_size / 1e6:>6.1f}  {same}", flush=True)
            del a, doc


if __name__ == "__main__":
    main()
