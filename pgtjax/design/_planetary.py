"""The planetary train's design set-up: its :class:`Response` (operating point re-solved per design) and
the ring's deformation along each ring-planet line of action at the moving mesh."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import Observables
from .._system import check_count
from ..models import planetary as pm
from ..models.ring import ring_nodal_inverse
from ._problem import Response
from ._variables import Variable


class _RingMeshMatrix(eqx.Module):
    """C(t) of :func:`ring_mesh_observables`, as a module: its arrays are pytree leaves, so that a solver
    compiled for one design is reused for the next (a closure would be a new static function each time)."""

    params: pm.PlanetaryParams  # resolved
    inverse: jax.Array
    angles: tuple[float, ...] = eqx.field(static=True)

    def __call__(self, t):
        lay = pm.layout(self.params)
        rows = jnp.stack(
            [
                pm.elastic_ring_part(self.params, self.params.mesh.carrier_speed * t + a, self.inverse)
                for a in self.angles
            ]
        )
        zeros = jnp.zeros((len(self.angles), lay.n_dof))
        return zeros.at[:, lay.ring_start : lay.ring_start + lay.n_ring].set(rows)


def ring_mesh_observables(p: pm.PlanetaryParams) -> Observables:
    """``ring_mesh{n}`` (m): the ring's displacement along planet n's ring-planet line of action at the
    moving contact point, ``sin a u_r + cos a (u_tau - e u_theta)`` (the ring's share of that mesh's
    deflection; thesis Eq. 3.16 as corrected, docs/corrections.md C4). Elastic ring only."""
    if p.ring_model != "elastic":
        raise ValueError(f"ring_mesh_observables needs ring_model = 'elastic', got {p.ring_model!r}")
    q = pm.resolved(p)
    angles = tuple(float(a) for a in p.planet_angles())
    # the nodal inverse is formed once per design, not at every step
    matrix = _RingMeshMatrix(q, ring_nodal_inverse(q.ring), angles)
    return Observables(matrix, names=[f"ring_mesh{n + 1}" for n in range(len(angles))])


def _wind_filter_covariance(params, system):
    # a module-level function (not a lambda): responses built separately compare equal, so compiled
    # solvers are reused between them (a resumed run, a second problem on the same model)
    return pm.wind_filter_stationary_covariance(params, pm.layout(params))


def planetary_response(
    p: pm.PlanetaryParams,
    *,
    periods: float = 1.0,
    dt: float = 0.0027,
    save_every: int = 1,
    ring_mesh: bool = True,
    rtol: float = 1e-10,
    step_multiple: int = 1,
) -> Response:
    """Response of the planetary train over ``periods`` carrier periods in steps of ``dt`` (s): each design
    starts at its own static equilibrium with the wind filter in its stationary distribution (thesis 3.7);
    ``ring_mesh`` adds :func:`ring_mesh_observables` (elastic ring); ``rtol``: SL's per-step tolerance.
    The number of steps is the nearest multiple of ``save_every`` and ``step_multiple`` (a Monte Carlo
    save interval, say)."""
    if isinstance(periods, bool) or not isinstance(periods, (int, float)) or not 0.0 < periods <= 100.0:
        raise ValueError(f"`periods` must be a number of carrier periods in (0, 100], got {periods!r}")
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not 0.0 < dt <= 0.1:
        raise ValueError(f"`dt` must be a time step in (0, 0.1] s, got {dt!r}")
    period = 2.0 * np.pi / float(p.mesh.carrier_speed)
    multiple = math.lcm(check_count("save_every", save_every), check_count("step_multiple", step_multiple))
    n_steps = max(int(round(periods * period / dt / multiple)), 1) * multiple
    observe = ring_mesh and p.ring_model == "elastic"
    return Response(
        build=pm.build,
        dt=float(dt),
        n_steps=n_steps,
        save_every=save_every,
        initial_covariance=_wind_filter_covariance,
        observables=ring_mesh_observables if observe else None,
        rtol=rtol,
    )


def bolt_variables(p: pm.PlanetaryParams, *, factor: float = 10.0) -> list[Variable]:
    """Radial and tangential stiffness of each bolt (2 x n_supports variables, log-mapped) within
    ``[k / factor, k * factor]`` of the parameters' values."""
    if not factor > 1.0:
        raise ValueError(f"`factor` must be > 1, got {factor!r}")
    n = len(p.ring.support_nodes)
    out = []
    for path, label in (("ring.k_support_radial", "k_radial"), ("ring.k_support_tangential", "k_tangential")):
        k = float(np.max(np.asarray(getattr(p.ring, path.split(".")[1]))))
        out.append(Variable(path, k / factor, k * factor, "log", size=n, name=label, unit="N/m"))
    return out
