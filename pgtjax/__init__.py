"""pgtjax: differentiable stochastic dynamics of planetary gear trains on JAX.

Layers: model builders (:mod:`pgtjax.models`) produce a :class:`System`; solvers consume it:
:func:`solve_moments` (statistical linearization + stochastic Newmark moments), :func:`monte_carlo`
(sampled nonlinear system), :func:`simulate` (deterministic Newmark-Newton), :func:`modal_analysis`.
Studies, plots and the CLI sit on top.
"""

from . import _config  # noqa: F401  (enables float64 before anything else)
from ._failure import SolverError as SolverError
from .contact import AbstractCriterion as AbstractCriterion
from .contact import Backlash as Backlash
from .contact import ContactLaw as ContactLaw
from .contact import EnergyCriterion as EnergyCriterion
from .contact import ForceCriterion as ForceCriterion
from .contact import Linearization as Linearization
from .deterministic import simulate as simulate
from .deterministic import static_equilibrium as static_equilibrium
from .linearization import solve_moments as solve_moments
from .modal import Modes as Modes
from .modal import modal_analysis as modal_analysis
from .montecarlo import monte_carlo as monte_carlo
from .montecarlo import quantity_names as quantity_names
from .newmark import (
    AbstractIntegrator as AbstractIntegrator,
)
from .newmark import (
    Newmark as Newmark,
)
from .newmark import (
    NewmarkBridge as NewmarkBridge,
)
from .results import (
    MomentResult as MomentResult,
)
from .results import (
    MonteCarloResult as MonteCarloResult,
)
from .results import (
    Trajectory as Trajectory,
)
from .results import (
    load_results as load_results,
)
from .results import (
    save_results as save_results,
)
from .system import Contacts as Contacts
from .system import FourierSeries as FourierSeries
from .system import Observables as Observables
from .system import System as System

__version__ = "0.1.0"
