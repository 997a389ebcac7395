"""The served app answers only the hosts it serves (DNS rebinding, issue 25 item 1) and serves the
network only when told to, with a token or saying it has none (item 8).

A server is started with ``baarda serve`` in a subprocess on 127.0.0.1; page and websocket
requests naming a foreign host (also with Origin = Host = that name, which Tornado does not send
through Bokeh's origin allowlist) are refused with 403; loopback requests work, a websocket
session included."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
GKF = REPO / "data" / "demo-levelling.gkf"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(url: str, host: str | None = None, timeout: float = 60):
    """(status, body, headers) of a GET, with an explicit Host header if given; redirects not followed."""
    class NoRedirect(urllib.request.HTTPRedirectHandler):
        def redirect_request(self, *a, **kw):
            return None
    req = urllib.request.Request(url, headers={"Host": host} if host else {})
    try:
        with urllib.request.build_opener(NoRedirect).open(req, timeout=timeout) as r:
            return r.status, r.read().decode("utf-8", "replace"), r.headers
    except urllib.error.HTTPError as err:
        return err.code, err.read().decode("utf-8", "replace"), err.headers


class Server:
    def __init__(self, *args, cwd):
        self.port = _free_port()
        env = dict(os.environ, DISPLAY="", BROWSER="false", OPENBLAS_NUM_THREADS="1")
        self.proc = subprocess.Popen([sys.executable, "-m", "baarda.cli", "serve", str(GKF), "--port",
                                      str(self.port), *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, start_new_session=True, env=env, cwd=cwd)
        self.first = self.proc.stdout.readline()
        self.url = f"http://127.0.0.1:{self.port}/"
        deadline = time.time() + 120
        while time.time() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=2):
                    return
            except OSError:
                assert self.proc.poll() is None, self.proc.stdout.read()
                time.sleep(0.3)
        raise RuntimeError("the server did not come up")

    def stop(self):
        os.killpg(self.proc.pid, signal.SIGTERM)
        self.proc.wait(timeout=30)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    s = Server(cwd=tmp_path_factory.mktemp("serve"))
    yield s
    s.stop()


async def _websocket(port: int, host: str, origin: str, token: str | None):
    """Open Bokeh's websocket with the given Host and Origin: the first message, or the error."""
    from tornado.httpclient import HTTPClientError, HTTPRequest
    from tornado.websocket import websocket_connect

    req = HTTPRequest(f"ws://127.0.0.1:{port}/ws", headers={"Host": host, "Origin": origin})
    try:
        conn = await websocket_connect(req, subprotocols=["bokeh", token] if token else ["bokeh"])
    except HTTPClientError as err:
        return err.code, ""
    try:
        msg = await asyncio.wait_for(conn.read_message(), 60)
    finally:
        conn.close()
    return 101, msg


def _token(page: str) -> str:
    m = re.search(r'"token":"([^"]+)"', page)
    assert m, "no session token in the page"
    return m.group(1)


def test_foreign_host_refused_loopback_served(served):
    port = served.port
    status, body, _ = _get(served.url)
    assert status == 200 and "baarda" in body
    status, body, _ = _get(served.url, host=f"localhost:{port}")
    assert status == 200
    for host in (f"evil.example:{port}", "evil.example", f"127.0.0.1.evil.example:{port}", f"localhost.evil:{port}"):
        status, body, headers = _get(served.url, host=host)
        assert status == 403, host
        assert body.startswith("baarda: refused: this server does not serve the host") and body.count("\n") == 1
        assert headers["Content-Type"].startswith("text/plain")
    # other paths too (static files, the websocket's autoload, anything)
    for path in ("static/js/bokeh.min.js", "ws", "liveness", "nothing"):
        assert _get(served.url + path, host=f"evil.example:{port}")[0] == 403, path


def test_websocket_with_foreign_host_and_same_origin_refused(served):
    port = served.port
    page = _get(served.url)[1]
    token = _token(page)
    # the rebinding attack: the page's own origin, under the attacker's name
    code, _ = asyncio.run(_websocket(port, f"evil.example:{port}", f"http://evil.example:{port}", token))
    assert code == 403
    # a loopback page's websocket gets its session
    code, msg = asyncio.run(_websocket(port, f"127.0.0.1:{port}", f"http://127.0.0.1:{port}", token))
    assert code == 101 and msg is not None


def test_allow_host_and_token(tmp_path):
    """--allow-host NAME serves NAME; --token asks every request to sign in first."""
    s = Server("--allow-host", "baarda.test", "--token", "s3cret-token", cwd=tmp_path)
    try:
        assert s.first.strip() == f"baarda dashboard: http://127.0.0.1:{s.port}/"
        status, _, headers = _get(s.url, host=f"baarda.test:{s.port}")
        assert status in (301, 302) and "login" in headers["Location"]        # served, after signing in
        assert _get(s.url, host=f"evil.example:{s.port}")[0] == 403
        status, _, headers = _get(s.url)
        assert status in (301, 302) and "login" in headers["Location"]
        # signing in with the token gives the page
        import http.cookiejar

        jar = http.cookiejar.CookieJar()
        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(jar))
        opener.open(s.url + "login", timeout=60).read()
        data = urllib.parse.urlencode({"username": "me", "password": "s3cret-token"}).encode()
        with opener.open(urllib.request.Request(s.url + "login", data=data), timeout=120) as r:
            assert r.status == 200 and "baarda" in r.read().decode("utf-8", "replace")
        bad = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
        data = urllib.parse.urlencode({"username": "me", "password": "wrong"}).encode()
        with bad.open(urllib.request.Request(s.url + "login", data=data), timeout=60) as r:
            assert "login" in r.geturl()                       # back to signing in
    finally:
        s.stop()


def test_network_address_needs_token_or_allow_remote(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "baarda.cli", "serve", str(GKF), "--address", "0.0.0.0",
                           "--port", str(_free_port())], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env=dict(os.environ, DISPLAY="", BROWSER="false"))
    assert proc.returncode == 2
    assert proc.stderr == ("baarda: error: --address 0.0.0.0 serves the dashboard to the network: give --token "
                           "TOKEN (a password to sign in with) or --allow-remote (no authentication)\n")
    assert proc.stdout == ""


def test_allow_remote_says_so(tmp_path):
    """Served to the network without authentication: a line says so. Run on this machine's own
    non-loopback address, where it has one."""
    try:
        other = socket.gethostbyname(socket.gethostname())
    except OSError:
        other = None
    if not other or other.startswith("127."):
        pytest.skip("no non-loopback address on this machine")
    port = _free_port()
    env = dict(os.environ, DISPLAY="", BROWSER="false", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "baarda.cli", "serve", str(GKF), "--address", other, "--port",
                             str(port), "--allow-remote"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env=env, cwd=tmp_path)
    try:
        assert proc.stdout.readline().strip() == f"baarda dashboard: http://{other}:{port}/"
        line = proc.stdout.readline()
        assert line.startswith(f"baarda dashboard: served to the network on {other}:{port} without authentication")
        deadline = time.time() + 120
        while time.time() < deadline:
            try:
                status = _get(f"http://{other}:{port}/", host=f"{other}:{port}")[0]
                break
            except OSError:
                time.sleep(0.3)
        assert status == 200                                  # an address as such: served
        assert _get(f"http://{other}:{port}/", host=f"evil.example:{port}")[0] == 403
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)


@pytest.mark.parametrize("host,remote,ok", [
    ("127.0.0.1:5006", False, True), ("localhost:5006", False, True), ("[::1]:5006", False, True),
    ("localhost", False, True), ("127.0.0.2:80", False, True), ("LOCALHOST:5006", False, True),
    ("evil.example:5006", False, False), ("10.0.0.5:5006", False, False), ("[fe80::1]:5006", False, False),
    ("10.0.0.5:5006", True, True), ("evil.example:5006", True, False), ("", False, False),
    ("local host", False, False), ("localhost:5006:1", False, False), ("proxy.lan:443", False, True),
])
def test_host_check(host, remote, ok):
    from baarda.dashboard.guard import HostCheck

    assert HostCheck(["Proxy.LAN"], remote=remote)(host) is ok


# --------------------------------------------------------------------------------------------
# limits the server keeps, whatever the page sends (issue 25 item 8)
# --------------------------------------------------------------------------------------------
def _rss_mb(pid: int) -> float:
    """Resident memory of the server process and its children (MB)."""
    total = 0.0
    pids = [pid] + [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    for p in pids:
        for line in Path(f"/proc/{p}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                total += int(line.split()[1]) / 1024
    return total


async def _send_raw(port: int, token: str, fragments):
    """Open a session's websocket, send ``fragments`` (str or bytes): ("closed", close code, None
    when the server dropped the connection without a close frame) or ("open", None)."""
    from tornado.httpclient import HTTPRequest
    from tornado.websocket import WebSocketClosedError, websocket_connect

    req = HTTPRequest(f"ws://127.0.0.1:{port}/ws", headers={"Origin": f"http://127.0.0.1:{port}"})
    conn = await websocket_connect(req, subprotocols=["bokeh", token], max_message_size=1 << 30)
    await asyncio.wait_for(conn.read_message(), 60)                  # the server's ACK
    try:
        for frag in fragments:
            await conn.write_message(frag, binary=isinstance(frag, bytes))
    except (WebSocketClosedError, OSError):
        pass
    deadline = time.time() + 60
    while time.time() < deadline:
        msg = await asyncio.wait_for(conn.read_message(), 60)
        if msg is None:
            return "closed", conn.close_code
    conn.close()
    return "open", None


def test_oversize_websocket_message_refused_while_streaming(served):
    """A 200 MB message (a page script sending a file around the upload widget) is refused from
    its frame header: the connection is closed and the server does not buffer it."""
    page = _get(served.url)[1]
    before = _rss_mb(served.proc.pid)
    state, code = asyncio.run(_send_raw(served.port, _token(page), [b"\0" * (200 << 20)]))
    assert state == "closed" and code in (1009, None)      # Tornado closes (1009) and drops the stream
    assert _rss_mb(served.proc.pid) - before < 100, (before, _rss_mb(served.proc.pid))
    assert _get(served.url)[0] == 200                      # the server serves on


def test_message_of_many_buffers_refused(served):
    """A Bokeh message announcing 40 buffers of 8 MB (each frame under the frame limit) is
    refused once its buffers pass 32 MB: Bokeh would hold them all before looking at it."""
    import json

    page = _get(served.url)[1]
    before = _rss_mb(served.proc.pid)
    head = json.dumps({"msgid": "x1", "msgtype": "PATCH-DOC", "num_buffers": 40})
    frags = [head, "{}", json.dumps({"events": []})]
    for k in range(40):
        frags += [json.dumps({"id": f"b{k}"}), b"\1" * (8 << 20)]
    state, code = asyncio.run(_send_raw(served.port, _token(page), frags))
    assert (state, code) == ("closed", 10001)
    assert _rss_mb(served.proc.pid) - before < 150, (before, _rss_mb(served.proc.pid))
    assert _get(served.url)[0] == 200
