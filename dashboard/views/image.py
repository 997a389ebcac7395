"""The image view: the residuals of one image's points in its own frame, coloured by |w|.

The vectors are drawn above hollow point markers sized from the vectors as drawn (the typical
vector shows, not only the outliers); the selected point is ringed; COLMAP's images are drawn
with y down, as their pixels are (BAL and Bundler: y up about the centre)."""

from __future__ import annotations

import math

import holoviews as hv
import numpy as np
import pandas as pd
import panel as pn
import param
from bokeh.models import FixedTicker

from .. import geometry
from ..geometry import image_points
from ..mapgeometry import W_COLORS, image_border, image_residuals, w_levels
from ..state import State
from ..text import fit_title, plain
from .maps import tips

#: The image view's frame (px): with its axes and colour bar it fits the map tabs' narrowest
#: width (``app.MAP_MIN_WIDTH``), so it is never cut beside the tables.
IMAGE_FRAME = 400
#: The least length (screen pixels) the image view draws an image's median residual vector with.
MEDIAN_PX = 12


class ImageResidualView(pn.viewable.Viewer):
    """Image-space residual vectors of one image of a block, exaggerated, coloured by |w|."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        self.dmap = hv.DynamicMap(self._render, streams=[hv.streams.Params(
            self.state, ["results", "reliability", "selected_image", "exaggeration", "selected_point",
                         "selected_obs"])])
        self._pane = pn.pane.HoloViews(self.dmap, css_classes=["map-image"], linked_axes=False)
        self._by_image = None

    def image_points(self, image) -> list[tuple[str, int, int]]:
        """(point, row of x, row of y) of every image point of ``image`` (full indices)."""
        if self._by_image is None:
            self._by_image = image_points(self.state.problem, self.state.problem_index())
        return self._by_image.get(str(image), [])

    def data(self) -> pd.DataFrame:
        """Observed image coordinates (file units) and residuals of the selected image's points."""
        s = self.state
        obs, _ = s.frames()
        pts = [(plain(t[0]), t[1], t[2]) for t in self.image_points(s.selected_image)
               if not (obs["excluded"].iat[t[1]] or obs["excluded"].iat[t[2]])]
        return image_residuals(pts, np.asarray(s.problem.info.value_file, dtype=float), obs["v"].to_numpy(dtype=float),
                               obs["w"].to_numpy(dtype=float), s.exaggeration)

    def selected(self, df: pd.DataFrame) -> pd.DataFrame:
        """The rows of ``df`` (this image's points) of the selected point, or of the selected
        observation's point."""
        s = self.state
        if s.selected_point is not None and s.selected_point < len(s.problem.points.ids):
            return df[df["point"] == plain(s.problem.points.ids[s.selected_point])]
        if s.selected_obs is not None:
            sel = df[df["obs"] == s.selected_obs]
            return sel if len(sel) else df[df["obs"] + 1 == s.selected_obs]   # (its y row)
        return df.iloc[[]]

    def span(self, df: pd.DataFrame) -> float:
        """The image's extent in its units: its size where known, else its points' extent."""
        span = max(float(np.ptp(df["x"])), float(np.ptp(df["y"])), 1e-12) if len(df) else 1.0
        size = (geometry.block(self.state.problem) or {}).get("image_size")
        return max(span, float(size[0]), float(size[1])) if size else span

    def exaggeration(self, df: pd.DataFrame) -> float:
        """The factor the vectors are drawn with: the state's, or larger where that draws this
        image's median residual vector shorter than :data:`MEDIAN_PX` screen pixels (the cap of
        the block's factor by its largest residual leaves the typical vectors a pixel long on
        real blocks): then a round factor (1, 2 or 5 × 10^k) giving it at least that. Long
        vectors then run off the image's frame."""
        ex = float(self.state.exaggeration)
        if not len(df):
            return ex
        med = float(np.nanmedian(np.hypot(df["vx"], df["vy"])))
        if not (med > 0):
            return ex
        need = MEDIAN_PX * self.span(df) / IMAGE_FRAME / med
        if ex >= need:
            return ex
        k = math.floor(math.log10(need))
        return float(next(m * 10 ** j for j in (k, k + 1) for m in (1, 2, 5) if m * 10 ** j >= need))

    def marker_size(self, df: pd.DataFrame) -> float:
        """The points' marker (hollow) in screen pixels: at most half the median residual vector
        as drawn (:data:`IMAGE_FRAME` for the image's extent), so that the typical vectors show
        beside their points and not only the outliers (issue 31, item 7); 3 to 6 px."""
        if not len(df):
            return 5.0
        drawn = np.hypot(df["x1"] - df["x"], df["y1"] - df["y"]).to_numpy(dtype=float) * IMAGE_FRAME / self.span(df)
        drawn = drawn[np.isfinite(drawn)]
        return float(np.clip(0.5 * np.median(drawn), 3.0, 6.0)) if drawn.size else 5.0

    def y_down(self) -> bool:
        """Whether the image's y axis points down (COLMAP's pixels; BAL and Bundler have y up)."""
        return (geometry.block(self.state.problem) or {}).get("convention") == "colmap"

    def _render(self, **_):
        s = self.state
        df = self.data()
        ex = self.exaggeration(df)
        df["x1"], df["y1"] = df["x"] + ex * df["vx"], df["y"] + ex * df["vy"]
        crit = s.reliability.critical
        top = max(crit, float(df["abs_w"].max()) if len(df) else 0.0)
        border = hv.Path(image_border(df, (geometry.block(s.problem) or {}).get("image_size"))).opts(color="#888888", nonselection_alpha=1)
        levels = w_levels(crit, top)
        vec = hv.Segments(df, ["x", "y", "x1", "y1"], ["point", "vx", "vy", "abs_w"]).opts(
            hover_tooltips=tips(["point", "vx", "vy", "abs_w"]),
            color="abs_w", cmap=W_COLORS, color_levels=levels, clim=(0, levels[-1]), line_width=2,
            colorbar=True, colorbar_opts={"ticker": FixedTicker(ticks=levels), "title_standoff": 8},
            clabel=f"|w| (critical {crit:.2f})", tools=["hover"], nonselection_alpha=1)
        # hollow points under the vectors, sized from the vectors as drawn
        pts = hv.Points(df, ["x", "y"], ["point", "vx", "vy", "abs_w"]).opts(
            color="#333333", fill_alpha=0, line_alpha=0.7, line_width=1, size=self.marker_size(df), tools=["hover"],
            nonselection_alpha=1)
        ring = hv.Points(self.selected(df), ["x", "y"], ["point"]).opts(
            size=20, fill_alpha=0, line_color="#e6007e", line_width=3, nonselection_alpha=1, tools=[])
        unit = ""
        if len(df):
            unit = s.frames()[0]["unit"].iat[int(df["obs"].iat[0])]
        down = self.y_down()
        frame = {}
        if len(df):                   # the image's frame: long vectors run off it, not the frame out
            edge = image_border(df, (geometry.block(s.problem) or {}).get("image_size"))
            xy = np.vstack([*edge, df[["x", "y"]].to_numpy(dtype=float)])
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            pad = 0.04 * float((hi - lo).max())
            frame = {"xlim": (lo[0] - pad, hi[0] + pad), "ylim": (lo[1] - pad, hi[1] + pad)}
        scale = f"×{ex:g}" + (f" (the block's ×{s.exaggeration:g} draws the median under {MEDIAN_PX} px)"
                              if ex != s.exaggeration else "")
        return (border * pts * vec * ring).opts(
            hv.opts.Overlay(title=fit_title(f"Image {plain(s.selected_image)}: residual vectors {scale} "
                                            f"(image units {plain(unit)}), colour |w|", IMAGE_FRAME),
                            xlabel=f"x [{unit}]", ylabel=f"y [{unit}]" + (" (down)" if down else ""),
                            invert_yaxis=down, frame_width=IMAGE_FRAME, frame_height=IMAGE_FRAME,
                            data_aspect=1, legend_position="top_left", **frame))

    def __panel__(self):
        return self._pane
