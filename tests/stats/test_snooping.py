"""Iterative data snooping on simulated blocks (F80 §4): finds planted errors, few false alarms."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from baarda.adjust import adjust
from baarda.build import read_problem
from baarda.io import read_truth
from baarda.model.bundle import build_block_problem
from baarda.simulate import simulate_block
from baarda.stats.snooping import iterate, leave_one_out
from baarda.stats.reliability import reliability_of

DATA = Path(__file__).resolve().parents[2] / "data"


def test_demo_block_first_removal_is_the_planted_image_error():
    p = read_problem(DATA / "demo-block.json")
    truth = read_truth(DATA / "demo-block.truth.json")
    res = iterate(p)
    planted = {int(r) for e in truth["errors"] for r in e["rows"]}
    image_error = next(e for e in truth["errors"] if e["kind"] == "image")
    assert res.removed[0] in image_error["rows"]
    assert len(res.removed) >= 2 and set(res.removed[:3]) <= planted | set(range(p.n))
    assert res.adjustment.sigma0_post < res.steps[0].sigma0_before
    # the estimated error of the first removal recovers the planted 100 µm within 30 %
    assert abs(abs(res.steps[0].nabla) - 0.1) < 0.03
    loo = leave_one_out(adjust(p), res.removed[:3])
    assert loo[0]["sigma0_without"] < adjust(p).sigma0_post


def _design(seed=5):
    block, _ = simulate_block(strips=2, images_per_strip=5, design=True, seed=seed, control="perimeter",
                              check=0, approx_sigma=0.0)
    return build_block_problem(block)


def _noise(p, rng):
    e = np.zeros(p.n)
    for idx, C in zip(p.cov.members, p.cov.blocks):
        e[idx] = np.linalg.cholesky(C) @ rng.normal(size=idx.size)
    return e


@pytest.mark.slow
def test_snooping_detection_rate_and_false_alarms():
    p = _design()
    base = adjust(p)
    candidates = np.flatnonzero(base.r > 0.2)
    rng = np.random.default_rng(77)
    n_sim = 200
    found = false = tests = 0
    for _ in range(n_sim):
        e = _noise(p, rng)
        # clean block: false alarms of the single-pass w-test per observation
        clean = adjust(dataclasses.replace(p, l=p.l + e), x0=base.x)
        false += int(reliability_of(clean).rejected.sum())
        tests += clean.n
        # one error of 1.2 × MDB on a random controllable observation
        i = int(rng.choice(candidates))
        e[i] += 1.2 * reliability_of(base).mdb[i] * rng.choice([-1, 1])
        res = iterate(dataclasses.replace(p, l=p.l + e), max_steps=3)
        found += int(bool(res.removed) and res.removed[0] == i)
    rate = found / n_sim
    assert rate >= 0.80 - 3 * np.sqrt(0.8 * 0.2 / n_sim), rate
    alpha = 0.001
    assert abs(false / tests - alpha) < 3 * np.sqrt(alpha * (1 - alpha) / tests) + 0.0005, false / tests


def test_estimated_error_for_correlated_observations_is_f80_nabla_s():
    """∇ŝ = −(Hᵀ P v)/(Hᵀ P C_vv P H) for H = e_i (F80 eq. 10): for GNSS vectors with full 3 × 3
    covariances it is not −v_i/r_i. Checked against the dense oracle of the first adjustment."""
    from tests.networks import problem, vector_network
    from tests.oracle import dense

    net = vector_network(seed=3)
    k = 7                                                   # a dy of the third vector
    noise = np.random.default_rng(5).normal(scale=0.002, size=len(net.observations))
    obs = [dataclasses.replace(o, value=o.value + e) for o, e in zip(net.observations, noise)]
    obs[k] = dataclasses.replace(obs[k], value=obs[k].value + 0.05)
    p = problem(dataclasses.replace(net, observations=tuple(obs)))
    d = dense(adjust(p))
    steps = iterate(p).steps
    assert steps and steps[0].removed == k
    Pv = d.P @ d.v
    expected = -Pv[k] / (d.P @ d.Cvv @ d.P)[k, k]
    assert steps[0].nabla == pytest.approx(expected, rel=1e-9)
    assert abs(steps[0].nabla - (-d.v[k] / np.diag(d.Cvv @ d.P)[k])) > 1e-6    # not −v/r here
