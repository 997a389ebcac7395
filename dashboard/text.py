"""Strings from files and users made safe for the dashboard's panes: text, never markup.

A point id, an image id, a title, a strip name, a hypothesis label or an upload's file name is
written by whoever made the file. The dashboard shows such strings literally:

- :func:`plain` shows control and other invisible characters as escapes (``\\n``, ``\\x1b``,
  :func:`baarda.text.printable`), for Bokeh titles, labels and table cells (drawn as text);
- :func:`html_text` also escapes ``<``, ``>``, ``&`` and quotes, for HTML panes, the HTML
  report and widget labels that the browser renders as HTML (Choices.js in ``MultiChoice``);
- :func:`md_text` escapes HTML and neutralises Markdown syntax (``*``, ``_``, ``[``, `` ` ``,
  ``#`` …), for the few Markdown panes (``Alert``) that show a message with such strings.
"""

from __future__ import annotations

import html
import re
import textwrap

from baarda.text import printable

#: ASCII punctuation that CommonMark lets a backslash escape (``&``, ``<``, ``>`` become
#: entities instead, so that no tag or entity is ever formed).
_MD_SPECIAL = re.compile(r"([\\`*_{}\[\]()#+\-.!|~=:$'\"^%@/,?])")


def plain(s) -> str:
    """``s`` as one line of text: every non-printable character shown as an escape."""
    return printable("" if s is None else s)


def html_text(s) -> str:
    """``s`` as HTML text: :func:`plain`, then ``< > & " '`` escaped."""
    return html.escape(plain(s), quote=True)


def md_text(s) -> str:
    """``s`` as Markdown text that renders literally (no emphasis, link, code, heading, list
    or HTML): :func:`plain`, ``& < >`` as entities and other punctuation backslash-escaped."""
    t = _MD_SPECIAL.sub(r"\\\1", plain(s))
    return t.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def labels(values) -> dict:
    """``{html_text(v): v}`` for widget options whose labels the browser renders as HTML
    (``MultiChoice``); a label two values would share gets a numbered suffix."""
    out: dict = {}
    for v in values:
        label = html_text(v)
        k = 2
        while label in out:
            label = f"{html_text(v)} ({k})"
            k += 1
        out[label] = v
    return out


#: The advance of an average glyph of a bold sans-serif title, in font sizes: 0.56-0.62 em
#: measured in Chromium for the maps' titles (system-ui, 12 and 14 px), with a margin.
TITLE_EM = 0.66


def fit_title(text: str, width: float, font_px: float = 14.0) -> str:
    """``text`` broken at spaces into lines that fit ``width`` pixels in a bold ``font_px`` font.

    Bokeh draws a plot's title on the canvas in one line per line of text and cuts what runs
    beyond the canvas (a map's title lost its scale and maximum: "…205, ma"); the title starts
    at the frame's left edge, so ``width`` is the frame's width."""
    per_line = max(int(width / (TITLE_EM * font_px)), 12)
    lines = textwrap.wrap(text, per_line, break_long_words=True, break_on_hyphens=False)
    return "\n".join(lines) if lines else text


def id_list(ids, most: int = 8) -> str:
    """Ids from a file as one plain line, at most ``most`` of them: "A, B, C and 7,773 more"."""
    ids = [plain(i) for i in ids]
    if len(ids) <= most:
        return ", ".join(ids)
    return f"{', '.join(ids[:most])} and {len(ids) - most:,} more"
