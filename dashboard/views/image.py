"""The image view: the residuals of one image's points in its own frame, coloured by |w|."""

from __future__ import annotations

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


class ImageResidualView(pn.viewable.Viewer):
    """Image-space residual vectors of one image of a block, exaggerated, coloured by |w|."""

    state = param.ClassSelector(class_=State)

    def __init__(self, **params):
        super().__init__(**params)
        self.dmap = hv.DynamicMap(self._render, streams=[hv.streams.Params(
            self.state, ["results", "reliability", "selected_image", "exaggeration"])])
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

    def _render(self, **_):
        s = self.state
        df = self.data()
        crit = s.reliability.critical
        top = max(crit, float(df["abs_w"].max()) if len(df) else 0.0)
        border = hv.Path(image_border(df, (geometry.block(s.problem) or {}).get("image_size"))).opts(color="#888888", nonselection_alpha=1)
        levels = w_levels(crit, top)
        vec = hv.Segments(df, ["x", "y", "x1", "y1"], ["point", "vx", "vy", "abs_w"]).opts(
            hover_tooltips=tips(["point", "vx", "vy", "abs_w"]),
            color="abs_w", cmap=W_COLORS, color_levels=levels, clim=(0, levels[-1]), line_width=3,
            colorbar=True, colorbar_opts={"ticker": FixedTicker(ticks=levels)},
            clabel=f"|w| (critical {crit:.2f}: rejected above)", tools=["hover"], nonselection_alpha=1)
        pts = hv.Points(df, ["x", "y"], ["point", "vx", "vy", "abs_w"]).opts(
            color="#333333", size=5, tools=["hover"], nonselection_alpha=1)
        unit = ""
        if len(df):
            unit = s.frames()[0]["unit"].iat[int(df["obs"].iat[0])]
        return (border * vec * pts).opts(
            hv.opts.Overlay(title=fit_title(f"Image {plain(s.selected_image)}: residual vectors ×{s.exaggeration:g} "
                                            f"(image units {plain(unit)}), colour |w|", IMAGE_FRAME),
                            xlabel=f"x [{unit}]", ylabel=f"y [{unit}]", frame_width=IMAGE_FRAME, frame_height=IMAGE_FRAME,
                            data_aspect=1, legend_position="top_left"))

    def __panel__(self):
        return self._pane
