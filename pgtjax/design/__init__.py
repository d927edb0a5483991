"""Differentiable design optimization: variables over any parameter leaf, objectives on SL results, costs
on the design, optax optimizers, Monte Carlo verification and batch evaluation (see docs/design.md).

    space = DesignSpace(params, [Variable("ring.k_support_radial", 1e9, 1e11, "log", size=6), ...])
    problem = DesignProblem(space, planetary_response(params), Std(["ring_mesh1"]), [SupportStiffness(weight=0.3)])
    result = optimize(problem, history="history.json")
    check = monte_carlo_check(problem, {"initial": result.initial_z, "optimum": result.z})
"""

from ._objectives import AbstractCost as AbstractCost
from ._objectives import AbstractObjective as AbstractObjective
from ._objectives import AbstractReduction as AbstractReduction
from ._objectives import ContactLoss as ContactLoss
from ._objectives import Custom as Custom
from ._objectives import DynamicFactor as DynamicFactor
from ._objectives import ParameterCost as ParameterCost
from ._objectives import RimMass as RimMass
from ._objectives import SmoothMax as SmoothMax
from ._objectives import Std as Std
from ._objectives import SupportStiffness as SupportStiffness
from ._objectives import TimeMean as TimeMean
from ._objectives import Variance as Variance
from ._optimize import OptimizeResult as OptimizeResult
from ._optimize import default_optimizer as default_optimizer
from ._optimize import optimize as optimize
from ._optimize import pareto_front as pareto_front
from ._planetary import bolt_variables as bolt_variables
from ._planetary import planetary_response as planetary_response
from ._planetary import ring_mesh_observables as ring_mesh_observables
from ._problem import DesignProblem as DesignProblem
from ._problem import Response as Response
from ._problem import Terms as Terms
from ._problem import evaluate as evaluate
from ._problem import monte_carlo_check as monte_carlo_check
from ._variables import AbstractTransform as AbstractTransform
from ._variables import Box as Box
from ._variables import DesignSpace as DesignSpace
from ._variables import Linear as Linear
from ._variables import Log as Log
from ._variables import Variable as Variable
