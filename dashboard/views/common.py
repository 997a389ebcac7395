"""Shared pieces of the map views: colours, the block context layers, click handling."""

from __future__ import annotations

import holoviews as hv
import numpy as np
import pandas as pd
from bokeh.models import NumeralTickFormatter

from .. import frames, geometry
from ..frames import R_UNCONTROLLED, R_WEAK
from ..jobs import shared
from ..mapgeometry import extent
from ..text import plain

STATUS_COLORS = {
    "fixed": "#111111", "adjusted": "#1f77b4", "constrained": "#9467bd",
    "tie": "#1f77b4", "control": "#d62728", "check": "#2ca02c",
}

#: Redundancy colour scale: r < 0.1 uncontrolled (red), < 0.3 weak (orange), then greens.
R_LEVELS = [0.0, R_UNCONTROLLED, R_WEAK, 0.6, 1.0]
R_COLORS = ["#d7191c", "#fdae61", "#a6d96a", "#1a9641"]

MAP_OPTS = dict(tools=["tap"], active_tools=["pan", "wheel_zoom", "tap"],
                toolbar="right", fontscale=1.0, fontsize={"title": "10.5pt"}, xrotation=0)


def formatters() -> dict:
    """Plain tick labels (no 1e+6 notation); new Bokeh models for every plot (one document each)."""
    return {"xformatter": NumeralTickFormatter(format="0.[00]"),
            "yformatter": NumeralTickFormatter(format="0.[00]")}


#: Pixels a responsive plot's title may take in the narrowest right panel (its least width, 420 px,
#: less the plot's vertical axis): such titles are broken to fit it (:func:`fit_title`).
NARROW_TITLE = 330


def frame_size(pts: pd.DataFrame, images=(), size: int = 420) -> dict:
    """Frame width/height and limits with equal scales on both axes (metres per pixel), the
    larger side ``size`` pixels; the block's footprints are included in the extent."""
    xs = list(pts["x"]) if len(pts) else [0.0]
    ys = list(pts["y"]) if len(pts) else [0.0]
    for im in images:
        for X, Y in im.get("footprint") or []:
            xs.append(float(X))
            ys.append(float(Y))
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    span = max(x1 - x0, y1 - y0, 1e-9)
    pad = 0.08 * span
    w, h = (x1 - x0) + 2 * pad, (y1 - y0) + 2 * pad
    scale = size / max(w, h)
    fw, fh = max(int(w * scale), 260), max(int(h * scale), 260)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    half_w, half_h = fw / scale / 2, fh / scale / 2
    return {"frame_width": fw, "frame_height": fh, "xlim": (cx - half_w, cx + half_w),
            "ylim": (cy - half_h, cy + half_h)}


def block_context(state) -> hv.Overlay:
    """Footprints, projection centres and strips of a block; empty layers for a network.

    The footprints are drawn as their edges (one columnar ``Segments`` element): a thousand
    polygons would make every update of the map recompute their ranges.
    """
    edges, cdf, paths = shared(state.problem, ("block-context",), lambda: _block_data(state.problem))
    footprints = hv.Segments(edges, ["x0", "y0", "x1", "y1"], label="footprints" if len(edges) else "").opts(
        color="#555555", line_alpha=0.35, line_width=1, nonselection_alpha=0.35, tools=[])
    proj = hv.Points(cdf, ["x", "y"], ["image", "strip"], label="projection centres" if len(cdf) else "").opts(
        marker="triangle", size=9 if len(cdf) <= 100 else 4, color="#444444", nonselection_alpha=1,
        tools=["hover"])
    strip_path = hv.Path(paths, label="strips" if paths else "").opts(color="#999999", line_dash="dashed",
                                                                      nonselection_alpha=1)
    return footprints * strip_path * proj


def _block_data(problem) -> tuple[np.ndarray, pd.DataFrame, list[np.ndarray]]:
    """The footprints' edges (n × 4), the projection centres (x, y, image, strip) and the strips'
    paths of a block: once per problem for every map and session (a loop over the images)."""
    images = geometry.images(problem)
    edges, centres, strips = [], [], {}
    for im in images:
        fp = im.get("footprint")
        if fp:
            fp = np.asarray(fp, dtype=float)
            edges.append(np.hstack([fp, np.roll(fp, -1, axis=0)]))
        if "X0" in im and "Y0" in im:
            centres.append((float(im["X0"]), float(im["Y0"]), plain(im.get("id")), plain(im.get("strip", ""))))
            strips.setdefault(str(im.get("strip", "")), []).append((float(im["X0"]), float(im["Y0"])))
    edges = np.vstack(edges) if edges else np.zeros((0, 4))
    cdf = pd.DataFrame(centres, columns=["x", "y", "image", "strip"])
    return edges, cdf, [np.array(v) for v in strips.values() if len(v) > 1]


def nearest(state, x: float, y: float, tol_fraction: float = 0.04):
    """What a click at (x, y) hits: ``("point", k)``, ``("obs", i)`` or None.

    A point within ``tol_fraction`` of the map extent wins; otherwise the nearest observation
    line within the same distance.
    """
    if x is None or y is None or state.results is None:
        return None
    obs, pts = state.frames()
    tol = tol_fraction * extent(pts)
    d = np.hypot(pts["x"].to_numpy() - x, pts["y"].to_numpy() - y)
    if d.size and d.min() <= tol:
        return ("point", int(np.argmin(d)))
    seg = frames.segments(state.frames()[1], state.problem_index())
    if len(seg):
        p0 = seg[["x0", "y0"]].to_numpy()
        p1 = seg[["x1", "y1"]].to_numpy()
        dv = p1 - p0
        L2 = np.maximum((dv ** 2).sum(1), 1e-300)
        t = np.clip(((np.array([x, y]) - p0) * dv).sum(1) / L2, 0, 1)
        ds = np.hypot(*(p0 + t[:, None] * dv - np.array([x, y])).T)
        if ds.min() <= tol:
            return ("obs", int(seg["obs"].iat[int(np.argmin(ds))]))
    return None


def on_tap(state):
    """A Tap-stream subscriber selecting what the click hit in ``state``."""
    def select(x=None, y=None, **_):
        hit = nearest(state, x, y)
        if hit is None:
            return
        if hit[0] == "point":
            state.param.update(selected_obs=None, selected_point=hit[1])
        else:
            state.param.update(selected_point=None, selected_obs=hit[1])
    return select


def selection_marks(state) -> tuple[pd.DataFrame, list[np.ndarray]]:
    """The selection: the points to ring (the selected point, or the selected observation's
    points; rows of the points table) and the selected observation's lines (2 × 2 arrays)."""
    obs, pts = state.frames()
    ring = pts.iloc[[]]
    line = []
    if state.selected_point is not None and state.selected_point < len(pts):
        ring = pts.iloc[[state.selected_point]]
    if state.selected_obs is not None and state.selected_obs < len(obs):
        k = state.problem_index()["obs_points"][state.selected_obs]
        ring = pts.iloc[k]
        if len(k) >= 2:
            line = [np.array([[pts["x"].iat[k[0]], pts["y"].iat[k[0]]], [pts["x"].iat[j], pts["y"].iat[j]]])
                    for j in k[1:]]
    return ring, line


def selection_data(state) -> tuple[dict, dict]:
    """:func:`selection_marks` as the data of two Bokeh sources: rings ``{x, y}`` and lines
    ``{xs, ys}`` (a map patches these on a click instead of redrawing its overlay)."""
    ring, line = selection_marks(state)
    return ({"x": ring["x"].to_numpy(dtype=float).tolist(), "y": ring["y"].to_numpy(dtype=float).tolist()},
            {"xs": [seg[:, 0].tolist() for seg in line], "ys": [seg[:, 1].tolist() for seg in line]})


def selection_layer(state) -> hv.Overlay:
    """Rings around the selected point and the selected observation's points and line (the
    options are set by the map: ``selection_opts``)."""
    ring, line = selection_marks(state)
    return hv.Path(line) * hv.Points(ring, ["x", "y"], ["id"])


def suspects_layer(state) -> hv.Overlay:
    """The robust suspects: their lines (network observations) and points (the options, orange,
    are set by the map: ``suspect_opts``)."""
    _, pts = state.frames()
    sus = frames.suspect_observations(state.robust, state.kept)
    lines, marks = [], set()
    for i in sus:
        k = state.problem_index()["obs_points"][i]
        marks.update(k[-1:] if state.problem.info.kind[i].startswith("image") else k)
        if len(k) >= 2 and not state.problem.info.kind[i].startswith("image"):
            lines += [np.array([[pts["x"].iat[k[0]], pts["y"].iat[k[0]]], [pts["x"].iat[j], pts["y"].iat[j]]])
                      for j in k[1:]]
    return hv.Path(lines) * hv.Points(pts.iloc[sorted(marks)], ["x", "y"], ["id"])
