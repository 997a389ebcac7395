"""The plot and the page of a design study (``baarda study``: ``study.svg``, ``index.html``).

Per design, three panels on one row: the empirical power of the w-test on the planted error with
±3 standard errors beside the expected power (B68; F80 eq. 8), the empirical size with ±3 standard
errors against α0, and the MDB in σ of its observation (median and largest, F80 eq. 8). Plain SVG
written here (the core imports no plotting library); every string of the recipe is escaped text.
"""

from __future__ import annotations

import html
import math

from ..text import printable

#: panel width and height, margins (px); at most KEYS designs named under the plot
WIDTH, HEIGHT, LEFT, RIGHT, TOP, BOTTOM = 300, 200, 64, 14, 34, 30
KEYS = 40
#: colours: empirical (dark blue), expected / nominal (orange), MDB max (grey)
EMPIRICAL, EXPECTED, LIGHT = "#1f4e79", "#d9730d", "#9a9a9a"


def design_label(row: dict, index: int) -> str:
    """A design's label: its grid values (``side_overlap=0.6, control=corners``) or its number."""
    grid = ", ".join(f"{k.removeprefix('design.')}={v}" for k, v in row.items() if k.startswith("design."))
    return printable(grid) if grid else f"design {index}"


def _t(text) -> str:
    return html.escape(printable(str(text)), quote=True)


def _ticks(low: float, high: float, n: int = 4) -> list[float]:
    step = (high - low) / n
    return [low + k * step for k in range(n + 1)]


def _panel(x0: float, title: str, ylabel: str, low: float, high: float, n: int,
           series: list[tuple[str, list, list | None, str]], reference: float | None = None,
           log: bool = False) -> list[str]:
    """One panel over designs 0 … n−1: ``series`` of (name, values, ±half-widths or None, colour)
    per design; a dashed line at ``reference``; ``log``: a log10 axis from ``low`` to ``high``
    (decades). Values are clipped to the frame (a clipped one is drawn hollow)."""
    w, h = WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM
    left, top = x0 + LEFT, TOP
    scale = math.log10 if log else float

    def y(v):
        v = scale(min(max(v, low), high))
        return top + h * (1 - (v - scale(low)) / (scale(high) - scale(low)))

    out = [f'<text x="{x0 + WIDTH / 2:.1f}" y="16" text-anchor="middle" font-weight="bold">{_t(title)}</text>',
           f'<rect x="{left}" y="{top}" width="{w}" height="{h}" fill="none" stroke="#444"/>',
           f'<text transform="translate({x0 + 12},{top + h / 2:.1f}) rotate(-90)" text-anchor="middle">'
           f'{_t(ylabel)}</text>']
    ticks = [10.0 ** k for k in range(round(math.log10(low)), round(math.log10(high)) + 1)] if log \
        else _ticks(low, high)
    for v in ticks:
        out.append(f'<line x1="{left - 4}" x2="{left}" y1="{y(v):.1f}" y2="{y(v):.1f}" stroke="#444"/>'
                   f'<text x="{left - 6}" y="{y(v) + 4:.1f}" text-anchor="end">{v:.3g}</text>')
    if reference is not None and low <= reference <= high:
        out.append(f'<line x1="{left}" x2="{left + w}" y1="{y(reference):.1f}" y2="{y(reference):.1f}" '
                   f'stroke="{EXPECTED}" stroke-dasharray="5,3"/>')
    for i in range(n):
        xc = left + w * (i + 0.5) / n
        if n <= 20 or i % math.ceil(n / 20) == 0:
            out.append(f'<text x="{xc:.1f}" y="{top + h + 14}" text-anchor="middle" font-size="10">{i}</text>')
        for j, (name, values, errors, colour) in enumerate(series):
            v = values[i]
            if v is None or not math.isfinite(v):
                continue
            xs = xc + (j - (len(series) - 1) / 2) * 10
            if errors is not None and math.isfinite(errors[i]):
                out.append(f'<line x1="{xs:.1f}" x2="{xs:.1f}" y1="{y(v - errors[i]):.1f}" y2="{y(v + errors[i]):.1f}" '
                           f'stroke="{colour}" stroke-width="1.5"/>')
            inside = low <= v <= high
            out.append(f'<circle cx="{xs:.1f}" cy="{y(v):.1f}" r="4" stroke="{colour}" stroke-width="1.5" '
                       f'fill="{colour if inside else "white"}"><title>{_t(name)}: {v:.4g}</title></circle>')
    return out


def study_svg(table: list[dict], title: str = "") -> str:
    """The study's plot (three panels over the designs, module docstring; the designs named under
    it) as an SVG document."""
    n = len(table)
    power_se = [3 * row["power_se"] for row in table]
    size = [row["empirical_size"] for row in table]
    size_se = [3 * row["size_se"] for row in table]
    alpha0 = table[0]["alpha0"] if table else 0.0
    size_high = max([alpha0 * 2] + [s + e for s, e in zip(size, size_se) if math.isfinite(s + e)])
    mdbs = [v for row in table for v in (row["mdb_sigma_median"], row["mdb_sigma_max"]) if math.isfinite(v) and v > 0]
    decades = (math.floor(math.log10(min(mdbs, default=1.0))), math.ceil(math.log10(max(mdbs, default=10.0))))
    parts = (_panel(0, "power on the planted error", "rate", 0.0, 1.0, n,
                    [("empirical power ± 3 SE", [row["empirical_power"] for row in table], power_se, EMPIRICAL),
                     ("expected power", [row["expected_power"] for row in table], None, EXPECTED)])
             + _panel(WIDTH, f"size of the w-test (α0 = {alpha0:g})", "false alarms per test", 0.0, size_high, n,
                      [("empirical size ± 3 SE", size, size_se, EMPIRICAL)], reference=alpha0)
             + _panel(2 * WIDTH, "MDB of the observations", "σ of the observation", 10.0 ** decades[0],
                      10.0 ** max(decades[1], decades[0] + 1), n,
                      [("median MDB", [row["mdb_sigma_median"] for row in table], None, EMPIRICAL),
                       ("largest MDB", [row["mdb_sigma_max"] for row in table], None, LIGHT)], log=True))
    y = HEIGHT + 4
    legend = (f'<g font-size="11"><circle cx="{LEFT}" cy="{y}" r="4" fill="{EMPIRICAL}"/>'
              f'<text x="{LEFT + 8}" y="{y + 4}">empirical (bars ± 3 standard errors); median MDB</text>'
              f'<circle cx="{LEFT + 330}" cy="{y}" r="4" fill="{EXPECTED}"/>'
              f'<text x="{LEFT + 338}" y="{y + 4}">expected power; dashed: α0</text>'
              f'<circle cx="{LEFT + 540}" cy="{y}" r="4" fill="{LIGHT}"/>'
              f'<text x="{LEFT + 548}" y="{y + 4}">largest MDB (log axis)</text></g>')
    keys = [f"design {i}: {design_label(row, i)}" for i, row in enumerate(table[:KEYS])]
    if n > KEYS:
        keys.append(f"… and {n - KEYS} more (study.csv)")
    key = "".join(f'<text x="{LEFT}" y="{y + 24 + 15 * k}" font-size="11">{_t(line)}</text>'
                  for k, line in enumerate(keys))
    height = y + 24 + 15 * len(keys)
    head = f'<title>{_t(title or "design study")}</title>'
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{3 * WIDTH}" height="{height}" '
            f'viewBox="0 0 {3 * WIDTH} {height}" font-family="sans-serif" font-size="12">{head}'
            + "".join(parts) + legend + key + "</svg>\n")


def study_html(table: list[dict], text: str, title: str = "") -> str:
    """A standalone page: the title, the plot and the table's text (escaped)."""
    name = _t(title or "Design study")
    lines = "".join(f"<li>{_t(line)}</li>" for line in text.splitlines())
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{name}</title></head><body style=\"font-family:sans-serif;max-width:960px;margin:1em auto\">"
            f"<h1 style=\"font-size:1.3em\">{name}</h1>{study_svg(table, title)}<ul>{lines}</ul>"
            "<p>Files: <a href=\"study.csv\">study.csv</a>, <a href=\"replicates.csv\">replicates.csv</a> (every "
            "replicate with its seed), <a href=\"designs.json\">designs.json</a>.</p></body></html>\n")
