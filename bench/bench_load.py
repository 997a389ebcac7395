"""Many users on one dashboard server (issue 12): sessions opened at once, and a click in one
session while another runs data snooping.

A 1,000-image aerial block (20 strips × 50 images, seed 1, noisy, four planted image errors
and a point-transfer error, so that iterative snooping runs for some 20 iterations) is written with ``baarda simulate`` into a temporary directory and served with
``baarda serve`` on 127.0.0.1 (a free port, loopback only). Debian's Chromium (Playwright with
``executable_path=/usr/bin/chromium``) then

0. waits until the server has read and adjusted the file (it warms its cache at start: the
   users of a running server open a file it has analysed);
1. opens ``--sessions`` pages at once and times, for each, until its summary shows (the text
   of the global test's verdict; the server writes it into the page before any script: it
   shows at the page's first contentful paint if it was in the page by then, which the page
   marks, otherwise when Playwright sees it), until Bokeh has rendered the live summary pane, and until its maps are there;
2. starts iterative data snooping in one session and, while it runs, clicks rows of the tests
   table in another one and times each click until the selection panel shows the observation
   (and counts the server's event-loop stalls over 0.1 s meanwhile, ``BAARDA_TIMING``);
3. cancels the snooping and times until the session says it stopped;
4. requests the page ``--sessions`` times at once without a browser (the server's share).

``--busy criterion`` (issue 29: the load test) serves data/demo-block.json instead (the
1,000-image block has too many coordinates for a criterion matrix) and has the busy session fit
its criterion matrix again and again (its Criterion tab, "Fit C1, C2": the dense covariance in
the S-base and its eigenvalues, on a task thread of the session) while the other one clicks; ``--blas default`` serves without
``OPENBLAS_NUM_THREADS`` (OpenBLAS's own thread count; the server's threadpoolctl limit is what
then keeps one session's linear algebra from starving the others), ``--blas 1`` (the default)
with it set to 1. Both, for the table of the issue:

    python -m bench.bench_load --sessions 5 --busy criterion --blas 1
    python -m bench.bench_load --sessions 5 --busy criterion --blas default

Everything is bounded (``--timeout`` seconds in all); the server is stopped at the end.

    OPENBLAS_NUM_THREADS=1 python -m bench.bench_load [--sessions 20] [--clicks 5] [--timeout 600]
                                                      [--busy snooping|criterion] [--blas 1|default]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
DEMO = Path(__file__).resolve().parents[1] / "data" / "demo-block.json"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run",
        "--disable-renderer-backgrounding", "--disable-background-timer-throttling"]
SUMMARY_LIMIT = 15.0     # seconds: every session shows its summary within this
CLICK_LIMIT = 1.0        # seconds: a click answers within this while another session snoops


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_block(folder: Path) -> Path:
    from baarda.cli import main

    out = folder / "aerial-1000.json"
    # noisy, with planted errors: iterative snooping then runs for ~20 iterations (a design-mode block
    # has w = 0 everywhere and its snooping ends before the clicks are timed)
    assert main(["simulate", str(out), "--strips", "20", "--images", "50", "--seed", "1",
                 "--error", "image:20", "--error", "image:25", "--error", "image:30", "--error", "image:40",
                 "--error", "transfer:12:images=3", "--quiet"]) == 0
    return out


def start_server(path: Path, port: int, blas: str = "1") -> subprocess.Popen:
    env = dict(os.environ, DISPLAY="", BROWSER="false", OPENBLAS_NUM_THREADS="1", BAARDA_TIMING="1")
    if blas == "default":              # OpenBLAS's own thread count (nothing set for the server)
        env.pop("OPENBLAS_NUM_THREADS")
    log = open(path.with_suffix(".log"), "w")
    proc = subprocess.Popen([sys.executable, "-m", "baarda.cli", "serve", str(path), "--port", str(port),
                             "--address", "127.0.0.1"], stdout=subprocess.PIPE, stderr=log,
                            text=True, start_new_session=True, env=env)
    proc.stdout.readline()                 # "baarda dashboard: URL" once it is about to listen
    proc.started = time.perf_counter()
    deadline = time.time() + 60
    while time.time() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return proc
        time.sleep(0.2)
    raise RuntimeError("server did not come up")


def get_page(url) -> float:
    import urllib.request

    t = time.perf_counter()
    with urllib.request.urlopen(url, timeout=120) as r:
        r.read()
    return time.perf_counter() - t


async def open_session(context, url, t0, t0_wall, timeout_ms):
    page = await context.new_page()
    out = {"page": page, "created": time.perf_counter() - t0}
    await page.goto(url, timeout=timeout_ms)
    out["loaded"] = time.perf_counter() - t0
    await page.locator(".summary").get_by_text("Global test").first.wait_for(timeout=timeout_ms)
    out["seen"] = time.perf_counter() - t0
    await page.locator(".summary:not(.first-summary)").get_by_text("Global test").first.wait_for(timeout=timeout_ms)
    out["live"] = time.perf_counter() - t0
    # the browser's first contentful paint (header and summary come in the page's first bytes)
    fcp = await page.evaluate("(() => { const e = performance.getEntriesByName('first-contentful-paint')[0];"
                              " return e ? performance.timeOrigin + e.startTime : null; })()")
    # the summary was in the page before its first contentful paint (the server's page marks
    # it): the summary shows at that paint. Playwright sees it later, once the page's main
    # thread has parsed the scripts that follow it.
    mark = await page.evaluate("(() => { const m = performance.getEntriesByName('baarda-first-summary')[0];"
                               " const p = performance.getEntriesByName('first-contentful-paint')[0];"
                               " return m && p && m.startTime <= p.startTime; })()")
    out["paint"] = None if fcp is None else fcp / 1000 - t0_wall
    # when the browser sent the page's request and had its answer (a request that waits for
    # one of the browser's six connections to the host is sent late)
    nav = await page.evaluate("(() => { const n = performance.getEntriesByType('navigation')[0];"
                              " return n ? [performance.timeOrigin + n.requestStart,"
                              " performance.timeOrigin + n.responseEnd] : null; })()")
    out["sent"], out["answered"] = (None, None) if not nav else (nav[0] / 1000 - t0_wall, nav[1] / 1000 - t0_wall)
    out["summary"] = out["paint"] if mark and out["paint"] is not None else out["seen"]
    print(f"  summary after {out['summary']:.1f} s", file=sys.stderr, flush=True)
    # the maps and the right-hand panel's first tab (the ranked suspects) are drawn
    await page.locator(".suspects-table .tabulator-row").first.wait_for(timeout=timeout_ms)
    out["maps"] = time.perf_counter() - t0
    print(f"  maps after {out['maps']:.1f} s", file=sys.stderr, flush=True)
    return out


async def click_tab(page, title: str) -> None:
    """Make the tab ``title`` of the page's tab bars the active one."""
    await page.get_by_role("tab", name=title, exact=True).click()


def stat_row(label, values, fmt="{:.1f}"):
    v = sorted(values)
    if not v:
        return (label, "", "", "", "")
    return (label, fmt.format(v[0]), fmt.format(statistics.median(v)), fmt.format(v[-1]), "")


def server_rows(log: Path, t0_wall: float) -> list[tuple]:
    """Per session, the server's own timestamps (``BAARDA_TIMING``): request received, the
    page's websocket up (onload), summary set, maps built, relative to the start of the run;
    and how long each session's maps took to build on the event loop."""
    events: dict = {}
    for line in log.read_text(errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[0] == "baarda-timing":
            events.setdefault(parts[2], {}).setdefault(parts[3], float(parts[1]))
    out = []
    for ev, what in (("request", "request received"), ("onload", "page's websocket up (onload)"),
                     ("summary", "summary set"), ("build-start", "maps build started"),
                     ("maps", "maps built")):
        out.append(stat_row(f"  server: {what} (s)", [e[ev] - t0_wall for e in events.values() if ev in e]))
    out.append(stat_row("  server: maps build per session (s)",
                        [e["maps"] - e["build-start"] for e in events.values() if "maps" in e and "build-start" in e],
                        "{:.2f}"))
    return out


def stall_times(log: Path) -> list[tuple[float, float]]:
    """The server's event-loop stalls (``baarda-timing WALL - stall:SECONDS``, logged when the
    loop woke a timer late): (wall time logged, seconds)."""
    out = []
    for line in log.read_text(errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[0] == "baarda-timing" and parts[3].startswith("stall:"):
            out.append((float(parts[1]), float(parts[3][6:])))
    return out


def wait_ready(proc, timeout: float) -> float:
    """Seconds from the server's start until it has read and adjusted its file (the line
    ``baarda dashboard: FILE read and adjusted in S s``; the server warms its cache at start)."""
    import threading

    box = {}

    def read():
        for line in proc.stdout:           # Panel's own "Launching server at …" comes first
            box["line"] = line
            if line.startswith("baarda dashboard:"):
                return
    t = threading.Thread(target=read, daemon=True)
    t.start()
    t.join(timeout)
    line = box.get("line", "")
    if "read and adjusted" not in line:
        raise RuntimeError(f"server not ready: {line.strip()!r}")
    return time.perf_counter() - proc.started


async def run(args) -> int:
    from playwright.async_api import TimeoutError as PlaywrightTimeout
    from playwright.async_api import async_playwright

    folder = Path(tempfile.mkdtemp(prefix="baarda-bench-load-"))
    if args.busy == "criterion":       # the largest demo whose criterion applies (not the 1,000-image block)
        path = folder / DEMO.name
        path.write_bytes(DEMO.read_bytes())
    else:
        path = write_block(folder)
    port = free_port()
    url = f"http://127.0.0.1:{port}/"
    server = start_server(path, port, args.blas)
    ms = int(args.timeout * 1000)
    rows, ok = [], True
    try:
        ready = wait_ready(server, args.timeout)
        rows.append(("server start: its file read and adjusted, into the cache (s)", "", f"{ready:.1f}", "", ""))
        async with async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            context = await browser.new_context(viewport={"width": 1600, "height": 1000})
            t0, t0_wall = time.perf_counter(), time.time()
            sessions = await asyncio.wait_for(
                asyncio.gather(*(open_session(context, url, t0, t0_wall, ms) for _ in range(args.sessions))),
                timeout=args.timeout)
            summary = sorted(s["summary"] for s in sessions)
            maps = sorted(s["maps"] for s in sessions)
            rows.append((f"{args.sessions} sessions opened at once: summary shown (s)",
                         f"{summary[0]:.1f}", f"{statistics.median(summary):.1f}", f"{summary[-1]:.1f}",
                         f"≤ {SUMMARY_LIMIT:g}"))
            rows.append(("  … maps and suspects table shown (s)", f"{maps[0]:.1f}", f"{statistics.median(maps):.1f}",
                         f"{maps[-1]:.1f}", ""))
            rows.append(("  (sessions whose summary was in their first paint)", "",
                         str(sum(s["summary"] == s["paint"] for s in sessions)), "", ""))
            for key, what in (("created", "browser: page created"), ("sent", "browser: page's request sent"),
                              ("answered", "browser: page's answer received"),
                              ("paint", "browser: first contentful paint"),
                              ("seen", "browser: summary visible to Playwright"),
                              ("loaded", "browser: page's load event"),
                              ("live", "browser: Bokeh's summary pane rendered")):
                rows.append(stat_row(f"  {what} (s)", [s[key] for s in sessions if s[key] is not None]))
            rows.extend(server_rows(path.with_suffix(".log"), t0_wall))
            ok &= summary[-1] <= SUMMARY_LIMIT
            for s in sessions[2:]:
                await s["page"].close()

            busy, clicker = sessions[0]["page"], sessions[1]["page"]
            if args.busy == "criterion":
                print("  fitting the criterion matrix in one session", file=sys.stderr, flush=True)
                await click_tab(busy, "Criterion")
                fit_started = time.perf_counter()
                fit = busy.locator(".criterion-fit button").first
                await fit.click(timeout=ms)
                done = busy.get_by_text("Fitted", exact=False).first
                fits = {"clicks": 1, "stop": False}

                async def keep_fitting():
                    """The fit again and again while the other session clicks (one fit of a
                    demo takes under a second with one BLAS thread)."""
                    while not fits["stop"]:
                        await asyncio.sleep(0.3)
                        await fit.click(timeout=ms)
                        fits["clicks"] += 1
                fitting = asyncio.ensure_future(keep_fitting())
                what = "while the other fits the criterion matrix"
            else:
                print("  starting iterative data snooping in one session", file=sys.stderr, flush=True)
                await busy.get_by_text("Find errors", exact=True).first.click()
                await busy.get_by_role("button", name="Run iterative data snooping").click()
                task = busy.locator(".task-panel")
                await task.get_by_text("iterative data snooping").first.wait_for(timeout=ms)
                what = "while snooping runs"
            times = []
            print(f"  clicks in the tests table of another session {what}", file=sys.stderr, flush=True)
            await click_tab(clicker, "Tests table")
            table_rows = clicker.locator(".tests-table .tabulator-row")
            await table_rows.first.wait_for(timeout=ms)
            clicks_from = time.time()
            info = clicker.locator(".selection-info")
            for k in range(args.clicks):
                row = table_rows.nth(3 * k + 1)    # sorted by |w|: the row's index cell names it
                i = (await row.locator('[tabulator-field="index"]').inner_text()).strip().replace(",", "")
                start = time.perf_counter()
                await row.click()
                await info.get_by_text(f"Observation {i} ").first.wait_for(timeout=ms)
                times.append(time.perf_counter() - start)
            clicks_to = time.time()
            if args.busy == "criterion":
                fits["stop"] = True
                await fitting
                running = True
            else:
                running = await task.is_visible()
            ended = " [snooping ended]"
            rows.append((f"click in another session {what} (s){'' if running else ended}",
                         f"{min(times):.2f}", f"{statistics.median(times):.2f}", f"{max(times):.2f}",
                         f"≤ {CLICK_LIMIT:g}"))
            ok &= max(times) <= CLICK_LIMIT and running
            if args.busy == "criterion":
                await done.wait_for(timeout=ms)
                rows.append((f"criterion: {fits['clicks']} fits asked for, the first shown; all over after (s)", "",
                             f"{time.perf_counter() - fit_started:.1f}", "", ""))
            else:
                start = time.perf_counter()
                if await task.is_visible():
                    try:
                        await busy.locator(".task-cancel button").first.click(timeout=10_000)
                    except PlaywrightTimeout:    # the snooping ended meanwhile: its button is gone
                        pass
                    await task.wait_for(state="hidden", timeout=ms)
                stop = time.perf_counter() - start
                rows.append(("snooping cancelled: stopped after (s)", "", f"{stop:.1f}", "", ""))
            stalls = [d for w, d in stall_times(path.with_suffix(".log")) if clicks_from <= w <= clicks_to]
            rows.append(("  server: event-loop stalls > 0.1 s while clicking (count, longest s)", "",
                         str(len(stalls)), f"{max(stalls, default=0):.2f}", ""))
            await browser.close()
        # the server's share: the same number of page requests at once, without a browser
        gets = sorted(await asyncio.gather(*(asyncio.to_thread(get_page, url) for _ in range(args.sessions))))
        rows.append((f"server only: {args.sessions} page requests at once (s)", f"{gets[0]:.1f}",
                     f"{statistics.median(gets):.1f}", f"{gets[-1]:.1f}", ""))
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
        if args.keep:
            print(f"server log: {path.with_suffix('.log')}", file=sys.stderr)
        else:
            for f in folder.iterdir():
                f.unlink()
            folder.rmdir()
    width = max(len(r[0]) for r in rows)
    print(f"busy session: {args.busy}; server OPENBLAS_NUM_THREADS="
          f"{'1' if args.blas == '1' else 'unset'}; {args.sessions} sessions")
    print(f"{'':{width}}  {'min':>6} {'median':>6} {'max':>6}  limit")
    for r in rows:
        print(f"{r[0]:{width}}  {r[1]:>6} {r[2]:>6} {r[3]:>6}  {r[4]}")
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--clicks", type=int, default=5)
    ap.add_argument("--timeout", type=float, default=600.0, help="bound of the whole run (s)")
    ap.add_argument("--keep", action="store_true", help="keep the block and the server log")
    ap.add_argument("--busy", choices=["snooping", "criterion"], default="snooping",
                    help="what one session runs while another clicks (default snooping)")
    ap.add_argument("--blas", choices=["1", "default"], default="1",
                    help="OPENBLAS_NUM_THREADS of the server: 1 (default) or not set")
    args = ap.parse_args()
    return asyncio.run(run(args))


if __name__ == "__main__":
    sys.exit(main())
