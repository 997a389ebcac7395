"""Shared test set-up.

``tests`` is a package (``tests/__init__.py``): pytest imports this file first as
``tests.conftest`` and puts the repository root on ``sys.path`` (``rootdir`` import mode
"prepend"), so every test module, ``tests/browser/`` included, and the benchmarks
(``python -m bench.bench_x``) import the helper modules by their full names without touching
``sys.path`` themselves:

- :mod:`tests.oracle`: dense reference implementations of the paper's formulas (the one oracle);
- :mod:`tests.networks`: small synthetic geodetic networks;
- :mod:`tests.extdata`: where ``../shared/extdata`` lives, skip/fail rules when it is absent;
- :mod:`tests.gama_result`: GNU Gama's XML adjustment results, read as reference values.

Shared session fixtures (one per pytest worker; treat their values as read-only — an
:class:`~baarda.result.Adjustment` only caches what it computes):

- ``data_dir``: the repository's ``data/`` folder (demo blocks and networks);
- ``demo_path``: ``data/demo-block.json`` (the demo block, written by ``data/make_demo.py``);
- ``demo_problem``, ``demo_adjustment``: that block read and adjusted once.
"""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(scope="session")
def demo_path() -> Path:
    return DATA / "demo-block.json"


@pytest.fixture(scope="session")
def demo_problem(demo_path):
    from baarda.build import read_problem

    return read_problem(demo_path)


@pytest.fixture(scope="session")
def demo_adjustment(demo_problem):
    from baarda import adjust

    return adjust(demo_problem)
