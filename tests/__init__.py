"""baarda's tests, a package: pytest imports every test module by its full name
(``tests.test_x``, ``tests.browser.test_x``) with the repository root on ``sys.path`` (its
``rootdir`` "prepend" import mode), so two test files may share a base name; the helper modules
are ``tests.oracle``, ``tests.networks``, ``tests.extdata`` and ``tests.gama_result``, which the
benchmarks import too (``python -m bench.bench_x`` from the repository root)."""
