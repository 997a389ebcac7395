"""Benchmarks that print tables, a package: run each from the repository root as a module,
``OPENBLAS_NUM_THREADS=1 python -m bench.bench_x`` (``make bench`` runs them all), so that they
import one another (``bench.bench_blocks``) and the tests' dense oracle (``tests.oracle``)
without touching ``sys.path``."""
