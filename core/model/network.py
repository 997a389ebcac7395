"""Geodetic networks as read from a file: points, observations, covariance clusters.

This is the file-level description of a local geodetic network (levelling, 2D, 3D). It holds
no adjustment logic: :func:`baarda.model.network_problem.build_problem` turns a :class:`Network` into the
generic :class:`baarda.model.problem.Problem` that the adjustment works on.

Conventions
-----------
- Coordinates are in the file's own axes (``x``, ``y``, ``z``, metres). The planimetric angle
  convention is carried by the network: a *bearing* from point i to point j is
  ``angle_sign * atan2(Δy, Δx) + azimuth_offset`` (radians), so that for GNU Gama's default
  (``axes-xy="ne"``, ``angles="left-handed"``) it is the usual clockwise bearing from x.
- A *direction* d of set s satisfies  d + o_s = bearing  (o_s the set's orientation unknown).
- An *angle* (from, left, right) is bearing(from→right) − bearing(from→left), in [0, 2π).
- An *azimuth* is the bearing itself.
- Zenith angles are measured from the zenith (+z) down, in [0, π].
- Observed values and sigmas are held in SI units (metres, radians); the file's own value,
  unit and sigma are kept beside them for reporting.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Observation kinds, named as in gama-local's adjustment XML.
KINDS = (
    "distance", "direction", "angle", "azimuth", "slope-distance", "zenith-angle",
    "height-diff", "dx", "dy", "dz", "coordinate-x", "coordinate-y", "coordinate-z",
)


#: (north, east) components of a unit vector along each of Gama's axis letters (``axes-xy``).
AXIS_NORTH_EAST = {"n": (1.0, 0.0), "e": (0.0, 1.0), "s": (-1.0, 0.0), "w": (0.0, -1.0)}


def east_north_matrix(axes_xy: str | None) -> np.ndarray:
    """M (2 × 2) with (east, north) = M (x, y) for a network whose x and y axes point as Gama's
    ``axes-xy`` says (``"ne"``: x north, y east; Gama manual §2.3); the identity for ``None``
    (a block's X, Y, taken as east, north)."""
    if not axes_xy:
        return np.eye(2)
    ax, ay = AXIS_NORTH_EAST[axes_xy[0]], AXIS_NORTH_EAST[axes_xy[1]]
    return np.array([[ax[1], ay[1]], [ax[0], ay[0]]])


@dataclass(frozen=True)
class NetPoint:
    """A point of the network.

    ``x``, ``y``, ``z`` are the given (approximate or fixed) coordinates in metres, ``None`` where
    the file gives none. ``fixed``, ``adjusted`` and ``constrained`` are strings of axis letters
    (e.g. ``"xy"``): fixed coordinates are held exactly; adjusted ones are unknowns; constrained
    ones are unknowns that also form the free-network datum (the S-base, Gama's ``adj="XY"``).
    """

    id: str
    x: float | None = None
    y: float | None = None
    z: float | None = None
    fixed: str = ""
    adjusted: str = ""
    constrained: str = ""
    line: int = 0


@dataclass(frozen=True)
class NetObservation:
    """One scalar observation.

    ``points`` are the point ids in the roles of ``kind``: (from, to) for most kinds,
    (from, left, right) for angles, (id,) for coordinate observations.
    ``value`` is in SI units (metres or radians). ``set_id`` is the index of the direction set
    (one orientation unknown each) for directions, else -1. ``from_dh`` and ``to_dh`` are the
    instrument and target heights (metres) of 3D observations. ``line`` is the 1-based line of
    the file where the observation is written. ``value_file``/``unit`` and
    ``sigma_file``/``sigma_unit`` are the numbers as the file has them (for reports).
    ``group_key`` tags the members of one test group inside a larger covariance cluster (e.g.
    the three components of one GNSS vector, or of one observed coordinate point, when one
    ``<cov-mat>`` covers several of them); empty for observations that are not in a group.
    ``extern`` is the file's free-text external reference (Gama's ``extern`` attribute), kept
    verbatim and otherwise ignored.
    """

    kind: str
    points: tuple[str, ...]
    value: float
    set_id: int = -1
    from_dh: float = 0.0
    to_dh: float = 0.0
    line: int = 0
    value_file: float = float("nan")
    unit: str = "m"
    sigma_file: float = float("nan")
    sigma_unit: str = "mm"
    group_key: str = ""
    extern: str = ""


@dataclass(frozen=True)
class Cluster:
    """A covariance cluster: observation indices and their covariance in SI units² (m², rad²).

    Every observation of a network is in exactly one cluster; an uncorrelated observation is a
    1 × 1 cluster. ``group`` says whether the cluster is a multi-dimensional test group
    (GNSS vectors, coordinate triples): those get T-tests of their own.
    """

    indices: tuple[int, ...]
    cov: np.ndarray
    group: bool = False
    line: int = 0


@dataclass(frozen=True)
class Network:
    """A local geodetic network as read from a file.

    ``sigma0`` is the a priori standard deviation of unit weight (dimensionless: the
    covariances in ``clusters`` are already the a priori covariances, i.e. σ0² Q).
    ``sigma_act`` says which σ0 the file asks the tests to use (``"apriori"`` or
    ``"aposteriori"``); ``conf_pr`` is the confidence level of the global test; ``tol_abs`` is
    Gama's outlier tolerance in metres (reported, never used to drop observations).
    """

    points: tuple[NetPoint, ...]
    observations: tuple[NetObservation, ...]
    clusters: tuple[Cluster, ...]
    sigma0: float = 1.0
    sigma_act: str = "aposteriori"
    conf_pr: float = 0.95
    tol_abs: float = 1.0
    angle_sign: float = 1.0
    azimuth_offset: float = 0.0
    axes_xy: str = "ne"
    angles: str = "left-handed"
    description: str = ""
    source: str = ""
    extra: dict = field(default_factory=dict)

    def point_index(self) -> dict[str, int]:
        return {p.id: i for i, p in enumerate(self.points)}
