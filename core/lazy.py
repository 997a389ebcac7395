"""Modules imported when first used (issue 30, item 5: start-up).

``stats = lazy("scipy.stats")`` at the top of a module gives a stand-in whose first attribute
access imports the module; ``baarda --help``, ``baarda batch`` on a client and any command that
needs no distribution do not pay for scipy.stats (≈ 1-2 s), scipy.optimize or pandas.
"""

from __future__ import annotations

import importlib
import importlib.util


class LazyModule:
    """A module imported on first attribute access (then every access goes to it)."""

    __slots__ = ("_name", "_module")

    def __init__(self, name: str):
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_module", None)

    def _load(self):
        module = object.__getattribute__(self, "_module")
        if module is None:
            module = importlib.import_module(object.__getattribute__(self, "_name"))
            object.__setattr__(self, "_module", module)
        return module

    def __getattr__(self, attr):
        return getattr(self._load(), attr)

    def __repr__(self) -> str:
        return f"<lazy module {object.__getattribute__(self, '_name')!r}>"


def lazy(name: str) -> LazyModule:
    """The module ``name``, imported when first used."""
    return LazyModule(name)


def installed(name: str) -> bool:
    """Whether the module ``name`` can be imported (without importing it)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False
