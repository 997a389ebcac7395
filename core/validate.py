"""Numbers a least-squares adjustment in double precision can handle, checked before adjusting.

Every reader checks that its numbers are numbers and finite; what it cannot see alone is whether
they fit double precision once they meet in the normal equations N = AᵀPA, P = (σ0²Q)⁻¹:

* a standard deviation below ``SIGMA_MIN`` makes its weight 1/σ² (and with it N) overflow or its
  variance σ² underflow to 0 (σ = 1e-300: σ² = 0, a singular covariance); above ``SIGMA_MAX``
  the weight underflows;
* a σ below ``RELATIVE`` × |value| is smaller than the rounding error of the value itself
  (2⁻⁵³|value|, a few units in the last place): the misclosure l − f(x) is then rounding noise
  of several σ and the w-test of that observation meaningless;
* an a priori σ0 (a dimensionless factor, normally 1) outside [1e-10, 1e10] squares into the
  statistics together with σ: it, too, can overflow them;
* a value or an approximate coordinate beyond ``VALUE_LIMIT`` overflows in the squares and
  products of the observation equations (1e308: a distance's dx² is inf).

Real networks and blocks are far inside these limits: the Gama examples, the BAL/Bundler/COLMAP
blocks and the demos have σ from 3e-6 to 5e-2 (SI units: m, rad, px), |values| and coordinates
up to 7e6 and σ/|value| ≥ 4e-9.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .model.bundle import Block
from .model.network import Network
from .model.problem import size_groups
from .model.sfm import SfmBlock
from .observations.projection import ProjectionSet

SIGMA_MIN = 1e-30
SIGMA_MAX = 1e30
VALUE_LIMIT = 1e20
RELATIVE = 2.0 ** -48          # 32 units in the last place of a double
SIGMA0_MIN, SIGMA0_MAX = 1e-10, 1e10   # σ0 (dimensionless): vᵀPv σ0², σ0² Q stay in range


def _where(problem, i: int, path, control) -> tuple[str, int]:
    """The file and line of observation ``i`` (control rows come from the control CSV)."""
    info = problem.info
    kind = info.kind[i]
    line = int(info.line[i]) if info.line is not None and i < len(info.line) else 0
    if control is not None and kind.startswith("control"):
        return str(control), line
    p = Path(path)
    if p.is_dir():           # a COLMAP model: image points come from images.txt/.bin
        for name in ("images.txt", "images.bin"):
            if (p / name).exists() and kind.startswith("image"):
                return str(p / name), line if name.endswith(".txt") else 0
        return str(p), 0
    return str(path), line


def _file_sigma(problem, i: int):
    """The σ of observation ``i`` as the file gives it (value, unit), or (None, None)."""
    info = problem.info
    try:
        sf = float(info.sigma_file[i])
        su = str(info.sigma_unit[i] or "")
    except (TypeError, ValueError, IndexError, AttributeError):
        return None, None
    return (sf, su) if np.isfinite(sf) and sf > 0 else (None, None)


def _label(problem, i: int) -> str:
    ids = " ".join(f"{k}={v}" for k, v in problem.info.ids[i].items())
    return f"{problem.info.kind[i]}{' ' + ids if ids else ''}"


def check_numeric_range(problem, path, control=None) -> None:
    """Refuse (:class:`InputError` naming the file, line and field) a problem whose σ, values or
    approximate coordinates lie outside what double precision can adjust (module docstring)."""
    s0 = float(problem.sigma0)
    if not SIGMA0_MIN <= s0 <= SIGMA0_MAX:
        raise InputError(path, 0, f"the a priori σ0 = {s0:g} is outside [{SIGMA0_MIN:g}, {SIGMA0_MAX:g}]: σ0² "
                         f"and the statistics scaled by it cannot be formed in double precision", field="sigma0")
    l = np.asarray(problem.l, dtype=float)
    n = l.size
    n_free = int(np.count_nonzero(~np.asarray(problem.params.fixed, dtype=bool)))
    if n == 0 or n_free == 0:
        left = len(problem.notes.local_defects)
        raise InputError(path, 0, f"nothing to adjust: {n} observations for {n_free} "
                         f"unknowns" + (f" after leaving out {left} undetermined points, images or "
                                        f"cameras" if left else ""))
    # σ of every observation: the diagonal of its covariance block; the block must be PD
    sigma = np.full(n, np.nan)
    not_pd = []                    # first observation of each cluster that is not positive definite
    for m, clusters, members, C in size_groups(problem.cov):      # (the stacks, not a block at a time)
        C = np.asarray(C, dtype=float).reshape(clusters.size, m, m)
        if C.shape[0] > 1 and C.strides[0] == 0:                   # one matrix broadcast (one σ for all)
            C = C[:1]
        finite = np.isfinite(C).all(axis=(1, 2))
        with np.errstate(all="ignore"):
            d = np.sqrt(np.clip(np.diagonal(C, axis1=1, axis2=2), 0.0, None))
        d[~finite] = np.nan
        sigma[members] = d
        if m > 1:
            Cs = np.where(finite[:, None, None], 0.5 * (C + np.swapaxes(C, 1, 2)), np.eye(m))
            pd = finite & (np.linalg.eigvalsh(Cs).min(axis=1) > 0)
            not_pd += [int(members[k, 0]) for k in np.flatnonzero(~pd)[:1]]
    bad_l = ~np.isfinite(l) | (np.abs(l) > VALUE_LIMIT)
    if bad_l.any():
        i = int(np.flatnonzero(bad_l)[0])
        f, line = _where(problem, i, path, control)
        if not np.isfinite(l[i]):
            raise InputError(f, line, f"{_label(problem, i)}: the value is not a finite number", field="value")
        raise InputError(f, line, f"{_label(problem, i)}: value {l[i]:.6g} is outside ±{VALUE_LIMIT:.0e}: "
                         f"too large to adjust in double precision", field="value")
    with np.errstate(all="ignore"):
        small = ~(sigma >= SIGMA_MIN) | (sigma < RELATIVE * np.abs(l))
        large = sigma > SIGMA_MAX
    if small.any() or large.any():
        i = int(np.flatnonzero(small | large)[0])
        f, line = _where(problem, i, path, control)
        s = sigma[i]
        if not np.isfinite(s):
            why = "not a finite number: its variance overflows in double precision"
        elif large[i]:
            why = f"above {SIGMA_MAX:.0e}: its weight 1/σ² underflows"
        elif s >= SIGMA_MIN:
            why = (f"below the rounding error of the value {l[i]:.6g} in double precision "
                   f"(σ must be ≥ {RELATIVE:.2g} × |value|)")
        else:
            why = f"below {SIGMA_MIN:.0e} (SI units): its weight 1/σ² overflows in double precision"
        shown = f" {s:.6g}" if np.isfinite(s) else ""
        sf, su = _file_sigma(problem, i)
        if sf is not None:
            shown = f" {sf:.6g}{' ' + su if su else ''}" + (f" (SI {s:.6g})" if np.isfinite(s) and s > 0 and su else "")
        raise InputError(f, line, f"{_label(problem, i)}: standard deviation{shown} is {why}",
                         field="sigma")
    if not_pd:                     # correlated blocks: positive definite
        i = min(not_pd)
        f, line = _where(problem, i, path, control)
        raise InputError(f, line, f"{_label(problem, i)}: the covariance matrix of this observation is not "
                         f"positive definite", field="cov")
    x0 = np.asarray(problem.params.x0, dtype=float)
    bad_x = ~np.isfinite(x0) | (np.abs(x0) > VALUE_LIMIT)
    if bad_x.any():
        j = int(np.flatnonzero(bad_x)[0])
        what = (f"{x0[j]:.6g} is outside ±{VALUE_LIMIT:.0e}: too large to adjust in double precision"
                if np.isfinite(x0[j]) else "is not a finite number (no approximate value could be computed)")
        raise InputError(path, 0, f"{problem.params.labels[j]}: coordinate or parameter {what}",
                         field=problem.params.labels[j])
    _check_projections(problem, path, control, x0)


def _check_projections(problem, path, control, x0) -> None:
    """An image point whose projection is undefined at the start values (a division or EUCM
    camera's model has no real distorted point there, a point in the camera's centre plane) is
    refused, naming it and its camera, instead of reaching the adjustment as NaN; so is any other
    observation whose value or derivatives are undefined there (a distance or direction between
    two points with the same approximate coordinates)."""
    for s in problem.sets:
        if not isinstance(s, ProjectionSet):
            _check_defined(problem, s, path, control, x0)
            continue
        with np.errstate(all="ignore"):
            f = s.values(x0)
        bad = ~np.isfinite(f)
        if not bad.any():
            continue
        k = int(np.flatnonzero(bad)[0])
        i = int(s.rows[k])
        fl, line = _where(problem, i, path, control)
        cam = ""
        if s.dcam is not None:
            labels = problem.params.labels
            j = int(s.iint[k // 2, 0])
            cam = f" through {labels[j].rsplit('.', 1)[0]}" if j >= 0 else ""
        raise InputError(fl, line, f"{_label(problem, i)}: its projection{cam} is undefined at the file's "
                         f"values (outside the camera model's field of view, or in the camera's centre "
                         f"plane); {max(int(bad.sum()) // 2, 1)} image point(s) in all", field="value")


def _check_defined(problem, s, path, control, x0) -> None:
    """Refuse the first observation of set ``s`` whose value or Jacobian is not finite at ``x0``."""
    with np.errstate(all="ignore"):
        f, jr, _, jv = s.evaluate(x0)
    bad = ~np.isfinite(np.asarray(f, dtype=float))
    jv = np.asarray(jv, dtype=float)
    if not bad.any() and np.isfinite(jv).all():
        return
    rows = np.zeros(problem.n, dtype=bool)
    rows[np.asarray(s.rows)[bad]] = True
    rows[np.asarray(jr)[~np.isfinite(jv)]] = True
    i = int(np.flatnonzero(rows)[0])
    fl, line = _where(problem, i, path, control)
    raise InputError(fl, line, f"{_label(problem, i)}: undefined at the approximate coordinates (points with "
                     f"the same approximate coordinates: a zero distance or an undefined direction); give them "
                     f"distinct approximate coordinates; {int(rows.sum())} observation(s) in all", field="value")


def _refuse_large(path, lines, values, what) -> None:
    """InputError at the first row of ``values`` (n × k) with a number beyond VALUE_LIMIT."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return
    v = v.reshape(v.shape[0], -1)
    bad = ~np.isfinite(v).all(axis=1) | (np.abs(v) > VALUE_LIMIT).any(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        line = int(lines[k]) if lines is not None and k < len(lines) else 0
        raise InputError(path, line, f"{what(k)}: {' '.join(f'{x:.6g}' for x in v[k])}: a number outside "
                         f"±{VALUE_LIMIT:.0e}, too large to adjust in double precision")


def check_model_range(model, path) -> None:
    """Before a bundle block is built (its builder already squares coordinates to find local
    defects and far points): approximate coordinates, image coordinates and camera parameters
    within ±VALUE_LIMIT. Networks: their observed values and given coordinates, finite and within
    ±VALUE_LIMIT, before the approximate coordinates are computed from them (a reader that let
    an infinite angle through would otherwise end in the approximation's trigonometry); the rest
    on their problem (:func:`check_numeric_range`)."""

    if isinstance(model, SfmBlock):
        def part(name, lines):      # a COLMAP model directory: the file inside it (binary: no lines)
            d = Path(path)
            if not d.is_dir():
                return path, lines
            if (d / f"{name}.txt").exists():
                return d / f"{name}.txt", lines
            return d / f"{name}.bin", None
        _refuse_large(*part("points3D", model.point_line), model.X, lambda k: f"point {model.points[k]}")
        _refuse_large(*part("images", model.obs_line), model.xy,
                      lambda k: f"image {model.images[int(model.obs_image[k])].id}: image point")
        _refuse_large(*part("images", [im.line for im in model.images]), [im.t for im in model.images],
                      lambda k: f"image {model.images[k].id}: translation")
        for cam in model.cameras:
            _refuse_large(*part("cameras", [cam.line]), [cam.params], lambda k: f"camera {cam.id}: parameters")
    elif isinstance(model, Block):
        _refuse_large(path, [getattr(p, "line", 0) for p in model.points], [(p.X, p.Y, p.Z) for p in model.points],
                      lambda k: f"point {model.points[k].id}")
        _refuse_large(path, [getattr(im, "line", 0) for im in model.images],
                      [(im.X0, im.Y0, im.Z0) for im in model.images], lambda k: f"image {model.images[k].id}")
        _refuse_large(path, model.obs.line, model.obs.xy, lambda k: "image point")
    elif isinstance(model, Network):
        obs = model.observations
        _refuse_large(path, [o.line for o in obs], [[o.value] for o in obs],
                      lambda k: f"{obs[k].kind} {' '.join(map(str, obs[k].points))}: value (SI)")
        _refuse_large(path, [p.line for p in model.points],
                      [[0.0 if v is None else v for v in (p.x, p.y, p.z)] for p in model.points],
                      lambda k: f"point {model.points[k].id}")
