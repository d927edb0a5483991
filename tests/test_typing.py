"""The jaxtyping annotations are checked while the tests run (conftest sets PGTJAX_TYPECHECK=1)."""

import jax.numpy as jnp
import numpy as np
import pytest

import pgtjax as pg
from pgtjax import _typing


def fields(n_times=3, n_dof=2, nc=1, dtype=jnp.float64):
    z = lambda *shape: jnp.zeros(shape, dtype)  # noqa: E731
    return dict(
        times=z(n_times),
        dof_names=tuple(f"x{i}" for i in range(n_dof)),
        dof_units=("m",) * n_dof,
        contact_names=tuple(f"c{i}" for i in range(nc)),
        mean_u=z(n_times, n_dof),
        std_u=z(n_times, n_dof),
        mean_v=z(n_times, n_dof),
        std_v=z(n_times, n_dof),
        mean_delta=z(n_times, nc),
        std_delta=z(n_times, nc),
        force_mean=z(n_times, nc),
        force_std=z(n_times, nc),
        k_e=z(n_times, nc),
        f_0=z(n_times, nc),
        iterations=jnp.zeros(n_times, int),
        residual=z(n_times),
        converged=jnp.ones(n_times, bool),
        mean_obs=z(n_times, 0),
        std_obs=z(n_times, 0),
        criterion="force",
    )


def test_checking_is_on_and_accepts_a_consistent_result():
    assert _typing.TYPECHECK
    r = pg.MomentResult(**fields())
    assert r.mean_u.shape == (3, 2)


@pytest.mark.parametrize(
    "change",
    [
        dict(std_u=jnp.zeros((4, 2))),  # n_times inconsistent with `times`
        dict(mean_delta=jnp.zeros((3, 2))),  # n_contacts inconsistent across fields
        dict(residual=jnp.zeros(3, jnp.float32)),  # not float64
        dict(converged=jnp.ones(3)),  # not bool
    ],
)
def test_inconsistent_or_single_precision_fields_are_refused(change):
    from jaxtyping import TypeCheckError

    with pytest.raises(TypeCheckError):
        pg.MomentResult(**{**fields(), **change})


def test_every_array_field_of_the_results_carries_a_shape():
    for cls in (pg.MomentResult, pg.MonteCarloResult, pg.Trajectory):
        for name, field in cls.__dataclass_fields__.items():
            if field.metadata.get("static") or name in (
                "histogram_edges",
                "histograms",
                "peak_edges",
                "peak_histograms",
            ):
                continue
            annotation = str(field.type)
            assert "Float64[" in annotation or "Int[" in annotation or "Bool[" in annotation, (cls, name)


def test_solver_results_pass_the_checks():
    system = pg.System(
        mass=[[1.0]], stiffness=[[4.0]], damping=[[0.1]], noise_input=[[1.0]], spectral_density=1e-3
    )
    r = pg.solve_moments(system, dt=0.01, n_steps=10, save_every=5, covariance_dofs="all")
    assert r.std_u.dtype == np.float64 and r.covariance.shape == (3, 2, 2)
