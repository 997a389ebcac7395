"""The map views: layout, redundancy, residuals / w, external reliability, MDB, precision.

Each view is one HoloViews DynamicMap over the state (``hv.streams.Params``) returning an
overlay of a fixed set of layers (block context, the view's own layers, the selection), so that
Bokeh updates its data sources in place. A click on the map goes through a ``Tap`` stream into
the state (:func:`baarda.dashboard.views.common.on_tap`).
"""

from __future__ import annotations

import holoviews as hv
import numpy as np
import pandas as pd
import panel as pn
import param
from bokeh.events import Tap

from baarda.hypotheses import HypothesisTest

from ..state import State, display_matrix
from .common import (MAP_OPTS, formatters, frame_size, R_COLORS, R_LEVELS, STATUS_COLORS, block_context, extent, on_tap,
                     round_scale, selection_layer)

HOVER_OBS = ["obs", "kind", "ids"]


def tips(columns) -> list:
    """Hover tooltips showing only the given columns (not the segment end coordinates)."""
    return [(c, f"@{{{c}}}") for c in columns]


def ellipse_xy(cov2: np.ndarray, n: int = 49) -> np.ndarray:
    """Points of the standard ellipse of a 2 × 2 covariance (n × 2, centred at 0)."""
    lam, V = np.linalg.eigh(0.5 * (cov2 + cov2.T))
    t = np.linspace(0, 2 * np.pi, n)
    return (V @ (np.sqrt(np.maximum(lam, 0.0))[:, None] * np.vstack([np.cos(t), np.sin(t)]))).T


class MapView(pn.viewable.Viewer):
    """Base class: subclasses give ``name_`` and ``layers()``; the title comes from ``title()``."""

    state = param.ClassSelector(class_=State)
    depends = ("results", "selected_point", "selected_obs", "robust")

    def __init__(self, **params):
        super().__init__(**params)
        self.dmap = hv.DynamicMap(self._render, streams=[hv.streams.Params(self.state, list(self.depends))])
        # A Tap stream with the overlay as its source receives no events in HoloViews 1.23, so
        # the figure's Bokeh Tap event is forwarded to the stream by a plot hook.
        self.tap = hv.streams.Tap(x=None, y=None)
        self.tap.add_subscriber(on_tap(self.state))
        self._hooked = set()
        self._pane = pn.pane.HoloViews(self.dmap, css_classes=[f"map-{self.key}"], linked_axes=False)

    key = "map"

    def _render(self, **_):
        s = self.state
        xl, yl = s.map_labels()
        overlay = block_context(s)
        for layer in self.layers():
            overlay = overlay * layer
        return (overlay * selection_layer(s)).opts(
            hv.opts.Overlay(title=self.title(), xlabel=xl, ylabel=yl, legend_position="bottom", legend_cols=4,
                            show_legend=self.key == "layout", hooks=[self._hook],
                            **frame_size(self.points(), s.images), **formatters(), **MAP_OPTS))

    def _hook(self, plot, element):
        fig = plot.state
        if fig.id in self._hooked:
            return
        self._hooked.add(fig.id)
        fig.on_event(Tap, lambda event: self.tap.event(x=event.x, y=event.y))

    def title(self) -> str:
        return self.key

    def layers(self) -> list:
        raise NotImplementedError

    # helpers ----------------------------------------------------------------------------------
    def segments(self, columns=()) -> pd.DataFrame:
        """The observation lines joined with the given columns of the observation table."""
        obs, _ = self.state.frames()
        seg = self.state.segments()
        cols = ["kind", "ids", *columns]
        seg = seg.join(obs[cols], on="obs") if len(seg) else pd.DataFrame(
            columns=["obs", "x0", "y0", "x1", "y1", *cols])
        return seg[~obs["excluded"].to_numpy()[seg["obs"].to_numpy(dtype=int)]] if len(seg) else seg

    def points(self) -> pd.DataFrame:
        return self.state.frames()[1]

    def labels(self) -> hv.Labels:
        pts = self.points()
        if len(pts) > 40:
            pts = pts.iloc[[]]
        return hv.Labels(pts, ["x", "y"], "id").opts(text_font_size="9pt", yoffset=0.02 * extent(pts),
                                                      text_color="#333333")

    def __panel__(self):
        return self._pane


class LayoutMap(MapView):
    """Points coloured by status, observation lines by kind; block footprints, centres, strips."""

    key = "layout"
    depends = ("results", "selected_point", "selected_obs", "robust", "hyp_results", "selected_hypothesis")

    def title(self):
        s = self.state
        text = f"Layout: {len(s.problem.points.ids)} points, {s.problem.n} observations"
        h, _ = self._hypothesis_ellipse()
        if h is not None:
            text = f"Layout; lower-bound ellipse: {h}"
        return text

    def _hypothesis_ellipse(self):
        """The selected 2D hypothesis' lower-bound ellipse on the map (label, n × 2) or (None, [])."""
        s = self.state
        k = s.selected_hypothesis
        if k is None or k >= len(s.hyp_results) or k >= len(s.hypotheses):
            return None, []
        h = s.hyp_results[k]
        if not isinstance(h, HypothesisTest) or h.q != 2 or not np.isfinite(h.ellipse_axes).all():
            return None, []
        pk = s.hypothesis_point(s.hypotheses[k])
        if pk is None:
            return None, []
        pts = self.points()
        e = h.ellipse()
        if s.hypotheses[k]["kind"] == "control":
            e = (display_matrix(s.problem) @ e.T).T
        scale = round_scale(0.08 * extent(pts) / max(np.abs(e).max(), 1e-300))
        xy = e * scale + np.array([pts["x"].iat[pk], pts["y"].iat[pk]])
        return f"{h.label} (×{scale:g})", [xy]

    def layers(self):
        seg = self.segments()
        lines = hv.Segments(seg, ["x0", "y0", "x1", "y1"], HOVER_OBS, label="observations").opts(
            hover_tooltips=tips(HOVER_OBS),
            color="kind", cmap="Category10", line_width=2, alpha=0.7, tools=["hover"],
            nonselection_alpha=0.7, show_legend=False)
        pts = self.points()
        points = hv.Points(pts, ["x", "y"], ["id", "status", "n_obs"]).opts(
            color="status", cmap=STATUS_COLORS, size=10, tools=["hover", "tap"], line_color="white",
            nonselection_alpha=1, show_legend=True)
        _, ell = self._hypothesis_ellipse()
        ellipse = hv.Path(ell, label="lower bound").opts(color="#e6007e", line_dash="dashed",
                                                         line_width=2, nonselection_alpha=1)
        return [lines, points, ellipse, self.labels()]


class RedundancyMap(MapView):
    """Per observation line r_i; per point the smallest r_i of its observations."""

    key = "redundancy"

    def title(self):
        return "Redundancy r_i (red < 0.1 uncontrolled, orange < 0.3 weak)"

    def layers(self):
        seg = self.segments(["r"])
        lines = hv.Segments(seg, ["x0", "y0", "x1", "y1"], [*HOVER_OBS, "r"]).opts(
            hover_tooltips=tips([*HOVER_OBS, "r"]),
            color="r", cmap=R_COLORS, color_levels=R_LEVELS, clim=(0, 1), line_width=3,
            tools=["hover"], nonselection_alpha=1)
        pts = self.points()
        points = hv.Points(pts, ["x", "y"], ["id", "status", "min_r", "n_obs"]).opts(
            color="min_r", cmap=R_COLORS, color_levels=R_LEVELS, clim=(0, 1), colorbar=True,
            size=12, line_color="#333333", tools=["hover", "tap"], nonselection_alpha=1,
            clipping_colors={"NaN": "#cccccc"}, clabel="r")
        return [lines, points, self.labels()]


class ResidualMap(MapView):
    """Baarda's w per observation line and the largest |w| per point; rejected ones thick."""

    key = "residuals"

    def title(self):
        adj = self.state.results
        crit = adj.critical_tau if self.state.sigma0_mode == "aposteriori" else adj.critical_w
        stat = "τ" if self.state.sigma0_mode == "aposteriori" else "w"
        return f"|w| of observations and points (critical |{stat}| = {crit:.2f})"

    def layers(self):
        seg = self.segments(["w", "v", "unit", "rejected"])
        seg = seg.assign(abs_w=np.abs(seg["w"].astype(float))) if len(seg) else seg.assign(abs_w=[])
        crit = max(self.state.results.critical_w, float(np.nanmax(seg["abs_w"], initial=0.0)) if len(seg) else 0)
        lines = hv.Segments(seg, ["x0", "y0", "x1", "y1"], [*HOVER_OBS, "w", "v", "unit", "abs_w"]).opts(
            hover_tooltips=tips([*HOVER_OBS, "w", "v", "unit", "abs_w"]),
            color="abs_w", cmap="YlOrRd", clim=(0, crit), line_width=3, tools=["hover"],
            nonselection_alpha=1)
        rej = seg[seg["rejected"].astype(bool)] if len(seg) else seg
        rejected = hv.Segments(rej, ["x0", "y0", "x1", "y1"], HOVER_OBS, label="rejected").opts(
            hover_tooltips=tips(HOVER_OBS),
            color="#b2182b", line_width=7, alpha=0.8, nonselection_alpha=0.8)
        pts = self.points()
        points = hv.Points(pts, ["x", "y"], ["id", "status", "max_w"]).opts(
            color="max_w", cmap="YlOrRd", clim=(0, crit), colorbar=True, size=12, line_color="#333333",
            tools=["hover", "tap"], nonselection_alpha=1, clipping_colors={"NaN": "#cccccc"},
            clabel="max |w|")
        return [rejected, lines, points, self.labels()]


class ExternalMap(MapView):
    """δ̄0 per point (largest over its observations); the deformation field of the selected
    observation's MDB (the core's Adjustment.deformation) or of the selected hypothesis' lower
    bound (the core's hypotheses.deformation) as vectors."""

    key = "external"
    depends = ("results", "selected_point", "selected_obs", "robust", "hyp_results", "selected_hypothesis",
               "field_source")

    def _field(self):
        s = self.state
        pts = self.points()
        label, shifts = s.external_field()
        d = (display_matrix(s.problem) @ shifts[:, :2].T).T
        if s.problem.points.dim == 1:
            d = np.column_stack([np.zeros(len(pts)), shifts[:, 2]])
        size = np.hypot(d[:, 0], d[:, 1])
        big = size.max(initial=0.0)
        scale = round_scale(0.12 * extent(pts) / big) if big > 0 else 1.0
        return label, d, size, scale

    def title(self):
        label, d, size, scale = self._field()
        if not label:
            return "External reliability δ̄0 (select an observation or a hypothesis: its ∇0x)"
        return (f"External reliability δ̄0; ∇0x of {label}: "
                f"max {1000 * size.max(initial=0):.3g} mm, ×{scale:g}")

    def layers(self):
        pts = self.points()
        points = hv.Points(pts, ["x", "y"], ["id", "status", "max_ext"]).opts(
            color="max_ext", cmap="viridis", colorbar=True, size=12, line_color="#333333",
            tools=["hover", "tap"], nonselection_alpha=1, clipping_colors={"NaN": "#cccccc"},
            clabel="δ̄0")
        _, d, size, scale = self._field()
        keep = size > 0
        vec = pd.DataFrame({"x0": pts["x"][keep], "y0": pts["y"][keep],
                            "x1": pts["x"][keep] + scale * d[keep, 0],
                            "y1": pts["y"][keep] + scale * d[keep, 1],
                            "id": pts["id"][keep], "shift_mm": 1000 * size[keep]})
        vectors = hv.Segments(vec, ["x0", "y0", "x1", "y1"], ["id", "shift_mm"], label="∇0x").opts(
            hover_tooltips=tips(["id", "shift_mm"]),
            color="#e6007e", line_width=3, tools=["hover"], nonselection_alpha=1)
        heads = hv.Points(vec, ["x1", "y1"], ["id", "shift_mm"]).opts(
            color="#e6007e", size=6, marker="circle", nonselection_alpha=1)
        context = hv.Segments(self.segments(), ["x0", "y0", "x1", "y1"], HOVER_OBS).opts(
            color="#cccccc", line_width=1, nonselection_alpha=1)
        return [context, points, vectors, heads, self.labels()]


class MDBMap(MapView):
    """MDB per observation in units of its σ (∇0l_i / σ_i = δ0/√r_i when uncorrelated)."""

    key = "mdb"

    def title(self):
        return f"Minimal detectable bias ∇0l / σ (δ0 = {self.state.results.delta0:.2f})"

    def layers(self):
        seg = self.segments(["mdb", "unit", "mdb_sigma", "r"])
        top = self._clim()
        lines = hv.Segments(seg, ["x0", "y0", "x1", "y1"], [*HOVER_OBS, "mdb", "unit", "mdb_sigma", "r"]).opts(
            hover_tooltips=tips([*HOVER_OBS, "mdb", "unit", "mdb_sigma", "r"]),
            color="mdb_sigma", cmap="plasma", clim=top, line_width=3, tools=["hover"],
            nonselection_alpha=1)
        pts = self.points()
        points = hv.Points(pts, ["x", "y"], ["id", "status", "max_mdb_sigma"]).opts(
            color="max_mdb_sigma", cmap="plasma", clim=top, colorbar=True, size=12, line_color="#333333",
            tools=["hover", "tap"], nonselection_alpha=1, clipping_colors={"NaN": "#cccccc"},
            clabel="MDB / σ")
        return [lines, points, self.labels()]

    def _clim(self):
        obs, _ = self.state.frames()
        d0 = self.state.results.delta0
        vals = obs["mdb_sigma"].to_numpy(dtype=float)
        vals = vals[np.isfinite(vals)]
        hi = float(np.percentile(vals, 98)) if vals.size else 3 * d0
        return (d0, max(hi, 1.5 * d0))


class PrecisionMap(MapView):
    """Standard error ellipses from the core's point covariances (σ0 as chosen), exaggerated."""

    key = "precision"
    depends = ("results", "selected_point", "selected_obs", "robust", "sbase")

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        datum = s.datum_points()
        self.sbase = pn.widgets.MultiChoice(
            name="S-base (empty: the problem's datum" + (f" — {', '.join(datum)})" if datum else
                                                        ", its fixed / weighted points)"),
            options=list(s.problem.points.ids), value=list(s.sbase), css_classes=["sbase-choice"],
            sizing_mode="stretch_width", visible=s.problem.points.dim > 1)
        self.sbase.param.watch(lambda e: setattr(s, "sbase", list(e.new)), "value")
        s.param.watch(lambda e: setattr(self.sbase, "value", list(e.new)), "sbase")
        self.note = pn.pane.Markdown(pn.bind(lambda *_: s.sbase_check(), s.param.results, s.param.sbase),
                                     css_classes=["sbase-note"], sizing_mode="stretch_width",
                                     visible=s.problem.points.dim > 1)

    def __panel__(self):
        return pn.Column(self.sbase, self.note, self._pane, sizing_mode="stretch_width")

    def _ellipses(self):
        s = self.state
        pts = self.points()
        M = display_matrix(s.problem)
        C = np.einsum("ij,mjk,lk->mil", M, s.point_cov2(), M)
        axis = np.sqrt(np.maximum(np.linalg.eigvalsh(C)[:, -1], 0.0))
        big = axis.max(initial=0.0)
        scale = round_scale(0.05 * extent(pts) / big) if big > 0 else 1.0
        paths = [ellipse_xy(C[k]) * scale + np.array([pts["x"].iat[k], pts["y"].iat[k]])
                 for k in range(len(pts)) if axis[k] > 0]
        return paths, scale, big

    def title(self):
        s = self.state
        sig = "σ̂0" if s.sigma0_mode == "aposteriori" else "σ0 a priori"
        if s.problem.points.dim == 1:
            return f"Precision: σ of the heights [mm] ({sig})"
        _, scale, big = self._ellipses()
        base = f"S-base {', '.join(s.sbase)}" if s.sbase and not s.sbase_error else "datum of the problem"
        return f"Standard ellipses ({sig}, {base}) ×{scale:g}, largest {1000 * big:.3g} mm"

    def layers(self):
        pts = self.points()
        paths, _, _ = self._ellipses() if self.state.problem.points.dim > 1 else ([], 1, 0)
        ell = hv.Path(paths, label="ellipses").opts(color="#1f4e9c", line_width=2, nonselection_alpha=1)
        cdim = "sz_mm" if self.state.problem.points.dim == 1 else "sx_mm"
        points = hv.Points(pts, ["x", "y"], ["id", "status", "sx_mm", "sy_mm", "sz_mm"]).opts(
            color=cdim if self.state.problem.points.dim == 1 else "status",
            cmap="viridis" if self.state.problem.points.dim == 1 else STATUS_COLORS,
            colorbar=self.state.problem.points.dim == 1, size=9, tools=["hover", "tap"],
            nonselection_alpha=1, show_legend=False)
        return [ell, points, self.labels()]


class ImageResidualView(pn.viewable.Viewer):
    """Image-space residual vectors of one image of a block, exaggerated, coloured by |w|."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        self.dmap = hv.DynamicMap(self._render, streams=[hv.streams.Params(
            self.state, ["results", "selected_image", "exaggeration", "selected_point"])])
        self._pane = pn.pane.HoloViews(self.dmap, css_classes=["map-image"], linked_axes=False)

    def data(self) -> pd.DataFrame:
        """Observed image coordinates (file units) and residuals of the selected image's points."""
        s = self.state
        p = s.problem
        obs, _ = s.frames()
        rows = {}
        for i, ids in enumerate(p.info.ids):
            if str(ids.get("image")) != str(s.selected_image) or obs["excluded"].iat[i]:
                continue
            comp = str(ids.get("component") or p.info.kind[i].rsplit("-", 1)[-1])
            rows.setdefault(str(ids.get("point")), {})[comp] = i
        recs = []
        ex = s.exaggeration
        for pid, d in rows.items():
            if "x" not in d or "y" not in d:
                continue
            ix, iy = d["x"], d["y"]
            x, y = float(p.info.value_file[ix]), float(p.info.value_file[iy])
            vx, vy = obs["v"].iat[ix], obs["v"].iat[iy]
            aw = np.nanmax(np.abs([obs["w"].iat[ix], obs["w"].iat[iy]]))
            recs.append((pid, x, y, x + ex * vx, y + ex * vy, vx, vy, aw, ix))
        return pd.DataFrame(recs, columns=["point", "x", "y", "x1", "y1", "vx", "vy", "abs_w", "obs"])

    def _render(self, **_):
        s = self.state
        df = self.data()
        crit = s.results.critical_w
        top = max(crit, float(df["abs_w"].max()) if len(df) else 0.0)
        size = (s.block or {}).get("image_size")
        frame = []
        if size:
            w, h = float(size[0]), float(size[1])
            x0, y0 = (0.0, 0.0) if (len(df) == 0 or df["x"].min() >= -1) else (-w / 2, -h / 2)
            frame = [np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h], [x0, y0]])]
        border = hv.Path(frame).opts(color="#888888", nonselection_alpha=1)
        vec = hv.Segments(df, ["x", "y", "x1", "y1"], ["point", "vx", "vy", "abs_w"]).opts(
            hover_tooltips=tips(["point", "vx", "vy", "abs_w"]),
            color="abs_w", cmap="YlOrRd", clim=(0, top), line_width=3, colorbar=True, clabel="|w|",
            tools=["hover"], nonselection_alpha=1)
        pts = hv.Points(df, ["x", "y"], ["point", "vx", "vy", "abs_w"]).opts(
            color="#333333", size=5, tools=["hover"], nonselection_alpha=1)
        unit = ""
        if len(df):
            unit = s.frames()[0]["unit"].iat[int(df["obs"].iat[0])]
        return (border * vec * pts).opts(
            hv.opts.Overlay(title=f"Image {s.selected_image}: residual vectors ×{s.exaggeration:g} "
                                  f"(image units {unit}), colour |w|",
                            xlabel=f"x [{unit}]", ylabel=f"y [{unit}]", frame_width=480, frame_height=480,
                            data_aspect=1, legend_position="top_left"))

    def __panel__(self):
        return self._pane


MAP_VIEWS = (LayoutMap, RedundancyMap, ResidualMap, ExternalMap, MDBMap, PrecisionMap)
