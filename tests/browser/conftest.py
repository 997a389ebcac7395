"""Browser tests of the served dashboard with Debian's Chromium (../shared/PANEL_NOTES.md).

The app runs in this process (``pn.serve(..., threaded=True)``) on 127.0.0.1 and a free port;
the fixture keeps every session's template so tests can compare the page with the state, and
stops all servers at teardown. Without /usr/bin/chromium or playwright the tests skip, unless
``BAARDA_REQUIRE_BROWSER=1`` (then they fail).
"""

from __future__ import annotations

import os
import shutil
import socket
import time
import urllib.request
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
ROOT = Path(__file__).resolve().parents[2]
SCREENSHOTS = ROOT / "screenshots"


def _missing() -> str | None:
    if not Path(CHROMIUM).exists() and not shutil.which("chromium"):
        return f"{CHROMIUM} not installed"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright not installed"
    return None


def pytest_collection_modifyitems(config, items):
    reason = _missing()
    if reason is None or os.environ.get("BAARDA_REQUIRE_BROWSER") == "1":
        return
    for item in items:
        if "browser" in item.keywords:
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture(autouse=True)
def _require_browser(request):
    reason = _missing()
    if reason and "browser" in request.keywords:
        pytest.fail(f"browser tests required (BAARDA_REQUIRE_BROWSER=1) but {reason}")


@pytest.fixture(scope="session")
def browser_type_launch_args(browser_type_launch_args):
    return {**browser_type_launch_args, "executable_path": CHROMIUM,
            "args": ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--no-first-run"]}


@pytest.fixture(scope="session")
def browser_context_args(browser_context_args):
    return {**browser_context_args, "viewport": {"width": 1600, "height": 1000}}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """A running dashboard: ``url`` and the templates of its sessions (``latest().state``)."""

    def __init__(self, factory):
        import panel as pn

        self.templates = []
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}/"

        def app():
            tpl = factory()
            self.templates.append(tpl)
            return tpl

        self.server = pn.serve({"/": app}, port=self.port, address="127.0.0.1", show=False, threaded=True,
                               websocket_origin=[f"127.0.0.1:{self.port}"], liveness=True)
        deadline = time.time() + 30
        while time.time() < deadline:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{self.port}/liveness", timeout=2)
                return
            except OSError:
                time.sleep(0.2)
        raise RuntimeError("dashboard server did not come up")

    def latest(self):
        return self.templates[-1]


@pytest.fixture(scope="session")
def serve_app():
    import panel as pn

    started = []

    def start(factory) -> Served:
        s = Served(factory)
        started.append(s)
        return s

    yield start
    pn.state.kill_all_servers()


@pytest.fixture(scope="session")
def network_app(serve_app):
    from tests.extdata import GAMA

    from baarda.dashboard.app import create_app

    path = GAMA / "gama-local.gkf"
    if not path.exists():
        pytest.skip(f"{path} not found")
    return serve_app(lambda: create_app(path))


@pytest.fixture(scope="session")
def block_app(serve_app):
    from baarda.dashboard.app import create_app

    demo = ROOT / "data" / "demo-block.json"
    if demo.exists():
        return serve_app(lambda: create_app(demo))
    from tests.dashboard.test_state import tiny_block_problem

    problem = tiny_block_problem()
    return serve_app(lambda: create_app(problem=problem))


@pytest.fixture(scope="module")
def ladybug_app(serve_app):
    """Ladybug (BAL, 49 images, 7,776 points; ../shared/extdata), served."""
    from tests.extdata import EXTDATA, require_extdata

    from baarda.dashboard.app import create_app

    path = require_extdata(EXTDATA / "bal" / "problem-49-7776-pre.txt")
    return serve_app(lambda: create_app(path))


@pytest.fixture(scope="session")
def screenshots():
    SCREENSHOTS.mkdir(exist_ok=True)
    return SCREENSHOTS
