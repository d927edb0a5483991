"""pgtjax: differentiable stochastic dynamics of planetary gear trains on JAX.

Layers: model builders (:mod:`pgtjax.models`) produce a :class:`System`; solvers consume it:
:func:`solve_moments` (statistical linearization + stochastic Newmark moments), :func:`monte_carlo`
(sampled nonlinear system), :func:`simulate` (deterministic Newmark-Newton), :func:`modal_analysis`.
Studies, plots and the CLI sit on top.

This module is the public surface of the core: everything a model, a contact law, an integrator or a study
needs is exported here. The underscore modules (``pgtjax._system``, ``pgtjax._linearization``, ...) are the
implementation and may change without notice.
"""

from . import _config  # noqa: F401  (enables float64 before anything else)
from ._config import use_compilation_cache as use_compilation_cache
from ._contact import AbstractCriterion as AbstractCriterion
from ._contact import Backlash as Backlash
from ._contact import ContactLaw as ContactLaw
from ._contact import EnergyCriterion as EnergyCriterion
from ._contact import ForceCriterion as ForceCriterion
from ._contact import Linearization as Linearization
from ._deterministic import simulate as simulate
from ._deterministic import static_equilibrium as static_equilibrium
from ._failure import ProcessFailedError as ProcessFailedError
from ._failure import SolverError as SolverError
from ._linearization import solve_moments as solve_moments
from ._modal import Modes as Modes
from ._modal import modal_analysis as modal_analysis
from ._modal import symmetric_eigen as symmetric_eigen
from ._montecarlo import monte_carlo as monte_carlo
from ._montecarlo import quantity_names as quantity_names
from ._netcdf import to_xarray as to_xarray
from ._newmark import (
    AbstractIntegrator as AbstractIntegrator,
)
from ._newmark import (
    Newmark as Newmark,
)
from ._newmark import (
    NewmarkBridge as NewmarkBridge,
)
from ._parallel import use_cpu_cores as use_cpu_cores
from ._results import (
    MomentResult as MomentResult,
)
from ._results import (
    MonteCarloResult as MonteCarloResult,
)
from ._results import (
    Trajectory as Trajectory,
)
from ._results import (
    load_results as load_results,
)
from ._results import (
    save_results as save_results,
)
from ._system import Contacts as Contacts
from ._system import FourierSeries as FourierSeries
from ._system import Observables as Observables
from ._system import System as System
from ._system import at_time as at_time

__version__ = "0.1.0"
