"""Variance components (F80 eq. 9): simulated group factors are recovered."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from baarda import variance
from baarda.adjust import adjust
from baarda.errors import BaardaError
from baarda.network import Cluster

from networks import grid_network, problem


def _network_with_true_factors(seed, f_dist=2.0, f_dir=0.5, sd=0.002, sr=1e-5):
    noisy = grid_network(7, 7, sigma_d=sd * np.sqrt(f_dist), sigma_r=sr * np.sqrt(f_dir), noise_seed=seed)
    nominal = tuple(Cluster((i,), np.array([[(sd if o.kind == "distance" else sr) ** 2]]))
                    for i, o in enumerate(noisy.observations))
    return dataclasses.replace(noisy, clusters=nominal)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_group_factors(seed):
    p = problem(_network_with_true_factors(seed))
    vc = variance.estimate(p)
    assert vc.converged
    est = dict(zip(vc.names, vc.factors))
    se = dict(zip(vc.names, vc.std_error))
    assert abs(est["distances"] - 2.0) < 3 * se["distances"]
    assert abs(est["angles"] - 0.5) < 3 * se["angles"]
    # after the iteration every group's estimate is 1 with the rescaled covariances
    adj = vc.adjustment
    for name, ix in variance.groups_by_kind(p).items():
        assert abs(adj.v[ix] @ adj.Pv[ix] / adj.r[ix].sum() - 1.0) < 1e-3
    # the redundancies of the groups add up to the total redundancy
    assert abs(vc.redundancy.sum() - adj.dof) < 1e-8


def test_single_group_factor_is_the_variance_factor():
    p = problem(_network_with_true_factors(4))
    adj = adjust(p)
    vc = variance.estimate(p, {"all": np.arange(p.n)})
    assert abs(vc.factors[0] - (adj.sigma0_post / adj.sigma0) ** 2) < 1e-3 * vc.factors[0]


def test_split_cluster_is_refused():
    from networks import vector_network
    p = problem(vector_network())
    with pytest.raises(BaardaError, match="cluster"):
        variance.estimate(p, {"a": np.arange(0, 4), "b": np.arange(4, p.n)})
