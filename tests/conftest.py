"""Shared test set-up.

pytest imports this file first (``rootdir`` import mode "prepend"): its folder ``tests/`` goes on
``sys.path``, so every test module, ``tests/browser/`` included, imports the helper modules by
name without touching ``sys.path`` itself:

- :mod:`oracle`: dense reference implementations of the paper's formulas (the one oracle);
- :mod:`networks`: small synthetic geodetic networks;
- :mod:`extdata`: where ``../shared/extdata`` lives, skip/fail rules when it is absent;
- :mod:`gama_result`: GNU Gama's XML adjustment results, read as reference values.
"""
