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


def corpus() -> list[tuple[str, str, str, str]]:
    rows = []
    for line in (HERE / "README.md").read_text().splitlines():
        m = re.match(r"\| (\S+) \| (\S*) \| (\d+|byte \d+) \| .*? \| (.*) \|$", line)
        if m and m.group(1) != "file":
            rows.append((m.group(1), m.group(2), m.group(3), m.group(4)))
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


@pytest.mark.filterwarnings("error")          # no RuntimeWarning on the way to the refusal
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
    err = capsys.readouterr().err
    assert "argument --sigma-px: must be a number from 1e-06 to 1e+06" in err and err.count("\n") == 1


def test_sfm_options_on_a_network_are_refused(capsys):
    assert main(["analyze", str(VALID / "levelling-valid.gkf"), "--sigma-px", "2"]) == 2
    assert "apply to bal, bundler, colmap input" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# issue 12: terminal-safe output, control CSV as spreadsheets write it, no nan in the summary
# --------------------------------------------------------------------------------------------
def test_printable_escapes_what_repr_escapes():
    """Second implementation: Python's repr escapes exactly the characters str.isprintable
    rejects, with the same \\xNN/\\uNNNN/\\UNNNNNNNN forms; printable must agree on every code
    point except the spaces (Zs), which it keeps, and the quote and backslash, which repr escapes
    for its own syntax."""
    import unicodedata

    from baarda.text import printable

    for o in range(0x110000):
        ch = chr(o)
        if ch in "\\'" or unicodedata.category(ch) == "Zs":
            continue
        assert printable(ch) == repr(ch)[1:-1], hex(o)
    assert printable("\u00a0a b\u3000") == "\u00a0a b\u3000"
    assert printable("P1\x1b[2J\r\u202eevil\x85") == "P1\\x1b[2J\\r\\u202eevil\\x85"
    assert printable("Čáp ∇ δ̄0 σ̂0 ① 点") == "Čáp ∇ δ̄0 σ̂0 ① 点"


HOSTILE = "P\x1b]0;owned\x07\x1b[2J\r\u202e\x85\u2028x"


def test_hostile_ids_and_title_are_escaped_in_the_summary(tmp_path, capsys):
    """Point ids and the title with ESC sequences, BEL, CR, C1 NEL, a bidi override and a line
    separator: the printed summary shows them escaped, every line of it is printable."""
    import json

    doc = json.loads((VALID / "levelling-valid.json").read_text())
    doc["title"] = "T" + HOSTILE
    for p in doc["points"]:
        p["id"] = p["id"] + HOSTILE
    for o in doc["observations"]:
        o["from"] += HOSTILE
        o["to"] += HOSTILE
    f = tmp_path / "hostile.json"
    f.write_text(json.dumps(doc))
    assert main(["analyze", str(f), "--top", "3"]) == 0
    out = capsys.readouterr().out
    assert all(line.isprintable() for line in out.splitlines()), out
    assert "of TP\\x1b]0;owned\\x07\\x1b[2J\n" in out      # a levelling title: its first line
    assert "from=A" + "P\\x1b]0;owned" in out


@pytest.mark.parametrize("name", ["control-spreadsheet-bom-crlf.csv", "control-spreadsheet-cr-quoted.csv"])
def test_control_csv_as_spreadsheets_write_it(name, tmp_path, capsys):
    """A BOM, CRLF or CR-only line ends and quoted fields read exactly like the plain file
    (the reference), and the analysis with them gives the same numbers."""
    import json

    from baarda.io.control import read_control

    plain = read_control(VALID / "control-valid.csv")
    assert read_control(VALID / name) == plain
    out = {}
    for csvname in ("control-valid.csv", name):
        js = tmp_path / f"{csvname}.json"
        assert main(["analyze", str(VALID / "bal-valid.txt"), "--control", str(VALID / csvname),
                     "--json", str(js), "--quiet"]) == 0, capsys.readouterr().err
        out[csvname] = json.loads(js.read_text())["summary"]
    assert out[name]["sigma0_aposteriori"] == out["control-valid.csv"]["sigma0_aposteriori"]
    assert out[name]["n_observations"] == out["control-valid.csv"]["n_observations"] == 96 + 12


def test_uncontrolled_observation_is_shown_as_not_testable(tmp_path, capsys):
    """A spur (point D measured by one height difference only) has r = 0 (F80: the observation
    alone determines D): its w-test does not exist. The summary says so instead of printing
    nan, the JSON has null."""
    import json

    gkf = (VALID / "levelling-valid.gkf").read_text()
    gkf = gkf.replace('<point id="C" z="102" adj="z"/>', '<point id="C" z="102" adj="z"/><point id="D" z="90" adj="z"/>')
    gkf = gkf.replace("</height-differences>", '<dh from="C" to="D" val="-12.0" stdev="1"/>\n</height-differences>')
    f = tmp_path / "spur.gkf"
    f.write_text(gkf)
    js = tmp_path / "spur.json"
    assert main(["analyze", str(f), "--json", str(js), "--top", "8"]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower() and "inf" not in out.replace("infinity", "").lower()
    assert "((P C_vv P)_ii = 0: not testable)" in out         # the criterion of "uncontrolled"
    assert "∞ (uncontrolled)" in out
    spur = [o for o in json.loads(js.read_text(), parse_constant=float)["observations"] if o.get("to") == "D"]
    assert spur[0]["w"] is None and abs(spur[0]["redundancy"]) < 1e-9


@pytest.mark.parametrize("factor,refused", [(1.01, False), (0.99, True)])
def test_sigma_at_the_rounding_of_its_value(factor, refused, tmp_path):
    """σ ≥ 2⁻⁴⁸·|value| (baarda.validate.RELATIVE): a dh of 1000 m with σ just above the limit
    (≈ 3.6e-12 m) is adjusted, just below it is refused at its line, field sigma."""
    import json

    from baarda.errors import InputError
    from baarda.build import read_problem
    from baarda.validate import RELATIVE

    doc = json.loads((VALID / "levelling-valid.json").read_text())
    doc["points"][1]["H"] = 1100.0
    doc["observations"][0]["dh"] = 1000.0
    doc["observations"][0]["sigma"] = factor * RELATIVE * 1000.0
    f = tmp_path / "tight.json"
    f.write_text(json.dumps(doc, indent=1))
    if not refused:
        assert read_problem(f).n == 3
        return
    with pytest.raises(InputError) as exc:
        read_problem(f)
    assert exc.value.field == "sigma" and "below the rounding error of the value 1000" in exc.value.message
    lines = f.read_text().splitlines()
    assert exc.value.line == lines.index(' "observations": [') + 2      # where observations[0] starts


@pytest.mark.parametrize("obs", ["<distance from='1' to='3' val='1000.02' stdev='10' />",
                                 "<direction from='1' to='3' val='0' stdev='10' />"])
def test_coincident_approximate_points_are_refused_naming_the_line(obs, tmp_path, capsys):
    """A point given the approximate coordinates of another one makes a distance or direction
    between them undefined at the start (zero length): refused naming the file, line and
    observation, not an internal error from the datum analysis's eigen solver."""
    gkf = tmp_path / "coincident.gkf"
    gkf.write_text(f"""<?xml version="1.0" ?>
<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">
<network axes-xy="ne">
<parameters sigma-apr="10" />
<points-observations>
<point id='1' x='0' y='1000' fix='xy' />
<point id='2' x='1000' y='1000' fix='xy' />
<point id='3' x='0' y='1000' adj='xy' />
<obs from='1'>
{obs}
<distance from='1' to='2' val='1000' stdev='10' />
</obs>
<obs from='2'>
<distance from='2' to='3' val='1414.2' stdev='10' />
</obs>
</points-observations>
</network>
</gama-local>
""")
    assert main(["analyze", str(gkf)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"baarda: error: {gkf}:10: ") and "from=1 to=3" in err, err
    assert "same approximate coordinates" in err and "internal error" not in err
