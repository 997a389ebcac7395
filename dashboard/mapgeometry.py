"""Display geometry of the maps: the frame, far points, colour scales, exaggerations, paths.

Plain functions of arrays, DataFrames (the state's points and observation tables) and the
core's objects: what the map views (:mod:`baarda.dashboard.views.maps`) draw, computed here so
that the views only render. The map frame (:func:`robust_box`) puts far points at its edge
(:func:`framed`, :func:`far_note`); the |w| colour scale (:func:`w_levels`); the round
exaggerations of the lower-bound ellipse (:func:`hypothesis_ellipse`), the deformation field
(:func:`deformation_field`) and the standard ellipses (:func:`ellipse_paths`); the image-space
residual vectors of a block (:func:`image_residuals`). Nothing here depends on the dashboard's
state or on Panel.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from baarda.stats import precision


def round_scale(raw: float) -> float:
    """A round number (1, 2 or 5 × 10^k) not above ``raw``, for displayed exaggerations."""
    if not np.isfinite(raw) or raw <= 0:
        return 1.0
    k = math.floor(math.log10(raw))
    for m in (5, 2, 1):
        if m * 10 ** k <= raw:
            return float(m * 10 ** k)
    return float(10 ** k)


def extent(pts: pd.DataFrame) -> float:
    """The larger side of the points' bounding box (map units), at least 1."""
    if len(pts) == 0:
        return 1.0
    span = max(float(np.ptp(pts["x"])), float(np.ptp(pts["y"])))
    return span if span > 0 else 1.0


def mean_spacing(pts: pd.DataFrame) -> float:
    """The points' mean spacing: √(area / n) of their bounding box (its larger side squared
    where they lie on a line), ∞ for fewer than two points."""
    if len(pts) < 2:
        return math.inf
    w, h = float(np.ptp(pts["x"])), float(np.ptp(pts["y"]))
    area = w * h if min(w, h) > 0.05 * max(w, h) else max(w, h) ** 2
    return math.sqrt(area / len(pts)) if area > 0 else math.inf


def joined(paths: np.ndarray) -> list[np.ndarray]:
    """m paths (m × n × 2) as one path broken by NaN rows: Bokeh draws one glyph instead of m."""
    if len(paths) == 0:
        return []
    gap = np.full((len(paths), 1, 2), np.nan)
    return [np.concatenate([paths, gap], axis=1).reshape(-1, 2)[:-1]]


def log_clim(values, low: float | None = None) -> tuple[float, float]:
    """Colour limits of a log scale: from ``low`` (default the smallest positive value, at
    least 10⁻⁶ of the largest) to the largest finite value; infinite values (r = 0) take the
    top colour."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    hi = float(v.max()) if v.size else 1.0
    lo = float(low) if low is not None else max(float(v.min()) if v.size else 0.1 * hi, 1e-6 * hi)
    return (lo, hi) if hi > lo * 1.01 else (lo, 10 * lo)


#: The map frame of a block or network of at least FRAME_MIN_POINTS points: the box of the
#: points' 5th to 95th percentiles, widened by FRAME_MARGIN of its size on every side (and never
#: beyond the points). Points outside it are far points: drawn at the frame's edge with their own
#: marker and listed, instead of setting the frame (Ladybug's few points drifting towards
#: infinity shrank its 7,764 real points to one pixel). Smaller sets keep their full extent.
FRAME_QUANTILES = (5.0, 95.0)
FRAME_MARGIN = 0.75
FRAME_MIN_POINTS = 50


def robust_box(x, y) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) of the map frame of points at (x, y) (see :data:`FRAME_MARGIN`)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return -1.0, 1.0, -1.0, 1.0
    x, y = x[ok], y[ok]
    if x.size < FRAME_MIN_POINTS:
        return float(x.min()), float(x.max()), float(y.min()), float(y.max())
    (ax, bx), (ay, by) = np.percentile(x, FRAME_QUANTILES), np.percentile(y, FRAME_QUANTILES)
    m = FRAME_MARGIN * max(bx - ax, by - ay, 1e-9)
    return (max(float(x.min()), ax - m), min(float(x.max()), bx + m),
            max(float(y.min()), ay - m), min(float(y.max()), by + m))


def framed(pts: pd.DataFrame) -> pd.DataFrame:
    """The points with far points moved to the frame's edge: columns ``x``, ``y`` clamped to
    :func:`robust_box`, ``far`` (bool) and the true coordinates ``x_true``, ``y_true``."""
    x0, x1, y0, y1 = robust_box(pts["x"], pts["y"])
    x = pts["x"].to_numpy(dtype=float)
    y = pts["y"].to_numpy(dtype=float)
    far = (x < x0) | (x > x1) | (y < y0) | (y > y1) | ~np.isfinite(x) | ~np.isfinite(y)
    return pts.assign(x=np.clip(np.nan_to_num(x), x0, x1), y=np.clip(np.nan_to_num(y), y0, y1), far=far,
                      x_true=x, y_true=y)


def clamped_segments(seg: pd.DataFrame, pts: pd.DataFrame) -> pd.DataFrame:
    """Observation lines (columns ``x0``, ``y0``, ``x1``, ``y1``) with their ends clamped to the
    frame (:func:`robust_box`) of the points ``pts`` (columns ``x``, ``y``, true coordinates)."""
    if not len(seg):
        return seg
    x0, x1, y0, y1 = robust_box(pts["x"], pts["y"])
    return seg.assign(x0=seg["x0"].clip(x0, x1), x1=seg["x1"].clip(x0, x1),
                      y0=seg["y0"].clip(y0, y1), y1=seg["y1"].clip(y0, y1))


def far_note(pts: pd.DataFrame, limit: int = 12) -> str:
    """The far points of a map as text: how many, and the ``limit`` farthest from the frame's
    centre with their coordinates."""
    far = pts[pts["far"]]
    if far.empty:
        return ""
    cx, cy = float(np.median(pts["x"])), float(np.median(pts["y"]))
    dist = np.hypot(far["x_true"].to_numpy(dtype=float) - cx, far["y_true"].to_numpy(dtype=float) - cy)
    far = far.iloc[np.argsort(-np.nan_to_num(dist, nan=np.inf), kind="stable")]
    listed = ", ".join(f"{r.id} ({r.x_true:.4g}, {r.y_true:.4g})" for r in far.head(limit).itertuples())
    more = f" and {len(far) - limit} more" if len(far) > limit else ""
    return f"{len(far)} far point(s) drawn at the frame's edge (▽), farthest first: {listed}{more}."


#: Standard ellipses larger than this many times the 90th percentile of the semi-major axes are
#: off-scale: not drawn (a drifting SfM point's σ of 10⁹ would shrink every other ellipse to nothing).
OFF_SCALE = 20.0


def length_text(value: float, unit: str) -> str:
    """A length in metres as millimetres where the block has units, else in the block's units."""
    if not np.isfinite(value):
        return "∞"
    return f"{1000 * value:.3g} mm" if unit == "m" else f"{value:.3g} (block units)"


#: Colours of a |w| scale: two bins below the critical value (accepted: grey, light blue), five
#: above it (rejected: orange to dark red) on a geometric scale up to the largest |w|.
W_COLORS = ["#d9d9d9", "#9ecae1", "#fee08b", "#fdae61", "#f46d43", "#d73027", "#7f0000"]


def w_levels(critical: float, top: float) -> list[float]:
    """Bin edges of the |w| colour scale: 0, critical/2, the critical value, then five geometric
    steps to the largest |w| (at least 1.5 × critical), rounded to two significant digits: a 13.4
    outlier is two bins above a 4.5 one, and the critical value is a tick of the colour bar."""
    top = max(float(top) if np.isfinite(top) else 0.0, 1.5 * critical)
    above = critical * np.geomspace(1.0, top / critical, 6)[1:]
    rounded = [float(f"{v:.2g}") for v in above]
    edges = [0.0, round(critical / 2, 2), round(critical, 2)]
    for v in rounded:
        edges.append(max(v, edges[-1] * 1.01))
    edges[-1] = max(edges[-1], top)
    return edges


def largest_abs_w(seg: pd.DataFrame, pts: pd.DataFrame) -> float:
    """The largest |w| of the lines (column ``abs_w``) and the points (column ``max_w``), at least 0."""
    top = float(np.nanmax(seg["abs_w"], initial=0.0)) if len(seg) else 0.0
    return max(top, float(np.nanmax(pts["max_w"], initial=0.0)))


def hypothesis_ellipse(e: np.ndarray, pts: pd.DataFrame, k: int) -> tuple[float, np.ndarray]:
    """The lower-bound ellipse ``e`` (n × 2, map axes) at point ``k`` of ``pts``, exaggerated by a
    round scale so that its largest coordinate is 8 % of the map's extent: (scale, n × 2)."""
    scale = round_scale(0.08 * extent(pts) / max(np.abs(e).max(), 1e-300))
    return scale, e * scale + np.array([pts["x"].iat[k], pts["y"].iat[k]])


def deformation_field(shifts: np.ndarray, M: np.ndarray, dim: int, pts: pd.DataFrame):
    """The map vectors of the point shifts ``shifts`` (m × 3; map axes (east, north) = M (x, y);
    a levelling network's height shift drawn northward): (d (m × 2), length (m), scale), the
    round scale making the longest vector 12 % of the map's extent."""
    d = (M @ shifts[:, :2].T).T
    if dim == 1:
        d = np.column_stack([np.zeros(len(pts)), shifts[:, 2]])
    size = np.hypot(d[:, 0], d[:, 1])
    big = size.max(initial=0.0)
    scale = round_scale(0.12 * extent(pts) / big) if big > 0 else 1.0
    return d, size, scale


def field_vectors(pts: pd.DataFrame, d: np.ndarray, size: np.ndarray, scale: float) -> pd.DataFrame:
    """The non-zero vectors of a :func:`deformation_field` from the points, exaggerated by
    ``scale``: columns x0, y0, x1, y1, id and the shift in millimetres (``shift_mm``)."""
    keep = size > 0
    return pd.DataFrame({"x0": pts["x"][keep], "y0": pts["y"][keep],
                         "x1": pts["x"][keep] + scale * d[keep, 0],
                         "y1": pts["y"][keep] + scale * d[keep, 1],
                         "id": pts["id"][keep], "shift_mm": 1000 * size[keep]})


def ellipse_paths(cov2: np.ndarray, M: np.ndarray, pts: pd.DataFrame, scale: float | None = None,
                  most: int | None = None):
    """Ellipse paths of point covariances (m × 2 × 2, in map axes by M), exaggerated so that the
    90th percentile of the semi-major axes of the points inside the frame is 5 % of the frame or
    half the points' mean spacing (:func:`mean_spacing`), whichever is less — a block of
    thousands of points (Ladybug) was a solid mass of ellipses at 5 % (or by ``scale``); ellipses over :data:`OFF_SCALE` times that percentile, and those of far
    points (column ``far`` of ``pts``), are not drawn. Returns (paths, scale, largest drawn axis,
    off-scale count). ``most``: only the ``most`` largest of them are drawn (the scale is the same)."""
    C = np.einsum("ij,mjk,lk->mil", M, cov2, M)
    ell = precision.standard_ellipses(0.5 * (C + np.swapaxes(C, 1, 2)))     # the core's (a, b, bearing)
    axis = ell[:, 0]
    far = pts["far"].to_numpy(dtype=bool)
    inside = axis[(axis > 0) & np.isfinite(axis) & ~far]
    ref = float(np.percentile(inside, 90)) if inside.size else 0.0
    drawn = (axis > 0) & np.isfinite(axis) & ~far & (axis <= OFF_SCALE * ref)
    if scale is None:
        scale = round_scale(min(0.05 * extent(pts), 0.5 * mean_spacing(pts[~far])) / ref) if ref > 0 else 1.0
    off = int(((axis > 0) & ~drawn).sum())
    if most is not None and drawn.sum() > most:
        keep = np.flatnonzero(drawn)
        drawn = np.zeros_like(drawn)
        drawn[keep[np.argsort(-axis[keep], kind="stable")[:most]]] = True
    centre = pts[["x", "y"]].to_numpy(dtype=float)[:, None, :]
    paths = (precision.ellipse_points(ell[drawn]) * scale + centre[drawn])
    big = float(axis[drawn].max(initial=0.0))
    return joined(paths), scale, big, off


IMAGE_COLUMNS = ["point", "x", "y", "x1", "y1", "vx", "vy", "abs_w", "obs"]


def image_residuals(pts: list[tuple[str, int, int]], value: np.ndarray, v: np.ndarray, w: np.ndarray,
                    exaggeration: float) -> pd.DataFrame:
    """Residual vectors of image points ``pts`` ((name, row of x, row of y)): observed image
    coordinates ``value`` (file units), residuals ``v`` exaggerated, the larger |w| of x and y."""
    if not pts:
        return pd.DataFrame(columns=IMAGE_COLUMNS)
    ix = np.array([t[1] for t in pts])
    iy = np.array([t[2] for t in pts])
    ex = exaggeration
    return pd.DataFrame({"point": [t[0] for t in pts], "x": value[ix], "y": value[iy],
                         "x1": value[ix] + ex * v[ix], "y1": value[iy] + ex * v[iy],
                         "vx": v[ix], "vy": v[iy], "abs_w": np.fmax(np.abs(w[ix]), np.abs(w[iy])),
                         "obs": ix}, columns=IMAGE_COLUMNS)


def image_border(df: pd.DataFrame, size) -> list[np.ndarray]:
    """The image's outline (w × h ``size``; [] if unknown): from (0, 0), or centred on the origin
    where the image coordinates (column ``x``) go below −1."""
    if not size:
        return []
    w, h = float(size[0]), float(size[1])
    x0, y0 = (0.0, 0.0) if (len(df) == 0 or df["x"].min() >= -1) else (-w / 2, -h / 2)
    return [np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h], [x0, y0]])]
