"""From a file-level model to the adjustment problem: the one place models become Problems.

:func:`build` turns a model read by :mod:`baarda.io` (a :class:`~baarda.model.network.Network`,
:class:`~baarda.model.bundle.Block`, :class:`~baarda.model.imodel.IModelBlock` or
:class:`~baarda.model.sfm.SfmBlock`) into a :class:`~baarda.model.problem.Problem`;
:func:`read_problem` reads and builds in one call.
"""

from __future__ import annotations

from .io import read_model
from .io.control import add_control
from .io.gnss import GnssOptions, ImuOptions, add_gnss, add_imu
from .model.bundle import Block
from .model.imodel import IModelBlock, build_imodel_problem
from .model.network import Network
from .model.sfm import SfmBlock
from .network_defects import build_network
from .sfm_defects import build as build_block
from .validate import check_model_range, check_numeric_range


def build(model, strict: bool = False):
    """The adjustment problem of a file-level model.

    Bundle blocks lose their local defects first (:mod:`baarda.sfm_defects`: points, images,
    cameras the observations do not determine), listed in ``problem.notes.local_defects``;
    strict: refuse them instead (InputError naming them all).
    """
    if isinstance(model, (SfmBlock, Block)):
        return build_block(model, strict=strict)
    if isinstance(model, IModelBlock):
        return build_imodel_problem(model)
    if isinstance(model, Network):
        return build_network(model, strict=strict)
    raise TypeError(f"cannot build a problem from {type(model).__name__}")


def read_problem(path, fmt: str = "auto", control=None, strict: bool = False, gnss=None, imu=None, **options):
    """Read ``path`` and return a :class:`baarda.model.problem.Problem` ready to adjust.

    control: optional control-point CSV (:func:`baarda.io.control.add_control`); gnss: GNSS
    projection centres, a CSV path or :class:`baarda.io.gnss.GnssOptions`
    (:func:`baarda.io.gnss.add_gnss`); imu: IMU attitudes, a CSV path or
    :class:`baarda.io.gnss.ImuOptions` (:func:`baarda.io.gnss.add_imu`); strict: local defects are an error (:func:`build`);
    options go to :func:`baarda.io.read_model`.
    """
    model = read_model(path, fmt, **options)
    if control is not None:
        model = add_control(model, control)
    if gnss is not None:
        model = add_gnss(model, gnss if isinstance(gnss, GnssOptions) else GnssOptions(gnss))
    if imu is not None:
        model = add_imu(model, imu if isinstance(imu, ImuOptions) else ImuOptions(imu))
    check_model_range(model, path)                   # values double precision can adjust
    problem = build(model, strict=strict)
    check_numeric_range(problem, path, control)      # σ and values double precision can adjust
    return problem
