"""Where the external reference data live, and how tests behave when they are absent.

Tests that need ``../shared/extdata`` skip with a reason in a user's clone and fail instead when
``BAARDA_REQUIRE_EXTDATA=1`` is set (as ``.ci/run`` does).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

EXTDATA = (Path(__file__).resolve().parents[1] / ".." / "shared" / "extdata").resolve()
GAMA = EXTDATA / "gama"


def require_extdata(path: Path = EXTDATA) -> Path:
    """Return ``path`` if it exists; otherwise skip, or fail when extdata are required."""
    if path.exists():
        return path
    msg = f"external reference data not found at {path}"
    if os.environ.get("BAARDA_REQUIRE_EXTDATA") == "1":
        pytest.fail(msg + " (BAARDA_REQUIRE_EXTDATA=1)")
    pytest.skip(msg)


def gama_cases() -> list[Path]:
    """Every Gama network with a result file, or [] when the data are absent."""
    if not GAMA.exists():
        return []
    return sorted(p for p in GAMA.rglob("*.gkf") if p.with_suffix(".xml").exists())
