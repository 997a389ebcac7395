"""The map views: layout, redundancy, residuals / w, external reliability, MDB (the precision map
in :mod:`.precision`, the image view in :mod:`.image`).

Each map is an overlay of layers, and each layer is its own HoloViews DynamicMap over only the
state parameters it shows (``hv.streams.Params``): the block context (static), the view's data
layers (``results``), a hypothesis layer (the lower-bound ellipse, the deformation field), the
robust suspects. A change redraws only the layers that depend on it; the others return their
memoized element and Bokeh keeps their data sources as they are. The selection (rings and the
selected line) is not a HoloViews layer: two Bokeh glyphs of the map's figure whose sources
are replaced on a click, so a click costs no overlay update (issue 12: a click answers in
well under a second while other sessions compute). The title
is set on the Bokeh figure after every update (:meth:`MapView._hook`). A click on the map goes
through a ``Tap`` stream into the state (:func:`baarda.dashboard.views.common.on_tap`).
The views only render: what they draw (the frame and its far points, the |w| scale, the
exaggerated ellipses and vectors) is computed by :mod:`baarda.dashboard.mapgeometry`.
"""

from __future__ import annotations

import functools
import operator

import holoviews as hv
import numpy as np
import pandas as pd
import panel as pn
import param
from bokeh.events import Tap
from bokeh.models import ColumnDataSource, FixedTicker


from .. import auxdata, frames, geometry, specs
from ..geometry import display_matrix, object_unit
from ..jobs import next_tick
from ..mapgeometry import (W_COLORS, clamped_segments, deformation_field, extent, far_note,
                           field_vectors, framed, hypothesis_ellipse, largest_abs_w, length_text,
                           log_clim, w_levels)
from ..state import State
from ..text import fit_title, plain
from .common import (MAP_OPTS, formatters, frame_size, R_COLORS, R_LEVELS, STATUS_COLORS, block_context, on_tap,
                     selection_data, selection_layer, suspects_layer)

HOVER_OBS = ["obs", "kind", "ids"]
#: The GNSS centres' colour (teal: not one of the |w| scale's, the statuses' or the selection's).
GNSS_COLOR = "#00838f"
#: The check points' residual colour (a darker green than the "check" status of the points).
CHECK_COLOR = "#1b5e20"
HOVER_GNSS = [("image", "@{image}"), ("strip", "@{strip}"),
              ("v x, y, z [m]", "@{vx}{0.0000}, @{vy}{0.0000}, @{vz}{0.0000}"),
              ("w x, y, z", "@{wx}{0.00}, @{wy}{0.00}, @{wz}{0.00}"),
              ("3-D test T", "@{T}{0.00} (critical @{critical}{0.00})")]
HOVER_CHECK = [("check point", "@{id}"), ("adjusted − known X, Y, Z", "@{dX}{0.0000}, @{dY}{0.0000}, @{dZ}{0.0000}")]



def selection_opts() -> tuple:
    """Options of the selection layer: rings and the selected line (magenta)."""
    return (hv.opts.Points(size=22, fill_alpha=0, line_color="#e6007e", line_width=3, nonselection_alpha=1,
                           tools=[]),
            hv.opts.Path(color="#e6007e", line_width=4, nonselection_alpha=1))


def suspect_opts() -> tuple:
    """Options of the robust suspects' layer (orange diamonds and dotted lines)."""
    return (hv.opts.Points(marker="diamond", size=20, fill_alpha=0, line_color="#ff7f0e", line_width=3,
                           nonselection_alpha=1, tools=[]),
            hv.opts.Path(color="#ff7f0e", line_width=6, alpha=0.6, line_dash="dotted", nonselection_alpha=0.6))


#: The state parameters behind each kind of layer (one ``Params`` stream per kind and view).
STREAMS = {
    "solution": ["solution"],
    # a new test policy: same results, new reliability, and "results" triggered after it
    # (State._options_changed); both are set together otherwise, reliability first
    "results": ["results"],
    "selection": ["selected_point", "selected_obs"],
    "robust": ["robust"],
    "hypothesis": ["outcomes", "selected_hypothesis"],
    "field": ["outcomes", "selected_hypothesis", "selected_obs", "field_source"],
    "sbase": ["sbase"],
}


class Changed(hv.streams.Stream):
    """A layer's trigger: ``n`` counts the changes of the state parameters behind it."""

    n = param.Integer(default=0)


#: The shortest colour bar of a map (px): the least frame height (``common.frame_size``) less
#: its ends. A colour bar's title runs along the bar and is cut where it is longer (issue 31,
#: item 10: the w map's was).
COLORBAR_PX = 250


def colorbar_title(text: str, char_px: float = 6.3) -> str:
    """``text`` as a colour bar's title: its words up to the last that fits :data:`COLORBAR_PX`
    (``char_px``: the mean width of a character of Bokeh's colour bar title, measured in
    Chromium), then "…"."""
    most = int(COLORBAR_PX / char_px)
    if len(text) <= most:
        return text
    return text[:most - 1].rsplit(" ", 1)[0] + "…"


def tips(columns) -> list:
    """Hover tooltips showing only the given columns (not the segment end coordinates)."""
    return [(c, f"@{{{c}}}") for c in columns]


def _same(a, b) -> bool:
    """The same object, or equal numbers / strings (a cache key compares results by identity)."""
    return a is b or (isinstance(a, (int, float, str)) and type(a) is type(b) and a == b)


#: Above this many points a map's markers are dots (Ladybug's 7,776 points at 4-6 px were one
#: solid mass on the precision map).
DENSE_POINTS = 3_000


def point_size(pts: pd.DataFrame, sizes: tuple = (12, 6, 2)) -> float:
    """Marker size of the data points: smaller on large blocks, so that they do not merge —
    ``sizes`` for at most 500 points, at most :data:`DENSE_POINTS`, and more."""
    n = len(pts)
    return sizes[0] if n <= 500 else sizes[1] if n <= DENSE_POINTS else sizes[2]


class MapView(pn.viewable.Viewer):
    """Base class: subclasses give ``key``, ``layers()`` and ``title()``."""

    state = param.ClassSelector(class_=State)
    key = "map"

    def __init__(self, **params):
        super().__init__(**params)
        self._streams = {}
        self._memo = {}
        #: on screen (the app tells, :meth:`set_shown`); a hidden map redraws nothing until shown
        self.shown = True
        self._pending: set = set()
        # A Tap stream with the overlay as its source receives no events in HoloViews 1.23, so
        # the figure's Bokeh Tap event is forwarded to the stream by a plot hook.
        self.tap = hv.streams.Tap(x=None, y=None)
        self.tap.add_subscriber(on_tap(self.state))
        self._hooked = set()
        s = self.state
        self._layers = [*self.layers(), self.layer(self._far, "solution"),
                        self.layer(self._suspects, "solution", "robust", opts=suspect_opts())]
        # the selection's Bokeh sources, one pair per figure of this view (same document)
        self._selection_sources: list[tuple[ColumnDataSource, ColumnDataSource]] = []
        s.param.watch(self._selection_changed, ["selected_point", "selected_obs", "solution"])
        dmaps = [hv.DynamicMap(lambda render=render, **_: render(),
                               streams=[self._stream(k) for k in kinds]).opts(*opts)
                 for render, kinds, opts in self._layers]
        self.dmap = functools.reduce(operator.mul, [block_context(s), *dmaps]).opts(self._overlay_opts())
        s.param.watch(self._state_changed, sorted({p for k in self._streams for p in STREAMS.get(k, ())}))

        self._pane = pn.pane.HoloViews(self.dmap, css_classes=[f"map-{self.key}"], linked_axes=False)
        self.far_note = pn.pane.HTML("", css_classes=["far-note"], sizing_mode="stretch_width", visible=False)
        self._far_changed()
        s.param.watch(self._far_changed, ["solution"])

    def _far_changed(self, *_):
        note = far_note(self.points()) if self.state.results is not None else ""
        self.far_note.param.update(object=plain(note), visible=bool(note))

    def _far(self):
        pts = self.points()
        far = pts[pts["far"]]
        return hv.Points(far, ["x", "y"], ["id", "x_true", "y_true"],
                         label="far points (at the edge)" if len(far) else "").opts(
            marker="inverted_triangle", size=11, fill_color="white", line_color="#555555", line_width=2,
            tools=["hover"], nonselection_alpha=1, show_legend=True)

    def far_count(self) -> int:
        return int(self.points()["far"].sum())

    def _overlay_opts(self):
        xl, yl = geometry.display_xy(self.state.problem, self.state.results.coordinates)[2:]
        size = frame_size(self.points(), geometry.images(self.state.problem))
        return hv.opts.Overlay(title=self.title_text(size["frame_width"]), xlabel=xl, ylabel=yl, legend_position="bottom",
                               legend_cols=4, show_legend=self.key == "layout" or self.aux_legend(),
                               hooks=[self._hook],
                               **size, **formatters(), **MAP_OPTS)

    def title_text(self, width: float) -> str:
        """The title as text (:func:`plain`) in lines that fit a frame ``width`` pixels wide."""
        return fit_title(plain(self.title()), width)

    @staticmethod
    def layer(render, *kinds, opts=()) -> tuple:
        """A layer: ``render()`` gives its element, redrawn when the parameters of ``kinds``
        (:data:`STREAMS`) change, and the options ``opts`` (``hv.opts.*``) set once on the
        layer (cheaper than on every element of a layer that changes often)."""
        return render, kinds, tuple(opts)

    def _stream(self, kind) -> Changed:
        """The view's one stream of a kind of layer (shared by its layers): triggered when the
        state parameters of that kind (:data:`STREAMS`) change while the map is shown."""
        if kind not in self._streams:
            self._streams[kind] = Changed(rename={"n": f"{kind}_changes"})
        return self._streams[kind]

    def _state_changed(self, *events):
        """Redraw the layers behind the changed parameters now, or once shown (:meth:`set_shown`)."""
        names = {e.name for e in events}
        kinds = {k for k in self._streams if names & set(STREAMS.get(k, ()))}
        if self.shown:
            self._redraw(kinds)
        else:
            self._pending |= kinds

    def _redraw(self, kinds) -> None:
        streams = [self._streams[k] for k in sorted(kinds)]
        for st in streams:
            st.update(n=st.n + 1)
        if streams:
            hv.streams.Stream.trigger(streams)

    def set_shown(self, shown: bool) -> None:
        """The map is on screen (``shown``) or not: a hidden map's layers are not redrawn while
        the state changes, and are redrawn once, with what changed meanwhile, when shown."""
        self.shown = bool(shown)
        if self.shown and self._pending:
            kinds, self._pending = self._pending, set()
            self._redraw(kinds)

    def static(self) -> hv.Overlay:
        """The map as it is now, as a plain overlay (for the HTML report)."""
        layers = [*self._layers, self.layer(self._selection, opts=selection_opts())]
        overlay = functools.reduce(operator.mul, [block_context(self.state),
                                                  *(r().opts(*o) for r, _, o in layers)])
        opts = self._overlay_opts()
        return overlay.opts(opts).opts(hv.opts.Overlay(title=opts.kwargs["title"], hooks=[]))

    def cached(self, name: str, key: tuple, compute):
        """``compute()``, kept until ``key`` changes (shared by a layer and the title)."""
        hit = self._memo.get(name)
        if hit is not None and len(hit[0]) == len(key) and all(map(_same, hit[0], key)):
            return hit[1]
        value = compute()
        self._memo[name] = (key, value)
        return value

    def _hook(self, plot, element):
        fig = plot.state
        fig.title.text = self.title_text(fig.frame_width or frame_size(self.points(), geometry.images(self.state.problem))["frame_width"])
        if fig.id in self._hooked:
            return
        self._hooked.add(fig.id)
        # the page's script scales the frame to the map tabs' width (app.KEYBOARD_JS, fitMaps)
        fig.tags = [*fig.tags, "baarda-map"]
        fig.on_event(Tap, lambda event: self.tap.event(x=event.x, y=event.y))
        rings, lines = selection_data(self.state)
        rings, lines = ColumnDataSource(rings), ColumnDataSource(lines)
        fig.multi_line(xs="xs", ys="ys", source=lines, line_color="#e6007e", line_width=4,
                       nonselection_line_alpha=1.0, name="selection-lines")
        fig.scatter(x="x", y="y", source=rings, size=22, fill_alpha=0, line_color="#e6007e", line_width=3,
                    nonselection_line_alpha=1.0, nonselection_fill_alpha=0, name="selection-rings")
        self._selection_sources.append((rings, lines))

    def _selection_changed(self, *_):
        """A new selection: only the two selection sources get new data (no overlay update)."""
        if not self._selection_sources or self.state.results is None:
            return
        rings, lines = selection_data(self.state)
        for r, l in self._selection_sources:
            doc = r.document
            if doc is None or doc.session_context is None:
                r.data, l.data = rings, lines
            else:
                # served: changed on the document's next tick, where Bokeh holds its lock
                # (a Panel widget's callback, e.g. a table row selected, runs without it)
                def patch(r=r, l=l):
                    r.data, l.data = rings, lines
                next_tick(doc, patch)

    def _suspects(self):
        return suspects_layer(self.state)

    def _selection(self):
        return selection_layer(self.state)

    def title(self) -> str:
        return self.key

    def layers(self) -> list:
        raise NotImplementedError

    # GNSS centres and check points (issue 28; baarda.dashboard.auxdata) -------------------------
    def aux_legend(self) -> bool:
        """Whether the map shows a legend for its GNSS or check-point layers (the residual map)."""
        s = self.state
        return self.key == "residuals" and (auxdata.has_gnss(s.problem) or auxdata.check_points(s)["n"] > 0)

    def aux_layers(self) -> list:
        """The GNSS residual vectors at the projection centres and the check points' residual
        vectors (adjusted − known), each with its legend entry (its exaggeration); none where the
        block has neither."""
        s = self.state
        out = []
        if auxdata.has_gnss(s.problem):
            out.append(self.layer(self._gnss, "results"))
        if auxdata.check_points(s)["n"]:
            out.append(self.layer(self._checks, "solution"))
        return out

    def _gnss_data(self):
        g = auxdata.gnss_centres(self.state)
        scale = auxdata.vector_scale(np.hypot(g["vx"].to_numpy(dtype=float), g["vy"].to_numpy(dtype=float)),
                                     self.points())
        seg = auxdata.vectors(g, "vx", "vy", scale)
        return seg.assign(edge=np.where(seg["rejected"].astype(bool), "#b2182b", "white")), scale

    def _gnss(self):
        seg, scale = self._gnss_data()
        vd = ["image", "strip", "vx", "vy", "vz", "wx", "wy", "wz", "T", "critical"]
        label = f"GNSS residuals ×{scale:g}"
        lines = hv.Segments(seg, ["x0", "y0", "x1", "y1"], vd, label=label).opts(
            color=GNSS_COLOR, line_width=3, hover_tooltips=HOVER_GNSS, tools=["hover"], nonselection_alpha=1,
            show_legend=True)
        marks = hv.Points(seg, ["x", "y"], [*vd, "edge"], label=label).opts(
            marker="diamond", size=12, color=GNSS_COLOR, line_color="edge", line_width=2,
            hover_tooltips=HOVER_GNSS, tools=["hover"], nonselection_alpha=1, show_legend=True)
        return lines * marks

    def _checks(self):
        cp = auxdata.check_vectors(self.state, self.points())
        scale = auxdata.vector_scale(np.hypot(cp["de"].to_numpy(dtype=float), cp["dn"].to_numpy(dtype=float)),
                                     self.points())
        seg = auxdata.vectors(cp, "de", "dn", scale)
        label = f"check points, adjusted − known ×{scale:g}"
        lines = hv.Segments(seg, ["x0", "y0", "x1", "y1"], ["id", "dX", "dY", "dZ"], label=label).opts(
            color=CHECK_COLOR, line_width=3, hover_tooltips=HOVER_CHECK, tools=["hover"], nonselection_alpha=1,
            show_legend=True)
        marks = hv.Points(seg, ["x", "y"], ["id", "dX", "dY", "dZ"], label=label).opts(
            marker="square", size=16, fill_alpha=0, line_color=CHECK_COLOR, line_width=2.5,
            hover_tooltips=HOVER_CHECK, tools=["hover"], nonselection_alpha=1, show_legend=True)
        return lines * marks

    # helpers ----------------------------------------------------------------------------------
    def segments(self, columns=()) -> pd.DataFrame:
        """The observation lines joined with the given columns of the observation table."""
        obs, _ = self.state.frames()
        seg = frames.segments(self.state.frames()[1], self.state.problem_index())
        cols = ["kind", "ids", *columns]
        seg = seg.join(obs[cols], on="obs") if len(seg) else pd.DataFrame(
            columns=["obs", "x0", "y0", "x1", "y1", *cols])
        seg = clamped_segments(seg, self.state.frames()[1])
        return seg[~obs["excluded"].to_numpy()[seg["obs"].to_numpy(dtype=int)]] if len(seg) else seg

    def points(self) -> pd.DataFrame:
        """The points table of the state with far points at the frame's edge (:func:`framed`)."""
        raw = self.state.frames()[1]
        return self.cached("points", (raw,), lambda: framed(raw))

    def labels(self) -> hv.Labels:
        pts = self.points()
        if len(pts) > 40:
            pts = pts.iloc[[]]
        return hv.Labels(pts, ["x", "y"], "id").opts(text_font_size="9pt", yoffset=0.02 * extent(pts),
                                                      text_color="#333333")

    def __panel__(self):
        return pn.Column(self._pane, self.far_note, sizing_mode="stretch_width")


class LayoutMap(MapView):
    """Points coloured by status, observation lines by kind; block footprints, centres, strips."""

    key = "layout"

    def title(self):
        s = self.state
        text = f"Layout: {len(s.problem.points.ids)} points, {s.problem.n} observations"
        if self.far_count():
            text += f" ({self.far_count()} far, at the edge)"
        h, _ = self._hypothesis_ellipse()
        if h is not None:
            text = f"Lower-bound ellipse {h}"     # short: the figure is narrow
        return text

    def _hypothesis_ellipse(self):
        """The selected 2D hypothesis' lower-bound ellipse on the map (label, n × 2) or (None, [])."""
        s = self.state
        k = s.selected_hypothesis
        if k is None or k >= len(s.outcomes) or k >= len(s.hypotheses):
            return None, []
        h = s.outcomes[k].test
        if h is None or h.q != 2 or not np.isfinite(h.ellipse_axes).all():
            return None, []
        pk = specs.point(s.problem, s.hypotheses[k], s.problem_index())
        if pk is None:
            return None, []
        pts = self.points()
        e = h.ellipse()
        if s.hypotheses[k]["kind"] == "control":
            e = (display_matrix(s.problem) @ e.T).T
        scale, xy = hypothesis_ellipse(e, pts, pk)
        return f"×{scale:g}: {h.label}", [xy]

    def layers(self):
        return [self.layer(self._lines, "solution"), self.layer(self._points, "solution"),
                self.layer(self._ellipse, "solution", "hypothesis", opts=[hv.opts.Path(
                    color="#e6007e", line_dash="dashed", line_width=2, nonselection_alpha=1)]),
                *self.aux_layers(), self.layer(self.labels, "solution")]

    def _lines(self):
        return hv.Segments(self.segments(), ["x0", "y0", "x1", "y1"], HOVER_OBS, label="observations").opts(
            hover_tooltips=tips(HOVER_OBS),
            color="kind", cmap="Category10", line_width=2, alpha=0.7, tools=["hover"],
            nonselection_alpha=0.7, show_legend=False)

    def _points(self):
        return hv.Points(self.points(), ["x", "y"], ["id", "status", "n_obs"]).opts(
            color="status", cmap=STATUS_COLORS, size=point_size(self.points(), (10, 5, 2)),
            tools=["hover", "tap"], line_color="white", nonselection_alpha=1, show_legend=True)

    def _ellipse(self):
        _, ell = self._hypothesis_ellipse()
        return hv.Path(ell, label="lower bound")


class RedundancyMap(MapView):
    """Per observation line r_i; per point the smallest r_i of its observations."""

    key = "redundancy"

    def title(self):
        return "Redundancy r_i (red < 0.1 uncontrolled, orange < 0.3 weak)"

    def layers(self):
        return [self.layer(self._lines, "solution"), self.layer(self._points, "solution"),
                self.layer(self.labels, "solution")]

    def _lines(self):
        return hv.Segments(self.segments(["r"]), ["x0", "y0", "x1", "y1"], [*HOVER_OBS, "r"]).opts(
            hover_tooltips=tips([*HOVER_OBS, "r"]),
            color="r", cmap=R_COLORS, color_levels=R_LEVELS, clim=(0, 1), line_width=3,
            tools=["hover"], nonselection_alpha=1)

    def _points(self):
        return hv.Points(self.points(), ["x", "y"], ["id", "status", "min_r", "n_obs"]).opts(
            color="min_r", cmap=R_COLORS, color_levels=R_LEVELS, clim=(0, 1), colorbar=True,
            size=point_size(self.points()), line_color="#333333", tools=["hover", "tap"], nonselection_alpha=1,
            clipping_colors={"NaN": "#cccccc"}, clabel=colorbar_title("r (red < 0.1, orange < 0.3)"))


class ResidualMap(MapView):
    """Baarda's w per observation line and the largest |w| per point; rejected ones thick."""

    key = "residuals"

    def title(self):
        rel = self.state.reliability
        return (f"|w| of observations and points (critical |{rel.policy.statistic_name}| = "
                f"{rel.critical:.2f})")

    def layers(self):
        return [self.layer(self._rejected, "results"), self.layer(self._lines, "results"),
                self.layer(self._points, "results"), *self.aux_layers(), self.layer(self.labels, "solution")]

    def _segments(self):
        return self.cached("segments", (self.state.reliability,), lambda: self._segments_now())

    def _segments_now(self):
        seg = self.segments(["w", "v", "unit", "rejected"])
        return seg.assign(abs_w=np.abs(seg["w"].astype(float))) if len(seg) else seg.assign(abs_w=[])

    def levels(self) -> list[float]:
        """The |w| scale (:func:`w_levels`) up to the largest |w| of the lines and points."""
        return w_levels(self.state.reliability.critical, largest_abs_w(self._segments(), self.points()))

    def _scale_opts(self) -> dict:
        levels = self.levels()
        return dict(cmap=W_COLORS, color_levels=levels, clim=(0, levels[-1]),
                    colorbar_opts={"ticker": FixedTicker(ticks=levels)})

    def _lines(self):
        return hv.Segments(self._segments(), ["x0", "y0", "x1", "y1"], [*HOVER_OBS, "w", "v", "unit", "abs_w"]).opts(
            hover_tooltips=tips([*HOVER_OBS, "w", "v", "unit", "abs_w"]),
            color="abs_w", line_width=3, tools=["hover"], nonselection_alpha=1, **self._scale_opts())

    def _rejected(self):
        seg = self._segments()
        rej = seg[seg["rejected"].astype(bool)] if len(seg) else seg
        return hv.Segments(rej, ["x0", "y0", "x1", "y1"], HOVER_OBS, label="rejected" if len(rej) else "").opts(
            hover_tooltips=tips(HOVER_OBS),
            color="#b2182b", line_width=7, alpha=0.8, nonselection_alpha=0.8)

    def _points(self):
        pts = self.points()
        crit = self.state.reliability.critical
        # the rejected points drawn last (on top of the accepted ones of a dense block)
        pts = pts.iloc[np.argsort(np.nan_to_num(pts["max_w"].to_numpy(dtype=float), nan=-1.0), kind="stable")]
        return hv.Points(pts, ["x", "y"], ["id", "status", "max_w"]).opts(
            color="max_w", colorbar=True, size=point_size(pts),
            line_color="#333333" if len(pts) <= 500 else None, tools=["hover", "tap"], nonselection_alpha=1,
            clipping_colors={"NaN": "#cccccc"}, clabel=colorbar_title(f"largest |w| per point (critical {crit:.2f})"),
            **self._scale_opts())


class ExternalMap(MapView):
    """δ̄0 per point (largest over its observations); the deformation field of the selected
    observation's MDB (the core's Adjustment.deformation) or of the selected hypothesis' lower
    bound (the core's hypotheses.deformation) as vectors."""

    key = "external"

    def _field(self):
        s = self.state
        key = (s.reliability, s.outcomes, s.selected_hypothesis, s.selected_obs, s.field_source)
        return self.cached("field", key, self._field_now)

    def _field_now(self):
        s = self.state
        pts = self.points()
        label, shifts = s.external_field()
        d, size, scale = deformation_field(shifts, display_matrix(s.problem), s.problem.points.dim, pts)
        return label, d, size, scale

    def title(self):
        label, d, size, scale = self._field()
        if not label:
            return "External reliability δ̄0 (select an observation or a hypothesis: its ∇0x)"
        return (f"External reliability: ∇0x of {label}, "
                f"max {length_text(size.max(initial=0), object_unit(self.state.problem))} ×{scale:g}")

    def layers(self):
        return [self.layer(self._context, "solution"), self.layer(self._points, "results"),
                self.layer(self._vectors, "results", "field", opts=[
                    hv.opts.Segments(hover_tooltips=tips(["id", "shift_mm"]), color="#e6007e", line_width=3,
                                     tools=["hover"], nonselection_alpha=1),
                    hv.opts.Points(color="#e6007e", size=6, marker="circle", nonselection_alpha=1)]),
                self.layer(self.labels, "solution")]

    def _points(self):
        pts = self.points()
        return hv.Points(pts, ["x", "y"], ["id", "status", "max_ext"]).opts(
            color="max_ext", cmap="viridis", logz=True, clim=log_clim(pts["max_ext"]), colorbar=True,
            size=point_size(pts), line_color="#333333", tools=["hover", "tap"], nonselection_alpha=1,
            clipping_colors={"NaN": "#cccccc"}, clabel=colorbar_title("δ̄0, largest per point (log scale)"))

    def _context(self):
        return hv.Segments(self.segments(), ["x0", "y0", "x1", "y1"], HOVER_OBS).opts(
            color="#cccccc", line_width=1, nonselection_alpha=1)

    def _vectors(self):
        pts = self.points()
        _, d, size, scale = self._field()
        vec = field_vectors(pts, d, size, scale)
        return (hv.Segments(vec, ["x0", "y0", "x1", "y1"], ["id", "shift_mm"], label="∇0x")
                * hv.Points(vec, ["x1", "y1"], ["id", "shift_mm"]))


class MDBMap(MapView):
    """MDB per observation in units of its σ (∇0l_i / σ_i = δ0/√r_i when uncorrelated)."""

    key = "mdb"

    def title(self):
        return f"Minimal detectable bias ∇0l / σ (δ0 = {self.state.reliability.delta0:.2f})"

    def layers(self):
        return [self.layer(self._lines, "results"), self.layer(self._points, "results"),
                self.layer(self.labels, "solution")]

    def _lines(self):
        seg = self.segments(["mdb", "unit", "mdb_sigma", "r"])
        return hv.Segments(seg, ["x0", "y0", "x1", "y1"], [*HOVER_OBS, "mdb", "unit", "mdb_sigma", "r"]).opts(
            hover_tooltips=tips([*HOVER_OBS, "mdb", "unit", "mdb_sigma", "r"]),
            color="mdb_sigma", cmap="plasma", logz=True, clim=self._clim(), line_width=3, tools=["hover"],
            nonselection_alpha=1)

    def _points(self):
        pts = self.points()
        return hv.Points(pts, ["x", "y"], ["id", "status", "max_mdb_sigma"]).opts(
            color="max_mdb_sigma", cmap="plasma", logz=True, clim=self._clim(), colorbar=True,
            size=point_size(pts), line_color="#333333", tools=["hover", "tap"], nonselection_alpha=1,
            clipping_colors={"NaN": "#cccccc"}, clabel=colorbar_title("MDB / σ, largest per point (log scale)"))

    def _clim(self):
        """From δ0 (r = 1) to the largest MDB / σ: a log scale does not saturate on the
        near-uncontrolled observations (r ≈ 1e-4 gives MDB / σ ≈ 100 δ0)."""
        obs, _ = self.state.frames()
        d0 = self.state.reliability.delta0
        return log_clim(obs["mdb_sigma"].to_numpy(dtype=float), low=d0)
