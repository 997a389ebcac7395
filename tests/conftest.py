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
"""
