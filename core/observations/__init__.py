"""Observation equations and their Jacobians: ``geodetic`` (levelling, directions, distances,
angles, coordinates) and ``rotation`` (rotation matrices and their derivatives)."""
