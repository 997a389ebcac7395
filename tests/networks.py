"""Small synthetic networks for the core tests (exact observations plus optional noise)."""

from __future__ import annotations

import itertools

import numpy as np

from baarda.model.network import Cluster, NetObservation, NetPoint, Network
from baarda.model.network_problem import build_problem


def grid_network(nx=3, ny=3, spacing=100.0, sigma_d=0.002, sigma_r=1e-5, datum="fixed",
                 noise_seed=None, jitter=0.0, seed=0):
    """A planimetric grid with distances and direction sets to neighbours within 1.5 spacings.

    datum: "fixed" (first point fixed, second point's x fixed → minimal), "free" (all points in
    the S-base), "over" (two corner points fixed).
    """
    rng = np.random.default_rng(seed)
    true = {f"P{i}{j}": (i * spacing + rng.normal() * spacing * 0.1, j * spacing + rng.normal() * spacing * 0.1)
            for i in range(nx) for j in range(ny)}
    ids = list(true)
    noise = np.random.default_rng(noise_seed) if noise_seed is not None else None
    pts = []
    for k, pid in enumerate(ids):
        x, y = true[pid]
        ax, ay = x + jitter * rng.normal(), y + jitter * rng.normal()
        if datum == "fixed" and k == 0:
            pts.append(NetPoint(pid, x=x, y=y, fixed="xy"))
        elif datum == "fixed" and k == 1:
            # P01 lies along y from P00: its x (across the baseline) fixes the rotation
            pts.append(NetPoint(pid, x=x, y=ay, fixed="x", adjusted="y"))
        elif datum == "over" and k in (0, len(ids) - 1):
            pts.append(NetPoint(pid, x=x, y=y, fixed="xy"))
        elif datum == "free":
            pts.append(NetPoint(pid, x=ax, y=ay, adjusted="xy", constrained="xy"))
        else:
            pts.append(NetPoint(pid, x=ax, y=ay, adjusted="xy"))
    obs, sig = [], []
    set_id = 0
    for a in ids:
        targets = [b for b in ids if b != a and np.hypot(true[b][0] - true[a][0], true[b][1] - true[a][1]) < 1.5 * spacing]
        o = rng.uniform(0, 2 * np.pi)
        for b in targets:
            dx, dy = true[b][0] - true[a][0], true[b][1] - true[a][1]
            d = np.hypot(dx, dy)
            if a < b:
                e = noise.normal() * sigma_d if noise is not None else 0.0
                obs.append(NetObservation("distance", (a, b), d + e))
                sig.append(sigma_d)
            e = noise.normal() * sigma_r if noise is not None else 0.0
            obs.append(NetObservation("direction", (a, b), (np.arctan2(dy, dx) - o + e) % (2 * np.pi), set_id=set_id))
            sig.append(sigma_r)
        set_id += 1
    clusters = tuple(Cluster((i,), np.array([[s * s]])) for i, s in enumerate(sig))
    return Network(tuple(pts), tuple(obs), clusters, sigma0=1.0, sigma_act="apriori")


def levelling_loop(m=4, sigma=0.001):
    """A closed levelling loop of m height differences, the first point fixed."""
    pts = tuple(NetPoint(f"H{i}", z=100.0 + i, fixed="z" if i == 0 else "", adjusted="" if i == 0 else "z")
                for i in range(m))
    obs = tuple(NetObservation("height-diff", (f"H{i}", f"H{(i + 1) % m}"), 1.0 if i < m - 1 else -(m - 1.0))
                for i in range(m))
    return Network(pts, obs, tuple(Cluster((i,), np.array([[sigma ** 2]])) for i in range(m)),
                   sigma_act="apriori")


def with_values(net: Network, values) -> Network:
    obs = tuple(NetObservation(o.kind, o.points, float(v), set_id=o.set_id) for o, v in zip(net.observations, values))
    return Network(net.points, obs, net.clusters, sigma0=net.sigma0, sigma_act=net.sigma_act,
                   angle_sign=net.angle_sign, azimuth_offset=net.azimuth_offset)


def vector_network(seed=0):
    """A 3D GNSS network: vectors with full 3 × 3 covariances, one fixed point."""
    rng = np.random.default_rng(seed)
    P = {f"G{i}": rng.uniform(-1000, 1000, 3) for i in range(5)}
    ids = list(P)
    pts = tuple(NetPoint(pid, *P[pid], fixed="xyz" if k == 0 else "", adjusted="" if k == 0 else "xyz")
                for k, pid in enumerate(ids))
    obs, clusters = [], []
    for a, b in itertools.combinations(ids, 2):
        d = P[b] - P[a]
        idx = []
        for c, kind in enumerate(("dx", "dy", "dz")):
            idx.append(len(obs))
            obs.append(NetObservation(kind, (a, b), float(d[c])))
        L = rng.normal(size=(3, 3)) * 0.002 + np.eye(3) * 0.003
        clusters.append(Cluster(tuple(idx), L @ L.T, group=True))
    return Network(pts, tuple(obs), tuple(clusters), sigma_act="apriori")


def problem(net):
    return build_problem(net)
