"""Modal analysis: natural frequencies and mode shapes of ``(M, K(t))``.

Symmetric K: generalized symmetric eigenproblem ``K phi = w^2 M phi`` through the Cholesky factor of M
(mass-normalised modes, ``phi^T M phi = I``). Non-symmetric K (e.g. the wind-filter coupling of thesis
Eqs. 3.30-3.31): general eigenproblem of ``M^-1 K``; frequencies are ``sqrt(Re(lambda))``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._config import require_x64
from ._numerics import safe_sqrt
from ._system import System, at_time, validate_system


class Modes(NamedTuple):
    frequencies_hz: jax.Array  # (n,), ascending
    angular_frequencies: jax.Array  # rad/s
    shapes: jax.Array  # (n, n), column j is mode j (mass-normalised when K is symmetric)
    dof_names: tuple[str, ...]


def modal_analysis(system: System, t: float = 0.0, *, include_contacts: bool = True) -> Modes:
    """Natural frequencies (Hz) and mode shapes at time ``t`` (s).

    With ``include_contacts`` the contacts are taken as closed linear springs of their current stiffness
    (``K + G diag(k) G^T``), the usual choice for gear meshes in contact.
    """
    validate_system(system, t, time_name="t")
    t = jnp.asarray(t, jnp.float64)
    k = at_time(system.stiffness, t)
    if include_contacts and system.n_contacts:
        g = system.contact_direction(t)
        k = k + (g * system.contact_stiffness(t)[None, :]) @ g.T
    modes = modes_of(system.mass, k, system.dof_names)
    concrete = not any(isinstance(x, jax.core.Tracer) for x in (k, system.mass))
    if concrete:  # the frequencies' safe_sqrt would show a negative omega^2 as 0 Hz
        values = _eigenvalues(np.asarray(system.mass), np.asarray(k))
        scale = float(np.max(np.abs(values))) if values.size else 0.0
        if values.size and values.min() < -1e-9 * scale:
            j = int(np.argmin(values))
            raise ValueError(
                f"modal_analysis: the stiffness{' with the contacts closed' if include_contacts and system.n_contacts else ''} "
                f"at t = {float(t):.6g} s has a negative eigenvalue omega^2 = {values[j]:.6g} rad^2/s^2 (mode {j + 1}): "
                "the system is statically unstable there and has no natural frequency; check `stiffness` "
                "(and the contacts' stiffness)"
            )
    return modes


def _eigenvalues(mass, stiffness):
    """Real parts of the eigenvalues of ``M^-1 K`` (omega^2, rad^2/s^2), ascending."""
    return np.sort(np.linalg.eigvals(np.linalg.solve(mass, stiffness)).real)


class SymmetricEigen(NamedTuple):
    """Solution of ``K phi = lam M phi`` (K, M symmetric, M positive definite)."""

    values: jax.Array  # (n,) eigenvalues lam = omega^2 (rad^2/s^2), ascending
    shapes: jax.Array  # (n, n) mass-normalised modes phi (columns): phi^T M phi = I
    factor: jax.Array  # (n, n) lower Cholesky factor L of M = L L^T
    rotated: jax.Array  # (n, n) orthonormal eigenvectors y of L^-1 K L^-T (phi = L^-T y, M phi = L y)


def symmetric_eigen(mass, stiffness) -> SymmetricEigen:
    """The one generalized symmetric eigen-solve of the package: through the Cholesky factor of M,
    ``L^-1 K L^-T y = lam y`` (symmetrized against rounding), ``phi = L^-T y``. Differentiable (``eigh``)."""
    require_x64("symmetric_eigen")
    mass, stiffness = jnp.asarray(mass, jnp.float64), jnp.asarray(stiffness, jnp.float64)
    n = mass.shape[0] if mass.ndim == 2 else -1
    if mass.shape != (n, n) or stiffness.shape != (n, n):
        raise ValueError(
            f"symmetric_eigen: `mass` and `stiffness` must be square matrices of one size, got {mass.shape} and "
            f"{stiffness.shape}"
        )
    if not isinstance(mass, jax.core.Tracer):
        m = np.asarray(mass)
        if not np.allclose(m, m.T, rtol=1e-10, atol=1e-12 * float(np.max(np.abs(m), initial=0.0))):
            raise ValueError("symmetric_eigen: `mass` must be symmetric")
        smallest = float(np.linalg.eigvalsh(0.5 * (m + m.T)).min())
        if not smallest > 0.0:
            raise ValueError(
                f"symmetric_eigen: `mass` must be positive definite, smallest eigenvalue {smallest!r}"
            )
    chol = jnp.linalg.cholesky(mass)
    a = jax.scipy.linalg.solve_triangular(chol, stiffness, lower=True)
    a = jax.scipy.linalg.solve_triangular(chol, a.T, lower=True).T
    lam, y = jnp.linalg.eigh(0.5 * (a + a.T))
    return SymmetricEigen(lam, jax.scipy.linalg.solve_triangular(chol.T, y, lower=False), chol, y)


def modes_of(mass, stiffness, dof_names=None) -> Modes:
    """Modes of a mass and a stiffness matrix (see :func:`modal_analysis`)."""
    n = mass.shape[0]
    names = tuple(dof_names) if dof_names is not None else tuple(f"q{i}" for i in range(n))
    symmetric = isinstance(stiffness, jax.core.Tracer) or np.allclose(
        np.asarray(stiffness),
        np.asarray(stiffness).T,
        rtol=1e-10,
        atol=1e-12 * float(jnp.max(jnp.abs(stiffness))),
    )
    if symmetric:
        lam, shapes, _, _ = symmetric_eigen(mass, stiffness)
    else:
        lam_c, v = np.linalg.eig(np.linalg.solve(np.asarray(mass), np.asarray(stiffness)))
        order = np.argsort(lam_c.real)
        lam, shapes = jnp.asarray(lam_c.real[order]), jnp.asarray(v[:, order].real)
    omega = safe_sqrt(lam)
    return Modes(omega / (2.0 * jnp.pi), omega, shapes, names)
