"""Georeferencing: a block in an arbitrary frame (an SfM model converted to the native format)
brought into the frame of its GNSS projection centres by a similarity transformation before the
adjustment, since the adjustment linearises at the block's coordinates.

The similarity X' = s Q X + t that best maps the images' projection centres X0 onto their GNSS
positions in least squares has the closed form of Umeyama (1991) / Horn (1987): with the centred
point sets A (model) and B (GNSS), the SVD U Σ Vᵀ = Bᵀ A / n and D = diag(1, 1, det(U Vᵀ)),
Q = U D Vᵀ, s = tr(Σ D) / (‖A‖² / n), t = b̄ − s Q ā. Robust to a few bad centres: fitted again
without the centres whose residual exceeds max(3 × 1.4826 × median residual, 10⁻⁹ × extent)
until none is left out (at least 3 kept; at most 10 rounds).

The block's points and centres are transformed, each image's rotation becomes Q R (the lever arm
stays in the camera frame); control points, GNSS and IMU observations are not touched.
:func:`georeference` records the transformation, its residuals and the centres left out in
``block.extra["georeference"]``; ``baarda analyze`` prints them (``--georeference``).

References: Umeyama, S. (1991), Least-squares estimation of transformation parameters between
two point patterns, IEEE TPAMI 13(4), 376-380; Horn, B. K. P. (1987), Closed-form solution of
absolute orientation using unit quaternions, JOSA A 4(4), 629-642.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .errors import InputError
from .observations.rotation import R_opk, opk_from_R


def similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, Q, t) of the least-squares similarity dst ≈ s Q src + t (module docstring); src, dst
    (n × 3), n ≥ 3 not collinear."""
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    a_bar, b_bar = src.mean(axis=0), dst.mean(axis=0)
    A, B = src - a_bar, dst - b_bar
    U, S, Vt = np.linalg.svd(B.T @ A / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    Q = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / ((A ** 2).sum() / len(src)))
    return s, Q, b_bar - s * Q @ a_bar


def robust_similarity(src, dst, max_rounds: int = 10):
    """(s, Q, t, kept mask, residual vectors dst − (s Q src + t)) with the centres whose residual
    is too large left out (module docstring)."""
    src, dst = np.asarray(src, dtype=float), np.asarray(dst, dtype=float)
    kept = np.ones(len(src), dtype=bool)
    extent = float(np.ptp(dst, axis=0).max()) if len(dst) else 0.0
    for _ in range(max_rounds):
        s, Q, t = similarity(src[kept], dst[kept])
        res = dst - (s * (Q @ src.T).T + t)
        norm = np.linalg.norm(res, axis=1)
        limit = max(3.0 * 1.4826 * float(np.median(norm[kept])), 1e-9 * extent)
        new = norm <= limit
        if new.sum() < 3 or np.array_equal(new, kept):
            break
        kept = new
    s, Q, t = similarity(src[kept], dst[kept])
    return s, Q, t, kept, dst - (s * (Q @ src.T).T + t)


def georeference(block, path=""):
    """The native block brought into the frame of its GNSS centres (a new block; module
    docstring). InputError when there are fewer than 3 centres or they are collinear."""
    if block.gnss is None or len(block.gnss.centres) < 3:
        raise InputError(path, 0, "--georeference needs GNSS positions of at least 3 images (--gnss)")
    where = {im.id: k for k, im in enumerate(block.images)}
    cs = block.gnss.centres
    src = np.array([[block.images[where[c.image]].X0, block.images[where[c.image]].Y0,
                     block.images[where[c.image]].Z0] for c in cs])
    dst = np.array([c.xyz for c in cs], dtype=float)
    sv = np.linalg.svd(dst - dst.mean(axis=0), compute_uv=False)
    sv_src = np.linalg.svd(src - src.mean(axis=0), compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300) or sv_src[1] <= 1e-9 * max(sv_src[0], 1e-300):
        raise InputError(path, 0, "--georeference: the projection centres lie on a line: the rotation about it "
                         "is not determined")
    s, Q, t, kept, res = robust_similarity(src, dst)

    def move(X):
        return s * Q @ np.asarray(X, dtype=float) + t

    images = []
    for im in block.images:
        X0 = move([im.X0, im.Y0, im.Z0])
        w, p, k = opk_from_R(Q @ R_opk(im.omega, im.phi, im.kappa))
        images.append(dataclasses.replace(im, X0=float(X0[0]), Y0=float(X0[1]), Z0=float(X0[2]),
                                          omega=float(w), phi=float(p), kappa=float(k)))
    points = []
    for p in block.points:
        X = move([p.X, p.Y, p.Z])
        points.append(dataclasses.replace(p, X=float(X[0]), Y=float(X[1]), Z=float(X[2])))
    norm = np.linalg.norm(res, axis=1)
    note = {"scale": s, "rotation": Q.tolist(), "translation": t.tolist(),
            "rms": float(np.sqrt((norm[kept] ** 2).mean())), "n": int(len(cs)), "kept": int(kept.sum()),
            "left_out": [c.image for c, k in zip(cs, kept) if not k],
            "residuals": [{"image": c.image, "residual": r.tolist(), "norm": float(n)}
                          for c, r, n in zip(cs, res, norm)]}
    return block.replace(images=tuple(images), points=tuple(points),
                         extra={**block.extra, "georeference": note})


def text_lines(note: dict, top: int = 5) -> list[str]:
    """The lines ``baarda analyze`` prints for a georeferenced block."""
    Q = np.asarray(note["rotation"])
    w, p, k = (float(np.degrees(a)) for a in opk_from_R(Q))
    out = [f"  georeferenced to {note['kept']} of {note['n']} GNSS centres by a similarity (Umeyama 1991): scale "
           f"{note['scale']:.8g}, rotation ω φ κ = {w:.4f}° {p:.4f}° {k:.4f}°, translation "
           f"{', '.join(f'{v:.4f}' for v in note['translation'])}; residual RMS {note['rms']:.4g} m"]
    if note["left_out"]:
        out.append(f"    left out of the fit (residual > 3 × robust σ): {', '.join(note['left_out'][:20])}")
    worst = sorted(note["residuals"], key=lambda r: -r["norm"])[:top]
    out.append("    largest residuals: " + ", ".join(f"{r['image']} {r['norm']:.3g} m" for r in worst))
    return out
