"""Typed errors (baarda.errors) carry their data as fields, survive pickling (the dashboard's
workers) and keep the message the CLI prints. References: the null space of a singular normal
matrix from a dense eigen-decomposition, the option tuples the modules publish."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import scipy.sparse as sp

from baarda.adjust import METHODS, Options, adjust
from baarda.errors import (BaardaError, ConversionError, CovarianceError, DatumDefectError, HypothesisError,
                           InputError, NotFoundError, OptionError, SingularError)
from baarda.model.bundle import build_block_problem, control_rows, image_rows
from baarda.model.problem import Covariance
from baarda.solve.linalg import SPDFactor
from baarda.simulate import simulate_block
from baarda.stats import distributions, risk
from baarda.stats.reliability import reliability_of

from tests.networks import grid_network, problem


def _singular_normal_matrix(seed=2, u=12):
    """N = AᵀA with column 7 of A the sum of columns 2 and 4: null vector e7 − e2 − e4."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(30, u))
    A[:, 7] = A[:, 2] + A[:, 4]
    return A.T @ A


def test_singular_error_names_an_unknown_of_the_null_space():
    N = _singular_normal_matrix()
    labels = [f"P{j}.x" for j in range(N.shape[0])]
    with pytest.raises(SingularError) as info:
        SPDFactor(sp.csr_matrix(N), labels=labels)
    err = info.value
    lam, V = np.linalg.eigh(N)
    null = V[:, np.argmin(np.abs(lam))]
    assert abs(null[err.index]) > 0.1                    # the pivot lies in the null space {2, 4, 7}
    assert err.index in (2, 4, 7) and err.unknown == labels[err.index]
    assert str(err) == f"normal matrix is singular: {err.unknown} is not determined by the observations"


def test_option_error_fields_and_value_error():
    pr = problem(grid_network(3, 3, noise_seed=1))
    with pytest.raises(OptionError) as info:
        adjust(pr, Options(method="simplex"))
    err = info.value
    assert isinstance(err, ValueError) and isinstance(err, BaardaError)
    assert (err.option, err.value, err.allowed) == ("method", "simplex", tuple(METHODS))
    assert str(err) == f"unknown method 'simplex' (known: {', '.join(METHODS)})"
    with pytest.raises(OptionError) as info:
        adjust(pr, Options(max_iter=0))
    assert (info.value.option, info.value.value) == ("max_iter", 0)


@pytest.mark.parametrize("args, bad", [((0.0, 0.8, 1), "alpha"), ((0.01, 1.0, 1), "beta"), ((0.01, 0.8, 0), "q")])
def test_delta0_names_the_bad_argument(args, bad):
    with pytest.raises(OptionError) as info:
        distributions.delta0(*args)
    assert info.value.option == bad and info.value.value == dict(zip(("alpha", "beta", "q"), args))[bad]


@pytest.mark.parametrize("args, bad", [((1.5, 1, 1, 1), "p"), ((0.1, 0, 1, 1), "L1"), ((0.1, 1, -1, 1), "L2"),
                                       ((0.1, 1, 1, 0), "lam_tol")])
def test_risk_names_the_bad_argument(args, bad):
    with pytest.raises(OptionError) as info:
        risk.critical_value(*args)
    assert info.value.option == bad


def test_hypothesis_error_carries_the_sizes():
    adj = adjust(problem(grid_network(3, 3, noise_seed=1)))
    H = sp.csc_matrix(np.ones((adj.n + 1, 1)))
    with pytest.raises(HypothesisError) as info:
        reliability_of(adj).test(H)
    assert (info.value.rows, info.value.n) == (adj.n + 1, adj.n)
    assert str(info.value) == f"H has {adj.n + 1} rows for {adj.n} observations"


def test_covariance_error_names_the_uncovered_observations():
    with pytest.raises(CovarianceError) as info:
        Covariance.from_blocks(5, [[0, 1], [3]], [np.eye(2), np.eye(1)])
    assert info.value.observations == (2, 4) and info.value.cluster is None
    with pytest.raises(CovarianceError) as info:
        Covariance.from_blocks(3, [[0, 1], [2]], [np.eye(3), np.eye(1)])
    assert info.value.cluster == 0


def test_not_found_names_the_missing_item():
    """A hypothesis on a measurement the block does not have: the ids as fields, the message
    without KeyError's quotes (the dashboard shows it as it is)."""
    block, _ = simulate_block(strips=1, images_per_strip=3, seed=2)
    pr = build_block_problem(block)
    image = block.images[0].id
    with pytest.raises(NotFoundError) as info:
        image_rows(pr, image, "no-such-point")
    err = info.value
    assert isinstance(err, KeyError) and (err.what, err.ids) == ("image point", {"image": image, "point": "no-such-point"})
    assert str(err) == f"no measurement of point no-such-point in image {image}"
    with pytest.raises(NotFoundError) as info:
        control_rows(pr, "no-such-point")
    assert info.value.ids == {"point": "no-such-point"}


@pytest.mark.parametrize("err", [
    SingularError(unknown="P7.x", index=3), SingularError("the adjustment diverged"),
    OptionError("solver", "x", ("generic", "schur"), "unknown solver 'x'"),
    ConversionError("camera 1", "f_x ≠ f_y has no native equivalent"),
    HypothesisError("no lower bound", q=0), CovarianceError("gap", observations=[2, 4]),
    DatumDefectError(1, ["P7.x"]), InputError("a.txt", 3, "bad number", field="x"),
    NotFoundError("image point", {"image": "101", "point": "7"}),
])
def test_errors_pickle_with_their_fields(err):
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is type(err) and str(back) == str(err) and vars(back) == vars(err)


def test_datum_defect_error_says_whether_it_is_local():
    """The network's safety net asks ``err.local`` (typed), not the message's words."""
    import pickle

    from baarda.errors import DatumDefectError

    err = DatumDefectError(1, ["P7.x"], "the observations do not determine P7.x", local=True)
    back = pickle.loads(pickle.dumps(err))
    assert back.local is True and back.undetermined == ["P7.x"] and str(back) == str(err)
    assert DatumDefectError(3, ["tx", "ty", "tz"]).local is False
