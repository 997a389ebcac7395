"""Solving the normal equations: ``linalg`` (sparse Cholesky factors, low-rank updates) and
``schur`` (point elimination: Schur structure, factor and compiled kernels with numpy twins)."""
