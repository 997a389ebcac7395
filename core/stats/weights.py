"""The weight functions and scores of robust reweighting (:mod:`baarda.stats.robust`): Huber's
and the Danish method's weight factors, R84's error classes, the global score of the start phase
and its start weights."""

from __future__ import annotations

import numpy as np


def huber(u, k=2.0):
    """Huber's weight function f(u) = 1 for u ≤ k, k/u above (H64; M84 §3.1).

    Parameters
    ----------
    u : array_like of float
        Normalised residuals |v_i| / (σ_i √r_i), dimensionless.
    k : float
        Threshold, dimensionless.

    Returns
    -------
    numpy.ndarray
        Weight factors in (0, 1], dimensionless.
    """
    u = np.asarray(u, dtype=float)
    return np.where(u <= k, 1.0, k / np.maximum(u, 1e-300))


def danish(u, c=3.0):
    """The Danish method's weight function f(u) = 1 for u ≤ c, exp(1 − (u/c)²) above (KJK80; R84 §7).

    Parameters
    ----------
    u : array_like of float
        Normalised residuals, dimensionless.
    c : float
        Threshold, dimensionless.

    Returns
    -------
    numpy.ndarray
        Weight factors in [0, 1], dimensionless.
    """
    u = np.asarray(u, dtype=float)
    t = np.minimum(u / c, 1e10)           # exp(1 − 10²⁰) is 0 already; (10²⁰⁰)² would overflow
    return np.where(u <= c, 1.0, np.exp(np.minimum(0.0, 1.0 - t * t)))


def error_class(size_sigma: float, size_base: float | None = None, medium_base: float = 2.5) -> str:
    """R84 §6 class of a gross error of ``size_sigma`` σ and ``size_base`` base lengths.

    Below 4σ random; 4σ-50σ small; above 50σ medium up to ``medium_base`` base lengths (R84:
    "between 50σ and 2-3 base lengths"), large above ("bigger than 3 base lengths"). Without a
    base length (no block geometry) an error above 50σ is medium.

    Parameters
    ----------
    size_sigma : float
        Size of the error in multiples of σ, dimensionless.
    size_base : float, optional
        Size in base lengths, dimensionless.
    medium_base : float
        Upper end of the medium class, base lengths.

    Returns
    -------
    str
        "random", "small", "medium" or "large".
    """
    if size_sigma < 4:
        return "random"
    if size_sigma <= 50:
        return "small"
    if size_base is None or size_base <= medium_base:
        return "medium"
    return "large"


def global_score(omega: float, dof: int) -> float:
    """z = (Ω/σ0² − r) / √(2r), the global test's statistic as a normal score (F80 §4.1).

    Ω/σ0² ~ χ²(r) under H0; Ω is already divided by σ0².

    Parameters
    ----------
    omega : float
        Ω/σ0², dimensionless.
    dof : int
        Redundancy r.

    Returns
    -------
    float
        z, dimensionless (0 when r ≤ 0).
    """
    return (omega - dof) / np.sqrt(2.0 * dof) if dof > 0 else 0.0


def start_factor(start: np.ndarray, g: float) -> np.ndarray:
    """R84 §8: the start weight factor tends to 1 as g = f(z) goes from 0 to 1, s = s_start^(1 − g).

    Parameters
    ----------
    start : numpy.ndarray
        Start weight factors s_start (1 or 1/100), dimensionless.
    g : float
        The Danish function of the global score, in [0, 1].

    Returns
    -------
    numpy.ndarray
        Weight factors s, dimensionless.
    """
    return np.asarray(start, dtype=float) ** (1.0 - g)
