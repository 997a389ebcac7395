"""baarda — reliability of block adjustments and geodetic networks.

Glossary of symbols (F80, M84; the references are listed below):

==========  ==================================================================================
l           observations (SI units: metres, radians; pixels or mm in image space)
C, P        a priori covariance σ0²Q of the observations, weight matrix P = C⁻¹
A           design matrix ∂f/∂x at the solution (over the estimated parameters)
N, Σ        normal matrix AᵀPA and its (generalised) inverse, the covariance of x̂
v           residuals v = f(x̂) − l, adjusted minus observed
r           redundancy numbers r_i = (C_vv P)_ii, Σ r_i = redundancy (dof)
w, tau      Baarda's w-test (σ0 a priori), Pope's τ (σ0 a posteriori)
delta0      δ0(α0, β0, q), the non-centrality a test detects with power β0
mdb         minimal detectable bias ∇0l_i
external    δ̄0,i, external reliability on the coordinates
T, R        multi-dimensional test statistics of a hypothesis H (F80 eq. 12)
u_k, u_t    contributions of an observation to the coordinates and to the nuisance parameters
            (F80 eq. 16)
nabla       ∇ŝ = −W_s⁻¹HᵀPv, the estimated error of a hypothesis (F80 eq. 10)
delta0'     δ0′(s), standardised sensitivity of a test in direction s (F80 eq. 14)
delta_bar0  δ̄0(s), effect of an undetected error on any function of the coordinates (F80 eq. 17)
lambda_bar  Baarda's λ̄ = ∇0kᵀ Q_kk⁻ ∇0k, datum invariant; δ̄0² (M84 §3.2)
==========  ==================================================================================

References (docstrings cite them by key and equation, e.g. ``F80 eq. 8``; also docs/references.md):

F80      Förstner, W. (1980). Evaluation of block adjustment results. Presented paper, Commission
         III, XIV Congress of the International Society for Photogrammetry, Hamburg.
M84      Molenaar, M. (1984). The present status of the theory for the evaluation of the quality of
         photogrammetric point determination. Invited paper, Commission III, Working Group 1, XV
         Congress of the ISPRS, Rio de Janeiro.
R84      Robust adjustment of photogrammetric blocks (§6 classification of gross errors, §7 their
         location). XV Congress of the ISPRS, Rio de Janeiro, Part A3 (a fragment; its authors are
         not in the surviving text).
B68      Baarda, W. (1968). A testing procedure for use in geodetic networks. Netherlands Geodetic
         Commission, Publications on Geodesy, New Series 2(5), Delft.
P76      Pope, A. J. (1976). The statistics of residuals and the detection of outliers. NOAA
         Technical Report NOS 65 NGS 1, Rockville, MD.
F79      Förstner, W. (1979). Ein Verfahren zur Schätzung von Varianz- und Kovarianzkomponenten.
         Allgemeine Vermessungs-Nachrichten 86.
H64      Huber, P. J. (1964). Robust estimation of a location parameter. Annals of Mathematical
         Statistics 35(1), 73–101.
KJK80    Krarup, T., Juhl, J., Kubik, K. (1980). Götterdämmerung over least squares adjustment. XIV
         Congress of the International Society for Photogrammetry, Hamburg, Commission III.
B71      Brown, D. C. (1971). Close-range camera calibration. Photogrammetric Engineering 37(8),
         855–866.
E76      Ebner, H. (1976). Self calibrating block adjustment. Bildmessung und Luftbildwesen 44.
F97      Fraser, C. S. (1997). Digital camera self-calibration. ISPRS Journal of Photogrammetry and
         Remote Sensing 52(4), 149–159.
K07      Kraus, K. (2007). Photogrammetry: Geometry from Images and Laser Scans, 2nd ed. de Gruyter,
         Berlin.
HZ04     Hartley, R., Zisserman, A. (2004). Multiple View Geometry in Computer Vision, 2nd ed.
         Cambridge University Press.
BAL10    Agarwal, S., Snavely, N., Seitz, S. M., Szeliski, R. (2010). Bundle adjustment in the
         large. European Conference on Computer Vision (ECCV).
S06      Snavely, N., Seitz, S. M., Szeliski, R. (2006). Photo tourism: exploring photo collections
         in 3D. ACM Transactions on Graphics 25(3) (SIGGRAPH) — Bundler.
SF16     Schönberger, J. L., Frahm, J.-M. (2016). Structure-from-motion revisited. IEEE Conference
         on Computer Vision and Pattern Recognition (CVPR) — COLMAP.
B00      Bradski, G. (2000). The OpenCV library. Dr. Dobb's Journal of Software Tools.
C11      Chirikjian, G. S. (2011). Stochastic Models, Information Theory, and Lie Groups, vol. 2.
         Birkhäuser, Boston.
TFC73    Takahashi, K., Fagan, J., Chen, M.-S. (1973). Formation of a sparse bus impedance matrix
         and its application to short circuit study. 8th PICA Conference Proceedings, Minneapolis.
CM69     Cuthill, E., McKee, J. (1969). Reducing the bandwidth of sparse symmetric matrices.
         Proceedings of the 24th ACM National Conference, 157–172.
BPS95    Barnard, S. T., Pothen, A., Simon, H. (1995). A spectral algorithm for envelope reduction
         of sparse matrices. Numerical Linear Algebra with Applications 2(4), 317–334.
N99      Nielsen, H. B. (1999). Damping parameter in Marquardt's method. Technical report
         IMM-REP-1999-05, Technical University of Denmark.
MNT04    Madsen, K., Nielsen, H. B., Tingleff, O. (2004). Methods for non-linear least squares
         problems, 2nd ed. Informatics and Mathematical Modelling, Technical University of Denmark.
CERES    Agarwal, S., Mierle, K., and the Ceres Solver team. Ceres Solver. http://ceres-solver.org
C90      Clinger, W. D. (1990). How to read floating point numbers accurately. Proceedings of the
         ACM SIGPLAN Conference on Programming Language Design and Implementation (PLDI), 92–101.
"""

from __future__ import annotations

import importlib
import sys
import types

#: where each public name lives; imported on first use (PEP 562), so ``import baarda`` and the
#: command line's parser load no numpy (issue 30, item 5; issue 25: Ctrl-C during start-up)
_EXPORTS = {
    "analyze": "analysis", "Analysis": "analysis", "Extras": "analysis", "SolverOptions": "analysis",
    "TestPolicy": "stats.policy", "read_problem": "build", "Options": "adjust", "adjust": "adjust",
    "Datum": "datum", "BaardaError": "errors", "DatumDefectError": "errors", "InputError": "errors",
    "SingularError": "errors", "HypothesisTest": "stats.hypotheses", "common_error": "stats.hypotheses",
    "selection": "stats.hypotheses",
}

__all__ = list(_EXPORTS)
__version__ = "0.1.0"


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'baarda' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value            # the next access is a plain lookup
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))


class _Package(types.ModuleType):
    """``baarda``: its name ``adjust`` stays the function :func:`baarda.adjust.adjust` (as
    ``from baarda import adjust`` always gave) when the import system binds the submodule of the
    same name to the package on its first import."""

    def __setattr__(self, name, value):
        if name in _EXPORTS and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
