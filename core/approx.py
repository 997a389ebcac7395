"""Approximate coordinates for the points of a :class:`~baarda.model.network.Network` lacking them.

gama-local computes missing approximate coordinates itself before adjusting; baarda does the
same here so that Gauss-Newton starts close enough to converge. The methods are the classical
ones of surveying computations (e.g. Ghilani, *Adjustment Computations*, ch. 11-15; GNU Gama's
``acord`` module follows the same ideas):

- heights: from observed coordinates, height differences, vector components, and from zenith
  angles with a horizontal distance (reduced with the instrument/target heights);
- plan: from observed coordinates and vectors; *bearings* are propagated through oriented
  direction sets (orientation from any known bearing of the set), azimuths, angles
  (bearing(from→right) = bearing(from→left) + angle) and back-bearings (+π); a point is then
  located by the polar method (bearing + distance), forward intersection of rays from two or
  more known stations, or a small least-squares fit of every constraint touching it
  (trilateration, resection with an unknown orientation, angles at the point), solved from
  several starting points and accepted only when its solution is unique;
- everything is iterated until no further point can be determined.

Coordinates already given in the network are never changed. Bearings follow the network's
convention ``bearing = angle_sign·atan2(Δy, Δx) + azimuth_offset`` (see
:mod:`baarda.model.network`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import replace

import numpy as np
from .lazy import lazy
from baarda.errors import InputError, OptionError
from baarda.model.network import Network

optimize = lazy("scipy.optimize")        # imported when first used (start-up)

__all__ = ["approximate_coordinates"]

TWO_PI = 2.0 * math.pi


def _wrap(a: float) -> float:
    """Angle reduced to (−π, π]."""
    return math.remainder(a, TWO_PI)


def _circular_mean(angles) -> float:
    angles = list(angles)
    return math.atan2(sum(math.sin(a) for a in angles), sum(math.cos(a) for a in angles))


def _median(values) -> float:
    """Median of a short list, the same number as ``np.median`` (mean of the middle two)."""
    v = sorted(values)
    n = len(v)
    return float(v[n // 2]) if n % 2 else float((v[n // 2 - 1] + v[n // 2]) / 2.0)


def _median_point(cands):
    arr = np.asarray(cands, dtype=float)
    return tuple(np.median(arr, axis=0))


class _Approx:
    """Working state: known coordinates and the observations in convenient tables."""

    def __init__(self, net: Network):
        self.net = net
        self.sign, self.offset = net.angle_sign, net.azimuth_offset
        self.xy: dict[str, tuple[float, float]] = {}
        self.z: dict[str, float] = {}
        for p in net.points:
            if p.x is not None and p.y is not None:
                self.xy[p.id] = (p.x, p.y)
            if p.z is not None:
                self.z[p.id] = p.z
        self.given_xy, self.given_z = set(self.xy), set(self.z)
        self.tables()

    # -- observation tables -----------------------------------------------------------
    def tables(self):
        self.sets = defaultdict(list)  # set_id -> [(station, target, direction)]
        self.azimuths, self.angles, self.hdist = [], [], []
        self.sdist, self.zenith, self.dh = [], [], []
        self.vec = defaultdict(dict)  # group key -> {"from", "to", "dx", ...}
        self.cobs = defaultdict(lambda: defaultdict(list))  # id -> axis -> [values]
        for k, o in enumerate(self.net.observations):
            p = o.points
            if o.kind == "direction":
                self.sets[o.set_id].append((p[0], p[1], o.value))
            elif o.kind == "azimuth":
                self.azimuths.append((p[0], p[1], o.value))
            elif o.kind == "angle":
                self.angles.append((p[0], p[1], p[2], o.value))
            elif o.kind == "distance":
                self.hdist.append((p[0], p[1], o.value))
            elif o.kind == "slope-distance":
                self.sdist.append((p[0], p[1], o.value, o.from_dh, o.to_dh))
            elif o.kind == "zenith-angle":
                self.zenith.append((p[0], p[1], o.value, o.from_dh, o.to_dh))
            elif o.kind == "height-diff":
                self.dh.append((p[0], p[1], o.value))
            elif o.kind in ("dx", "dy", "dz"):
                v = self.vec[o.group_key or f"#{k}"]
                v["from"], v["to"] = p
                v[o.kind[1]] = o.value
                if o.kind == "dz":  # Δz between the marks (the vector joins the antennas)
                    v["z"] = o.value - o.to_dh + o.from_dh
            elif o.kind.startswith("coordinate-"):
                self.cobs[p[0]][o.kind[-1]].append(o.value)

    # -- geometry helpers ---------------------------------------------------------------
    def bearing_xy(self, a, b) -> float:
        (xa, ya), (xb, yb) = self.xy[a], self.xy[b]
        return self.sign * math.atan2(yb - ya, xb - xa) + self.offset

    def polar(self, a, beta, d):
        """Point at horizontal distance ``d`` and bearing ``beta`` from known point ``a``."""
        phi = self.sign * (beta - self.offset)
        xa, ya = self.xy[a]
        return xa + d * math.cos(phi), ya + d * math.sin(phi)

    def horizontal_distances(self) -> dict:
        """Horizontal distances between point pairs (frozenset) from all distance-like data.

        They depend on the known heights only (slope distances without a zenith angle are
        reduced with them), so the table is kept until a height is added.
        """
        key = len(self.z)
        cached = getattr(self, "_hd_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        out = defaultdict(list)
        for a, b, d in self.hdist:
            out[frozenset((a, b))].append(d)
        zen = defaultdict(list)
        for a, b, zz, _, _ in self.zenith:
            zen[frozenset((a, b))].append(zz)
        for a, b, s, fdh, tdh in self.sdist:
            key = frozenset((a, b))
            if zen.get(key):
                out[key].append(s * abs(math.sin(zen[key][0])))
            elif a in self.z and b in self.z:
                dz = self.z[b] + tdh - self.z[a] - fdh
                out[key].append(math.sqrt(max(s * s - dz * dz, 0.0)))
            elif key not in out:
                out[key].append(s)  # crude: better than nothing for flat networks
        hd = {k: _median(v) for k, v in out.items()}
        self._hd_cache = (key, hd)
        return hd

    # -- heights ---------------------------------------------------------------------------
    def heights_sweep(self) -> bool:
        cand = defaultdict(list)
        for pid, axes in self.cobs.items():
            if "z" in axes and pid not in self.z:
                cand[pid].extend(axes["z"])
        for a, b, d in self.dh:
            self._pair(cand, a, b, d)
        for v in self.vec.values():
            if "z" in v:
                self._pair(cand, v["from"], v["to"], v["z"])
        hd = self.horizontal_distances()
        for a, b, zz, fdh, tdh in self.zenith:
            key = frozenset((a, b))
            if a in self.xy and b in self.xy:
                h = math.dist(self.xy[a], self.xy[b])
            elif key in hd:
                h = hd[key]
            else:
                continue
            if abs(math.sin(zz)) < 1e-9:
                continue
            self._pair(cand, a, b, h * math.cos(zz) / math.sin(zz) + fdh - tdh)
        for pid, vals in cand.items():
            self.z[pid] = float(np.median(vals))
        return bool(cand)

    def _pair(self, cand, a, b, diff):
        """Candidate heights from ``z_b − z_a = diff``."""
        if a in self.z and b not in self.z:
            cand[b].append(self.z[a] + diff)
        elif b in self.z and a not in self.z:
            cand[a].append(self.z[b] - diff)

    # -- bearings ------------------------------------------------------------------------
    def bearing_index(self):
        """Which direction sets and angles each (from, to) pair enters, and each point's pairs.

        Built once: :meth:`bearings` and :meth:`extend_bearings` then touch only the sets and
        angles a new bearing can orient or carry, not the whole network.
        """
        self.set_rank = {sid: k for k, sid in enumerate(self.sets)}
        self.pair_sets = defaultdict(list)
        for sid, dirs in self.sets.items():
            for a, b, _ in dirs:
                for key in ((a, b), (b, a)):
                    if not self.pair_sets[key] or self.pair_sets[key][-1] != sid:
                        self.pair_sets[key].append(sid)
        self.pair_angles = defaultdict(list)
        for k, (f, l, r, _) in enumerate(self.angles):
            for t in (l, r):
                for key in ((f, t), (t, f)):
                    if not self.pair_angles[key] or self.pair_angles[key][-1] != k:
                        self.pair_angles[key].append(k)
        pairs = {(a, b) for st in self.sets.values() for a, b, _ in st}
        pairs |= {(f, t) for f, l, r, _ in self.angles for t in (l, r)}
        pairs |= {(a, b) for a, b, _ in self.hdist}
        self.point_pairs = defaultdict(list)
        for a, b in sorted(pairs):
            self.point_pairs[a].append((a, b))
            self.point_pairs[b].append((a, b))
        self.neighbours = defaultdict(set)  # every pair a bearing or a distance can join
        for tup in (pairs, self.azimuths, self.sdist, self.zenith):
            for t in tup:
                self.neighbours[t[0]].add(t[1])
                self.neighbours[t[1]].add(t[0])
        self.sets_at = defaultdict(list)  # direction sets by standpoint
        for sid, dirs in self.sets.items():
            for a in dict.fromkeys(a for a, _, _ in dirs):
                self.sets_at[a].append(sid)
        self.angles_at = defaultdict(list)
        for f, l, r, al in self.angles:
            self.angles_at[f].append((l, r, al))

    def known_neighbours(self, pid) -> list:
        """Points of known position joined to ``pid`` by a bearing or distance (sorted)."""
        if not hasattr(self, "neighbours"):
            self.bearing_index()
        return sorted(s for s in self.neighbours.get(pid, ()) if s in self.xy)

    @staticmethod
    def _put(B, a, b, beta, depth, src=-1) -> bool:
        if (a, b) not in B:
            B[(a, b)] = (beta, depth, src)
            B[(b, a)] = (beta + math.pi, depth, src)
            return True
        return False

    def _propagate(self, B, orient, level, depth):
        """Carry the bearings ``level`` (pairs new at ``depth``) through sets and angles.

        Breadth-first, one depth per orientation or angle transfer; at each depth only the
        sets and angles that contain a bearing new at that depth are looked at.
        """
        while level:
            sids, angs = set(), set()
            for key in level:
                sids.update(s for s in self.pair_sets.get(key, ()) if s not in orient)
                angs.update(self.pair_angles.get(key, ()))
            new = []
            for sid in sorted(sids, key=self.set_rank.__getitem__):
                dirs = self.sets[sid]
                known = [B[(a, b)][0] - d for a, b, d in dirs
                         if (a, b) in B and B[(a, b)][1] == depth]
                if known:
                    orient[sid] = (_circular_mean(known), depth)
                    new.extend((a, b, orient[sid][0] + d, sid) for a, b, d in dirs)
            for k in sorted(angs):
                f, l, r, alpha = self.angles[k]
                if (f, l) in B and B[(f, l)][1] == depth:
                    new.append((f, r, B[(f, l)][0] + alpha, -1))
                if (f, r) in B and B[(f, r)][1] == depth:
                    new.append((f, l, B[(f, r)][0] - alpha, -1))
            level = []
            for a, b, beta, src in new:
                if self._put(B, a, b, beta, depth + 1, src):
                    level.append((a, b))
            depth += 1

    def bearings(self):
        """Close the bearings known from coordinates, azimuths, oriented sets and angles.

        Returns ``(B, orient)``: ``B[(a, b)] = (bearing a→b, depth, source set or -1)`` and
        ``orient[set_id] = (orientation, depth)``. Bearings are added breadth-first: depth 0
        from coordinates and azimuths, and each orientation or angle transfer adds one, so a
        set is oriented on the shallowest (most direct) bearings available and a bearing
        carried along a long traverse never replaces a direct one.
        """
        if not hasattr(self, "pair_sets"):
            self.bearing_index()
        B: dict = {}
        orient: dict = {}
        level = []
        for a, b, beta in self.azimuths:
            if self._put(B, a, b, beta, 0):
                level.append((a, b))
        done = set()
        for p in self.xy:
            for a, b in self.point_pairs.get(p, ()):
                if (a, b) not in done and a in self.xy and b in self.xy:
                    done.add((a, b))
                    if self._put(B, a, b, self.bearing_xy(a, b), 0):
                        level.append((a, b))
        self._propagate(B, orient, level, 0)
        return B, orient

    def extend_bearings(self, B, orient, pid):
        """Add the bearings that the newly located point ``pid`` makes known (in place).

        The bearings between ``pid`` and the known points enter at depth 0 and are carried
        on as in :meth:`bearings`; bearings already known are kept (so the whole closure is
        not recomputed after every located point, which made large networks slow).
        """
        level = []
        for a, b in self.point_pairs.get(pid, ()):
            if a in self.xy and b in self.xy and self._put(B, a, b, self.bearing_xy(a, b), 0):
                level.append((a, b))
        self._propagate(B, orient, level, 0)

    # -- plan ------------------------------------------------------------------------------
    def plan_sweep(self, wanted: set) -> tuple[bool, dict]:
        """Try to locate every wanted point once; returns (progress, ambiguous reasons)."""
        B, orient = self.bearings()
        hd = self.horizontal_distances()  # depends on heights only, fixed during the sweep
        progress, ambiguous = False, {}
        for pid in sorted(wanted - set(self.xy)):
            pos = self.direct(pid, B, hd)
            if pos is None:
                pos, why = self.fit(pid, B, orient, hd)
                if pos is None:
                    if why:
                        ambiguous[pid] = why
                    continue
            self.xy[pid] = pos
            progress = True
            self.extend_bearings(B, orient, pid)  # new point: new bearings for the next ones
        return progress, ambiguous

    def direct(self, pid, B, hd):
        """Coordinates observed, vectors, or polar from known stations (median of all)."""
        axes = self.cobs.get(pid, {})
        if "x" in axes and "y" in axes:
            return float(np.median(axes["x"])), float(np.median(axes["y"]))
        cands = []
        if not hasattr(self, "vec_at"):
            self.vec_at = defaultdict(list)  # vectors by end point, in file order
            for v in self.vec.values():
                for q in dict.fromkeys((v["from"], v["to"])):
                    self.vec_at[q].append(v)
        for v in self.vec_at.get(pid, ()):
            if "x" in v and "y" in v:
                if v["to"] == pid and v["from"] in self.xy:
                    xa, ya = self.xy[v["from"]]
                    cands.append((xa + v["x"], ya + v["y"]))
                elif v["from"] == pid and v["to"] in self.xy:
                    xb, yb = self.xy[v["to"]]
                    cands.append((xb - v["x"], yb - v["y"]))
        if cands:
            return _median_point(cands)
        polar = [(B[(s, pid)][1], s) for s in self.known_neighbours(pid)
                 if (s, pid) in B and frozenset((s, pid)) in hd]
        if polar:
            dmin = min(d for d, _ in polar)
            cands = [self.polar(s, B[(s, pid)][0], hd[frozenset((s, pid))])
                     for d, s in polar if d == dmin]
        return _median_point(cands) if cands else None

    def constraints(self, pid, B, orient, hd):
        """Equations touching ``pid`` whose other points are known (for :meth:`fit`)."""
        resect = []  # (set index, target, direction) of sets at pid, orientation unknown
        if not hasattr(self, "sets_at"):
            self.bearing_index()
        for sid in self.sets_at.get(pid, ()):
            known = [(b, d) for a, b, d in self.sets[sid] if a == pid and b in self.xy]
            if len(known) >= 2 or (known and sid not in orient):
                resect.extend((sid, b, d) for b, d in known)
        rsets = {sid for sid, _, _ in resect}
        # rays from known stations, except those that came from a set at pid itself (that set
        # is solved as a resection instead of trusting an orientation carried from afar)
        near = self.known_neighbours(pid)
        rays = [(s, B[(s, pid)][0]) for s in near
                if (s, pid) in B and B[(s, pid)][2] not in rsets]
        dists = [(s, hd[frozenset((s, pid))]) for s in near if frozenset((s, pid)) in hd]
        angles = [(l, r, al) for l, r, al in self.angles_at.get(pid, ())
                  if l in self.xy and r in self.xy]
        return rays, dists, resect, angles

    def free_station(self, rays, dists, resect, angles):
        """Closed-form free station: one direction set at the point, a distance to each target.

        The targets' polar coordinates in the set's frame (direction, distance) are mapped onto
        their known coordinates by a rigid 2D transformation (rotation = the set's orientation,
        translation = the station), fitted by least squares in closed form (complex-number
        Procrustes: c = Σ (T−T̄)·conj(u−ū) normalised to |c| = 1, P = T̄ − c·ū). Used only when
        those are all the constraints, with ≥ 2 targets, and accepted only when the residuals
        are small; otherwise :meth:`fit` takes the general path. Unique by construction (the
        directions fix the sense of rotation, so there is no mirror solution).
        """
        if rays or angles or len(resect) < 2 or len({sid for sid, _, _ in resect}) != 1:
            return None
        dist = dict(dists)
        targets = [b for _, b, _ in resect]
        if len(dist) != len(dists) or set(dist) != set(targets) or len(set(targets)) != len(targets):
            return None
        u = np.array([dist[b] * complex(math.cos(self.sign * (d - self.offset)),
                                        math.sin(self.sign * (d - self.offset)))
                      for _, b, d in resect])
        t = np.array([complex(*self.xy[b]) for b in targets])
        du, dt = u - u.mean(), t - t.mean()
        c = np.sum(dt * np.conj(du))
        if abs(c) < 1e-12 * max(float(np.sum(np.abs(du) ** 2)), 1e-300):
            return None
        c /= abs(c)
        p = t.mean() - c * u.mean()
        L = max(max(dist.values()), 1.0)
        rms = math.sqrt(float(np.mean(np.abs(t - p - c * u) ** 2)))
        if not np.isfinite(p) or rms > 1e-3 * L + 0.05:
            return None
        return float(p.real), float(p.imag)

    def fit(self, pid, B, orient, hd):
        """Least-squares location from all constraints, from several starts; unique or None."""
        rays, dists, resect, angles = self.constraints(pid, B, orient, hd)
        free = self.free_station(rays, dists, resect, angles)
        if free is not None:
            return free, ""
        sids = sorted({sid for sid, _, _ in resect})
        n_eq = len(rays) + len(dists) + len(resect) + len(angles)
        if n_eq < 2 + len(sids) or (not rays and not dists and not resect and not angles):
            return None, ""
        involved = {s for s, _ in rays} | {s for s, _ in dists} | {b for _, b, _ in resect}
        involved |= {p for l, r, _ in angles for p in (l, r)}
        pts = np.array([self.xy[s] for s in involved])
        centre = pts.mean(axis=0)
        scale = max(float(np.max(np.linalg.norm(pts - centre, axis=1))), 1.0)
        for _, d in dists:
            scale = max(scale, d)
        L = scale

        def brg(x, y, s, reverse=False):
            xs, ys = self.xy[s]
            dx, dy = (xs - x, ys - y) if reverse else (x - xs, y - ys)
            return self.sign * math.atan2(dy, dx) + self.offset

        def resid(u):
            x, y = u[0], u[1]
            r = [L * _wrap(brg(x, y, s) - beta) for s, beta in rays]
            r += [math.hypot(x - self.xy[s][0], y - self.xy[s][1]) - d for s, d in dists]
            r += [L * _wrap(brg(x, y, b, True) - d - u[2 + sids.index(sid)])
                  for sid, b, d in resect]
            r += [L * _wrap(brg(x, y, rr, True) - brg(x, y, ll, True) - al)
                  for ll, rr, al in angles]
            return np.array(r)

        sols = []
        starts = [centre] + [centre + L * np.array([math.cos(t), math.sin(t)])
                             for t in np.linspace(0, TWO_PI, 12, endpoint=False)]
        for st in starts:
            u0 = [st[0], st[1]]
            for sid in sids:  # initial orientation from the start point
                b, d = next((b, d) for s2, b, d in resect if s2 == sid)
                u0.append(brg(st[0], st[1], b, True) - d)
            try:
                res = optimize.least_squares(resid, np.array(u0), method="lm", xtol=1e-12, ftol=1e-12)
            except Exception:  # noqa: BLE001 - a failed start is just skipped
                continue
            rms = math.sqrt(2 * res.cost / max(n_eq, 1))
            sols.append((rms, res.x[:2]))
        if not sols:
            return None, ""
        best = min(s[0] for s in sols)
        tol = max(1e-3 * L, 0.05)
        good = sorted((s for s in sols if s[0] <= max(best * 3, tol)), key=lambda s: s[0])
        distinct = []
        for _, xy in good:
            if all(np.linalg.norm(xy - d) > max(1e-3 * L, 0.1) for d in distinct):
                distinct.append(xy)
        redundancy = n_eq - 2 - len(sids)
        if best > 0.05 * L:  # no consistent solution
            return None, f"constraints inconsistent (rms {best:.3g} m)"
        if len(distinct) > 1:
            return None, f"{len(distinct)} solutions (e.g. mirror images), redundancy {redundancy}"
        return (float(distinct[0][0]), float(distinct[0][1])), ""

    # -- local frame -----------------------------------------------------------------------
    def seeds(self):
        """Pairs (a, b, distance or None) to start a local frame with, distances first."""
        out, seen = [], set()
        for a, b, d in self.hdist:
            if frozenset((a, b)) not in seen:
                seen.add(frozenset((a, b)))
                out.append((a, b, d))
        hd = self.horizontal_distances()
        for key, d in hd.items():
            if key not in seen:
                seen.add(key)
                out.append((*sorted(key), d))
        if not out:  # shape only (angles, directions): the scale comes from the fit
            for dirs in self.sets.values():
                for a, b, _ in dirs:
                    if frozenset((a, b)) not in seen:
                        seen.add(frozenset((a, b)))
                        out.append((a, b, None))
            for f, l, r, _ in self.angles:
                for t in (l, r):
                    if frozenset((f, t)) not in seen:
                        seen.add(frozenset((f, t)))
                        out.append((f, t, None))
        return out

    def local_frame(self, wanted: set, max_seeds: int = 12) -> bool:
        """Solve the plan in a free local frame and fit it onto the known points.

        Used when no point can be located directly, e.g. a triangulation whose fixed points
        are not observed from each other (``bug/krasovsky-1926.gkf``): starting from a seed
        pair of points, the shape is propagated with the usual methods, then a 2D similarity
        transformation fitted on ≥ 2 points of known position maps the new points in.
        """
        known = set(self.xy)
        if not known:
            return False
        seeds = self.seeds()
        # prefer seeds touching the unknown part of the network
        seeds.sort(key=lambda s: (s[0] in known) + (s[1] in known))
        best = None
        for a, b, d in seeds[:max_seeds]:
            sub = object.__new__(_Approx)
            sub.__dict__.update(self.__dict__)
            sub.xy = {a: (0.0, 0.0)}
            sub.xy[b] = sub.polar(a, 0.0, d if d else 1000.0)
            for _ in range(10 * len(self.net.points) + 10):
                if not sub.plan_sweep(wanted | known)[0]:
                    break
            common = sorted(known & set(sub.xy))
            new = set(sub.xy) - known
            if len(common) >= 2 and new and (best is None or len(new) > best[0]):
                best = (len(new), sub.xy, common)
        if best is None:
            return False
        _, lxy, common = best
        loc = np.array([complex(*lxy[c]) for c in common])
        glo = np.array([complex(*self.xy[c]) for c in common])
        lm, gm = loc.mean(), glo.mean()
        c = np.vdot(loc - lm, glo - gm) / np.vdot(loc - lm, loc - lm).real
        for pid, (x, y) in lxy.items():
            if pid not in known:
                w = c * (complex(x, y) - lm) + gm
                self.xy[pid] = (float(w.real), float(w.imag))
        return True

    # -- driver ----------------------------------------------------------------------------
    def run(self):
        need_xy = {p.id for p in self.net.points
                   if set("xy") & set(p.fixed + p.adjusted) and p.id not in self.xy}
        need_z = {p.id for p in self.net.points
                  if "z" in p.fixed + p.adjusted and p.id not in self.z}
        # points without coordinates that observations connect: locating them helps chains
        plan_obs = set()
        for s in self.sets.values():
            plan_obs |= {q for a, b, _ in s for q in (a, b)}
        for tup in (self.azimuths, self.hdist, self.sdist, self.angles):
            for t in tup:
                plan_obs |= {q for q in t if isinstance(q, str)}
        wanted_xy = need_xy | (plan_obs - set(self.xy))
        ambiguous = {}
        for _ in range(10 * len(self.net.points) + 10):
            p1 = self.heights_sweep()
            p2, ambiguous = self.plan_sweep(wanted_xy)
            if not (p1 or p2) and wanted_xy - set(self.xy):
                p2 = self.local_frame(wanted_xy)
            if not (p1 or p2):
                break
        return need_xy, need_z, ambiguous


def approximate_coordinates(net: Network, missing: str = "error") -> Network:
    """A copy of ``net`` where every fixed/adjusted coordinate has an approximate value.

    Given coordinates are kept unchanged; missing ones are computed from the observations
    (see the module docstring). Points that cannot be determined: ``missing="error"`` raises
    :class:`~baarda.errors.InputError` naming every one of them (at the line of the first);
    ``missing="keep"`` leaves their coordinates ``None`` and records them, with the reason, in
    ``Network.extra["approx_missing"]`` (``{id: (axes, reason)}``) for
    :func:`baarda.network_defects.build_network` to treat as local defects.
    """
    if missing not in ("error", "keep"):
        raise OptionError("missing", missing, ("error", "keep"), "missing must be 'error' or 'keep'")
    st = _Approx(net)
    need_xy, need_z, ambiguous = st.run()
    undetermined = []
    for p in net.points:
        axes = [a for a in "xyz" if a in p.fixed + p.adjusted and getattr(p, a) is None
                and (p.id not in (st.xy if a != "z" else st.z))]
        if axes:
            undetermined.append((p, axes))
    reasons = {}
    for p, axes in undetermined:
        why = ambiguous.get(p.id, "not connected to points of known position by enough "
                            "observations")
        if axes == ["z"]:
            why = "no height difference, zenith angle, vector or observed height links it"
        reasons[p.id] = ("".join(axes), why)
    if undetermined and missing == "error":
        parts = [f"{pid} ({axes}): {why}" for pid, (axes, why) in reasons.items()]
        first = undetermined[0][0]
        ids = ", ".join(p.id for p, _ in undetermined)
        raise InputError(net.source, first.line, f"no approximate coordinates for point "
                         f"{ids}: " + "; ".join(parts))
    points = []
    for p in net.points:
        upd = {}
        if p.x is None and "x" in p.fixed + p.adjusted and p.id in st.xy:
            upd["x"] = st.xy[p.id][0]
        if p.y is None and "y" in p.fixed + p.adjusted and p.id in st.xy:
            upd["y"] = st.xy[p.id][1]
        if p.z is None and "z" in p.fixed + p.adjusted and p.id in st.z:
            upd["z"] = st.z[p.id]
        points.append(replace(p, **upd) if upd else p)
    if reasons:
        return replace(net, points=tuple(points), extra={**net.extra, "approx_missing": reasons})
    return replace(net, points=tuple(points))
