"""Start-up of the command line (issue 30, item 5; issue 25, item 6): the parser loads no numpy,
so ``baarda --help`` answers at once; a Ctrl-C or SIGTERM while the computation loads ends in one
line (130 / 143), not a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

DEMO = Path(__file__).resolve().parents[1] / "data" / "demo-block.json"

#: a child that sends itself SIGNAL when the import of numpy begins (inside ``baarda.cli.main``,
#: after the arguments are parsed): a signal during start-up, at a known point
_SIGNAL_DURING_IMPORT = """
import os, signal, sys

class Hook:
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), getattr(signal, {signal!r}))
        return None

sys.meta_path.insert(0, Hook())
from baarda.cli import main
sys.exit(main(["analyze", {demo!r}]))
"""


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)


def test_the_parser_and_help_load_no_numpy():
    out = _run("import sys\nfrom baarda import cli\n"
               "text = cli.build_parser().format_help()\n"
               "for command in ('analyze', 'test', 'simulate', 'batch', 'study', 'serve'):\n"
               "    try:\n"
               "        cli.build_parser().parse_args([command, '--help'])\n"
               "    except SystemExit:\n"
               "        pass\n"
               "print(sorted(m for m in ('numpy', 'scipy', 'numba', 'baarda.analysis', 'baarda.commands') "
               "if m in sys.modules))")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_import_baarda_is_lazy_and_its_names_resolve():
    out = _run("import sys, baarda\nloaded = 'numpy' in sys.modules\n"
               "import baarda.adjust\n"
               "from baarda import adjust, analyze, TestPolicy, Analysis, SingularError\n"
               "print(loaded, callable(adjust) and adjust.__module__ == 'baarda.adjust', baarda.adjust is adjust,"
               " analyze.__module__, TestPolicy.__name__, sorted(baarda.__all__) == sorted(set(baarda.__all__)))")
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True", "True", "baarda.analysis", "TestPolicy", "True"]


@pytest.mark.parametrize("signal, status, line", [("SIGINT", 130, "baarda: interrupted"),
                                                  ("SIGTERM", 143, "baarda: terminated")])
def test_a_signal_while_the_computation_loads_ends_in_one_line(signal, status, line):
    out = _run(_SIGNAL_DURING_IMPORT.format(signal=signal, demo=str(DEMO)))
    assert out.returncode == status, out.stderr
    assert out.stderr.splitlines() == [line]
    assert "Traceback" not in out.stderr and out.stdout == ""
