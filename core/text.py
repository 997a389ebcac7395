"""Text from files made safe for a terminal.

A point id, a title or a file name comes from whoever wrote the file. Printed as it is, an
escape sequence in it can set the window title or clear the screen, a carriage return can
overwrite what was printed before, a newline can forge a second line of an error message and
a bidi override (U+202E) can reverse what follows. :func:`printable` shows every such
character as an escape (``\\x1b``, ``\\r``, ``\\u202e``), in the style of Python's ``repr``.
"""

from __future__ import annotations

import math
import unicodedata

_SHORT = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(ch: str) -> str:
    if ch in _SHORT:
        return _SHORT[ch]
    o = ord(ch)
    if o < 0x100:
        return f"\\x{o:02x}"
    if o < 0x10000:
        return f"\\u{o:04x}"
    return f"\\U{o:08x}"


def printable(s) -> str:
    """``s`` (any object, converted with ``str``) with every character that is not printable
    shown as an escape: C0 and C1 controls, DEL, format characters (bidi embeddings and
    overrides U+202A–U+202E, isolates U+2066–U+2069, zero-width characters), line and
    paragraph separators, lone surrogates, private-use and unassigned code points. Letters,
    digits, punctuation, symbols and spaces of any script are kept as they are."""
    s = s if isinstance(s, str) else str(s)
    if s.isprintable():
        return s
    return "".join(ch if ch.isprintable() or unicodedata.category(ch) == "Zs" else _escape(ch) for ch in s)


def printable_lines(text: str) -> str:
    """Several lines, each made :func:`printable`; the newlines between them are kept."""
    return "\n".join(printable(line) for line in str(text).split("\n"))


def number(x, spec: str = ".4g", missing: str = "—") -> str:
    """``format(x, spec)`` for a finite number; ``missing`` for None, NaN or ±inf (a summary
    never prints ``nan``)."""
    if x is None:
        return missing
    try:
        v = float(x)
    except (TypeError, ValueError):
        return missing
    return format(v, spec) if math.isfinite(v) else missing


def shorten(s: str, limit: int = 600) -> str:
    """``s`` cut to about ``limit`` characters (keeping its end, where a message's reason often
    is, when it is short): a 200,000-character field quoted in an error stays readable."""
    if len(s) <= limit:
        return s
    return s[: limit - 80] + f" … [{len(s) - limit + 80} characters] … " + s[-60:]
