"""Hypothesis specifications of the dashboard and their translation to the core's tests.

A specification is a plain dict, ``{"kind": ..., "active": bool, "label": str, ...}``:

- ``{"kind": "observation", "index": i}`` — one observation (q = 1, T = w²);
- ``{"kind": "group", "group": g}`` — a test group of the problem (GNSS vector, image point);
- ``{"kind": "image-point", "image": j, "point": p[, "keypoint": k]}`` — both coordinates of one
  image point (``keypoint`` tells apart several keypoints of one image on one COLMAP point);
- ``{"kind": "control", "point": p}`` — every observation of a control (weighted) point;
- ``{"kind": "transfer", "point": p, "images": [j1, j2, ...]}`` — one 2D point-transfer error
  common to the image coordinates of point p in the images listed (F80 §2.2, H = (0 … I₂ … I₂ … 0)ᵀ);
- ``{"kind": "ap-group", "camera": c, "group": g}`` — a group of additional parameters of a
  block's camera: tested by :func:`baarda.stats.ap_tests.ap_test` when the group is estimated
  (``problem.notes.ap_groups``), otherwise as the hypothesis H = ∂f/∂s of
  :func:`baarda.stats.hypotheses.h_ap_group` (F80 §7.2).

Observation indices are those of the full problem as read; ``kept`` maps each observation of the
reduced (adjusted) problem to its full index, ``index`` is the problem's
:func:`baarda.dashboard.geometry.problem_index`.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from baarda.errors import BaardaError
from baarda.stats.ap_tests import ap_test
from baarda.stats.hypotheses import common_error, external_reliability, h_ap_group, hypothesis_rows, selection

from .geometry import observation_label, reduced_index
from .outcomes import Outcome


def rows(problem, spec: dict, index: dict) -> list[np.ndarray]:
    """The full observation indices a hypothesis acts on, one array per component of ∇s for a
    common error (point transfer), else one array of independently tested rows — the core's
    :func:`baarda.stats.hypotheses.hypothesis_rows` (``baarda test`` uses the same) over the
    problem's image-point index."""
    return hypothesis_rows(problem, spec, index=index["image_rows"])


def ap_estimated(problem, spec: dict) -> bool:
    """True if the AP group of an ``ap-group`` hypothesis is estimated in the model."""
    return f"{spec['camera']}:{spec['group']}" in problem.notes.ap_groups


def matrix(problem, adj, kept, spec: dict, index: dict):
    """H (reduced n × q) of a hypothesis for the adjustment ``adj`` of the reduced problem;
    excluded observations drop out."""
    full_rows = rows(problem, spec, index)
    n = adj.n
    red = [reduced_index(kept, problem.n, r) for r in full_rows]
    red = [r[r >= 0] for r in red]
    if not any(r.size for r in red):
        raise ValueError("no (included) observations")
    if spec["kind"] == "transfer":
        return common_error(n, [r for r in red if r.size])
    if spec["kind"] == "ap-group":
        # ∂f/∂s of the full problem at the current solution, cut to the observations kept
        # (the core's builder reads the collinearity sets, which exclusion wraps)
        full = SimpleNamespace(problem=problem, x=adj.x, n=problem.n)
        return h_ap_group(full, str(spec["camera"]), str(spec["group"])).tocsr()[kept].tocsc()
    return selection(n, red[0])


def evaluate(problem, adj, rel, kept, spec: dict, index: dict) -> Outcome:
    """The core's test of one hypothesis as an :class:`~baarda.dashboard.outcomes.Outcome`: a
    :class:`~baarda.stats.hypotheses.HypothesisTest` (with δ̄0(s) at its maximum, F80 eq. 17,
    in ``external``) or an :class:`~baarda.stats.ap_tests.APTest` of an estimated AP group;
    "inactive" if the hypothesis is switched off or there is no adjustment; "refused" with the
    core's message."""
    label = spec.get("label", "")
    if not spec.get("active", True) or adj is None:
        return Outcome("inactive", label)
    policy = rel.policy
    try:
        if spec["kind"] == "ap-group" and ap_estimated(problem, spec):
            return Outcome("ap-test", label, ap=ap_test(adj, str(spec["camera"]), str(spec["group"]), policy=policy),
                           policy=policy)
        H = matrix(problem, adj, kept, spec, index)
        h = rel.test(H, label=label)
        # δ̄0(s) at its maximum (F80 eq. 17), shown beside δ0′max
        ext = external_reliability(adj, h) if h.q else None
        return Outcome("test", label, test=h, external=ext, policy=policy)
    except (ValueError, KeyError, BaardaError, np.linalg.LinAlgError) as err:
        return Outcome("refused", label, message=f"{label}: {err}", policy=policy)


def key(spec: dict) -> tuple:
    """What a hypothesis' test depends on in its specification (not ``active`` or ``label``)."""
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in spec.items()
                        if k not in ("active", "label")))


def describe(problem, spec: dict, index: dict) -> str:
    """A hypothesis' default label: ``obs 12 direction A→B``, ``control point P7``…"""
    kind = spec["kind"]
    if kind == "observation":
        return "obs " + observation_label(problem, int(spec["index"]))
    if kind == "group":
        r = rows(problem, spec, index)[0]
        first = observation_label(problem, int(r[0])).split(" ", 2)[-1] if r.size else ""
        return f"group {spec['group']} ({first})"
    if kind == "image-point":
        kp = f" (keypoint {spec['keypoint']})" if spec.get("keypoint") is not None else ""
        return f"image point {spec['point']} in image {spec['image']}{kp}"
    if kind == "control":
        return f"control point {spec['point']}"
    if kind == "transfer":
        return f"transfer of {spec['point']} in images {', '.join(map(str, spec['images']))}"
    if kind == "ap-group":
        how = "estimated" if ap_estimated(problem, spec) else "not in the model"
        return f"AP group {spec['group']} of camera {spec['camera']} ({how})"
    return str(spec)


def point(problem, spec: dict, index: dict):
    """The point index a hypothesis is about (for drawing its ellipse on the map), or None."""
    pid = spec.get("point")
    if spec["kind"] == "ap-group":
        return None
    if pid is None and spec["kind"] in ("observation", "group"):
        r = rows(problem, spec, index)[0]
        pts = index["obs_points"][int(r[0])] if r.size else []
        return pts[-1] if pts else None
    if pid is None:
        return None
    return index["point_index"].get(str(pid))
