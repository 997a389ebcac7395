"""``baarda batch`` on Dask (issue 30): a real ``dask scheduler`` with two ``dask worker``
processes on 127.0.0.1, and the default local cluster, each on a mixed set of blocks (demo
files, a Gama network and a BAL problem of ../shared/extdata, a malformed file, a file that does
not converge); every row and every block's JSON compared with the serial ``baarda analyze
--json`` of the file, bit for bit (but the timings); a worker killed in the middle of a batch.
The processes started here are bounded by timeouts and stopped by the test."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.extdata import EXTDATA, require_extdata

distributed = pytest.importorskip("distributed", reason="the batch extra (dask[distributed]) is not installed")

from baarda import batch, cli  # noqa: E402
from baarda.errors import UsageError  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
MALFORMED = ROOT / "tests" / "malformed" / "bal-garbage.txt"
NUMBERS = [c for c in batch.COLUMNS if c not in ("file", "format", "status", "error", "json", "time_s",
                                                  "peak_memory_mb")]


def wait_for(condition, timeout: float, what: str, every: float = 0.05):
    """Poll ``condition`` until it is truthy (its value returned); fail after ``timeout`` s."""
    end = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > end:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(every)


@pytest.fixture(scope="module")
def blocks(tmp_path_factory):
    """The mixed set: (path, kind) with kind ok, error (malformed) or not-converged."""
    require_extdata()
    d = tmp_path_factory.mktemp("blocks")
    benning = EXTDATA / "gama" / "krumm" / "2D" / "Benning82_Distance_fix.gkf"
    nonconv = d / "inconsistent.gkf"           # a distance of 50 km in a 1 km square: Gauss-Newton never settles
    nonconv.write_text(benning.read_text().replace('val="1000.02"', 'val="50000"'))
    return [(ROOT / "data" / "demo-levelling.gkf", "ok"), (ROOT / "data" / "demo-imodel.json", "ok"),
            (ROOT / "data" / "demo-block.json", "ok"), (benning, "ok"), (EXTDATA / "gama" / "cube-1.gkf", "ok"),
            (EXTDATA / "bal" / "dubrovnik-3-7-pre.txt", "ok"), (MALFORMED, "error"),
            (nonconv, "not-converged")]


@pytest.fixture(scope="module")
def serial(blocks, tmp_path_factory):
    """The serial ``baarda analyze --json`` of each file: {path: (exit status, document or None, stderr)}."""
    d = tmp_path_factory.mktemp("serial")
    out = {}
    for k, (path, _) in enumerate(blocks):
        js = d / f"{k}.json"
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = cli.main(["analyze", str(path), "--json", str(js), "--quiet"])
        out[str(path)] = (code, json.loads(js.read_text()) if js.exists() else None, err.getvalue())
    return out


def start(args, log: Path, env=None):
    return subprocess.Popen([str(BIN / "dask"), *map(str, args)], stdout=log.open("wb"), stderr=subprocess.STDOUT,
                            env=env, start_new_session=True)


def stop(procs):
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` (one thread each) on 127.0.0.1: its address.
    allowed-failures 1, as README's "Batches" sets it: a task that kills two workers is reported."""
    d = tmp_path_factory.mktemp("dask")
    sfile = d / "scheduler.json"
    env = {**os.environ, "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1",
           "PYTHONPATH": str(ROOT)}            # (the test's own task, `crashing`, imported by name there)
    procs = []
    try:
        procs.append(start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                            "--scheduler-file", sfile], d / "scheduler.log", env))

        def address():
            try:
                return json.loads(sfile.read_text())["address"]
            except (OSError, ValueError, KeyError):
                return None
        addr = wait_for(address, 60, "the scheduler's address")
        for i in range(2):
            procs.append(start(["worker", addr, "--nthreads", "1", "--nworkers", "1", "--host", "127.0.0.1",
                                "--no-dashboard", "--memory-limit", "2GB", "--name", f"w{i}"], d / f"worker{i}.log", env))
        with distributed.Client(addr, timeout="30s") as client:
            client.wait_for_workers(2, timeout=120)
        yield addr, d
    finally:
        stop(procs)


def read_rows(out: Path) -> dict:
    with (out / "summary.csv").open(newline="", encoding="utf-8") as fh:
        return {r["file"]: r for r in csv.DictReader(fh)}


def as_csv(v) -> str:
    return "" if v is None else repr(v) if isinstance(v, float) else str(v)


def without_timings(doc):
    doc = json.loads(json.dumps(doc))
    doc["summary"].pop("timings", None)
    return doc


def check_against_serial(out: Path, blocks, serial, same_source=True):
    """Every row of summary.csv and every block's JSON equal the serial run's (``same_source``
    False: but the source named in the summary, for a copy of the file)."""
    rows = read_rows(out)
    assert list(rows) == [str(p) for p, _ in blocks]           # one row per input file, in order
    for path, kind in blocks:
        row, (code, doc, err) = rows[str(path)], serial[str(path)]
        assert row["status"] == kind, (path, row)
        if kind == "error":
            assert code == 2 and err.strip() == f"baarda: error: {row['error']}"
            assert row["json"] == "" and all(row[c] == "" for c in NUMBERS)
            continue
        assert code == (0 if kind == "ok" else cli.NOT_CONVERGED)
        assert (row["error"] == "") == (kind == "ok")
        expected = batch.summary_row(doc)
        for c in expected:                                      # the numbers bit for bit (repr round trip)
            assert row[c] == as_csv(expected[c]), (path, c, row[c], expected[c])
        mine, theirs = without_timings(json.loads((out / row["json"]).read_text())), without_timings(doc)
        if not same_source and str(path) != theirs["summary"]["source"]:
            mine["summary"].pop("source"), theirs["summary"].pop("source")
        assert mine == theirs
        assert float(row["time_s"]) > 0 and float(row["peak_memory_mb"]) > 10
    html = (out / "index.html").read_text()
    assert f"{sum(k == 'ok' for _, k in blocks)} of {len(blocks)} blocks" in html


def run_cli(args, timeout=240):
    return subprocess.run([str(BIN / "baarda"), "batch", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_batch_on_a_dask_scheduler_equals_the_serial_runs(blocks, serial, scheduler, tmp_path):
    scheduler, _ = scheduler
    out = tmp_path / "out"
    res = run_cli([*(p for p, _ in blocks), "--out", out, "--scheduler", scheduler])
    assert res.returncode == 1, res.stderr                     # not every file worked
    assert "Traceback" not in res.stderr and "on 2 worker(s)" in res.stderr
    check_against_serial(out, blocks, serial)
    pq = pytest.importorskip("pyarrow.parquet")
    table = pq.read_table(out / "summary.parquet").to_pylist()
    assert [r["file"] for r in table] == [str(p) for p, _ in blocks]
    assert [r["omega"] for r in table] == [serial[str(p)][1] and serial[str(p)][1]["summary"]["omega"]
                                           for p, _ in blocks]


def test_batch_on_the_local_cluster_equals_the_serial_runs_and_a_rerun_skips_them(blocks, serial, tmp_path):
    out = tmp_path / "out"
    res = run_cli([*(p for p, _ in blocks), "--out", out, "--workers", "2"])
    assert res.returncode == 1, res.stderr
    assert "dashboard http://127.0.0.1:" in res.stderr and "Traceback" not in res.stderr
    check_against_serial(out, blocks, serial)
    before = (out / "summary.csv").read_text()
    err = io.StringIO()                                         # every block done: no cluster, same summary
    code, _ = batch.run_batch([p for p, _ in blocks], out, batch.options_of(cli.build_parser().parse_args(
        ["batch", "x"])), stream=err)
    assert code == 1 and "nothing to analyse" in err.getvalue()
    assert (out / "summary.csv").read_text() == before


def held(path, options):
    """The batch's task; for a file named held-*, first wait until a file ``go`` beside it exists
    (so that the test kills the worker while it holds that block)."""
    if Path(path).name.startswith("held-"):
        go = Path(path).with_name("go")
        end = time.monotonic() + 120
        while not go.exists() and time.monotonic() < end:
            time.sleep(0.05)
    return batch.analyze_block(path, options)


def test_a_worker_killed_mid_batch_and_the_batch_completes(blocks, serial, scheduler, tmp_path):
    """SIGKILL to the worker process that holds a block: the nanny starts a new one, the
    scheduler gives the block to a worker again (allowed-failures 1), every file works."""
    import threading
    scheduler, logs = scheduler
    good = [(p, k) for p, k in blocks if k == "ok"]
    level = ROOT / "data" / "demo-levelling.gkf"
    held_file = tmp_path / "held-levelling.gkf"
    held_file.write_text(level.read_text())
    killed = {}

    def kill_the_holder():
        with distributed.Client(scheduler, timeout="30s") as client:
            def holder():
                return next((w for w, keys in client.processing().items()
                             if any("held-levelling" in str(k) for k in keys)), None)
            end = time.monotonic() + 120
            while (victim := holder()) is None and time.monotonic() < end:
                time.sleep(0.05)
            killed["key"] = next(k for k in client.processing()[victim] if "held-levelling" in str(k))
            killed["pid"] = client.run(os.getpid, workers=[victim])[victim]
            os.kill(killed["pid"], signal.SIGKILL)
            (tmp_path / "go").write_text("")
            end = time.monotonic() + 120
            while client.processing().get(victim) and time.monotonic() < end:
                time.sleep(0.05)
    killer = threading.Thread(target=kill_the_holder)
    killer.start()
    options = batch.options_of(cli.build_parser().parse_args(["batch", "x"]))
    code, rows = batch.run_batch([held_file, *(p for p, _ in good)], tmp_path / "out", options, scheduler=scheduler,
                                 quiet=True, task=held)
    killer.join(timeout=150)
    assert code == 0, rows
    check_against_serial_rows = {r["file"]: r for r in rows}
    again = check_against_serial_rows.pop(str(held_file))
    expected = batch.summary_row(serial[str(level)][1])
    assert {c: again[c] for c in expected} == expected            # the held block, analysed on its second worker
    check_against_serial(tmp_path / "out", [(held_file, "ok"), *good], {**serial, str(held_file): serial[str(level)]},
                         same_source=False)
    with distributed.Client(scheduler, timeout="30s") as client:
        story = client.story(killed["key"])
        to_processing = sum(1 for t in story if killed["key"] in t and t[t.index(killed["key"]) + 2] == "processing")
        assert to_processing >= 2, story
        client.wait_for_workers(2, timeout=120)                    # the nanny started a new worker
    assert any(f"Worker process {killed['pid']} was killed by signal 9" in log.read_text()
               for log in logs.glob("worker*.log"))


def crashing(path, options):
    """A task that kills its worker process for a file named crash*; else the batch's own."""
    if Path(path).name.startswith("crash"):
        os._exit(3)
    return batch.analyze_block(path, options)


def test_ctrl_c_keeps_what_is_done_and_a_rerun_does_the_rest(blocks, serial, scheduler, tmp_path, monkeypatch):
    scheduler, _ = scheduler
    good = [(p, k) for p, k in blocks if k == "ok"][:3]
    out = tmp_path / "out"
    save = batch._save

    def save_then_interrupt(*a, **kw):
        row = save(*a, **kw)
        raise KeyboardInterrupt
    monkeypatch.setattr(batch, "_save", save_then_interrupt)
    options = batch.options_of(cli.build_parser().parse_args(["batch", "x"]))
    with pytest.raises(KeyboardInterrupt):
        batch.run_batch([p for p, _ in good], out, options, scheduler=scheduler, quiet=True)
    rows = read_rows(out)
    assert sorted(r["status"] for r in rows.values()) == ["interrupted", "interrupted", "ok"]
    monkeypatch.setattr(batch, "_save", save)
    err = io.StringIO()
    code, _ = batch.run_batch([p for p, _ in good], out, options, scheduler=scheduler, stream=err)
    assert code == 0 and "2 block(s) to analyse (1 done before)" in err.getvalue()
    check_against_serial(out, good, serial)


def test_a_block_that_kills_two_workers_is_a_row(scheduler, tmp_path):
    """allowed-failures 1: the block is given to a second worker once, then reported."""
    scheduler, _ = scheduler
    crash = tmp_path / "crash.gkf"
    crash.write_text((ROOT / "data" / "demo-levelling.gkf").read_text())
    options = batch.options_of(cli.build_parser().parse_args(["batch", "x"]))
    code, rows = batch.run_batch([crash, ROOT / "data" / "demo-levelling.gkf"], tmp_path / "out", options,
                                 scheduler=scheduler, quiet=True, task=crashing)
    assert code == 1
    assert rows[0]["status"] == "killed" and "killed its worker twice" in rows[0]["error"]
    assert rows[1]["status"] == "ok" and rows[1]["error"] == ""
    with distributed.Client(scheduler, timeout="30s") as client:    # the nannies start new workers
        client.wait_for_workers(2, timeout=120)


def test_inputs_files_globs_and_folders(tmp_path):
    for name in ("a.gkf", "b.json", "b.truth.json", "c.txt.bz2", "notes.md"):
        (tmp_path / name).write_text("x")
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "cameras.txt").write_text("x")
    got = batch.expand([tmp_path, str(tmp_path / "*.gkf"), tmp_path / "b.json"])
    assert [Path(p).name for p in got] == ["a.gkf", "b.json", "c.txt.bz2", "model"]   # each once, in order
    with pytest.raises(UsageError, match="nothing matches"):
        batch.expand([str(tmp_path / "*.xyz")])
    assert batch.block_name("x/problem.txt") != batch.block_name("y/problem.txt")


def test_overview_and_summary_are_text_never_markup(tmp_path):
    evil = '<script>alert(1)</script>\x1b[31m.gkf'
    rows = [batch._fault_row(evil, "error", f"{evil}:1: =HYPERLINK(\"x\") bad <b>")]
    rows[0]["json"] = 'blocks/"><img src=x>.json'
    batch.write_summary(tmp_path, rows)
    page = (tmp_path / "index.html").read_text()
    assert "<script>" not in page and "<b>" not in page and "<img" not in page and "\x1b" not in page
    assert "&lt;script&gt;" in page
    text = (tmp_path / "summary.csv").read_text()
    assert "\x1b" not in text and "'=HYPERLINK" not in text       # the error starts with the file name
    cell = list(csv.DictReader(io.StringIO(text)))[0]
    assert cell["file"].startswith("<script>") and cell["status"] == "error"
