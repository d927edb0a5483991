"""Numerical failures are reported with when and where, by every solver, never returned silently."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _chains import backlash_oscillator

import pgtjax as pg


def _stiffness(t):
    """A stiffness that becomes NaN from t = 0.5 s on."""
    return jnp.where(t < 0.5, 1.0, jnp.nan) * jnp.array([[100.0]])


def _system():
    return pg.System(
        mass=[[1.0]],
        stiffness=_stiffness,
        damping=[[0.5]],
        load=[1.0],
        noise_input=[[1.0]],
        spectral_density=0.01,
        dof_names=["x"],
    )


KW = dict(dt=0.01, n_steps=100, save_every=10)


@pytest.mark.parametrize("solver", ["solve_moments", "monte_carlo", "simulate"])
def test_first_nonfinite_time_and_quantity_are_named(solver):
    run = {
        "solve_moments": lambda **kw: pg.solve_moments(_system(), **KW, **kw),
        "monte_carlo": lambda **kw: pg.monte_carlo(
            _system(), n_samples=20, key=jax.random.key(0), progress=False, **KW, **kw
        ),
        "simulate": lambda **kw: pg.simulate(_system(), **KW, **kw),
    }[solver]
    with pytest.raises(pg.SolverError, match=r"non-finite .*'(u:)?x'.* first at t = 0\.5 s") as info:
        run()
    assert isinstance(info.value, RuntimeError)
    assert "likely causes" in str(info.value)
    result = run(throw=False)  # returned as it is when asked
    values = np.asarray(result.mean_u if solver != "simulate" else result.u)
    assert np.all(np.isfinite(values[:5])) and not np.all(np.isfinite(values[5:]))


def test_nonfinite_moments_under_jit_raise_too():
    def std_at_end(scale):
        system = pg.System(
            mass=[[1.0]],
            stiffness=lambda t: scale * _stiffness(t),
            damping=[[0.5]],
            noise_input=[[1.0]],
            spectral_density=0.01,
        )
        return pg.solve_moments(system, **KW).std_u[-1, 0]

    with pytest.raises(RuntimeError, match="non-finite values"):
        jax.block_until_ready(jax.jit(std_at_end)(1.0))


def test_unconverged_fixed_point_names_the_time():
    system = backlash_oscillator()
    with pytest.raises(pg.SolverError, match=r"did not converge.* t = 0\.1 s.*max_iter"):
        pg.solve_moments(system, dt=0.01, n_steps=20, save_every=10, max_iter=1, rtol=1e-15)


def test_float32_is_refused_plainly():
    system = _system()
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(ValueError, match="jax_enable_x64"):
            pg.solve_moments(system, **KW)
    finally:
        jax.config.update("jax_enable_x64", True)
    assert pg.solve_moments(system, dt=0.01, n_steps=10).mean_u.dtype == jnp.float64
