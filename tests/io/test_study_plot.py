"""The design study's plot (baarda.io.study_plot): each design's values where the axes put them,
the recipe's strings as text."""

from __future__ import annotations

import re
from xml.etree import ElementTree

from baarda.io import study_plot

SVG = "{http://www.w3.org/2000/svg}"


def _row(power, size, **grid):
    return {**{f"design.{k}": v for k, v in grid.items()}, "empirical_power": power, "power_se": 0.01,
            "expected_power": 0.8, "empirical_size": size, "size_se": 0.002, "alpha0": 0.05,
            "mdb_sigma_median": 4.0, "mdb_sigma_max": 8.0}


def _points(svg: str) -> dict[str, list[float]]:
    """The y pixel of each named point, in the order drawn."""
    out: dict[str, list[float]] = {}
    for c in ElementTree.fromstring(svg).iter(SVG + "circle"):
        tip = c.find(SVG + "title")
        if tip is not None:
            out.setdefault(tip.text.split(":")[0], []).append(float(c.get("cy")))
    return out


def test_points_are_placed_on_their_axes():
    table = [_row(0.5, 0.05, control="perimeter"), _row(1.0, 0.0, control="corners")]
    pts = _points(study_plot.study_svg(table, "t"))
    top, bottom = study_plot.TOP, study_plot.HEIGHT - study_plot.BOTTOM
    power = pts["empirical power ± 3 SE"]
    assert power[0] == round((top + bottom) / 2, 1) and power[1] == top     # 0.5 mid-frame, 1.0 at the top
    assert pts["empirical size ± 3 SE"][1] == bottom                          # size 0 on the axis
    assert pts["expected power"] == [round(top + (bottom - top) * 0.2, 1)] * 2


def test_recipe_strings_are_text():
    evil = '<script>alert(1)</script>\u202e"'
    svg = study_plot.study_svg([_row(0.7, 0.04, control=evil)], evil)
    ElementTree.fromstring(svg)                                               # still well-formed
    assert "<script" not in svg and "\u202e" not in svg
    page = study_plot.study_html([_row(0.7, 0.04, control=evil)], f"design 0 ({evil})", evil)
    assert "<script" not in page and "\u202e" not in page
    assert re.search(r"&lt;script&gt;", page)
