"""Citations in the code name what a reader can find: the papers by their short keys
(docs/references.md), never a file the repository does not ship (issue 13); the notes beside a
clone are cited as ../shared/NAME.md."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_citation_of_files_outside_the_repository():
    shipped = {p.name for p in ROOT.rglob("*.md") if ".venv" not in p.parts}
    missing = []
    for folder in ("core", "dashboard", "bench", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                for name in re.findall(r"((?:\.\./shared/)?\b[A-Z][A-Za-z_-]*\.md)\b", line):
                    # the project's notes beside the clone (../shared) are named as such
                    if name not in shipped and not name.startswith("../shared/"):
                        missing.append(f"{path.relative_to(ROOT)}:{n}: {name}")
    assert not missing, "\n".join(missing)


def test_every_short_key_cited_is_in_the_references():
    refs = (ROOT / "docs" / "references.md").read_text(encoding="utf-8")
    keys = set(re.findall(r"\*\*([A-Z][A-Za-z]*\d{2})\*\*|\b([A-Z][A-Za-z]*\d{2})\b", refs))
    known = {k for pair in keys for k in pair if k}
    cited = set()
    for path in (ROOT / "core").rglob("*.py"):
        cited |= set(re.findall(r"\b(F80|M84|R84|B68|[A-Z][a-z]+\d{2})\s*(?:§|eq\.)", path.read_text(encoding="utf-8")))
    assert cited, "no citations found: the pattern is broken"
    assert cited <= known, f"cited but not in docs/references.md: {sorted(cited - known)}"
