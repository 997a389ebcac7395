"""The precision map: standard ellipses of the points in an S-base the user chooses (M84 §2),
beside the same scale in the problem's own datum, and the S-base lesson of a controlled block
seen as a free one (:mod:`baarda.dashboard.sbase`). The projection centres of a block with
GNSS centres or IMU attitudes get their standard ellipses of X0, Y0 too, at the points' scale
(the core's pose covariance, :func:`baarda.stats.pose.pose_covariance`, issue 28), in the
problem's own datum only: they are not drawn in a chosen S-base or the free-block view. (Without
auxiliary data the centres are far less precise than the points: at the points' scale their
ellipses would cover the map.)
"""

from __future__ import annotations

import holoviews as hv
import numpy as np
import pandas as pd
import panel as pn

from baarda.errors import BaardaError

from .. import auxdata, geometry
from .. import sbase as sbase_lesson
from ..geometry import display_matrix, object_unit
from ..mapgeometry import ellipse_paths, length_text
from ..text import fit_title, html_text, id_list, labels, plain
from .common import STATUS_COLORS, formatters, frame_size
from .maps import MapView, point_size

#: The S-base list opens in the page flow (pushing the map down) instead of over the map.
INLINE_DROPDOWN = (".choices__list--dropdown, .choices__list[aria-expanded] "
                   "{ position: relative; max-height: 180px; }"
                   ".choices__list--dropdown:not(.is-active), .choices__list[aria-expanded]:not(.is-active) "
                   "{ display: none; }"
                   ".choices__list--dropdown .choices__list { max-height: 170px; }")


#: The most ellipses a precision map draws (the largest): thousands (Ladybug's 7,776) overlap
#: into a solid mass at any scale that shows them (issue 31, item 10).
MOST_ELLIPSES = 400



class PrecisionMap(MapView):
    """Standard error ellipses from the core's point covariances (σ0 as chosen), exaggerated."""

    key = "precision"

    def __init__(self, **params):
        super().__init__(**params)
        s = self.state
        datum = sbase_lesson.datum_points(s.problem)
        n_points = len(s.problem.points.ids)
        named = (f"all {n_points:,} points" if len(datum) == n_points > 8 else id_list(datum))
        self.sbase = pn.widgets.MultiChoice(
            label="S-base (empty: the problem's datum" + (f" — {named})" if datum else
                                                        ", its fixed / weighted points)"),
            options=labels(s.problem.points.ids), value=list(s.sbase), css_classes=["sbase-choice"],
            sizing_mode="stretch_width", visible=s.problem.points.dim > 1, stylesheets=[INLINE_DROPDOWN])
        self.sbase.param.watch(lambda e: setattr(s, "sbase", list(e.new)), "value")
        s.param.watch(lambda e: setattr(self.sbase, "value", list(e.new)), "sbase")
        self.free_reason = sbase_lesson.free_block_reason(s) if s.problem.points.dim > 1 else "not planimetric"
        self.free_box().visible = not self.free_reason
        self.note = pn.pane.HTML(pn.bind(lambda *_: self.note_html(), s.param.solution, s.param.sbase,
                                         self.free.param.value),
                                 css_classes=["sbase-note"], sizing_mode="stretch_width",
                                 visible=s.problem.points.dim > 1)
        self.compare = pn.pane.HoloViews(pn.bind(lambda *_: self.comparison(), s.param.solution, s.param.sbase,
                                                 self.free.param.value),
                                         css_classes=["sbase-compare"], linked_axes=False,
                                         visible=s.problem.points.dim > 1)

    def free_box(self) -> pn.widgets.Checkbox:
        """The free-block view's checkbox (made with the map's layers, whose ellipses follow it)."""
        if getattr(self, "free", None) is None:
            self.free = pn.widgets.Checkbox(label="free-block view (control left out: the S-base matters)",
                                            value=False, css_classes=["sbase-free"])
        return self.free

    def _stream(self, kind):
        """The map's streams, and one over the free-block checkbox (a layer redrawn by a state
        parameter triggered with an unchanged value would return its memoized element)."""
        if kind == "free":
            if kind not in self._streams:
                self._streams[kind] = hv.streams.Params(self.free_box(), ["value"])
            return self._streams[kind]
        return super()._stream(kind)

    def free_view(self) -> bool:
        free = getattr(self, "free", None)      # the title is asked for while the map is made
        return free is not None and bool(free.value) and not getattr(self, "free_reason", "not yet known")

    def note_html(self) -> str:
        """The note beside the S-base control (HTML): the free-block view, why the S-base changes nothing, or the r and w check."""
        s = self.state
        if self.free_view():
            base = ", ".join(s.sbase) if s.sbase else "every point (inner constraints)"
            self._ellipses()
            if getattr(self, "_free_error_for", None) != tuple(s.sbase):
                self.point_cov2()           # the ellipses came from the cache: this S-base's message
            return html_text(f"Free-block view: the control observations left out, the block adjusted as a "
                             f"free network (M84 §2); S-base: {base}. Choose other S-base points: the "
                             "ellipses change, r and w do not. " + getattr(self, "_free_error", ""))
        if s.sbase:
            s.coordinate_covariance()       # sbase_error of this S-base (the map may be drawn after the note)
        if getattr(s.problem.datum, "kind", "") != "free" and s.problem.points.dim > 1:
            text = sbase_lesson.WHY_NOT if not self.free_reason else (
                sbase_lesson.WHY_NOT.split(" Tick")[0] + f" (No free-block view: {self.free_reason}.)")
            return html_text(text + (" " + s.sbase_check() if s.sbase else ""))
        return html_text(s.sbase_check())

    def point_cov2(self) -> np.ndarray:
        """The planimetric point covariances the map shows: the state's (its S-base) or, in the
        free-block view, the free block's in the chosen S-base."""
        s = self.state
        self._free_error, self._free_error_for = "", tuple(s.sbase)
        if self.free_view():
            try:
                return sbase_lesson.free_point_cov2(s, s.sbase)
            except (BaardaError, np.linalg.LinAlgError) as err:   # a base that does not fix the datum
                self._free_error = f"S-base {', '.join(s.sbase)}: {err}; shown with every point instead."
                return sbase_lesson.free_point_cov2(s, [])
        return s.point_cov2()

    def comparison(self):
        """The same ellipses at the same scale in the reference base (the problem's own datum; in
        the free-block view the inner constraints over every point) beside the chosen S-base."""
        s = self.state
        pts = self.points()
        _, scale, _, _ = self._ellipses()
        if self.free_view():
            cov, name = sbase_lesson.free_point_cov2(s, []), "free block, all points"
        else:
            cov, name = s.results.point_cov[:, :2, :2], "own datum"
        paths, _, _, _ = self._ellipse_paths(cov, scale)
        size = frame_size(pts, geometry.images(s.problem), size=260)
        return (hv.Path(paths).opts(color="#7f7f7f", line_width=2)
                * hv.Points(pts, ["x", "y"], ["id"]).opts(color="#333333", size=point_size(pts, (3, 3, 1)))).opts(
            # no axes (the map's beside it has them): a 260-px frame's tick labels overlapped
            title=fit_title(f"Same scale ×{scale:g}: {name}", size["frame_width"] - 20, 12), xlabel="", ylabel="",
            toolbar=None, fontsize={"title": "9pt"}, xaxis=None, yaxis=None,
            **size, **formatters())

    def __panel__(self):
        # the comparison in a row of its own: a plot in the column beside the map had its frame
        # aligned with the map's (85 px in, past its 280-px pane: the plot and its title cut)
        return pn.Column(self.sbase, self.free, self.note, self._pane, self.far_note, pn.Row(self.compare),
                         sizing_mode="stretch_width")

    def _ellipses(self):
        s = self.state
        return self.cached("ellipses", (s.solution, s.sbase, self.free_view()), self._ellipses_now)

    def _ellipse_paths(self, cov2: np.ndarray, scale: float | None = None):
        """The standard ellipses of ``cov2`` on this map (:func:`~baarda.dashboard.mapgeometry.ellipse_paths`),
        the :data:`MOST_ELLIPSES` largest."""
        return ellipse_paths(cov2, display_matrix(self.state.problem), self.points(), scale, most=MOST_ELLIPSES)

    def _ellipses_now(self):
        return self._ellipse_paths(self.point_cov2())

    def title(self):
        s = self.state
        sig = "σ̂0" if s.sigma0_mode == "aposteriori" else "σ0 a priori"
        unit = object_unit(s.problem)
        if s.problem.points.dim == 1:
            return f"Precision: σ of the heights [{'mm' if unit == 'm' else 'block units'}] ({sig})"
        _, scale, big, off = self._ellipses()
        base = f"S-base {plain(', '.join(s.sbase))}" if s.sbase and not s.sbase_error else "own datum"
        if self.free_view():
            base = "free block, " + (f"S-base {plain(', '.join(s.sbase))}" if s.sbase else "all points")
        text = f"Standard ellipses ×{scale:g}, largest drawn {length_text(big, unit)}"
        if len(self.points()) - off > MOST_ELLIPSES:
            text += f"; the {MOST_ELLIPSES} largest of {len(self.points()):,}"
        if off:
            text += f"; {off} off-scale, not drawn"
        return f"{text} ({sig}, {base})"

    def layers(self):
        # the centres above the points (the points of a regular pattern lie under the centres)
        return [self.layer(self._ellipse_layer, "solution", "sbase", "free"), self.layer(self._points, "solution"),
                self.layer(self._centre_layer, "solution", "sbase", "free"), self.layer(self.labels, "solution")]

    def aux_legend(self) -> bool:
        """The precision map of a block with GNSS or IMU has a legend (the projection centres' ellipses)."""
        p = self.state.problem
        return bool(geometry.images(p)) and (auxdata.has_gnss(p) or auxdata.has_imu(p))

    def _centres_shown(self) -> bool:
        s = self.state
        return self.aux_legend() and s.problem.points.dim > 1 and not s.sbase and not self.free_view()

    def centre_ellipses(self):
        """The projection centres' standard ellipses at the points' scale: (paths, centres table)."""
        s = self.state
        c = auxdata.centre_precision(s) if self._centres_shown() else None
        if c is None or not len(c):
            return [], pd.DataFrame(columns=["image", "x", "y", "sX0_mm", "sY0_mm", "sZ0_mm"])
        scale = self._ellipses()[1]
        paths, _, _, _ = ellipse_paths(np.stack(c["cov"].to_list()), display_matrix(s.problem), c.assign(far=False),
                                       scale)
        return paths, c.drop(columns="cov")

    def _centre_layer(self):
        paths, c = self.centre_ellipses()
        label = "projection centres, σ X0, Y0 (own datum)" if len(c) else ""
        return (hv.Path(paths, label=label).opts(color="#00838f", line_width=2, line_dash="dashed",
                                                 nonselection_alpha=1, show_legend=True)
                * hv.Points(c, ["x", "y"], ["image", "sX0_mm", "sY0_mm", "sZ0_mm"], label=label).opts(
                    marker="triangle", size=8, color="#00838f", tools=["hover"], nonselection_alpha=1,
                    show_legend=True))

    def _ellipse_layer(self):
        paths = self._ellipses()[0] if self.state.problem.points.dim > 1 else []
        return hv.Path(paths, label="ellipses").opts(color="#1f4e9c", line_width=2, nonselection_alpha=1)

    def _points(self):
        level = self.state.problem.points.dim == 1
        pts = self.points()
        return hv.Points(pts, ["x", "y"], ["id", "status", "sx_mm", "sy_mm", "sz_mm"]).opts(
            color="sz_mm" if level else "status", cmap="viridis" if level else STATUS_COLORS,
            colorbar=level, clabel="σ height [mm]", size=point_size(pts, (9, 4, 2)), tools=["hover", "tap"],
            nonselection_alpha=1, show_legend=False)
