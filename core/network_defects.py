"""Local defects of a geodetic network: the coordinates its observations do not determine.

:func:`build_network` names and sets aside the coordinates no observation involves or that have
no approximate value before the problem is built; :func:`adjust_network` is the safety net for
those only the singular normal equations show (the block counterpart is :mod:`baarda.sfm_defects`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .approx import approximate_coordinates
from .defects import LocalDefect, adjust_setting_aside
from .model.network import Network
from .model.problem import Problem
from .model.network_problem import AXES, NEEDS, build_problem, point_axes


def build_network(net: Network, strict: bool = False) -> Problem:
    """The adjustment problem of a network, its local defects named and set aside.

    Missing approximate coordinates are computed first (:mod:`baarda.approx`). A *local
    defect* is an adjusted coordinate the observations do not determine on their own:

    - one that no observation involves (a traverse point declared ``adj="xyz"`` without any
      height difference, zenith angle, slope distance, vector or observed height), or
    - one for which no approximate value can be computed (not connected to points of known
      position or height).

    Each is named as a :class:`baarda.defects.LocalDefect` in
    ``problem.notes.local_defects``; the point is adjusted in the components that are
    determined (as gama-local does for points without height information), or left out when
    none is, with the observations that need an undetermined coordinate (their lines are
    named). ``strict`` keeps the former behaviour: an :class:`~baarda.errors.InputError` for a
    coordinate without an approximate value, and the datum-defect diagnosis of the adjustment
    for one no observation involves. A defect of the whole network (its datum) is diagnosed by
    the adjustment as before.
    """
    net = set_aside_heightless(net)
    if any(getattr(p, a) is None for p in net.points for a in "xyz"
           if a in (p.adjusted + p.constrained).lower()):
        net = approximate_coordinates(net, missing="error" if strict else "keep")
    if strict:
        return build_problem(net)
    net, defects = _set_aside_local_defects(net)
    problem = build_problem(net)
    # the network kept for adjust_network's safety net
    return problem.with_notes(network_model=net, local_defects=(*problem.notes.local_defects, *defects))


#: what the observations that need heights are called in the note of set_aside_heightless
_HEIGHT_KINDS = {"zenith-angle": "zenith angle", "slope-distance": "slope distance",
                 "height-diff": "height difference", "coordinate-z": "observed height"}


def set_aside_heightless(net: Network) -> Network:
    """The network without the observations that need a height no point can have, as gama-local
    reads a 2-D network.

    A point with no z coordinate whose z is neither adjusted nor constrained (``adj="xy"``
    without a height) can get no height: gama-local's revision of the observations makes every
    observation that needs its z passive — zenith angles, slope distances, height differences
    (GNU Gama, ``LocalNetwork::revision_observations``; a 2-D survey observed with directions,
    horizontal distances and zenith angles per set is adjusted from its directions and distances
    alone). baarda does the same and says so: ``net.extra["reader_notes"]`` gets one line (the
    counts by kind, the points, the first lines), which ``baarda analyze`` prints as a warning;
    ``net.extra["set_aside"]`` lists them (line, kind, points). Vectors (Δx, Δy, Δz together)
    are left to the usual checks. Returns ``net`` itself when nothing is set aside.
    """
    no_z = {p.id for p in net.points if p.z is None and "z" not in (p.adjusted + p.constrained).lower()}
    if not no_z:
        return net
    keep, gone = [], []
    for o in net.observations:
        drop = o.kind in _HEIGHT_KINDS and any(pid in no_z for pid in o.points)
        keep.append(not drop)
        if drop:
            gone.append(o)
    if not gone:
        return net
    counts: dict[str, int] = {}
    for o in gone:
        counts[o.kind] = counts.get(o.kind, 0) + 1
    pts = sorted({pid for o in gone for pid in o.points if pid in no_z})
    lines = sorted({o.line for o in gone})
    what = ", ".join(f"{n} {_HEIGHT_KINDS[k]}{'s' if n > 1 else ''}" for k, n in counts.items())
    note = (f"{what} set aside, as gama-local does: they need heights that point(s) "
            f"{', '.join(pts[:10])}{' ...' if len(pts) > 10 else ''} do not have (no z, not adjusted in z); "
            f"the network is adjusted from its other observations (line(s) "
            f"{', '.join(map(str, lines[:10]))}{' ...' if len(lines) > 10 else ''})")
    extra = dict(net.extra)
    extra["reader_notes"] = list(extra.get("reader_notes", ())) + [note]
    extra["set_aside"] = [{"line": o.line, "kind": o.kind, "points": list(o.points)} for o in gone]
    return _keep_observations(replace(net, extra=extra), keep)


#: rounds of the safety net in :func:`adjust_network`
MAX_ROUNDS = 5


def adjust_network(problem: Problem, options=None, progress=None, strict: bool = False):
    """Adjust a network from :func:`build_network`; ``(adjustment, problem adjusted)``.

    Safety net for local defects the structural checks of :func:`build_network` cannot see:
    when the normal equations turn out singular in the coordinates of a few points (a point
    with approximate coordinates observed by a single direction, say), those coordinates are
    named as local defects, set aside with the observations that need them, and the network
    is adjusted again. A defect of the whole network (its datum), one involving other
    unknowns (orientations), or any defect with ``strict`` raises
    :class:`~baarda.errors.DatumDefectError` as :func:`baarda.adjust.adjust` does.
    """
    return adjust_setting_aside(problem, options, progress, MAX_ROUNDS,
                                lambda problem, err, first: _set_aside(problem, err, first, strict))


def _set_aside(problem: Problem, err, first, strict: bool) -> Problem:
    """The network's problem without the coordinates ``err`` names (:func:`adjust_network`)."""
    net = problem.notes.network_model
    if (net is None or strict or not err.local
            or problem.notes.kept_rows is not None or len(net.observations) != problem.n):
        raise first from None   # (a subset of the network's problem: not rebuilt from it)
    ids = {p.id for p in net.points}
    named: dict[str, set] = {}
    for label in err.undetermined:
        pid, _, a = label.rpartition(".")
        if pid not in ids or a not in AXES:
            raise first from None
        named.setdefault(pid, set()).add(a)
    if not named or len(named) > max(3, len(net.points) // 4):
        raise first from None
    keep = [not any(pid in named and set(NEEDS[o.kind]) & named[pid] for pid in o.points)
            for o in net.observations]
    lines = {pid: sorted({o.line for o, k in zip(net.observations, keep) if not k
                          and pid in o.points}) for pid in named}
    points = []
    for p in net.points:
        if p.id in named:
            gone = named[p.id]
            p = replace(p, adjusted="".join(a for a in p.adjusted if a.lower() not in gone),
                        constrained="".join(a for a in p.constrained if a.lower() not in gone))
        points.append(p)
    found = []
    for p in points:
        if p.id not in named:
            continue
        left = "".join(a for a in "xyz" if a in (p.adjusted + p.constrained).lower())
        action = f"adjusted in {', '.join(left)}" if left else "left out"
        if lines[p.id]:
            action += (f", with {len(lines[p.id])} observation(s) left out (line(s) "
                       f"{', '.join(map(str, lines[p.id][:20]))})")
        found.append(LocalDefect("point", p.id, tuple(a for a in "xyz" if a in named[p.id]),
                                 "the adjustment finds it undetermined (singular normal "
                                 "equations: too few observations to it)", action))
    old = problem.notes.local_defects
    problem = build_network(_keep_observations(replace(net, points=tuple(points)), keep))
    return problem.with_notes(local_defects=(*old, *found, *problem.notes.local_defects))


def _set_aside_local_defects(net: Network):
    """``(network, defects)``: undetermined adjusted coordinates removed (see :func:`build_network`)."""
    reasons = dict(net.extra.get("approx_missing", {}))
    found: dict[str, dict] = {}   # id -> {"axes": set, "why": [..], "lines": [..]}
    while True:
        touched = point_axes(net)
        bad: dict[str, set] = {}
        for p, used in zip(net.points, touched):
            for a in sorted(set((p.adjusted + p.constrained).lower())):
                if a not in used:
                    why = ("no observation involves its height (no height difference, zenith angle, "
                           "slope distance, vector or observed height)" if a == "z" else
                           "no observation involves its position")
                elif getattr(p, a) is None:
                    why = reasons.get(p.id, ("", "no approximate coordinates could be computed"))[1]
                else:
                    continue
                bad.setdefault(p.id, set()).add(a)
                rec = found.setdefault(p.id, {"axes": set(), "why": [], "lines": []})
                rec["axes"].add(a)
                if why not in rec["why"]:
                    rec["why"].append(why)
        if not bad:
            break
        # observations that need a coordinate set aside (only those without a value can be
        # needed: a coordinate no observation involves is needed by none)
        keep = []
        for o in net.observations:
            drop = [pid for pid in o.points if pid in bad and set(NEEDS[o.kind]) & bad[pid]]
            keep.append(not drop)
            for pid in dict.fromkeys(drop):
                found[pid]["lines"].append(o.line)
        points = []
        for p in net.points:
            if p.id in bad:
                gone = bad[p.id]
                p = replace(p, adjusted="".join(a for a in p.adjusted if a.lower() not in gone),
                            constrained="".join(a for a in p.constrained if a.lower() not in gone))
            points.append(p)
        net = _keep_observations(replace(net, points=tuple(points)), keep)
    defects = []
    for p in net.points:
        if p.id not in found:
            continue
        rec = found[p.id]
        left = "".join(a for a in "xyz" if a in (p.adjusted + p.constrained).lower())
        lines = sorted(set(rec["lines"]))
        action = f"adjusted in {', '.join(left)}" if left else "left out"
        if lines:
            action += (f", with {len(lines)} observation(s) left out (line(s) "
                       f"{', '.join(map(str, lines[:20]))}{' ...' if len(lines) > 20 else ''})")
        defects.append(LocalDefect("point", p.id, tuple(a for a in "xyz" if a in rec["axes"]),
                                   "; ".join(rec["why"]), action))
    return net, defects


def _keep_observations(net: Network, keep) -> Network:
    """The network without the observations whose ``keep`` is False (clusters cut to match)."""
    if all(keep):
        return net
    new_index = {}
    for i, k in enumerate(keep):
        if k:
            new_index[i] = len(new_index)
    obs = tuple(o for o, k in zip(net.observations, keep) if k)
    clusters = []
    for c in net.clusters:
        kept = [j for j, i in enumerate(c.indices) if keep[i]]
        if kept:
            clusters.append(replace(c, indices=tuple(new_index[c.indices[j]] for j in kept),
                                    cov=c.cov[np.ix_(kept, kept)]))
    return replace(net, observations=obs, clusters=tuple(clusters))
