"""Deterministic Newmark (average acceleration) against closed-form responses of a damped oscillator."""

import jax.numpy as jnp
import numpy as np
import pytest

import pgtjax as pg

M, C, K = 2.0, 1.2, 800.0  # kg, N s/m, N/m: omega_n = 20 rad/s, zeta = 0.015
OMEGA = np.sqrt(K / M)
ZETA = C / (2 * np.sqrt(K * M))
OMEGA_D = OMEGA * np.sqrt(1 - ZETA**2)


def oscillator(load):
    return pg.System(mass=[[M]], stiffness=[[K]], damping=[[C]], load=load, dof_names=["x"])


def step_response(t, force):
    """x(t) of m x'' + c x' + k x = F H(t) from rest."""
    decay = np.exp(-ZETA * OMEGA * t)
    return force / K * (1 - decay * (np.cos(OMEGA_D * t) + ZETA / np.sqrt(1 - ZETA**2) * np.sin(OMEGA_D * t)))


def harmonic_response(t, force, w):
    """x(t) of m x'' + c x' + k x = F sin(w t) from rest: particular + homogeneous solution."""
    denom = (K - M * w**2) ** 2 + (C * w) ** 2
    a = force * (K - M * w**2) / denom  # coefficient of sin
    b = -force * C * w / denom  # coefficient of cos
    # homogeneous e^{-zeta w_n t}(c1 cos w_d t + c2 sin w_d t) cancels x(0) = 0 and x'(0) = 0
    c1 = -b
    c2 = (-(a * w) + ZETA * OMEGA * c1) / OMEGA_D
    decay = np.exp(-ZETA * OMEGA * t)
    return (
        a * np.sin(w * t) + b * np.cos(w * t) + decay * (c1 * np.cos(OMEGA_D * t) + c2 * np.sin(OMEGA_D * t))
    )


def _order(errors, steps):
    return np.polyfit(np.log(steps), np.log(errors), 1)[0]


@pytest.mark.parametrize("kind", ["step", "harmonic"])
def test_second_order_convergence(kind):
    t_end, force, w = 1.0, 50.0, 13.0
    if kind == "step":
        system, exact = oscillator(jnp.array([force])), step_response(t_end, force)
    else:
        load = lambda t: jnp.array([force]) * jnp.sin(w * t)  # noqa: E731
        system, exact = oscillator(load), harmonic_response(t_end, force, w)
    steps = np.array([1 / 200, 1 / 400, 1 / 800, 1 / 1600])
    errors = []
    for dt in steps:
        n = int(round(t_end / dt))
        traj = pg.simulate(system, dt=dt, n_steps=n, save_every=n)
        assert traj.u.dtype == jnp.float64
        errors.append(abs(float(traj.u[-1, 0]) - exact))
    order = _order(np.array(errors), steps)
    assert 1.9 < order < 2.1, (order, errors)
    # leading error of the trapezoidal rule: a period error ~ omega^3 t dt^2 / 12 on an amplitude ~ F/K
    assert errors[-1] < 2.0 * abs(force / K) * OMEGA**3 * t_end * steps[-1] ** 2 / 12


def test_backlash_free_flight_and_contact():
    """A mass released inside the gap moves freely until it hits the flank: the contact time is exact for
    free flight, and afterwards the mass oscillates about the flank with the contact's frequency."""
    b, k, v0 = 1e-3, 1e4, 0.1
    system = pg.System(
        mass=[[1.0]], stiffness=[[0.0]], contacts=pg.Contacts(direction=[[1.0]], stiffness=[k], clearance=[b])
    )
    traj = pg.simulate(system, dt=1e-5, n_steps=2000, initial_velocity=[v0])
    t = np.asarray(traj.times)
    x = np.asarray(traj.u[:, 0])
    free = t < b / v0
    np.testing.assert_allclose(x[free], v0 * t[free], rtol=1e-12, atol=1e-15)
    # in contact: x = b + (v0 / w) sin(w (t - t_c)) until it leaves at half a period
    w = np.sqrt(k)
    inside = (t > b / v0) & (t < b / v0 + np.pi / w)
    expected = b + v0 / w * np.sin(w * (t[inside] - b / v0))
    np.testing.assert_allclose(x[inside], expected, atol=2e-3 * v0 / w)
    assert int(traj.unconverged) == 0
