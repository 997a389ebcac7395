"""The scripts of ``examples/`` run as the README says (from the repository root) and print what
their comments promise; the README's Python session runs as written."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(args, tmp_path, timeout=900):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONWARNINGS": "error::DeprecationWarning:baarda"}
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def test_quickstart(tmp_path):
    out = _run(["examples/quickstart.py"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert re.search(r"<Analysis demo-block.json: 448 observations, 324 unknowns, r = 124", out.stdout)
    assert "image-point:302:P05003: T = " in out.stdout
    assert out.stdout.count("FOUND") == 4            # the four planted errors


def test_network(tmp_path):
    target = tmp_path / "net.json"
    out = _run(["examples/network.py", str(target)], tmp_path)
    assert out.returncode == 0, out.stderr
    assert "data snooping removed" in out.stdout and target.exists()
    import json
    doc = json.loads(target.read_text())
    assert doc["schema"].startswith("baarda-analysis/") and "snooping" in doc


@pytest.mark.slow
def test_map_view(tmp_path):
    target = tmp_path / "maps.html"
    out = _run(["examples/map_view.py", str(target)], tmp_path)
    assert out.returncode == 0, out.stderr
    html = target.read_text(encoding="utf-8")
    assert "Bokeh" in html and "Redundancy" in html and "aerial block, RC30" in html   # (the title JSON-escaped)


def test_readme_python_session(tmp_path):
    """The README's "Python API" code block, run as one script."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    script = tmp_path / "readme_session.py"
    script.write_text(code.replace("a.view()", "a.view().get_root()"), encoding="utf-8")
    out = _run([str(script)], tmp_path)
    assert out.returncode == 0, out.stderr
    assert "<Analysis demo-block.json" in out.stdout
