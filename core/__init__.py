"""baarda — reliability of block adjustments and geodetic networks.

Glossary of symbols (Förstner 1980, Molenaar 1984; THEORY.md):

=========  ==================================================================================
l          observations (SI units: metres, radians; pixels or mm in image space)
C, P       a priori covariance σ0²Q of the observations, weight matrix P = C⁻¹
A          design matrix ∂f/∂x at the solution (over the estimated parameters)
N, Σ       normal matrix AᵀPA and its (generalised) inverse, the covariance of x̂
v          residuals v = f(x̂) − l, adjusted minus observed
r          redundancy numbers r_i = (C_vv P)_ii, Σ r_i = redundancy (dof)
w, tau     Baarda's w-test (σ0 a priori), Pope's τ (σ0 a posteriori)
delta0     δ0(α0, β0, q), the non-centrality a test detects with power β0
mdb        minimal detectable bias ∇0l_i
external   δ̄0,i, external reliability on the coordinates
T, R       multi-dimensional test statistics of a hypothesis H (F80 eq. 12)
=========  ==================================================================================
"""

from .adjust import Options, adjust
from .datum import Datum
from .errors import BaardaError, DatumDefectError, InputError, SingularError
from .stats.hypotheses import HypothesisTest, common_error, selection

__all__ = ["Options", "adjust", "Datum", "BaardaError", "DatumDefectError", "InputError",
           "SingularError", "HypothesisTest", "common_error", "selection"]
__version__ = "0.1.0"
