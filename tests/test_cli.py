"""The `baarda analyze` command: JSON contract, exit codes, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib import resources
from pathlib import Path

import jsonschema
import pytest

from baarda import batch
from baarda.cli import build_parser, main
from baarda.iteration import STOPS

from tests.extdata import GAMA, require_extdata

SCHEMA = json.loads(resources.files("baarda").joinpath("schema/analysis.schema.json").read_text())
ALL_GKF = sorted(GAMA.rglob("*.gkf")) if GAMA.exists() else []
LEVELLING = """<?xml version="1.0"?>
<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">
<network><parameters sigma-apr="1" sigma-act="apriori"/>
<points-observations>
<point id="A" z="100" fix="z"/><point id="B" z="101" adj="z"/><point id="C" z="102" adj="z"/>
<height-differences>
<dh from="A" to="B" val="1.002" stdev="1"/>
<dh from="B" to="C" val="0.999" stdev="1"/>
<dh from="C" to="A" val="-2.003" stdev="1"/>
</height-differences>
</points-observations></network></gama-local>
"""


def test_every_gama_network_analyses_and_validates(tmp_path, capsys):
    require_extdata(GAMA)
    ok = errors = 0
    for path in ALL_GKF:
        out = tmp_path / (path.stem + ".json")
        code = main(["analyze", str(path), "--json", str(out), "--quiet"])
        err = capsys.readouterr().err
        if code == 0:
            doc = json.loads(out.read_text())
            jsonschema.validate(doc, SCHEMA)
            assert doc["summary"]["n_observations"] == len(doc["observations"])
            assert doc["summary"]["converged"] is True, path
            ok += 1
        else:
            # the only network baarda refuses has observations to undefined points (talapkova),
            # which gama-local drops: so does --drop-undefined, with a warning
            assert code == 2 and err.startswith("baarda: error: ") and err.count("\n") == 1, err
            assert "--drop-undefined" in err
            assert main(["analyze", str(path), "--json", str(out), "--quiet", "--drop-undefined"]) == 0
            assert json.loads(out.read_text())["summary"]["converged"] is True
            errors += 1
    assert ok >= len(ALL_GKF) - 1 and errors <= 1, f"{errors} networks refused"


def test_json_contract_fields(tmp_path):
    src = tmp_path / "loop.gkf"
    src.write_text(LEVELLING)
    out = tmp_path / "loop.json"
    assert main(["analyze", str(src), "--json", str(out), "--quiet", "--csv", str(tmp_path / "csv")]) == 0
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    s = doc["summary"]
    assert s["dof"] == 1 and s["n_observations"] == 3 and s["n_unknowns"] == 2
    obs = doc["observations"][0]
    assert obs["kind"] == "height-diff" and obs["from"] == "A" and obs["to"] == "B"
    assert abs(obs["redundancy"] - 1 / 3) < 1e-12
    # the loop closes at −2 mm; spread over three equal height differences: v = +2/3 mm each
    # (adjusted − observed), w = v / (σ √r)
    assert abs(obs["residual"] - 0.002 / 3) < 1e-12
    assert abs(obs["w"] - (0.002 / 3) / (0.001 * (1 / 3) ** 0.5)) < 1e-9
    assert {p["id"] for p in doc["points"]} == {"A", "B", "C"}
    assert (tmp_path / "csv" / "observations.csv").read_text().count("\n") == 4
    assert set(s["timings"]) >= {"read", "solve", "reliability"}


@pytest.mark.parametrize("text,line,needle", [
    ("<gama-local><network><points-observations><point id='A' z='x' fix='z'/>", 1, ""),
    (LEVELLING.replace('stdev="1"/>\n<dh from="B"', 'stdev="0"/>\n<dh from="B"'), 7, "stdev"),
    (LEVELLING.replace('to="C" val="0.999"', 'to="Q" val="0.999"'), 8, "Q"),
    (LEVELLING.replace('val="-2.003"', 'val="nan"'), 9, ""),
])
def test_bad_input_one_line_error(tmp_path, capsys, text, line, needle):
    src = tmp_path / "bad.gkf"
    src.write_text(text)
    before = src.read_bytes()
    code = main(["analyze", str(src)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"baarda: error: {src}:{line}: ") and err.count("\n") == 1, err
    assert needle in err
    assert src.read_bytes() == before


def test_datum_defect_is_diagnosed(tmp_path, capsys):
    src = tmp_path / "free.gkf"
    src.write_text(LEVELLING.replace('fix="z"', 'adj="z"'))
    assert main(["analyze", str(src)]) == 2
    err = capsys.readouterr().err
    assert "datum defect 1" in err and "translation z" in err


def test_missing_file_and_unknown_format(tmp_path, capsys):
    assert main(["analyze", str(tmp_path / "nope.gkf")]) == 2
    (tmp_path / "x.txt").write_text("hello")
    assert main(["analyze", str(tmp_path / "x.txt")]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and "unknown file format" in err


def test_console_script_runs(tmp_path):
    src = tmp_path / "loop.gkf"
    src.write_text(LEVELLING)
    res = subprocess.run([sys.executable, "-m", "baarda.cli", "analyze", str(src)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "global test" in res.stdout and "largest |w|" in res.stdout


def test_theory_options_reachable_from_the_cli(tmp_path, capsys):
    require_extdata(GAMA)
    src = GAMA / "krumm" / "2D" / "Wolf_DistanceDirectionAngle_free.gkf"
    out = tmp_path / "w.json"
    code = main(["analyze", str(src), "--json", str(out), "--snoop", "--robust", "danish",
                 "--variance-components", "--sbase", "1,2,3", "--criterion", "linear"])
    text = capsys.readouterr().out
    assert code == 0
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    assert {"snooping", "robust", "variance_components", "criterion"} <= set(doc)
    rs = doc["summary"]["robust"]           # whether the robust step cleaned the block (issue 27 item 10)
    assert rs["method"] == "danish" and rs["suspects"] == len(doc["robust"]["suspects"])
    assert rs["cleaned"] is doc["robust"]["cleaned"]["complete"] and (rs["reason"] is None) is rs["cleaned"]
    assert doc["summary"]["sbase"] == ["1", "2", "3"]
    assert "ellipse" in doc["points"][5]
    for needle in ("iterative data snooping", "robust estimation", "variance components", "criterion matrix"):
        assert needle in text
    assert main(["risk", "--p", "0.01", "--L1", "1", "--L2", "10", "--lambda-tol", "17"]) == 0
    assert "critical value C" in capsys.readouterr().out
    assert main(["analyze", str(src), "--sbase", "nope"]) == 2


def test_convert_of_a_network_the_native_format_cannot_hold_is_refused(tmp_path, capsys):
    """Only levelling networks have a native form: a levelling network converts and analyses the
    same; a network with directions is refused with the reason (it wrote 'H': null before)."""
    src = tmp_path / "loop.gkf"
    src.write_text(LEVELLING)
    out = tmp_path / "loop.json"
    assert main(["convert", str(src), str(out), "--quiet"]) == 0
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["analyze", str(src), "--quiet", "--json", str(a)]) == 0
    assert main(["analyze", str(out), "--quiet", "--json", str(b)]) == 0
    ra = [o["redundancy"] for o in json.loads(a.read_text())["observations"]]
    rb = [o["redundancy"] for o in json.loads(b.read_text())["observations"]]
    assert ra == pytest.approx(rb, abs=1e-12)
    capsys.readouterr()
    plan = tmp_path / "plan.gkf"
    plan.write_text(LEVELLING.replace('<point id="C" z="102" adj="z"/>',
                                      '<point id="C" x="0" y="0" z="102" adj="z"/><point id="D" x="10" y="0"/>')
                    .replace("</height-differences>", "</height-differences><obs from=\"C\">"
                             "<direction to=\"D\" val=\"0\" stdev=\"10\"/></obs>"))
    assert main(["convert", str(plan), str(tmp_path / "plan.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "levelling networks only" in err and "direction" in err
    assert not (tmp_path / "plan.json").exists()


def _demo_with_gross_control_error(tmp_path, shift=2760.0):
    """The demo block with control point P00002 moved by ``shift`` metres in X (3 base lengths
    of the 1:10,000 RC30 block): least squares diverges (R84 §6: a large error)."""
    doc = json.loads((Path(__file__).resolve().parents[1] / "data" / "demo-block.json").read_text())
    point = next(p for p in doc["points"] if p["id"] == "P00002")
    point["ref"] = [point["ref"][0] + shift, *point["ref"][1:]]
    path = tmp_path / "gross.json"
    path.write_text(json.dumps(doc))
    return path


def test_a_diverged_adjustment_is_a_status_not_a_crash(tmp_path, capsys, monkeypatch):
    """An unconverged adjustment whose normal equations are singular at the last iterate, and
    singular again without the robust estimation's suspects: exit status 4 (not converged), one
    line saying no reliability could be computed and that the robust estimation (R84's, run
    without --robust too) did not mend it; no JSON written. With --robust the robust estimation
    names the error. (The singular systems are forced here; the real case follows.)"""
    from baarda import cli, commands
    from baarda.errors import SingularError

    def singular(*_):
        raise SingularError("normal matrix is singular: P00006.x is not determined by the observations")

    monkeypatch.setattr(commands.results, "to_dict", singular)
    path = _demo_with_gross_control_error(tmp_path)
    out = tmp_path / "out.json"
    assert main(["analyze", str(path), "--max-iter", "3", "--json", str(out)]) == cli.NOT_CONVERGED
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "NOT converged after 3 iterations" in err[0]
    assert "no reliability computed" in err[0] and "robust estimation (r84) gives none either" in err[0]
    assert not out.exists()
    assert main(["analyze", str(path), "--max-iter", "3", "--robust", "r84"]) == cli.NOT_CONVERGED
    text = capsys.readouterr().out
    assert "robust estimation (r84" in text and "id=P00002" in text and "large" in text


def test_gross_control_error_ends_with_a_status_and_one_line(tmp_path):
    """The real thing, end to end in a fresh process: whatever least squares makes of a
    3-base-length control error, the run ends with status 0 or 4 and, at 4, one line on stderr —
    never a traceback."""
    path = _demo_with_gross_control_error(tmp_path)
    res = subprocess.run([sys.executable, "-m", "baarda.cli", "analyze", str(path), "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode in (0, 4), res.stderr
    assert "Traceback" not in res.stderr
    if res.returncode == 4:
        assert len(res.stderr.strip().splitlines()) == 1 and "NOT converged" in res.stderr


def test_the_command_line_limits_blas_threads(monkeypatch, capsys):
    """The CLI (and the server it starts) runs BLAS on BAARDA_BLAS_THREADS threads, default 1;
    a bad value is a one-line usage error."""
    from threadpoolctl import threadpool_info, threadpool_limits

    with threadpool_limits(limits=2, user_api="blas"):          # restored after the test
        monkeypatch.delenv("BAARDA_BLAS_THREADS", raising=False)
        assert main(["risk", "--p", "0.1"]) == 0
        blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
        assert blas and set(blas) == {1}
        monkeypatch.setenv("BAARDA_BLAS_THREADS", "2")
        assert main(["risk", "--p", "0.1"]) == 0
        assert {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == {2}
        monkeypatch.setenv("BAARDA_BLAS_THREADS", "many")
        capsys.readouterr()
        assert main(["risk", "--p", "0.1"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "BAARDA_BLAS_THREADS" in err[0]


def test_stop_option_reaches_the_solver(tmp_path, capsys):
    """``--stop ceres`` (issue 29, item 4) stops the demo block's adjustment by Ceres's rule
    (SolverOptions.stop through baarda.analyze: status 5, in at most the strict optimum's
    iterations, its w within 1e-3 of the optimum's); ``--stop optimum`` is the default; any
    other value is a one-line usage error (exit 2) naming baarda.iteration.STOPS."""
    demo = Path(__file__).resolve().parents[1] / "data" / "demo-block.json"
    runs = {}
    for stop in (None, "optimum", "ceres"):
        out = tmp_path / f"{stop}.json"
        assert main(["analyze", str(demo), "--json", str(out), "--quiet", *(["--stop", stop] if stop else [])]) == 0
        runs[stop] = json.loads(out.read_text())
    default, optimum, ceres = runs[None]["summary"], runs["optimum"]["summary"], runs["ceres"]["summary"]
    assert "Ceres" in ceres["termination"] and "Ceres" not in optimum["termination"]
    assert default["termination"] == optimum["termination"] and default["iterations"] == optimum["iterations"]
    assert ceres["iterations"] <= optimum["iterations"]
    w = {k: [o["w"] for o in runs[k]["observations"]] for k in ("optimum", "ceres")}
    assert max(abs(a - b) for a, b in zip(w["optimum"], w["ceres"])) < 1e-3
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["analyze", str(demo), "--stop", "fast"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--stop" in err[0] and "invalid choice" in err[0]
    assert all(stop in err[0] for stop in STOPS)
    args = build_parser().parse_args(["batch", str(demo), "--stop", "ceres"])       # batch's workers get it too
    assert batch.options_of(args)["solver"] == {"max_iter": 200, "stop": "ceres"}
