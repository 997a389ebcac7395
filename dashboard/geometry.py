"""Display geometry of a problem: where the dashboard draws points, in which units it shows
observations, and the index of the problem's observations by point and image point.

Plain functions of the core's :class:`~baarda.model.problem.Problem` (immutable, so that
:func:`problem_index` is built once per problem): the map axes (:func:`display_matrix`,
:func:`display_xy`, a schematic layout of a levelling network), the file's units
(:func:`display_factor`), a block's images (:func:`block`, :func:`images`), the position of
each point id (:func:`point_index`), short observation labels, the observation-point incidence and the rows of
each image point of a block. Nothing here depends on the test settings or on the dashboard's state.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import shortest_path
from scipy.spatial import cKDTree

from baarda.model.network import east_north_matrix
from baarda.stats.hypotheses import image_point_index

from .text import plain

#: Keys of ``ObservationInfo.ids`` that name something other than a point.
#: (A COLMAP keypoint index is a number too: without "keypoint" here keypoint 7 would be
#: taken for the point whose id is 7.)
NOT_POINT_KEYS = ("image", "keypoint", "component", "group", "set")


def display_matrix(problem) -> np.ndarray:
    """M (2 × 2) with (east, north) = M (x, y) for the problem's planimetric axes.

    A Gama network's x, y axes point as its ``axes-xy`` says (``"ne"``: x north, y east); a
    block's X, Y are plotted as they are (M = I).
    """
    return east_north_matrix(problem.axes_xy)


def display_xy(problem, coords: np.ndarray) -> tuple[np.ndarray, np.ndarray, str, str]:
    """Map coordinates (east, north) of the points and the axis labels.

    Planimetric coordinates go through :func:`display_matrix`. A levelling network has no
    planimetric coordinates: its points are placed schematically by classical scaling of the
    graph distances of its observations.
    """
    X, Y = coords[:, 0], coords[:, 1]
    if np.isfinite(X).any() and np.isfinite(Y).any():
        e, n = display_matrix(problem) @ np.vstack([np.nan_to_num(X), np.nan_to_num(Y)])
        if not problem.axes_xy:
            unit = f" [{object_unit(problem)}]" if object_unit(problem) else ""
            return e, n, f"X{unit}", f"Y{unit}"
        return e, n, "east [m]", "north [m]"
    e, n = schematic_layout(problem)
    return e, n, "schematic position", "schematic position"


def object_unit(problem) -> str:
    """The unit of the object coordinates: "m", or "" for a structure-from-motion block (BAL,
    Bundler, COLMAP) without control, whose scale is arbitrary."""
    if problem.convention and getattr(problem.datum, "kind", "") == "free":
        return ""
    return "m"


def schematic_layout(problem) -> tuple[np.ndarray, np.ndarray]:
    """2D positions of the points from the graph of their observations (classical scaling)."""
    m = len(problem.points.ids)
    if m == 1:
        return np.zeros(1), np.zeros(1)
    pairs = observation_points(problem)
    rows, cols = [], []
    for pts in pairs:
        for a in pts:
            for b in pts:
                if a != b:
                    rows.append(a)
                    cols.append(b)
    G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))
    D = shortest_path(G, unweighted=True, directed=False)
    finite = np.isfinite(D)
    D[~finite] = (D[finite].max() if finite.any() else 1.0) + 1.0
    J = np.eye(m) - 1.0 / m
    B = -0.5 * J @ (D ** 2) @ J
    lam, V = np.linalg.eigh(B)
    top = np.argsort(lam)[::-1][:2]
    xy = V[:, top] * np.sqrt(np.maximum(lam[top], 1e-12))
    if m <= SCHEMATIC_STRESS_MAX:
        xy = stress_layout(D, xy)
    return xy[:, 0], xy[:, 1]


#: Up to this many points the schematic layout is refined by stress majorization.
SCHEMATIC_STRESS_MAX = 400


def stress_layout(D: np.ndarray, xy: np.ndarray, iterations: int = 300) -> np.ndarray:
    """Positions whose distances fit the graph distances D (SMACOF stress majorization, de Leeuw
    1977; unit weights), started from ``xy`` spread by a small circle: classical scaling of a
    symmetric graph puts several points on one position (the levelling demo's 8 benchmarks on
    4), which stress majorization from distinct points does not."""
    m = len(D)
    span = max(float(np.ptp(xy)), 1.0)
    t = 2 * np.pi * np.arange(m) / m
    X = xy + 0.1 * span * np.column_stack([np.cos(t), np.sin(t)])
    for _ in range(iterations):
        d = np.sqrt(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1))
        with np.errstate(divide="ignore", invalid="ignore"):
            Bm = np.where(d > 0, -D / d, 0.0)
        np.fill_diagonal(Bm, 0.0)
        np.fill_diagonal(Bm, -Bm.sum(axis=1))
        X = Bm @ X / m
    return X


def block(problem) -> dict | None:
    """The block geometry of a problem as a dict (cameras, images, image size), or None
    (a network, or no problem)."""
    geo = problem.geometry if problem is not None else None
    return geo.as_dict() if geo is not None else None


def images(problem) -> list[dict]:
    """The images of a block problem (:func:`block`), [] for a network or no problem."""
    b = block(problem)
    return list(b.get("images", [])) if isinstance(b, dict) else []


def point_index(problem) -> dict:
    """Position of each point id in ``problem.points.ids``."""
    return {pid: k for k, pid in enumerate(problem.points.ids)}


def observation_points(problem) -> list[list[int]]:
    """Per observation, the indices of the points it names (``from`` first)."""
    index = point_index(problem)
    out = []
    for ids in problem.info.ids:
        pts = []
        for key, val in ids.items():
            if key in NOT_POINT_KEYS:
                continue
            k = index.get(str(val))
            if k is not None and k not in pts:
                pts.append(k)
        out.append(pts)
    return out


def display_factor(problem) -> tuple[np.ndarray, tuple[str, ...]]:
    """Factor from SI to the unit of each observation's σ in the file (mm, cc, px...), and the unit."""
    sig_si = problem.cov.sigma()
    sig_file = np.asarray(problem.info.sigma_file, dtype=float)
    ok = np.isfinite(sig_file) & (sig_file > 0) & (sig_si > 0)
    factor = np.where(ok, sig_file / np.where(sig_si > 0, sig_si, 1.0), 1.0)
    units = tuple(u if o else "SI" for u, o in zip(problem.info.sigma_unit, ok))
    return factor, units


def observation_label(problem, i: int) -> str:
    """A short readable name of observation i: ``12 direction A→B``, ``40 image-x 101:P7``,
    ``316 gnss-x image 101``."""
    kind = problem.info.kind[i]
    ids = problem.info.ids[i]
    if "from" in ids:
        rest = [str(v) for k, v in ids.items() if k != "from"]
        name = f"{ids['from']}→{','.join(rest)}"
    elif "image" in ids and "point" in ids:
        name = f"{ids['image']}:{ids['point']}"
    elif "image" in ids:                 # a GNSS centre or IMU attitude of the image
        name = f"image {ids['image']}"
    else:
        name = " ".join(str(v) for v in ids.values())
    return f"{i} {kind} {name}"


def problem_index(p) -> dict:
    """Index arrays of a problem (built once per problem by the state: the problem is
    immutable): the observation-point incidence (``inc_obs``, ``inc_pt``: observation i names
    point k), the network lines (``line_obs``, ``line_from``, ``line_to``), the short
    observation labels, the rows of each (image, point, keypoint) of a block (``image_rows``),
    the file's units (``factor``: :func:`display_factor`) and the position of each point id
    (``point_index``)."""
    obs_points = observation_points(p)
    inc_obs = np.repeat(np.arange(p.n), [len(pp) for pp in obs_points])
    inc_pt = np.fromiter((k for pp in obs_points for k in pp), dtype=np.int64, count=inc_obs.size)
    lines = [(i, pp[0], k) for i, pp in enumerate(obs_points)
             if len(pp) >= 2 and not p.info.kind[i].startswith("image") for k in pp[1:]]
    lines = np.array(lines, dtype=np.int64).reshape(-1, 3)
    # one image point = (image, point, keypoint): COLMAP may observe a point by several
    # keypoints of one image, each an image point of its own
    image_rows = image_point_index(p)
    return {"obs_points": obs_points, "inc_obs": inc_obs, "inc_pt": inc_pt,
            "line_obs": lines[:, 0], "line_from": lines[:, 1], "line_to": lines[:, 2],
            "labels": [plain(observation_label(p, i).split(" ", 2)[-1]) for i in range(p.n)],
            "image_rows": image_rows, "factor": display_factor(p), "point_index": point_index(p)}


def keypoints_of(index: dict, image, point) -> list[str | None]:
    """The keypoints by which ``image`` observes ``point``: ``[None]`` for an ordinary image
    point, the keypoint indices (sorted) where a COLMAP image has several on the point."""
    im, pid = str(image), str(point)
    return sorted((kp for (j, q, kp) in index["image_rows"] if j == im and q == pid),
                  key=lambda k: (k is not None, len(k or ""), k or ""))


def image_point_rows(index: dict, image, point, keypoint=None) -> list[int]:
    """Full indices of the observations of one image point: ``point`` in ``image``, measured
    by ``keypoint`` where the image has several keypoints on the point (COLMAP); without
    ``keypoint`` such an image point is ambiguous (ValueError)."""
    rows = index["image_rows"]
    if keypoint is not None:
        return rows.get((str(image), str(point), str(keypoint)), [])
    kps = keypoints_of(index, image, point)
    if len(kps) > 1:
        raise ValueError(f"image {plain(image)} observes point {plain(point)} by keypoints "
                         f"{', '.join(map(str, kps))}: choose one")
    return rows.get((str(image), str(point), kps[0]), []) if kps else []


def point_rows_in_image(index: dict, image, point) -> list[int]:
    """Full indices of every observation of ``point`` in ``image`` (all its keypoints)."""
    im, pid = str(image), str(point)
    return sorted(i for (j, q, _), rows in index["image_rows"].items()
                  if j == im and q == pid for i in rows)


def images_of_point(index: dict, point) -> list[str]:
    """The images in which ``point`` is measured (sorted ids)."""
    return sorted({im for im, pid, _ in index["image_rows"] if pid == str(point)})


def observations_of_point(index: dict, k: int) -> list[int]:
    """Full indices of the observations that name point ``k``."""
    return sorted(set(index["inc_obs"][index["inc_pt"] == k].tolist()))


def image_points(problem, index: dict) -> dict:
    """Per image id, (point, row of x, row of y) of each of its image points (full indices)."""
    by_image: dict = {}
    for (im, pid, _kp), rows in index["image_rows"].items():
        comp = {str(problem.info.ids[i].get("component") or problem.info.kind[i].rsplit("-", 1)[-1]): i
                for i in rows}
        if "x" in comp and "y" in comp:
            by_image.setdefault(im, []).append((pid, comp["x"], comp["y"]))
    return by_image


def auto_exaggeration(problem, index: dict, v: np.ndarray) -> float:
    """Image residual vectors at the block's own scale (BAL and Bundler files have no image
    size): the median residual vector ``v`` (full problem, file units) drawn half the median
    spacing of the image points (nearest neighbours in their images, up to 30 images), the
    largest at most 30 % of the span of the image coordinates (1st to 99th percentile); a round
    factor (1, 2 or 5 × 10^k)."""
    value = np.asarray(problem.info.value_file, dtype=float)
    spacing, lengths, by_image = [], [], {}
    for (im, _pid, _kp), rows in index["image_rows"].items():
        if len(rows) == 2:
            lengths.append(math.hypot(v[rows[0]], v[rows[1]]))
            by_image.setdefault(im, []).append((value[rows[0]], value[rows[1]]))
    for im in list(by_image)[:30]:
        xy = np.asarray(by_image[im], dtype=float)
        if len(xy) >= 2:
            d, _ = cKDTree(xy).query(xy, k=2)
            spacing.append(np.median(d[:, 1]))
    lengths = np.asarray(lengths, dtype=float)
    lengths = lengths[np.isfinite(lengths)]
    vref = float(np.median(lengths)) if lengths.size else 0.0
    sref = float(np.median(spacing)) if spacing else 0.0
    if vref <= 0 or sref <= 0:
        return 1.0
    xy = np.concatenate([np.asarray(v, dtype=float) for v in by_image.values()])
    span = float(np.ptp(np.percentile(xy, [1, 99], axis=0), axis=0).max())
    raw = min(0.5 * sref / vref, 0.3 * span / float(lengths.max()))
    k = math.floor(math.log10(raw))
    return float(next(m * 10 ** k for m in (5, 2, 1) if m * 10 ** k <= raw))


def reduced_index(kept, n: int, full) -> np.ndarray:
    """Reduced indices of full observation indices (−1 where excluded); ``kept``: the full index
    of each observation of the reduced problem, ``n``: observations of the full problem."""
    pos = np.full(n, -1, dtype=np.int64)
    pos[kept] = np.arange(kept.size)
    return pos[np.asarray(full, dtype=np.int64)]


def expand(values, kept, n: int, fill=np.nan) -> np.ndarray:
    """A per-observation array of the reduced problem spread to the full problem (``fill``
    where excluded)."""
    values = np.asarray(values)
    out = np.full(n, fill, dtype=np.result_type(values.dtype, type(fill)))
    out[kept] = values
    return out
