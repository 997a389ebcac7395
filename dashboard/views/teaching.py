"""Teaching views: the power function of the test and the MDB against the redundancy number.

The first plot shows the density of T under H0 (central χ²(q)) and under Ha (non-central
χ'²(q, δ0²)), the critical value k = χ²_{1−α}(q) with the size α (area of H0 right of k) and
the power β0 (area of Ha right of k); the second shows the tail right of k on a log scale, where
α = 0.001 is visible. δ0 and k come from the core (:mod:`baarda.stats.distributions`); the
densities are only drawn here. The last plot is ∇0l/σ = δ0/√r (F80 §5) with the observations
of the problem on it (those with r ≈ 0 at its top edge).
"""

from __future__ import annotations

import holoviews as hv
import numpy as np
import panel as pn
import param
from scipy import stats as sps


from ..state import State
from ..text import fit_title
from .common import NARROW_TITLE

#: The tail plot's title width: its log axis's labels (1e-10 at q = 6) take some 60 px more of
#: the narrowest panel than the power plot's (the title was cut at q = 6, issue 31, item 3).
TAIL_TITLE = NARROW_TITLE - 70


# Every element of the q-dependent plots normalised per frame: the axes follow q (HoloViews
#: keeps a DynamicMap's first ranges otherwise: the plots stayed on the q = 1 axes, issue 31).
def framewise() -> tuple:
    return tuple(getattr(hv.opts, e)(framewise=True) for e in ("Area", "Curve", "VLine", "Text"))

#: Above this many observations the MDB plot shows one point per occupied cell of a fine grid.
MAX_POINTS = 2000


def thinned(obs, cells: int = 400):
    """The rows of ``obs`` to plot in (r, MDB/σ): all of them up to :data:`MAX_POINTS`, else
    the first of each kind in every cell of a ``cells`` × ``cells`` grid over r and
    log(MDB/σ) — the same picture with far fewer glyphs (a block has tens of thousands)."""
    if len(obs) <= MAX_POINTS:
        return obs
    r = obs["r"].to_numpy(dtype=float)
    m = np.log(obs["mdb_sigma"].to_numpy(dtype=float))
    cell_r = np.floor(np.clip(r, 0, 1) * cells)
    cell_m = np.floor((m - m.min()) / max(np.ptp(m), 1e-12) * cells)
    key = obs.assign(_r=cell_r, _m=cell_m)[["kind", "_r", "_m"]]
    return obs[~key.duplicated().to_numpy()]


class TeachingView(pn.viewable.Viewer):
    state = param.ClassSelector(class_=State)
    q = param.Integer(default=1, bounds=(1, 6), doc="Dimension of the test shown.")

    def __init__(self, **params):
        super().__init__(**params)
        self.q_widget = pn.widgets.IntSlider(label="test dimension q", start=1, end=6, value=self.q, width=220)
        self.q_widget.link(self, value="q")
        self.power = hv.DynamicMap(self._power, streams=[hv.streams.Params(self.state, ["results", "reliability"]),
                                                         hv.streams.Params(self, ["q"])])
        self.tail = hv.DynamicMap(self._tail, streams=[hv.streams.Params(self.state, ["results", "reliability"]),
                                                       hv.streams.Params(self, ["q"])])
        self.mdb = hv.DynamicMap(self._mdb_curve, streams=[hv.streams.Params(self.state, ["results", "reliability"])])

    def power_frame(self, q: int | None = None) -> dict:
        """The frame of the power plot for dimension ``q`` (default: the view's): x-range [0, top]
        with top past δ0² + q + 5 sd of Ha and 1.3 k; y-range [0, ymax] with the maximum of Ha
        and, for q ≥ 2, of H0 (at its mode q − 2) inside, 10 % above the higher (χ²(1) goes to
        infinity at 0: there ymax is 2.5 × the maximum of Ha and H0 is clipped). Recomputed per q:
        the plot follows the slider (issue 31, item 3)."""
        policy = self.state.reliability.policy
        q = self.q if q is None else int(q)
        alpha, d0, k = policy.alpha(q), policy.delta0(q), policy.critical_T(q)
        lam = d0 ** 2
        top = max(lam + q + 5 * np.sqrt(2 * (q + 2 * lam)), k * 1.3)
        x = np.linspace(1e-3, top, 600)
        f0 = sps.chi2.pdf(x, q)
        fa = sps.ncx2.pdf(x, q, lam)
        if q == 1:
            ymax = float(np.nanmax(fa)) * 2.5
        else:
            mode0 = float(sps.chi2.pdf(max(q - 2, 1e-3), q))
            ymax = 1.1 * max(mode0, float(np.nanmax(f0)), float(np.nanmax(fa)))
        return {"q": q, "alpha": alpha, "d0": d0, "k": k, "lam": lam, "x": x, "f0": f0, "fa": fa,
                "xlim": (0.0, float(top)), "ylim": (0.0, ymax)}

    def tail_frame(self, q: int | None = None) -> dict:
        """The frame of the log-tail plot for dimension ``q``: x-range [k, top] (as
        :meth:`power_frame`), y-range [floor, 3 × max of Ha there] on a log scale."""
        policy = self.state.reliability.policy
        q = self.q if q is None else int(q)
        alpha, d0, k = policy.alpha(q), policy.delta0(q), policy.critical_T(q)
        lam = d0 ** 2
        top = max(lam + q + 5 * np.sqrt(2 * (q + 2 * lam)), k * 1.3)
        x = np.linspace(k, top, 300)
        f0 = sps.chi2.pdf(x, q)
        fa = sps.ncx2.pdf(x, q, lam)
        floor = max(float(f0.min()), 1e-5 * float(fa.max()))
        return {"q": q, "alpha": alpha, "k": k, "lam": lam, "x": x, "f0": f0, "fa": fa, "floor": floor,
                "xlim": (float(k), float(top)), "ylim": (floor, float(fa.max()) * 3)}

    def _power(self, **_):
        policy = self.state.reliability.policy
        fr = self.power_frame()
        q, alpha, d0, k, lam, x, fa = fr["q"], fr["alpha"], fr["d0"], fr["k"], fr["lam"], fr["x"], fr["fa"]
        top, ymax = fr["xlim"][1], fr["ylim"][1]
        f0 = np.minimum(fr["f0"], ymax)
        right = x >= k
        kd, vd = "T", "density"
        pad = 0.015 * top
        h0 = f"H0: χ²({q})" + (" (→ ∞ at 0)" if q == 1 else "")
        return (hv.Area((x[right], fa[right]), kd, vd, label=f"power β0 = {policy.beta0:.2f}").opts(
                    color="#e6007e", alpha=0.3)
                * hv.Area((x[right], f0[right]), kd, vd, label=f"size α = {alpha:.2g}").opts(color="#1f4e9c", alpha=0.6)
                * hv.Curve((x, f0), kd, vd, label=h0).opts(color="#1f4e9c", line_width=2)
                * hv.Curve((x, fa), kd, vd, label=f"Ha: χ'²({q}, δ0² = {lam:.2f})").opts(color="#e6007e", line_width=2)
                * hv.VLine(k).opts(color="black", line_dash="dashed")
                * hv.Text(k + pad, ymax * 0.9, f"k = {k:.2f}", halign="left", kdims=[kd, vd]).opts(text_font_size="10pt")
                * hv.VLine(lam).opts(color="#e6007e", line_dash="dotted")
                * hv.Text(lam + pad, ymax * 0.75, f"δ0² (δ0 = {d0:.2f})", halign="left", kdims=[kd, vd]).opts(
                    text_font_size="10pt")
                ).opts(title=fit_title(f"Power of the {q}-dimensional test (α = {alpha:.2g}, β0 = {policy.beta0:.2f})",
                                       NARROW_TITLE, 14.4),
                       xlabel="T", ylabel="density", xlim=fr["xlim"], ylim=fr["ylim"], responsive=True, height=290,
                       legend_position="top_right", fontscale=0.9, framewise=True).opts(*framewise())

    def _tail(self, **_):
        """The tail right of k on a log scale: the size α (area of H0 there), invisible on the
        linear plot at α = 0.001, beside the power β0 (area of Ha)."""
        policy = self.state.reliability.policy
        fr = self.tail_frame()
        alpha, k, x, f0, fa, floor = fr["alpha"], fr["k"], fr["x"], fr["f0"], fr["fa"], fr["floor"]
        kd, vd = "T", "density"
        base = np.full(x.size, floor)
        f0 = np.maximum(f0, floor)
        return (hv.Area((x, base, fa), kd, [vd, "top"], label=f"β0 = {policy.beta0:.2f}").opts(
                    color="#e6007e", alpha=0.3)
                * hv.Area((x, base, f0), kd, [vd, "top"], label=f"α = {alpha:.2g}").opts(color="#1f4e9c", alpha=0.6)
                * hv.Curve((x, f0), kd, vd).opts(color="#1f4e9c", line_width=2)
                * hv.Curve((x, fa), kd, vd).opts(color="#e6007e", line_width=2)
                ).opts(hv.opts.Overlay(
                    title=fit_title(f"Right of k = {k:.2f} on a log scale: the size α (area under H0)", TAIL_TITLE, 13.6),
                    xlabel="T", ylabel="density (log)", logy=True, xlim=fr["xlim"], ylim=fr["ylim"],
                    responsive=True, height=200, legend_position="top_right", fontscale=0.85, framewise=True),
                    *framewise())

    def _mdb_curve(self, **_):
        """δ0/√r with the observations on it; those above the plot (r ≈ 0: MDB → ∞) are drawn at
        its top edge as triangles and counted in the legend, not dropped."""
        obs, _ = self.state.frames()
        r = np.linspace(0.02, 1.0, 200)
        d0 = self.state.reliability.delta0
        ytop = max(6 * d0, 1.0)
        live = obs[~obs["excluded"]]
        m = live["mdb_sigma"].to_numpy(dtype=float)
        off = ~np.isfinite(m) | (m > ytop)
        on = thinned(live[~off])
        high = live[off].assign(mdb_sigma=ytop * 0.985, r=np.clip(live["r"][off].to_numpy(dtype=float), 0, 1))
        return (hv.Curve((r, d0 / np.sqrt(r)), "r", "mdb_sigma", label="δ0 / √r").opts(color="black")
                * hv.Points(on, ["r", "mdb_sigma"], ["kind", "ids"]).opts(
                    color="kind", cmap="Category10", size=7, tools=["hover"], alpha=0.8, show_legend=True)
                * hv.Points(high, ["r", "mdb_sigma"], ["kind", "ids"],
                            label=f"{int(off.sum())} above the plot (r ≈ 0)" if off.any() else "").opts(
                    marker="triangle", size=9, color="#d7191c", tools=["hover"], show_legend=bool(off.any()))
                * hv.VSpan(0, 0.1).opts(color="#d7191c", alpha=0.1)
                * hv.VSpan(0.1, 0.3).opts(color="#fdae61", alpha=0.1)
                ).opts(title=fit_title(f"MDB in units of σ against the redundancy number (δ0 = {d0:.2f})", NARROW_TITLE, 14.4),
                       xlim=(0, 1.02), ylim=(0, ytop), responsive=True, height=290, legend_position="top_right",
                       fontscale=0.9, xlabel="redundancy number r", ylabel="∇0l / σ")

    def __panel__(self):
        return pn.Column(self.q_widget,
                         pn.pane.HoloViews(self.power, sizing_mode="stretch_width", css_classes=["teach-power"],
                                           linked_axes=False),
                         pn.pane.HoloViews(self.tail, sizing_mode="stretch_width", css_classes=["teach-tail"],
                                           linked_axes=False),
                         pn.pane.HoloViews(self.mdb, sizing_mode="stretch_width", css_classes=["teach-mdb"],
                                           linked_axes=False),
                         sizing_mode="stretch_width")
