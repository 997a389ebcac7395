"""Which statistic flags observations (issue 14, item 15): Baarda's w with σ0 a priori, Pope's τ
with its critical value where σ0 a posteriori is used (P76; F80 §4) — in the JSON flags, the
text and iterative data snooping (``--statistic``; by default the file's ``sigma-act``).

τ's critical value is computed here from Pope's definition, τ²/r ~ Beta(1/2, (r − 1)/2):
P(|τ| > τ_c) = α0 ⇔ τ_c = √(r · Beta⁻¹_{1−α0}(1/2, (r − 1)/2)), not through baarda's code.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

from baarda.cli import main

DATA = Path(__file__).resolve().parents[2] / "data"
LEVELLING = DATA / "demo-levelling.gkf"


def tau_critical(alpha: float, r: int) -> float:
    return float(np.sqrt(r * sps.beta.isf(alpha, 0.5, (r - 1) / 2.0)))


def _analyze(tmp_path, path, *extra):
    out = tmp_path / "r.json"
    assert main(["analyze", str(path), "--json", str(out), "--quiet", *extra]) == 0
    return json.loads(out.read_text())


def test_tau_flags_with_popes_critical_value(tmp_path):
    """The demo levelling (r = 5): |w| = 3.59 on C → D exceeds 3.29, but τ = w σ0/σ̂0 = 2.07 stays
    below τ_c(0.1 %, 5) = 2.18 — the w-test rejects it, the τ-test does not."""
    w_doc = _analyze(tmp_path, LEVELLING)
    tau_doc = _analyze(tmp_path, LEVELLING, "--statistic", "tau")
    r = w_doc["summary"]["dof"]
    tc = tau_critical(0.001, r)
    assert w_doc["summary"]["critical_tau"] == pytest.approx(tc, rel=1e-9)
    assert (w_doc["summary"]["statistic"], tau_doc["summary"]["statistic"]) == ("w", "tau")
    for doc in (w_doc, tau_doc):
        for o in doc["observations"]:
            assert o["rejected_tau"] == (o["tau"] is not None and abs(o["tau"]) > tc)
            assert o["rejected_w"] == (o["w"] is not None and abs(o["w"]) > sps.norm.isf(0.0005))
    assert [o["rejected"] for o in w_doc["observations"]] == [o["rejected_w"] for o in w_doc["observations"]]
    assert [o["rejected"] for o in tau_doc["observations"]] == [o["rejected_tau"] for o in tau_doc["observations"]]
    assert w_doc["summary"]["n_rejected"] == 1 and tau_doc["summary"]["n_rejected"] == 0


def test_default_follows_the_files_sigma_act(tmp_path):
    post = tmp_path / "post.gkf"
    post.write_text(LEVELLING.read_text().replace('sigma-act="apriori"', 'sigma-act="aposteriori"'))
    doc = _analyze(tmp_path, post)
    assert doc["summary"]["statistic"] == "tau" and doc["summary"]["n_rejected"] == 0
    assert _analyze(tmp_path, post, "--statistic", "w")["summary"]["n_rejected"] == 1


def test_snooping_on_tau(tmp_path, capsys):
    """--snoop removes by the chosen statistic: w removes C → D, τ removes nothing."""
    assert len(_analyze(tmp_path, LEVELLING, "--snoop")["snooping"]) == 1
    assert _analyze(tmp_path, LEVELLING, "--snoop", "--statistic", "tau")["snooping"] == []
    assert main(["analyze", str(LEVELLING), "--snoop", "--alpha", "0.05", "--statistic", "tau"]) == 0
    text = capsys.readouterr().out
    assert "iterative data snooping on τ" in text and "|τ| = " in text
    assert "rejected by τ" in text


def test_bad_statistic_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["analyze", str(LEVELLING), "--statistic", "t"])
    assert exc.value.code == 2
    assert "--statistic" in capsys.readouterr().err
