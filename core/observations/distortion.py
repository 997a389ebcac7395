"""Brown's radial-tangential lens distortion: the one formula of both camera models.

At image coordinates (u, v) (a photogrammetric camera's ideal x̄, ȳ in its unit; a projective
camera's normalised u, v), with r² = u² + v²,

.. math::

    Δu = u\\,(k_1 r² + k_2 r⁴ + k_3 r⁶) + p_1 (r² + 2u²) + 2 p_2 u v,

    Δv = v\\,(k_1 r² + k_2 r⁴ + k_3 r⁶) + 2 p_1 u v + p_2 (r² + 2v²),

the decentring terms in the photogrammetric order (Brown 1971; Fraser 1997). OpenCV's model
(COLMAP ``OPENCV``, Bradski 2000) writes the same terms with its p₁ and p₂ exchanged: it is
``brown(u, v, k1, k2, 0, p2_opencv, p1_opencv)``.

:func:`brown` returns Δu, Δv and the Jacobian of the distorted point (u + Δu, v + Δv) with
respect to (u, v). It is plain arithmetic, so it serves numpy arrays (the reference paths) and,
compiled by numba, the kernels of :mod:`baarda.observations.collinearity` and
:mod:`baarda.observations.projection` — the same formula in both.

References (full in the package docstring): B71 (Brown); F97 (Fraser); B00 (OpenCV).
"""

from __future__ import annotations


def brown(u, v, k1, k2, k3, p1, p2):
    """Brown's radial-tangential distortion at (u, v) and the Jacobian of the distorted point (B71; F97).

    Δu = u (k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2u²) + 2 p2 u v and Δv likewise (module docstring),
    r² = u² + v²; J = ∂(u + Δu, v + Δv)/∂(u, v) is symmetric (J10 = J01). Plain arithmetic on
    scalars or arrays that broadcast (numba compiles it for the kernels).

    Parameters
    ----------
    u, v : float or numpy.ndarray
        Image coordinates: a photogrammetric camera's ideal x̄, ȳ (pixels or millimetres, its unit)
        or a projective camera's normalised coordinates (dimensionless).
    k1, k2, k3 : float or numpy.ndarray
        Radial coefficients, per unit² of u, per unit⁴, per unit⁶.
    p1, p2 : float or numpy.ndarray
        Decentring coefficients in the photogrammetric order, per unit of u.

    Returns
    -------
    du : float or numpy.ndarray
        Δu, same unit as u.
    dv : float or numpy.ndarray
        Δv, same unit as v.
    J00 : float or numpy.ndarray
        ∂(u + Δu)/∂u, dimensionless.
    J01 : float or numpy.ndarray
        ∂(u + Δu)/∂v = ∂(v + Δv)/∂u, dimensionless.
    J11 : float or numpy.ndarray
        ∂(v + Δv)/∂v, dimensionless.
    """
    r2 = u * u + v * v
    r4 = r2 * r2
    rad = k1 * r2 + k2 * r4 + k3 * r4 * r2
    drad = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4            # ∂rad/∂(r²)
    du = u * rad + p1 * (r2 + 2 * u * u) + 2 * p2 * u * v
    dv = v * rad + 2 * p1 * u * v + p2 * (r2 + 2 * v * v)
    cross = 2 * u * v * drad + 2 * p1 * v + 2 * p2 * u
    j00 = 1.0 + rad + 2 * u * u * drad + 6 * p1 * u + 2 * p2 * v
    j11 = 1.0 + rad + 2 * v * v * drad + 2 * p1 * u + 6 * p2 * v
    return du, dv, j00, cross, j11
