"""The teaching plots follow q (issue 31, item 3), without a browser: the Bokeh figure a served
session holds is updated in place when q changes, and for q = 1…6 its ranges hold k, the maximum
of the H0 density χ²(q) (q ≥ 2; χ²(1) is infinite at 0) at its mode q − 2, the maximum of Ha and
the labels; the log-tail plot's x-range starts at the new k."""

from __future__ import annotations

import pytest

pytest.importorskip("panel")

import panel as pn  # noqa: E402
from bokeh.document import Document  # noqa: E402
from bokeh.models import Plot  # noqa: E402
from scipy import optimize, stats  # noqa: E402

from baarda.dashboard.state import State  # noqa: E402
from baarda.dashboard.views.teaching import TeachingView  # noqa: E402


@pytest.fixture(scope="module")
def view(demo_path):
    return TeachingView(state=State(demo_path))


def figure(view, name):
    root = pn.pane.HoloViews(getattr(view, name), linked_axes=False).get_root(Document())
    return lambda: next(iter(root.select({"type": Plot})))


def test_power_and_tail_ranges_follow_q(view):
    policy = view.state.reliability.policy
    power, tail = figure(view, "power"), figure(view, "tail")
    first = power()
    for q in (1, 2, 3, 4, 5, 6, 2, 1):
        view.q = q
        f, t = power(), tail()
        assert f is first                                         # updated in place, not replaced
        k = stats.chi2.isf(policy.alpha(q), q)                    # independent of the core
        lam = policy.delta0(q) ** 2
        x0, x1, y0, y1 = f.x_range.start, f.x_range.end, f.y_range.start, f.y_range.end
        assert x0 <= 0 and x0 < k < x1 and x0 < lam < x1, q
        if q >= 2:
            assert y1 > stats.chi2.pdf(q - 2 if q > 2 else 1e-9, q) and x0 <= q - 2 < x1, q
            assert y1 < 1.5 * max(stats.chi2.pdf(max(q - 2, 1e-9), q), 0.05)     # not left on a taller frame
        top_a = -optimize.minimize_scalar(lambda x, q=q, lam=lam: -stats.ncx2.pdf(x, q, lam),
                                          bounds=(0.5, 3 * lam + 20), method="bounded").fun
        assert y0 == 0 and y1 > top_a, q
        assert f"{q}-dimensional" in f.title.text
        # the log tail: x from this q's k, y over the tail of Ha
        assert t.x_range.start == pytest.approx(k, rel=1e-9) and t.x_range.end > lam
        assert t.y_range.end > stats.ncx2.pdf(k, q, lam) and 0 < t.y_range.start < stats.chi2.pdf(k, q)
    # the labels sit inside the frame
    for q in range(1, 7):
        fr = view.power_frame(q)
        assert fr["xlim"][0] < fr["k"] < fr["xlim"][1] and 0.9 * fr["ylim"][1] < fr["ylim"][1]
