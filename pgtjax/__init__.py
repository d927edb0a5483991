"""pgtjax: differentiable stochastic dynamics of planetary gear trains on JAX.

Layers: model builders (:mod:`pgtjax.models`) produce a :class:`System`; solvers consume it:
:func:`solve_moments` (statistical linearization + stochastic Newmark moments), :func:`monte_carlo`
(sampled nonlinear system), :func:`simulate` (deterministic Newmark-Newton), :func:`modal_analysis`.
Studies, plots and the CLI sit on top.
"""

from . import _config  # noqa: F401  (enables float64 before anything else)
from .contact import Backlash as Backlash, ContactLaw as ContactLaw, Linearization as Linearization
from .deterministic import simulate as simulate, static_equilibrium as static_equilibrium
from .linearization import solve_moments as solve_moments
from .modal import Modes as Modes, modal_analysis as modal_analysis
from .montecarlo import monte_carlo as monte_carlo, quantity_names as quantity_names
from .results import (
    MomentResult as MomentResult,
    MonteCarloResult as MonteCarloResult,
    Trajectory as Trajectory,
    load_results as load_results,
    save_results as save_results,
)
from .system import Contacts as Contacts, FourierSeries as FourierSeries, Observables as Observables, System as System

__version__ = "0.1.0"
