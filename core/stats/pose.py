"""Precision of the images' exterior orientation: the 6 × 6 covariance of each pose.

A bundle block's pose of image i is (X0, Y0, Z0, ω, φ, κ): the projection centre in object
coordinates and the rotation R_ωφκ = R_ω R_φ R_κ (camera → object,
:func:`baarda.observations.rotation.R_opk`). Its covariance is the 6 × 6 block of
Σ = σ0² N⁻¹ (F80 eq. 3) on the image's parameters — in the adjustment's datum: the frame of the
control points and GNSS centres when they define it, the S-base of a free block otherwise
(Σ_S = S Σ Sᵀ, M84 §2; :meth:`baarda.result.Adjustment.cov_entries`) — scaled by the σ0 the
problem uses (:attr:`baarda.result.Adjustment.variance_factor`). Only the 21 entries of each
image's block are computed (the selected inverse, or the camera blocks of the reduced camera
system of a Schur solve), never the dense Σ.

A native block carries these six as its parameters. A structure-from-motion block (BAL, Bundler,
COLMAP; :mod:`baarda.model.sfm`) carries the world → camera rotation R(ρ) = exp([ρ]×) and the
translation t, with X0 = −Rᵀ t and R_ωφκ = (D R)ᵀ (D = diag(1, −1, −1) for COLMAP, I for BAL and
Bundler; :func:`baarda.model.sfm.to_block`); its covariance is carried over by the law of
propagation, Σ_pose = J Σ_ρt Jᵀ with J = ∂(X0, ω, φ, κ)/∂(ρ, t). With R(ρ + dρ) = R exp([δ]×),
δ = J_r(ρ) dρ (the right Jacobian of SO(3), C11):

- dX0 = [X0]× δ − Rᵀ dt (from dRᵀ = −[δ]× Rᵀ);
- dR_ωφκ = −[δ]× R_ωφκ; with W_a = vee((∂R_ωφκ/∂a) R_ωφκᵀ) for a = ω, φ, κ
  (:func:`baarda.observations.rotation.R_opk_derivatives`), W (dω, dφ, dκ)ᵀ = −δ.

References (full in the package docstring): F80; M84; C11.
"""

from __future__ import annotations

import numpy as np

from ..errors import BaardaError
from ..observations.projection import right_jacobian
from ..observations.rotation import R_from_rodrigues, R_opk_derivatives, opk_from_R, skew

#: the components of a pose, in the order of :func:`pose_covariance`
POSE_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
_SFM_NAMES = ("rho1", "rho2", "rho3", "tx", "ty", "tz")


def pose_parameters(problem, images=None) -> tuple[list[str], np.ndarray, bool]:
    """The parameters of the images' poses.

    Parameters
    ----------
    problem : baarda.model.problem.Problem
        A bundle block's problem (native or SfM).
    images : iterable of str, optional
        Image ids (default: every image of the block, in its order).

    Returns
    -------
    ids : list of str
        The image ids.
    index : numpy.ndarray
        n × 6 parameter indices (into ``Problem.params``): X0, Y0, Z0, ω, φ, κ, or ρ, t of an SfM block.
    sfm : bool
        Whether they are ρ, t (module docstring).

    Raises
    ------
    baarda.errors.BaardaError
        For a problem without images, or an unknown image id.
    """
    geo = problem.geometry
    if geo is None or not geo.images:
        raise BaardaError("pose precision needs a bundle block with images")
    sfm = geo.convention is not None
    order = {im.id: k for k, im in enumerate(geo.images)}
    ids = list(order) if images is None else [str(i) for i in images]
    labels = problem.params.labels
    index = np.empty((len(ids), 6), dtype=np.int64)
    for n, iid in enumerate(ids):
        k = order.get(iid)
        if k is None:
            raise BaardaError(f"image {iid} is not an image of the block")
        index[n] = 6 * k + np.arange(6)             # the first parameters, image by image (model modules)
        want = f"image {iid}.rho1" if sfm else f"{iid}.X0"
        if labels[index[n, 0]] != want:
            raise BaardaError(f"image {iid}: its pose parameters are not where the block's layout puts them")
    return ids, index, sfm


def sfm_pose_jacobian(rho: np.ndarray, t: np.ndarray, convention: str) -> np.ndarray:
    """J = ∂(X0, Y0, Z0, ω, φ, κ)/∂(ρ, t) of SfM poses (module docstring).

    Parameters
    ----------
    rho : numpy.ndarray
        n × 3 Rodrigues vectors of the world → camera rotations, radians.
    t : numpy.ndarray
        n × 3 translations, object units.
    convention : str
        "colmap", "bal" or "bundler".

    Returns
    -------
    numpy.ndarray
        n × 6 × 6: rows X0, Y0, Z0 (object units) and ω, φ, κ (radians) per unit of ρ1..3 (radians)
        and t (object units).
    """
    rho, t = np.asarray(rho, dtype=float), np.asarray(t, dtype=float)
    D = np.diag([1.0, -1.0, -1.0]) if convention == "colmap" else np.eye(3)
    R = R_from_rodrigues(rho)
    Rt = np.swapaxes(R, -1, -2)
    X0 = -np.einsum("nij,nj->ni", Rt, t)
    Jr = right_jacobian(rho)
    Ropk = Rt @ D
    w, p, k = opk_from_R(Ropk)
    _, dw, dp, dk = R_opk_derivatives(w, p, k)
    RoT = np.swapaxes(Ropk, -1, -2)
    W = np.stack([_vee(dR @ RoT) for dR in (dw, dp, dk)], axis=-1)      # n × 3 × 3, columns ω, φ, κ
    J = np.zeros((rho.shape[0], 6, 6))
    J[:, :3, :3] = skew(X0) @ Jr
    J[:, :3, 3:] = -Rt
    J[:, 3:, :3] = -np.linalg.solve(W, Jr)
    return J


def _vee(S: np.ndarray) -> np.ndarray:
    """The vector s of skew-symmetric matrices [s]× (n × 3 × 3 → n × 3)."""
    return 0.5 * np.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]],
                          axis=-1)


def pose_covariance(adj, images=None) -> np.ndarray:
    """Covariance of the images' poses (X0, Y0, Z0, ω, φ, κ), n × 6 × 6 (module docstring).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        A bundle block's adjustment.
    images : iterable of str, optional
        Image ids (default: every image, in the block's order).

    Returns
    -------
    numpy.ndarray
        n × 6 × 6 covariances in the adjustment's datum (control/GNSS frame, or the S-base of a
        free block), scaled by the σ0 in use: X0, Y0, Z0 in the object units (m), ω, φ, κ in
        radians (m², m·rad, rad²); rows and columns of held parameters are 0.

    Raises
    ------
    baarda.errors.BaardaError
        For a problem without images, or an unknown image id.
    """
    problem = adj.problem
    _, index, sfm = pose_parameters(problem, images)
    params = problem.params
    fpos = np.full(params.size, -1)
    fpos[params.free] = np.arange(params.free.size)
    loc = fpos[index]                                            # n × 6, -1 where held
    a, b = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    upper = a <= b
    li, lj = loc[:, a[upper]], loc[:, b[upper]]                  # the 21 entries of each block
    both = (li >= 0) & (lj >= 0)
    vals = np.zeros(li.shape)
    vals[both] = adj.cov_entries(li[both], lj[both])
    out = np.zeros((index.shape[0], 6, 6))
    out[:, a[upper], b[upper]] = vals
    out[:, b[upper], a[upper]] = vals
    out *= adj.variance_factor
    if sfm:
        x = adj.x[index]
        J = sfm_pose_jacobian(x[:, :3], x[:, 3:], problem.geometry.convention)
        out = J @ out @ np.swapaxes(J, -1, -2)
    return out


def pose_sigma(cov: np.ndarray) -> np.ndarray:
    """Standard deviations of the pose components.

    Parameters
    ----------
    cov : numpy.ndarray
        n × 6 × 6 covariances of :func:`pose_covariance` (m², m·rad, rad²).

    Returns
    -------
    numpy.ndarray
        n × 6: σ of X0, Y0, Z0 (m) and ω, φ, κ (rad).
    """
    return np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))


def pose_values(adj, images=None) -> np.ndarray:
    """The adjusted poses (X0, Y0, Z0, ω, φ, κ); an SfM block's from ρ, t (module docstring).

    Parameters
    ----------
    adj : baarda.result.Adjustment
        A bundle block's adjustment.
    images : iterable of str, optional
        Image ids (default: every image, in the block's order).

    Returns
    -------
    numpy.ndarray
        n × 6: X0, Y0, Z0 (object units, m) and ω, φ, κ (radians).
    """
    problem = adj.problem
    _, index, sfm = pose_parameters(problem, images)
    x = adj.x[index]
    if not sfm:
        return x
    D = np.diag([1.0, -1.0, -1.0]) if problem.geometry.convention == "colmap" else np.eye(3)
    R = R_from_rodrigues(x[:, :3])
    Rt = np.swapaxes(R, -1, -2)
    X0 = -np.einsum("nij,nj->ni", Rt, x[:, 3:])
    return np.column_stack([X0, *opk_from_R(Rt @ D)])
