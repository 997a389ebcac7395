"""Synthetic aerial blocks with planted errors (F80 §7.3 design mode; R84 §6 error classes).

A block of s strips × m images flown along object X (odd strips flown back, κ = π), with
forward overlap p and side overlap q: the ground footprint of the format is
W = width · H / c by H_g = height · H / c, the air base B = (1 − p) W and the strip distance
A = (1 − q) H_g. Tie points lie on a grid in the von Gruber positions: along the strip every
2B/(nx − 1) (nx = 3: every base, each point in up to 3 images of a strip; nx = 5: every half
base), across at the strip axis and in the middle of the side overlaps (seen by two strips),
so that a point appears in 2-6 images. Points seen by fewer than two images are dropped.
Terrain heights are a smooth random surface of amplitude ``relief · H``.

Control configurations: ``"corners"`` (the four block corners), ``"perimeter"`` (every
``control_spacing`` base lengths around the block edge), ``"dense"`` (every other grid point),
``"minimal"`` (7 coordinates: two XYZ points and one height — a minimum datum), ``"none"``.

Errors (planted after the noise, sizes in σ of the observation unless ``size_base`` gives base
lengths; the class follows R84 §6: < 4σ random, 4σ-50σ small, up to 2.5 base lengths medium,
above large):

- ``"image"``: one image coordinate;
- ``"image-point"`` / ``"misidentification"``: a 2D error of one image point;
- ``"control"``: a control coordinate (``axis`` x, y or z);
- ``"transfer"``: the same 2D offset in ``images`` (default 3) consecutive images of one
  strip of a point also seen by another strip (a point-transfer error);
- ``"exchange"``: two neighbouring points swapped in one image;
- a systematic image deformation: ``radial`` = a1 of Brown's basis (camera units at the
  reference radius, :mod:`baarda.model.bundle`), added to every image point.

*Design mode* (``design=True``): no noise, approximations equal to the truth — the
observations are exact projections, so reliability measures depend only on geometry
(F80 §7.3). Everything is drawn from ``numpy.random.default_rng(seed)``: a recipe and a seed
give the same block on every machine with the same numpy.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from . import simulate_gnss
from .catalog import CAMERAS, RANGES
from .errors import OptionError
from .io.native import write_native
from .io.output import write_text
from .model.bundle import Block, Camera, Image, ImageObservations, ObjectPoint
from .observations.collinearity import project
from .model.imodel import IModelBlock, Model, ModelObservations, PlanPoint

DEFAULTS = {
    "strips": 3, "images_per_strip": 8, "camera": "aerial", "flying_height": 1500.0,
    "forward_overlap": 0.6, "side_overlap": 0.25, "pattern": [3, 3], "relief": 0.03,
    "attitude_sigma": 0.01, "position_sigma": 5.0, "control": "perimeter", "control_spacing": 2,
    "check": 0, "sigma_image": None, "rho": 0.0, "sigma_control_h": 0.05, "sigma_control_v": 0.05,
    "radial": 0.0, "ap": [], "errors": [], "design": False, "approx_sigma": 0.5,
    "datum": "control", "seed": 0, "title": "",
    "gnss_sigma": None, "gnss_lever": [0.0, 0.0, 0.0], "gnss_shift": False, "gnss_drift": False,
    "imu_sigma": None, "imu_boresight": [0.0, 0.0, 0.0],
}


#: the ranges of the numbers of a planted error (``errors[k]``)
ERROR_RANGES = {"size": (0.0, 1e6, False), "size_base": (0.0, 1e3, False), "images": (1, 100, True),
                "direction": (-1e4, 1e4, False), "sign": (-1.0, 1.0, False)}


def check_number(name: str, value, low, high, integer: bool = False):
    """``value`` if it is a number (an integer if ``integer``) in [low, high], else OptionError
    naming ``name`` and the range."""
    kind = "an integer" if integer else "a number"
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if not ok or not low <= value <= high:
        raise OptionError(name, value, (), f"{name} must be {kind} from {low:g} to {high:g} (got {value!r})")
    return int(value) if integer else float(value)


def check_recipe(recipe: dict) -> dict:
    """``recipe`` with every key known and every number within :data:`RANGES` (OptionError
    naming the key otherwise), its integers as int: what :func:`simulate_block` accepts."""
    if not isinstance(recipe, dict):
        raise OptionError("recipe", recipe, (), "a recipe must be a JSON object")
    unknown = set(recipe) - set(DEFAULTS)
    if unknown:
        raise OptionError("recipe", sorted(unknown), tuple(DEFAULTS), f"unknown recipe keys: {', '.join(sorted(unknown))}")
    r = dict(recipe)
    for key, (low, high, integer) in RANGES.items():
        if key in r and not (key in ("sigma_image", "gnss_sigma", "imu_sigma") and r[key] is None):
            r[key] = check_number(key, r[key], low, high, integer)
    for key in ("control", "datum", "title"):
        if key in r and not isinstance(r[key], str):
            raise OptionError(key, r[key], (), f"{key} must be a string (got {r[key]!r})")
    if "camera" in r and not (r["camera"] in CAMERAS if isinstance(r["camera"], str) else isinstance(r["camera"], dict)):
        raise OptionError("camera", r["camera"], tuple(CAMERAS), f"camera must be one of {', '.join(CAMERAS)} "
                                                                 f"or an object (got {r['camera']!r})")
    for key in ("pattern", "ap", "errors"):
        if key in r and not isinstance(r[key], (list, tuple)):
            raise OptionError(key, r[key], (), f"{key} must be a list (got {r[key]!r})")
    if "pattern" in r:
        r["pattern"] = [check_number("pattern", v, 3, 5, True) for v in r["pattern"]]
    errors = []
    for k, spec in enumerate(r.get("errors", ())):
        if not isinstance(spec, dict) or not isinstance(spec.get("kind"), str):
            raise OptionError(f"errors[{k}]", spec, (), f"errors[{k}] must be an object with a kind (got {spec!r})")
        spec = dict(spec)
        for key, (low, high, integer) in ERROR_RANGES.items():
            if key in spec:
                spec[key] = check_number(f"errors[{k}].{key}", spec[key], low, high, integer)
        for key in ("image", "point", "component", "axis", "strip"):
            if key in spec and not isinstance(spec[key], str):
                raise OptionError(f"errors[{k}].{key}", spec[key], (), f"errors[{k}].{key} must be a string")
        for key, allowed in (("component", ("x", "y")), ("axis", ("x", "y", "z"))):
            if spec.get(key) is not None and spec[key] not in allowed:
                raise OptionError(f"errors[{k}].{key}", spec[key], allowed)
        errors.append(spec)
    if "errors" in r:
        r["errors"] = errors
    for key in ("design", "gnss_shift", "gnss_drift"):
        if key in r and not isinstance(r[key], bool):
            raise OptionError(key, r[key], (), f"{key} must be true or false (got {r[key]!r})")
    for key, lim in (("gnss_lever", 1e3), ("imu_boresight", 10.0)):
        if key in r:
            lev = r[key]
            if not isinstance(lev, (list, tuple)) or len(lev) != 3:
                raise OptionError(key, lev, (), f"{key} must be a list of three numbers (got {lev!r})")
            r[key] = [check_number(key, v, -lim, lim) for v in lev]
    return r


def error_class(size_sigma: float, size_base: float) -> str:
    """R84 §6 class of a gross error of ``size_sigma`` σ and ``size_base`` base lengths."""
    if size_sigma < 4:
        return "random"
    if size_sigma <= 50:
        return "small"
    return "medium" if size_base <= 2.5 else "large"


def _camera(spec) -> Camera:
    d = dict(CAMERAS[spec]) if isinstance(spec, str) else dict(spec)
    return Camera(**{k: (tuple(v) if k == "ap" else v) for k, v in d.items()})


def simulate_block(**recipe) -> tuple[Block, dict]:
    """A simulated block and the truth of what was planted (module docstring).

    Returns (Block, truth): truth = {"format": "baarda-truth", "version": 1, "recipe": ...,
    "errors": [{"kind", "class", "ids", "rows", "vector", "unit", "size_sigma",
    "size_base"}], "radial": ..., "points": {id: [X, Y, Z]}, "images": {id: [X0, Y0, Z0,
    ω, φ, κ]}}. ``rows`` are the rows of the errors in :func:`baarda.model.bundle.build_block_problem`.
    """
    r = {**DEFAULTS, **check_recipe(recipe)}
    rng = np.random.default_rng(r["seed"])
    try:
        cam = _camera(r["camera"])
        cam = Camera(**{**cam.__dict__, "ap": tuple(r["ap"])})
        if not all(isinstance(v, (int, float)) and 0 < v < 1e7 for v in (cam.c, cam.width, cam.height)):
            raise ValueError
    except (TypeError, ValueError):
        raise OptionError("camera", r["camera"], tuple(CAMERAS),
                          "camera must be one of " + ", ".join(CAMERAS) + " or an object with the fields of "
                          "baarda.model.bundle.Camera (c, width, height > 0)") from None
    sigma = r["sigma_image"] if r["sigma_image"] is not None else (0.005 if cam.unit == "mm" else 0.5)
    H = float(r["flying_height"])
    s_n, m_n = int(r["strips"]), int(r["images_per_strip"])
    Wg, Hg = cam.width * H / cam.c, cam.height * H / cam.c
    B = (1 - r["forward_overlap"]) * Wg
    A = (1 - r["side_overlap"]) * Hg
    # terrain: a smooth random surface
    ph = rng.uniform(0, 2 * np.pi, 4)
    Lx, Ly = max(m_n * B, B), max(s_n * A, A)

    def terrain(X, Y):
        return r["relief"] * H * (0.6 * np.sin(2 * np.pi * X / Lx + ph[0]) * np.cos(2 * np.pi * Y / Ly + ph[1])
                                  + 0.4 * np.sin(4 * np.pi * X / Lx + ph[2] + 2 * np.pi * Y / Ly + ph[3]))

    # images
    images = []
    for i in range(s_n):
        for j in range(m_n):
            X0, Y0 = j * B, i * A
            dp = rng.normal(0, r["position_sigma"], 3)
            da = rng.normal(0, r["attitude_sigma"], 3)
            images.append(Image(id=f"{i + 1}{j + 1:02d}", camera=cam.id, X0=X0 + dp[0], Y0=Y0 + dp[1],
                                Z0=H + dp[2], omega=da[0], phi=da[1],
                                kappa=(np.pi if i % 2 else 0.0) + da[2], strip=str(i + 1)))
    # tie point grid
    nx, ny = (int(v) for v in r["pattern"])
    if ny != 3 or nx not in (3, 5):
        raise OptionError("pattern", [nx, ny], ([3, 3], [5, 3]), "pattern must be [3, 3] or [5, 3]")
    stepx = 2 * B / (nx - 1)
    xs = np.arange(-round(B / stepx), round((m_n - 1) * B / stepx) + round(B / stepx) + 1) * stepx
    ys = np.arange(-1, 2 * s_n) * A / 2
    grid = [(ix, iy, X, Y) for iy, Y in enumerate(ys) for ix, X in enumerate(xs)]
    P = np.array([[X, Y, terrain(X, Y)] for _, _, X, Y in grid])
    pid = [f"P{iy:02d}{ix:03d}" for ix, iy, _, _ in grid]
    # visibility
    obs_i, obs_p, xy_true = [], [], []
    for k, im in enumerate(images):
        xy = project(cam, [im] * len(P), P)
        inside = (np.abs(xy[:, 0] - cam.x0) <= 0.49 * cam.width) & (np.abs(xy[:, 1] - cam.y0) <= 0.49 * cam.height)
        for p in np.flatnonzero(inside):
            obs_i.append(k)
            obs_p.append(p)
            xy_true.append(xy[p])
    obs_i, obs_p = np.array(obs_i), np.array(obs_p)
    count = np.bincount(obs_p, minlength=len(P))
    keep_pts = np.flatnonzero(count >= 2)
    if keep_pts.size == 0:
        raise OptionError("images_per_strip", m_n, (), "no point is seen in two images: simulate more images "
                                                       "(images_per_strip, strips) or more overlap")
    newp = np.full(len(P), -1)
    newp[keep_pts] = np.arange(keep_pts.size)
    sel = newp[obs_p] >= 0
    obs_i, obs_p = obs_i[sel], newp[obs_p[sel]]
    xy_true = np.array(xy_true)[sel]
    P = P[keep_pts]
    pid = [pid[k] for k in keep_pts]
    gxy = np.array([(grid[k][0], grid[k][1]) for k in keep_pts])
    # systematic image deformation (radial, Brown a1)
    if r["radial"]:
        xy_true = project(cam, [images[k] for k in obs_i], P[obs_p],
                          ap={"brown": [r["radial"], 0, 0, 0, 0, 0, 0]})
    m = obs_i.size
    cov1 = sigma ** 2 * np.array([[1.0, r["rho"]], [r["rho"], 1.0]])
    cov = np.repeat(cov1[None], m, axis=0)
    xy = xy_true.copy()
    if not r["design"]:
        L = np.linalg.cholesky(cov1)
        xy = xy + rng.standard_normal((m, 2)) @ L.T
    # control and check points
    status = _control_configuration(r, gxy, xs.size, ys.size, B, stepx, rng)
    n_check = int(r["check"])
    if n_check:
        interior = np.flatnonzero((status == "tie") & (gxy[:, 1] > 0) & (gxy[:, 1] < ys.size - 1))
        status[rng.choice(interior, size=min(n_check, interior.size), replace=False)] = "check"
    sh, sv = float(r["sigma_control_h"]), float(r["sigma_control_v"])
    ref = P.copy()
    ctrl = np.array([str(st).startswith("control") for st in status])
    if not r["design"]:
        ref[ctrl] += rng.standard_normal((int(ctrl.sum()), 3)) * np.array([sh, sh, sv])
    truth_errors = []
    gnss_errors = [e for e in r["errors"] if str(e.get("kind", "")).startswith("gnss")]
    if gnss_errors and r["gnss_sigma"] is None:
        raise OptionError("errors", gnss_errors[0]["kind"], (), "a GNSS error needs gnss_sigma (--gnss-sigma)")
    imu_errors = [e for e in r["errors"] if e.get("kind") == "imu"]
    if imu_errors and r["imu_sigma"] is None:
        raise OptionError("errors", "imu", (), "an IMU error needs imu_sigma (--imu-sigma)")
    gnss_errors += imu_errors
    xy, ref = _plant({**r, "errors": [e for e in r["errors"] if e not in gnss_errors]}, rng, images, pid, obs_i,
                     obs_p, xy, ref, status, sigma, sh, sv, cam, B, truth_errors)
    # approximations
    Pa, imgs_a = P.copy(), images
    if not r["design"] and r["approx_sigma"]:
        Pa = P + rng.normal(0, r["approx_sigma"], P.shape)
        imgs_a = [Image(**{**im.__dict__, "X0": im.X0 + e[0], "Y0": im.Y0 + e[1], "Z0": im.Z0 + e[2],
                           "omega": im.omega + e[3], "phi": im.phi + e[4], "kappa": im.kappa + e[5]})
                  for im, e in zip(images, rng.normal(0, 1, (len(images), 6))
                                   * np.array([1, 1, 1, 1e-3, 1e-3, 1e-3]) * r["approx_sigma"])]
    points = []
    for k in range(len(P)):
        st, axes = str(status[k]), "xyz"
        if st == "control-z":
            st, axes = "control", "z"
        points.append(ObjectPoint(id=pid[k], X=float(Pa[k, 0]), Y=float(Pa[k, 1]), Z=float(Pa[k, 2]), status=st,
                                  ref=tuple(float(v) for v in ref[k]) if st != "tie" else None,
                                  sigma_h=sh if st == "control" else 0.0,
                                  sigma_v=sv if st == "control" else 0.0, axes=axes))
    order = np.lexsort((obs_p, obs_i))
    obs = ImageObservations(image=obs_i[order], point=obs_p[order], xy=xy[order], cov=cov[order],
                            line=np.zeros(m, dtype=np.int64))
    inv = np.empty(m, dtype=np.int64)
    inv[order] = np.arange(m)
    title = r["title"] or f"simulated block {s_n} × {m_n}"
    block = Block(cameras=(cam,), images=tuple(imgs_a), points=tuple(points), obs=obs, datum=r["datum"],
                  sigma0=1.0, title=title, extra={"simulated": True, "base": B, "strip_distance": A})
    for e in truth_errors:
        e["rows"] = _rows(e, inv, block)
        e.pop("_k", None)
    eo = {im.id: [im.X0, im.Y0, im.Z0, im.omega, im.phi, im.kappa] for im in images}
    if r["gnss_sigma"] is not None:
        block, more = simulate_gnss.add_gnss(block, eo, r, [e for e in gnss_errors if e["kind"] != "imu"])
        truth_errors += more
    if r["imu_sigma"] is not None:
        block, more = simulate_gnss.add_imu(block, eo, r, imu_errors)
        truth_errors += more
    truth = {"format": "baarda-truth", "version": 1, "recipe": {**r, "pattern": list(r["pattern"])},
             "sigma_image": sigma, "base": B, "strip_distance": A, "radial": r["radial"],
             "errors": truth_errors,
             "points": {p: [float(v) for v in P[k]] for k, p in enumerate(pid)},
             "images": {im.id: [im.X0, im.Y0, im.Z0, im.omega, im.phi, im.kappa] for im in images}}
    return block, truth


def _control_configuration(r, gxy, nxs, nys, B, stepx, rng) -> np.ndarray:
    ix, iy = gxy[:, 0], gxy[:, 1]
    status = np.array(["tie"] * len(gxy), dtype=object)
    # block edge: the outermost grid rows/columns that still hold points
    x_lo, x_hi = ix.min(), ix.max()
    y_lo, y_hi = iy.min(), iy.max()
    edge = (ix == x_lo) | (ix == x_hi) | (iy == y_lo) | (iy == y_hi)
    kind = r["control"]
    if kind == "none":
        return status
    if kind in ("corners", "minimal"):
        corners = []
        for cx in (x_lo, x_hi):
            for cy in (y_lo, y_hi):
                d = (ix - cx) ** 2 + (iy - cy) ** 2
                corners.append(int(np.argmin(d)))
        if kind == "corners":
            status[corners] = "control"
        else:
            status[corners[0]] = "control"
            status[corners[3]] = "control"
            status[corners[1]] = "control-z"
        return status
    if kind == "perimeter":
        k = max(1, int(round(r["control_spacing"] * B / stepx)))
        along = edge & ((iy == y_lo) | (iy == y_hi)) & (((ix - x_lo) % k == 0) | (ix == x_hi))
        across = edge & ((ix == x_lo) | (ix == x_hi)) & (iy % 2 == 0)
        status[along | across] = "control"
        return status
    if kind == "dense":
        status[(ix % 2 == 0) & (iy % 2 == 0)] = "control"
        return status
    raise OptionError("control", kind, (), f"unknown control configuration '{kind}'")


def _plant(r, rng, images, pid, obs_i, obs_p, xy, ref, status, sigma, sh, sv, cam, B, out):
    """Add the recipe's errors to the observations; append their records to ``out``."""
    b_img = B * cam.c / r["flying_height"]
    used_points = set()
    track = {p: np.flatnonzero(obs_p == p) for p in range(len(pid))}
    strip = np.array([im.strip for im in images])
    image_ids = [im.id for im in images]
    for spec in r["errors"]:
        spec = dict(spec)
        kind = spec.pop("kind")
        for key in ("point", "image", "strip"):          # ids are text, as the readers keep them
            if key in spec and spec[key] is not None:
                spec[key] = str(spec[key])
        if "point" in spec and spec["point"] not in pid:
            raise OptionError("point", spec["point"], (), f"error {kind}: no point {spec['point']!r} in the block")
        if "image" in spec and spec["image"] not in image_ids:
            raise OptionError("image", spec["image"], (), f"error {kind}: no image {spec['image']!r} in the block")

        def size_of(sig):
            if "size_base" in spec:
                return spec["size_base"] * b_img if kind != "control" else spec["size_base"] * B
            return spec.get("size", 20.0) * sig

        def refuse(why):
            raise OptionError("errors", kind, (), f"cannot plant the {kind} error: {why}")

        def pick_point(candidates):
            cand = [p for p in candidates if p not in used_points]
            if "point" in spec:
                if spec["point"] not in pid:
                    refuse(f"no point {spec['point']!r} in the block")
                p = pid.index(spec["point"])
            elif not cand:
                refuse("no point left for it (the block is too small for the errors asked)")
            else:
                p = int(rng.choice(cand))
            used_points.add(p)
            return p

        def measurement(p, image=None):
            ks = track[p]
            if image is not None:
                ks = [k for k in ks if images[obs_i[k]].id == image]
                if not ks:
                    refuse(f"point {pid[p]} is not measured in image {image!r}")
            return int(ks[0] if image is not None else rng.choice(ks))

        ties = [p for p in range(len(pid)) if status[p] == "tie"]
        if kind == "image":
            p = pick_point(ties)
            k = measurement(p, spec.get("image"))
            comp = spec.get("component") or str(rng.choice(["x", "y"]))
            val = size_of(sigma) * (spec.get("sign") or rng.choice([-1.0, 1.0]))
            xy[k, "xy".index(comp)] += val
            vec = [float(val)]
            ids = {"image": images[obs_i[k]].id, "point": pid[p], "component": comp}
            ks, sz = [k], float(abs(val))
        elif kind in ("image-point", "misidentification"):
            p = pick_point(ties)
            k = measurement(p, spec.get("image"))
            t = rng.uniform(0, 2 * np.pi) if "direction" not in spec else np.radians(spec["direction"])
            sz = size_of(sigma)
            d = sz * np.array([np.cos(t), np.sin(t)])
            xy[k] += d
            vec = d.tolist()
            ids = {"image": images[obs_i[k]].id, "point": pid[p]}
            ks = [k]
        elif kind == "transfer":
            nimg = int(spec.get("images", 3))
            cands = []
            for p in ties:
                strips = strip[obs_i[track[p]]]
                for s in set(strips):
                    if (strips == s).sum() >= nimg and len(set(strips)) >= 2:
                        cands.append(p)
                        break
            p = pick_point(cands)
            strips = strip[obs_i[track[p]]]
            s = spec.get("strip") or next((s for s in sorted(set(strips)) if (strips == s).sum() >= nimg), None)
            if s is None:
                refuse(f"point {pid[p]} is not measured {nimg} times in one strip")
            ks = sorted(track[p][strips == s], key=lambda k: images[obs_i[k]].id)[:nimg]
            if not ks:
                refuse(f"point {pid[p]} is not measured in strip {s!r}")
            t = rng.uniform(0, 2 * np.pi) if "direction" not in spec else np.radians(spec["direction"])
            sz = size_of(sigma)
            d = sz * np.array([np.cos(t), np.sin(t)])
            xy[ks] += d
            vec = d.tolist()
            ids = {"point": pid[p], "images": [images[obs_i[k]].id for k in ks]}
        elif kind == "exchange":
            k_img = int(rng.integers(len(images))) if "image" not in spec else \
                next((i for i, im in enumerate(images) if im.id == spec["image"]), None)
            if k_img is None:
                refuse(f"no image {spec['image']!r} in the block")
            ks_img = np.flatnonzero(obs_i == k_img)
            ks_img = [k for k in ks_img if obs_p[k] not in used_points and status[obs_p[k]] == "tie"]
            if len(ks_img) < 2:
                refuse(f"image {images[k_img].id} has fewer than two tie points left to exchange")
            a = ks_img[int(rng.integers(len(ks_img)))]
            dist = np.linalg.norm(xy[ks_img] - xy[a], axis=1)
            dist[ks_img.index(a)] = np.inf
            b = ks_img[int(np.argmin(dist))]
            xy[[a, b]] = xy[[b, a]]
            used_points.update([int(obs_p[a]), int(obs_p[b])])
            d = xy[a] - xy[b]
            vec = [1.0]
            sz = float(np.linalg.norm(d))
            ids = {"image": images[k_img].id, "point_a": pid[obs_p[a]], "point_b": pid[obs_p[b]]}
            ks = [a, b]
        elif kind == "control":
            ctrl = [p for p in range(len(pid)) if status[p] == "control"]
            p = pick_point(ctrl)
            axis = spec.get("axis") or str(rng.choice(["x", "y", "z"]))
            sig = sv if axis == "z" else sh
            val = float(size_of(sig) * (spec.get("sign") or rng.choice([-1.0, 1.0])))
            ref[p, "xyz".index(axis)] += val
            out.append({"kind": "control", "ids": {"id": pid[p], "axis": axis}, "vector": [val], "unit": "m",
                        "size_sigma": float(abs(val) / sig), "size_base": float(abs(val) / B),
                        "class": error_class(abs(val) / sig, abs(val) / B), "_k": None})
            continue
        else:
            raise OptionError("errors.kind", kind, (), f"unknown error kind '{kind}'")
        out.append({"kind": kind, "ids": ids, "vector": vec, "unit": cam.unit,
                    "size_sigma": float(sz / sigma), "size_base": float(sz / b_img),
                    "class": error_class(sz / sigma, sz / b_img), "_k": [int(k) for k in ks]})
    return xy, ref


def _rows(e, inv, block) -> list[int]:
    """Problem rows of a planted error (layout of :func:`baarda.model.bundle.build_block_problem`)."""
    if e["kind"] == "control":
        row = 2 * block.obs.size
        for p in block.points:
            if p.status != "control":
                continue
            for a in "xyz":
                if a not in p.axes:
                    continue
                if p.id == e["ids"]["id"] and a == e["ids"]["axis"]:
                    return [row]
                row += 1
        return []
    rows = []
    for k in e["_k"]:
        j = int(inv[k])
        if e["kind"] == "image":
            rows.append(2 * j + "xy".index(e["ids"]["component"]))
        else:
            rows += [2 * j, 2 * j + 1]
    return rows


def simulate_to_files(recipe: dict, out_path, truth_path=None) -> tuple[Block, dict]:
    """Simulate a block from ``recipe`` and write it (native format) and its truth (JSON)."""
    block, truth = simulate_block(**recipe)
    write_native(block, out_path)
    if block.gnss is not None:                  # the native format has no GNSS: a file beside it
        write_text(gnss_path(out_path), simulate_gnss.gnss_csv(block.gnss))
        truth["gnss_file"] = gnss_path(out_path).name
    if block.imu is not None:
        write_text(gnss_path(out_path, ".imu.csv"), simulate_gnss.imu_csv(block.imu))
        truth["imu_file"] = gnss_path(out_path, ".imu.csv").name
    if truth_path is not None:
        write_text(truth_path, json.dumps(truth, indent=1, default=_json_default) + "\n")
    return block, truth


def gnss_path(out_path, ending: str = ".gnss.csv") -> Path:
    """The GNSS (or IMU, ``ending`` ".imu.csv") file written beside a simulated block
    ``OUT.json``: ``OUT.gnss.csv``."""
    p = Path(out_path)
    return p.with_name((p.name[:-len(p.suffix)] if p.suffix else p.name) + ending)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def simulate_imodel(strips: int = 2, models_per_strip: int = 5, base: float = 920.0,
                    strip_distance: float = 1700.0, model_scale: float = 0.102, sigma_model: float = 0.01,
                    sigma_control: float = 0.05, control: str = "perimeter", errors=(), design: bool = False,
                    datum: str = "control", seed: int = 0, title: str = ""):
    """A planimetric independent-model block (:mod:`baarda.model.imodel`) and its truth.

    Model j of strip i covers the overlap of images j and j + 1: six points in the von Gruber
    positions X = jB, (j + 1)B, Y = iA + (−A/2, 0, A/2) (base B and strip distance A in m);
    neighbouring models share three points, neighbouring strips two. Model coordinates (mm at
    photo scale, ``model_scale`` mm per m) in a random rotation and shift, σ ``sigma_model``
    (mm). Control: "corners" or "perimeter" (every other point on the block edge). Errors:
    [{"kind": "model-point", "size": σ-multiple}, {"kind": "control", "size": ..., "axis"}].
    """
    rng = np.random.default_rng(seed)
    xs = np.arange(models_per_strip + 1) * base
    ys = np.arange(-1, 2 * strips) * strip_distance / 2
    pts = {(ix, iy): (X, Y) for iy, Y in enumerate(ys) for ix, X in enumerate(xs)}
    ids = {k: f"Q{k[1]:02d}{k[0]:03d}" for k in pts}
    models, mo_i, mo_p, xy, truth_models = [], [], [], [], {}
    keys = sorted(pts, key=lambda k: (k[1], k[0]))
    kindex = {k: i for i, k in enumerate(keys)}
    for i in range(strips):
        for j in range(models_per_strip):
            th = rng.uniform(-np.pi, np.pi)
            a, b = model_scale * np.cos(th), model_scale * np.sin(th)
            c, d = rng.uniform(-50, 50, 2)
            mid = f"M{i + 1}{j + 1:02d}"
            truth_models[mid] = [a, b, c, d]
            e = np.zeros(4) if design else rng.normal(0, 1e-3, 4) * np.array([model_scale, model_scale, 1, 1])
            models.append(Model(mid, a + e[0], b + e[1], c + e[2], d + e[3], strip=str(i + 1)))
            for ix in (j, j + 1):
                for iy in (2 * i, 2 * i + 1, 2 * i + 2):
                    X, Y = pts[(ix, iy)]
                    mo_i.append(len(models) - 1)
                    mo_p.append(kindex[(ix, iy)])
                    xy.append([a * X - b * Y + c, b * X + a * Y + d])
    xy = np.array(xy)
    m = len(xy)
    if not design:
        xy = xy + rng.normal(0, sigma_model, xy.shape)
    ix_all = np.array([k[0] for k in keys])
    iy_all = np.array([k[1] for k in keys])
    edge = (ix_all == 0) | (ix_all == xs.size - 1) | (iy_all == 0) | (iy_all == ys.size - 1)
    if control == "corners":
        ctrl = ((ix_all == 0) | (ix_all == xs.size - 1)) & ((iy_all == 0) | (iy_all == ys.size - 1))
    else:
        ctrl = edge & ((ix_all + iy_all) % 2 == 0)
    P = np.array([pts[k] for k in keys])
    ref = P.copy()
    if not design:
        ref[ctrl] += rng.normal(0, sigma_control, (int(ctrl.sum()), 2))
    truth_errors = []
    mo_i, mo_p = np.array(mo_i), np.array(mo_p)
    for spec in errors:
        spec = dict(spec)
        if spec["kind"] == "model-point":
            k = int(rng.integers(m))
            t = rng.uniform(0, 2 * np.pi)
            dv = spec.get("size", 20.0) * sigma_model * np.array([np.cos(t), np.sin(t)])
            xy[k] += dv
            truth_errors.append({"kind": "model-point", "ids": {"model": models[mo_i[k]].id,
                                 "point": ids[keys[mo_p[k]]]}, "rows": [2 * k, 2 * k + 1],
                                 "vector": dv.tolist(), "unit": "mm", "size_sigma": float(spec.get("size", 20.0)),
                                 "class": error_class(float(spec.get("size", 20.0)), 0.0)})
        elif spec["kind"] == "control":
            p = int(rng.choice(np.flatnonzero(ctrl)))
            axis = spec.get("axis", "x")
            val = spec.get("size", 20.0) * sigma_control
            ref[p, "xy".index(axis)] += val
            row = 2 * m + 2 * int(ctrl[:p].sum()) + "xy".index(axis)
            truth_errors.append({"kind": "control", "ids": {"id": ids[keys[p]], "axis": axis}, "rows": [row],
                                 "vector": [val], "unit": "m", "size_sigma": float(spec.get("size", 20.0)),
                                 "class": error_class(float(spec.get("size", 20.0)), 0.0)})
        else:
            raise OptionError("errors.kind", spec["kind"], (), f"unknown error kind '{spec['kind']}'")
    approx = P + (0 if design else rng.normal(0, 0.5, P.shape))
    points = tuple(PlanPoint(ids[k], float(approx[i, 0]), float(approx[i, 1]),
                             "control" if ctrl[i] else "tie",
                             (float(ref[i, 0]), float(ref[i, 1])) if ctrl[i] else None,
                             sigma_control if ctrl[i] else 0.0) for i, k in enumerate(keys))
    obs = ModelObservations(mo_i, mo_p, xy, np.repeat((sigma_model ** 2 * np.eye(2))[None], m, 0),
                            np.zeros(m, dtype=np.int64))
    block = IModelBlock(tuple(models), points, obs, unit="mm", datum=datum,
                        title=title or f"independent-model block {strips} × {models_per_strip}")
    truth = {"format": "baarda-truth", "version": 1, "kind": "imodel", "errors": truth_errors,
             "points": {ids[k]: list(pts[k]) for k in keys}, "models": truth_models, "seed": seed}
    return block, truth
