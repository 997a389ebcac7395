"""The bad-input corpus (tests/malformed/README.md): every file is refused with exit status 2 and
one line ``baarda: error: FILE:LINE: ...`` naming the line and what is wrong; nothing is written
to the user's files."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from baarda.cli import main

HERE = Path(__file__).resolve().parent / "malformed"
VALID = HERE / "valid"


def corpus() -> list[tuple[str, str, int, str]]:
    rows = []
    for line in (HERE / "README.md").read_text().splitlines():
        m = re.match(r"\| (\S+) \| (\S*) \| (\d+) \| .*? \| (.*) \|$", line)
        if m and m.group(1) != "file":
            rows.append((m.group(1), m.group(2), int(m.group(3)), m.group(4)))
    return rows


CASES = corpus()


def snapshot(path: Path) -> dict:
    files = sorted(path.rglob("*")) if path.is_dir() else [path]
    return {str(f): (f.stat().st_mtime_ns, f.read_bytes()) for f in files if f.is_file()}


def test_corpus_is_complete():
    listed = {name for name, *_ in CASES}
    present = {p.name for p in HERE.iterdir() if p.name not in ("README.md", "make_corpus.py", "valid",
                                                                  "__pycache__")}
    assert listed == present
    assert len(CASES) >= 30
    kinds = {name.split("-")[0] for name in listed}
    assert kinds >= {"bal", "bundler", "colmap", "native", "gama", "control"}


@pytest.mark.parametrize("name,inner,line,needle", CASES, ids=[c[0] for c in CASES])
def test_corpus_file_is_refused(name, inner, line, needle, capsys):
    path = HERE / name
    if name.startswith("control-"):
        argv = ["analyze", str(VALID / "bal-valid.txt"), "--control", str(path)]
        watched = [path, VALID / "bal-valid.txt"]
    else:
        argv = ["analyze", str(path)]
        watched = [path]
    before = [snapshot(p) for p in watched]
    code = main(argv)
    err = capsys.readouterr().err
    where = str(path / inner) if inner else str(path)
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"baarda: error: {where}:{line}: "), err
    assert needle in err, err
    assert [snapshot(p) for p in watched] == before


@pytest.mark.parametrize("name", ["bal-valid.txt", "bundler-valid.out", "colmap-valid", "levelling-valid.gkf",
                                  "levelling-valid.json"])
def test_valid_seeds_analyse(name, capsys):
    path = VALID / name
    before = snapshot(path)
    assert main(["analyze", str(path), "--quiet"]) == 0, capsys.readouterr().err
    assert snapshot(path) == before


def test_bad_sigma_option_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["analyze", str(VALID / "bal-valid.txt"), "--sigma-px", "0"])
    assert exc.value.code == 2
    assert "--sigma-px must be a positive number" in capsys.readouterr().err


def test_sfm_options_on_a_network_are_refused(capsys):
    assert main(["analyze", str(VALID / "levelling-valid.gkf"), "--sigma-px", "2"]) == 2
    assert "apply to bal, bundler, colmap input" in capsys.readouterr().err
