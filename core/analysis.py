"""One analysis of a block or network, the same for every caller.

:func:`analyze` reads a file (or takes a :class:`~baarda.model.problem.Problem`), adjusts it with its
local defects set aside (networks: :mod:`baarda.network_defects`, blocks: :mod:`baarda.sfm_defects`,
chosen by the model type; ``strict=True`` refuses them instead) and returns an immutable
:class:`Analysis`: the problem adjusted, the adjustment, the test policy and the reliability under
it. Everything beyond that — data snooping, robust estimation, variance components, the criterion
matrix in an S-base, risk minimisation, exchange tests, hypothesis tests — is computed when asked
for and kept on the analysis. The command line (``baarda analyze``, ``test``, ``report``), the
dashboard, the HTML report and a Python user all go through here, so one file gives one set of
numbers whichever door it comes in by.

>>> import baarda
>>> a = baarda.analyze("data/demo-block.json")           # doctest: +SKIP
>>> a.summary()["global_test"]["passed"]                 # doctest: +SKIP
>>> a.records("observations", frame=True).nlargest(5, "w")   # doctest: +SKIP

The solver's options (:class:`SolverOptions`: tolerance, iteration limit, method, elimination) are
kept apart from the test policy (:class:`~baarda.stats.policy.TestPolicy`: α0, β0, B-method, σ0 of
the decisions, global test): :meth:`Analysis.with_policy` re-tests without adjusting again.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .lazy import installed, lazy
from .adjust import STOPS, Options, adjust
from .build import read_problem
from .datum import split_normal
from .errors import BaardaError, DatumDefectError, InputError, OptionError, UsageError
from . import truth
from .georeference import text_lines as georeference_lines
from .io import read_truth, results, summary_text
from .io.analysis_text import check_point_lines, extras_text, strip_test_lines, summary_html
from .io.hypothesis import parse_hypothesis, read_hypothesis
from .model.bundle import check_points as _check_points, has_check_points
from .model.problem import without as problem_without
from .network_defects import adjust_network
from .sfm_defects import adjust_block
from .stats import analyses, gnss, hypotheses, misidentification, precision, risk, robust, snooping, variance
from .stats.ap_tests import ap_test
from .stats.check_points import check_point_tests
from .stats.policy import TestPolicy
from .stats.reliability import Reliability
from .text import printable

# optional, imported when first used: Analysis.records(frame=True) (pandas comes with the dashboard extra)
pd = lazy("pandas") if installed("pandas") else None

#: The methods of the adjustment (:class:`baarda.adjust.Options`).
METHODS = ("auto", "gauss-newton", "levenberg-marquardt")
#: How the normal equations are solved (:class:`baarda.adjust.Options`).
SOLVERS = ("auto", "schur", "generic")
#: The kinds of variance-component estimation :meth:`Analysis.variance_components` knows.
VARIANCE_KINDS = ("families", "radial", "radial-isotropic")


@dataclass(frozen=True)
class SolverOptions:
    """How the adjustment is computed; no test decision depends on it.

    Parameters
    ----------
    tol : float
        Convergence: the largest step of an unknown relative to its standard deviation
        (dimensionless, default 1e-9).
    max_iter : int
        Iteration limit (default 200); an adjustment that reaches it is marked not converged.
    method : {"auto", "gauss-newton", "levenberg-marquardt"}
        The iteration (:class:`baarda.adjust.Options`).
    solver : {"auto", "schur", "generic"}
        Point elimination through the reduced camera system, or one sparse Cholesky of N.
    backend : {"numba", "numpy"} or None
        The pair loops of the Schur path (None: numba when installed). Same numbers either way.
    stop : {"optimum", "ceres"}
        The stopping rule: the strict optimum (default; the reliability is computed there) or
        Ceres Solver's at its defaults (function tolerance 1e-6 relative: the cost to about
        1e-6 in Ceres's time; :class:`baarda.adjust.Options`).

    Raises
    ------
    OptionError
        On construction, for a value outside its range.
    """

    tol: float = 1e-9
    max_iter: int = 200
    method: str = "auto"
    solver: str = "auto"
    backend: str | None = None
    stop: str = "optimum"

    def __post_init__(self):
        if not (isinstance(self.tol, (int, float)) and 0 < float(self.tol) < 1):
            raise OptionError("tol", self.tol, (), f"tol must lie strictly between 0 and 1 (got {self.tol!r})")
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 1:
            raise OptionError("max_iter", self.max_iter, (), f"max_iter must be a positive integer (got {self.max_iter!r})")
        if self.method not in METHODS:
            raise OptionError("method", self.method, METHODS)
        if self.solver not in SOLVERS:
            raise OptionError("solver", self.solver, SOLVERS)
        if self.backend not in (None, "numba", "numpy"):
            raise OptionError("backend", self.backend, ("numba", "numpy"))
        if self.stop not in STOPS:
            raise OptionError("stop", self.stop, STOPS)

    def options(self, policy: TestPolicy) -> Options:
        """The :class:`baarda.adjust.Options` of these solver options and ``policy``."""
        return Options(alpha0=policy.alpha0, beta0=policy.beta0, b_method=policy.b_method, tol=float(self.tol),
                       max_iter=int(self.max_iter), solver=self.solver, backend=self.backend, method=self.method,
                       sigma0=policy.sigma0, global_test=policy.global_test, conf_pr=policy.conf_pr,
                       stop=self.stop)


@dataclass(frozen=True)
class Extras:
    """What a caller asks for beyond the adjustment and its tests (the CLI's options).

    snooping: iterative data snooping; risk: ``(p, L1, L2)`` with one of ``risk_lambda_bar`` or
    ``risk_coordinate``; exchanges: ``(spec "IMAGE:A:B", both)`` pairs (``both`` False: one
    point misidentified); sbase: point ids of an S-base (the precision transformed into it);
    criterion / criterion_c0: a criterion-matrix fit in that S-base (M84 §2.3); robust: a robust
    method ("r84", "huber", "danish"); variance_components: one of :data:`VARIANCE_KINDS`, with
    merge_groups ``"A+B[,C+D]"`` families given one factor together;
    truth: a ``.truth.json`` with planted errors to compare with.
    """

    snooping: bool = False
    risk: tuple | None = None
    risk_lambda_bar: float | None = None
    risk_coordinate: float | None = None
    exchanges: tuple = ()
    sbase: tuple | None = None
    criterion: str | None = None
    criterion_c0: float | None = None
    robust: str | None = None
    variance_components: str | None = None
    merge_groups: str | None = None
    truth: str | None = None


class _NoModel:
    """A model without points (a network's analysis has no check points)."""

    points = ()


def _policy_for(problem, policy) -> TestPolicy:
    """The policy: a TestPolicy as it is; None or a dict of TestPolicy's fields without
    ``sigma0``: deciding on the σ0 the file asks for (GNU Gama's ``sigma-act``)."""
    if isinstance(policy, TestPolicy):
        return policy
    fields_ = dict(policy or {})
    if fields_.get("sigma0") is None:
        fields_["sigma0"] = "aposteriori" if getattr(problem, "sigma_act", "apriori") == "aposteriori" else "apriori"
    return TestPolicy(**fields_)


def adjust_with_defects(problem, options: Options, progress=None, strict: bool = False):
    """Adjust ``problem`` with its local defects set aside, by model type: a network's
    (:func:`baarda.network_defects.adjust_network`) or a block's
    (:func:`baarda.sfm_defects.adjust_block`). Returns ``(adjustment, problem adjusted)``;
    :class:`~baarda.errors.DatumDefectError` for a defect that is not local (or any, ``strict``)."""
    if problem.notes.network_model is not None:
        return adjust_network(problem, options, progress=progress, strict=strict)
    return adjust_block(problem, options, progress=progress, strict=strict)


def defect_message(err: DatumDefectError, problem) -> str:
    """The datum-defect message with the counts and the undetermined unknowns by entity."""
    n, u = problem.n, problem.params.free.size
    groups: dict[str, list[str]] = {}
    for label in err.undetermined:
        entity, _, name = label.rpartition(".")
        if entity:
            groups.setdefault(entity, []).append(name)
    kinds: dict[str, list[str]] = {}
    for e in groups:
        kind, _, ident = e.rpartition(" ")
        kinds.setdefault(kind or "unknown", []).append(ident or e)
    summary = "; ".join(f"{k}s {', '.join(v[:12])}{' ...' if len(v) > 12 else ''}" if k != "unknown"
                        else ", ".join(v[:12]) for k, v in kinds.items())
    gauge = " (7 of them fixed by the free-block datum)" if problem.convention else ""
    lines = f"{n} observations for {u} unknowns{gauge}"
    return f"{lines}; {err.message}" + (f" [by entity: {summary}]" if summary and len(groups) > 1 else "")


def analyze(source, *, format: str = "auto", solver: SolverOptions | None = None,  # noqa: A002 - the CLI's name
            policy: TestPolicy | dict | None = None, strict: bool = False, excluded=(), control=None,
            sigma_px: float | None = None, refine_intrinsics: bool | None = None, drop_undefined: bool = False,
            gnss=None, imu=None, progress=None) -> "Analysis":
    """Read, adjust and test a block or network.

    Parameters
    ----------
    source : str, os.PathLike or Problem
        A file or model folder (GNU Gama ``.gkf``, native JSON, BAL, Bundler, COLMAP; plain or
        compressed), or a problem already built (:func:`baarda.build.read_problem`).
    format : str
        ``"auto"`` (by content) or one of gama, native, bal, bundler, colmap.
    solver : SolverOptions, optional
        How the adjustment is computed.
    policy : TestPolicy or dict, optional
        α0, β0, B-method, σ0 of the decisions and global test; default: α0 = 0.001, β0 = 0.80,
        deciding on τ where the file asks for σ0 a posteriori (GNU Gama's ``sigma-act``), on w
        otherwise. A dict of TestPolicy's fields without ``sigma0`` takes the file's σ0 too.
    strict : bool
        Local defects (points, images, cameras the observations do not determine) are an error
        instead of being left out and listed.
    excluded : iterable of int
        Observations (indices of the problem after its local defects are set aside) to leave out.
    control, sigma_px, refine_intrinsics, drop_undefined
        The reader's options (:func:`baarda.io.read_model`): a control-point CSV, σ of image
        coordinates in pixels, whether intrinsics are estimated, Gama observations to undefined
        points dropped.
    gnss : str, os.PathLike or baarda.io.gnss.GnssOptions, optional
        GNSS projection centres (a CSV ``image,x,y,z,sx,sy,sz``; the options give the lever arm
        and whether each strip gets a shift and a drift): observations of a bundle block (an SfM
        model converted to one; :mod:`baarda.observations.gnss`), tested like any observation.
    imu : str, os.PathLike or baarda.io.gnss.ImuOptions, optional
        IMU attitudes (a CSV ``image,omega,phi,kappa,somega,sphi,skappa`` in degrees) with a
        boresight rotation, estimated unless held (:mod:`baarda.observations.imu`).
    progress : callable, optional
        ``progress(iteration, largest step / σ)`` during the adjustment.

    Returns
    -------
    Analysis

    Raises
    ------
    InputError
        The file cannot be read, or its observations do not determine the unknowns (the message
        names them).
    """
    t0 = time.perf_counter()
    if isinstance(source, (str, Path)) or hasattr(source, "__fspath__"):
        problem = read_problem(source, format, control=control, gnss=gnss, imu=imu, sigma_px=sigma_px,
                               refine_intrinsics=refine_intrinsics, strict=strict, drop_undefined=drop_undefined)
        name = str(source)
    else:
        problem, name = source, str(getattr(source, "source", "") or "problem")
    t_read = time.perf_counter() - t0
    policy = _policy_for(problem, policy)
    solver = solver or SolverOptions()
    try:
        adj, base = adjust_with_defects(problem, solver.options(policy), progress=progress, strict=strict)
    except DatumDefectError as err:
        raise InputError(name, 0, defect_message(err, problem)) from None
    adj.timings["read"] = t_read
    analysis = Analysis(base, adj, policy, solver, name=name)
    excluded = frozenset(int(i) for i in excluded)
    return analysis.without(excluded, progress=progress) if excluded else analysis


@dataclass(frozen=True, eq=False)
class Analysis:
    """The analysis of one block or network (made by :func:`analyze`).

    Attributes
    ----------
    problem : Problem
        The problem after its local defects are set aside: every observation index of the
        analysis (``excluded``, ``kept``, :meth:`test`) refers to it.
    adjustment : baarda.result.Adjustment
        The least-squares adjustment of ``problem`` without the ``excluded`` observations.
    policy : TestPolicy
        The test policy of every decision.
    solver : SolverOptions
    name : str
        Where the data came from (a path), as error messages show it.
    excluded : frozenset of int
        Observations of ``problem`` left out.
    kept : ndarray of int
        ``kept[k]``: the index in ``problem`` of the adjustment's observation k.
    """

    problem: object
    adjustment: object
    policy: TestPolicy
    solver: SolverOptions = field(default_factory=SolverOptions)
    name: str = ""
    excluded: frozenset = frozenset()
    kept: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        if self.kept is None:
            object.__setattr__(self, "kept", np.arange(self.adjustment.n))

    # -- what depends on the policy ----------------------------------------------------------------
    @property
    def options(self) -> Options:
        """The :class:`baarda.adjust.Options` of this analysis (solver options and policy)."""
        return self.solver.options(self.policy)

    @property
    def reliability(self) -> Reliability:
        """Tests and reliability measures under :attr:`policy` (F80 eq. 8-17)."""
        return self._cached("reliability", lambda: Reliability(self.adjustment, self.policy))

    @property
    def local_defects(self) -> list:
        """The local defects set aside (:class:`baarda.defects.LocalDefect`)."""
        return list(self.problem.notes.local_defects)

    def with_policy(self, policy: TestPolicy) -> "Analysis":
        """The same adjustment tested under ``policy``: nothing is adjusted again; what does not
        depend on α0/β0 (the adjustment, its r, w, τ, covariances) is shared."""
        if policy == self.policy:
            return self
        return replace(self, policy=policy, _cache={})

    def without(self, excluded, sigma_act: str | None = None, progress=None) -> "Analysis":
        """The analysis of :attr:`problem` without the observations ``excluded`` (indices of
        :attr:`problem`; replaces the current exclusions), adjusted again (from the file's
        values). ``sigma_act``: the σ0 of the covariances, ``"apriori"`` or ``"aposteriori"``
        (default: the problem's). An exclusion that leaves unknowns undetermined is an
        :class:`~baarda.errors.InputError` naming them."""
        excluded = frozenset(int(i) for i in excluded)
        current = self.adjustment.problem.sigma_act
        sigma_act = current if sigma_act is None else sigma_act
        if excluded == self.excluded and sigma_act == current:
            return self
        bad = sorted(i for i in excluded if not 0 <= i < self.problem.n)
        if bad:
            raise BaardaError(f"no observation {bad[0]} (the problem has {self.problem.n})")
        if excluded:
            reduced, kept = problem_without(self.problem, excluded)
        else:
            reduced, kept = self.problem, np.arange(self.problem.n)
        if reduced.sigma_act != sigma_act:
            reduced = replace(reduced, sigma_act=sigma_act)
        try:
            adj = adjust(reduced, self.options, progress=progress)
        except DatumDefectError as err:
            what = "without the observation(s) left out: " if excluded else ""
            raise InputError(self.name, 0, what + defect_message(err, reduced)) from None
        return Analysis(self.problem, adj, self.policy, self.solver, name=self.name, excluded=excluded,
                        kept=np.asarray(kept))

    def _cached(self, key, make):
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    # -- the document ------------------------------------------------------------------------------
    def summary(self) -> dict:
        """The summary numbers (``summary`` of the JSON document, docs/json-schema.md)."""
        return results.summary(self.adjustment, self.reliability)

    def to_dict(self, extras: Extras | None = None) -> dict:
        """The result document (docs/json-schema.md) with what ``extras`` asks for; records of
        observations, points and groups are made when read (:class:`baarda.io.results.Records`)."""
        doc = results.to_dict(self.adjustment, self.reliability)
        if extras is not None:
            self._add_extras(doc, extras)
        return doc

    def records(self, table: str = "observations", frame: bool = False):
        """One table of the result — ``"observations"``, ``"points"``, ``"groups"`` or (bundle
        blocks) ``"images"`` — with the JSON document's keys as columns: a dict of numpy arrays
        (``None`` in JSON is NaN here), or with ``frame=True`` a pandas DataFrame (pandas needed)."""
        makers = {"observations": lambda: results.observations(self.adjustment, self.reliability),
                  "points": lambda: results.points(self.adjustment),
                  "groups": lambda: results.groups(self.adjustment, self.reliability)}
        if results.has_images(self.adjustment):
            makers["images"] = lambda: results.images(self.adjustment)
        if table not in makers:
            raise OptionError("table", table, tuple(makers))
        cols = self._cached(("records", table), lambda: results.columns(makers[table]()))
        if not frame:
            return dict(cols)
        if pd is None:
            raise BaardaError("records(frame=True) needs pandas (pip install pandas); the columns without it: frame=False")
        return pd.DataFrame(cols)

    def text(self, top: int = 8, extras: Extras | None = None) -> str:
        """The text summary ``baarda analyze`` prints, with the lines of ``extras``."""
        head = summary_text.text_summary(self.adjustment, top=top, reliability=self.reliability)
        if has_check_points(self.problem.notes.local_model):
            head = "\n".join([head, *check_point_lines(self.check_points())])
        if self.gnss_strip_tests():
            head = "\n".join([head, *strip_test_lines(self.gnss_strip_tests())])
        geo = results.georeference_of(self.adjustment)
        if geo is not None:
            head = "\n".join([head, *(printable(x) for x in georeference_lines(geo))])
        return head if extras is None else "\n".join([head, *extras_text(self, extras, top)])

    def gnss_strip_tests(self) -> list:
        """The test of a shift of each strip's GNSS centres (a cycle slip, F80 §2.2 eq. 10-12) whose
        shift the model does not estimate (:func:`baarda.stats.gnss.strip_tests`); empty
        without GNSS centres."""
        spec = getattr(self.problem.notes.local_model, "gnss", None)
        if spec is None or not spec.centres:
            return []
        return self._cached("gnss_strip_tests", lambda: gnss.strip_tests(self.adjustment, self.reliability))

    def check_points(self) -> dict:
        """The check points (native ``status: check``, or ``role`` check in a control CSV): adjusted
        minus known coordinates and the RMSE per axis (:func:`baarda.model.bundle.check_points`),
        the RMSE the precision predicts and each point's test under the analysis' policy
        (:func:`baarda.stats.check_points.check_point_tests`); they never enter the adjustment.
        Empty (``n`` 0) for a model without them."""
        model = self.problem.notes.local_model
        return self._cached("check_points", lambda: check_point_tests(
            self.adjustment, _check_points(self.adjustment, model if model is not None else _NoModel()), self.policy))

    # -- computed on demand --------------------------------------------------------------------------
    def test(self, spec, label: str | None = None) -> dict:
        """The test of one hypothesis (F80 eq. 10-17): ``spec`` a dict of
        :func:`baarda.stats.hypotheses.hypothesis_matrix`, a string ``KIND:...`` as ``baarda test
        -H`` takes it, or an n × q matrix H. Returns the dict of
        :func:`baarda.stats.analyses.hypothesis_analysis` (or ``{"ap_test": …}`` for a group of
        additional parameters), with ``"exchange_test"`` for an exchange (F80 §7.1)."""
        adj, rel = self.adjustment, self.reliability
        label = label if label is not None else (spec if isinstance(spec, str) else "")
        if isinstance(spec, str):
            spec = parse_hypothesis(spec)
        if not isinstance(spec, dict):
            H = np.asarray(spec, dtype=float)
            return {"spec": {"kind": "matrix"}, **analyses.hypothesis_analysis(adj, H, reliability=rel)}
        if spec["kind"] == "ap-group" and f"{spec['camera']}:{spec['group']}" in self.problem.notes.ap_groups:
            return {"spec": spec, "ap_test": ap_test(adj, str(spec["camera"]), str(spec["group"]),
                                                     policy=self.policy).as_dict()}
        H = self.matrix(spec)
        out = {"spec": spec, **analyses.hypothesis_analysis(adj, H, label=label, reliability=rel)}
        if spec["kind"] == "exchanged":
            out["exchange_test"] = misidentification.exchange_test(
                adj, str(spec["image"]), str(spec["a"]), str(spec["b"]), policy=self.policy).as_dict()
        return out

    def matrix(self, spec):
        """The hypothesis matrix H (n × q, over the adjustment's observations) of ``spec`` (a
        string or dict as :meth:`test` takes; ``file:PATH`` read by
        :func:`baarda.io.hypothesis.read_hypothesis`)."""
        if isinstance(spec, str):
            spec = parse_hypothesis(spec)
        if spec["kind"] == "file":
            return read_hypothesis(spec["path"], self.adjustment.n)
        return hypotheses.hypothesis_matrix(self.adjustment, spec)

    def snooping(self):
        """Iterative data snooping on the policy's statistic (B68; P76 for τ):
        :class:`baarda.stats.snooping.SnoopResult`."""
        return self._cached("snooping", lambda: snooping.iterate(
            self.adjustment.problem, self.options, use_tau=self.policy.sigma0 == "aposteriori"))

    def robust(self, method: str = "r84"):
        """Robust estimation (R84 §6-8) followed by least squares without the suspects:
        :class:`baarda.stats.robust.RobustResult`."""
        return self._cached(("robust", method), lambda: robust.estimate(self.adjustment.problem, method, self.options))

    def variance_components(self, kind: str = "families", merge: str | None = None):
        """Variance components (F80 eq. 9; F79): ``"families"`` — one factor per observation
        family (:func:`baarda.stats.variance.estimate`; ``merge`` "A+B[,C+D]" gives families one
        factor together, :func:`baarda.stats.variance.merge_groups`) — or the radial model of a
        block, ``"radial"`` / ``"radial-isotropic"`` (F80 §2.1)."""
        if kind not in VARIANCE_KINDS:
            raise OptionError("variance_components", kind, VARIANCE_KINDS)

        def make():
            if kind == "families":
                problem = self.adjustment.problem
                groups = variance.merge_groups(variance.groups_by_kind(problem), merge) if merge else None
                return variance.estimate(problem, groups, options=self.options)
            structure = "isotropic" if kind == "radial-isotropic" else "radial"
            return analyses.radial_variance(self.adjustment.problem, self.options, structure)
        return self._cached(("variance", kind, merge or ""), make)

    def precision(self, sbase=None):
        """The coordinates' covariance in the S-base ``sbase`` (point ids; a free network's
        default: its first two points; ``"normal=ID"`` entries name a 3D base's normal):
        :class:`baarda.stats.precision.CoordinateCovariance` (M84 §2.2)."""
        ids = self.problem.points.ids
        base = [str(b).strip() for b in sbase] if sbase else [str(i) for i in ids[:2]]
        named, normal = split_normal(base)
        known = set(map(str, ids))
        unknown = [b for b in named + ([normal] if normal is not None else []) if b not in known]
        if unknown:
            raise UsageError(f"--sbase: unknown point id(s) {', '.join(unknown)}")
        return self._cached(("precision", tuple(base)), lambda: precision.covariance(self.adjustment, sbase=base))

    def criterion(self, kind: str = "logarithmic", C0: float | None = None, sbase=None) -> dict:
        """The criterion matrix fitted to the covariance in the S-base (M84 §2.3):
        the dict of :func:`baarda.stats.analyses.criterion_fit`."""
        reason = analyses.criterion_reason(self.adjustment)
        if reason:
            raise UsageError(f"--criterion: {reason}")
        cc = self.precision(sbase)

        def make():
            try:
                return analyses.criterion_fit(analyses.criterion_setup(self.adjustment, self._sbase(cc), cov=cc),
                                              kind=kind, C0=C0 if C0 is not None else 0.0)
            except BaardaError as err:
                raise UsageError(f"--criterion: {err}") from None
        return self._cached(("criterion", kind, C0, id(cc)), make)

    @staticmethod
    def _sbase(cc) -> list:
        named, _ = split_normal(list(cc.sbase))
        return named + [b for b in cc.sbase if str(b).startswith("normal=")]

    def risk(self, p: float, L1: float, L2: float, lambda_bar_tol: float | None = None,
             coordinate_tol: float | None = None):
        """Risk-minimising critical values per observation (M84 §3.3):
        :class:`baarda.stats.risk` ``per_observation``."""
        if (lambda_bar_tol is None) == (coordinate_tol is None):
            raise UsageError("--risk: give one tolerance, --risk-lambda-bar TOL or --risk-coordinate METRES")
        key = ("risk", p, L1, L2, lambda_bar_tol, coordinate_tol)
        try:
            return self._cached(key, lambda: risk.per_observation(self.adjustment, p, L1, L2,
                                                                  lambda_bar_tol=lambda_bar_tol,
                                                                  coordinate_tol=coordinate_tol))
        except BaardaError as err:
            raise UsageError(f"--risk: {err}") from None

    def exchange(self, spec: str, both: bool = True):
        """The test of an exchange (``both``) or a misidentification of points A and B in an
        image, ``spec`` = ``"IMAGE:A:B"`` (F80 §7.1)."""
        option = "--exchange" if both else "--misidentified"
        parts = [x.strip() for x in str(spec).split(":")]
        if len(parts) != 3 or not all(parts):
            raise UsageError(f"{option}: expected IMAGE:A:B, got {spec!r}")
        try:
            return self._cached(("exchange", tuple(parts), both), lambda: misidentification.exchange_test(
                self.adjustment, *parts, both=both, policy=self.policy))
        except BaardaError as err:
            raise UsageError(f"{option} {spec}: {err}") from None

    def planted(self, truth_path, robust=None, final=...) -> list:
        """The planted errors of a ``.truth.json`` (:mod:`baarda.simulate`) and whether the tests
        found them (:func:`baarda.truth.compare`). With ``robust`` (a
        :class:`~baarda.stats.robust.RobustResult` of this analysis, the case where least squares
        on all observations gave no result): against ``final`` (default the robust result's least
        squares without its suspects; None: against the suspects alone, R84 §7), an error among
        the suspects marked ``robust_suspect``."""
        if robust is None:
            return self._cached(("planted", str(truth_path)), lambda: truth.compare(
                self.adjustment, read_truth(truth_path), reliability=self.reliability))
        final = robust.final if final is ... else final
        kept = self.problem.notes.kept_rows           # the truth file numbers the file's rows
        # a suspect whose point was left out (R84 §7, a 2-ray point) takes all the point's rays with it
        left = [np.asarray(sp.get("left_out", sp["members"]), dtype=np.int64) for sp in robust.suspects]
        if kept is not None:
            left = [np.asarray(kept)[m] for m in left]
        return truth.compare(final, read_truth(truth_path), left_out=left)

    # -- the document's extras ---------------------------------------------------------------------
    def _add_extras(self, doc: dict, ex: Extras) -> None:
        """Add to ``doc`` what ``ex`` asks for (the keys of docs/json-schema.md); a number that
        does not exist (NaN, ±inf) is ``null`` there, as everywhere in the document."""
        before = set(doc)
        if ex.truth is not None:
            doc["planted"] = self.planted(ex.truth)
        if ex.snooping:
            doc["snooping"] = [s.__dict__ for s in self.snooping().steps]
        if ex.risk is not None or ex.risk_lambda_bar is not None or ex.risk_coordinate is not None:
            if ex.risk is None:
                raise UsageError("--risk-lambda-bar / --risk-coordinate need --risk P,L1,L2")
            r = self.risk(*ex.risk, lambda_bar_tol=ex.risk_lambda_bar, coordinate_tol=ex.risk_coordinate)
            doc["risk"] = {"p": r.p, "L1": r.L1, "L2": r.L2, "tolerance": r.tolerance, "rejected": int(r.rejected.sum())}

            def risk_of(i, r=r):
                d = {k: results.finite(float(getattr(r, k)[i])) for k in ("lam_tol", "C", "alpha", "beta", "r_C")}
                return {"risk": {**d, "rejected": bool(r.rejected[i])}}
            doc["observations"].add(risk_of, lambda r=r: results.risk_fields(r, self.adjustment.n))
        exchanges = [self.exchange(spec, both) for spec, both in ex.exchanges]
        if exchanges:
            doc["exchange_tests"] = [e.as_dict() for e in exchanges]
        if ex.sbase is not None or ex.criterion:
            cc = self.precision(ex.sbase)
            ell = cc.ellipses()
            sd = np.sqrt(np.maximum(np.diag(cc.cov), 0.0))

            def transformed(i, cc=cc, sd=sd, ell=ell):      # (point i's record is point i of ids)
                d = {"s" + "xyz"[cc.axis[c]]: float(sd[c]) for c in np.flatnonzero(cc.point == i)}
                if i < len(ell) and np.isfinite(ell[i, 0]):
                    d["ellipse"] = {"a": float(ell[i, 0]), "b": float(ell[i, 1]), "bearing": float(ell[i, 2])}
                return d
            doc["points"].add(transformed)
            doc["summary"]["sbase"] = self._sbase(cc)
            if ex.criterion:
                doc["criterion"] = self.criterion(ex.criterion, ex.criterion_c0, ex.sbase)
        if ex.robust:
            rob = self.robust(ex.robust)
            doc["robust"] = rob.as_dict()
            doc["summary"]["robust"] = results.finite(rob.summary())
        if ex.variance_components:
            try:
                est = self.variance_components(ex.variance_components, ex.merge_groups)
            except BaardaError as err:
                doc["variance_components"] = {"error": str(err)}
            else:
                doc["variance_components"] = est.as_dict()
                if ex.variance_components == "families":
                    doc["variance_estimate"] = est.summary()
                else:
                    doc["variance_estimate"] = {"kind": ex.variance_components, "converged": bool(est.converged),
                                                "iterations": int(est.iterations), "std_error": "rigorous",
                                                "notes": list(est.notes)}
        for key in set(doc) - before:
            doc[key] = results.finite(doc[key])

    # -- in a notebook ---------------------------------------------------------------------------
    def _repr_html_(self) -> str:
        return summary_html(self)

    def __repr__(self) -> str:
        s = self.summary()
        g = s["global_test"]
        return (f"<Analysis {Path(self.name).name or 'problem'}: {s['n_observations']} observations, "
                f"{s['n_unknowns']} unknowns, r = {s['dof']}, global test "
                f"{'passed' if g['passed'] else 'FAILED'}, {s['n_rejected']} rejected>")

    def view(self, what: str = "maps"):
        """The dashboard's maps and tables of this analysis as a Panel object, to show inline in
        a notebook (``pn.extension()`` first). ``what``: ``"maps"`` (layout, residuals,
        redundancy, external reliability), ``"suspects"``, ``"tests"`` or ``"app"`` (the whole
        dashboard). Needs the ``dashboard`` extra (Panel, HoloViews, Bokeh)."""
        from .dashboard.notebook import view
        return view(self, what)
