"""Two-node thin curved-beam (circular arc) element for in-plane vibration of a ring.

Sign conventions (those implied by the thesis shape functions, Eqs. 6.1-6.3 / 3.17-3.19 with the
correction of Eq. 3.18, docs/corrections.md C5):

* the angle ``s`` runs counter-clockwise along the arc, measured from the element's first node;
* ``u_r`` [m] is the radial displacement, **positive towards the ring centre** (inward).  This is
  the only sign for which the two trigonometric modes of the shape functions, ``(u_r, u_tau) =
  (cos s, sin s)`` and ``(sin s, -cos s)``, are rigid translations of the arc;
* ``u_tau`` [m] is the tangential displacement, positive in the direction of increasing ``s``;
* ``u_theta`` [rad] is the rotation of the cross-section, positive counter-clockwise,
  ``u_theta = (u_tau + du_r/ds) / R`` (Eq. 3.19, C5).

Node DOF order (Eq. 3.44 / 6.10): ``(u_r, u_tau, u_theta)`` of node 1, then of node 2.

Displacement field (Eqs. 6.1-6.3, with ``J = 1 + I / (A R^2)``, Eq. 6.8)::

    u_r   = G1 + G2 cos s + G3 sin s + G4 s sin s + G6 s cos s
    u_tau = G1 J s + G2 sin s - G3 cos s + G4 (sin s - s cos s) + G5 + G6 (cos s + s sin s)
    u_th  = (u_tau + u_r') / R = (G1 J s + 2 G4 sin s + G5 + 2 G6 cos s) / R

Strain energy.  The six functions above are exactly the homogeneous static solutions of the
classical thin-ring theory with membrane strain and bending strain

    eps   = (du_tau/ds - u_r) / R              [-]      (extension of the centre line)
    chi   = (d^2u_r/ds^2 + u_r) / R^2          [1/m]    (change of curvature)
    U     = 1/2 int (E A eps^2 + E I chi^2) R ds

(equilibrium: ``N' = 0`` and ``M'' + M = R N``; the constant-``N`` solution is the ``G1`` mode, which
is where the factor ``J`` comes from; ``G4``, ``G6`` are inextensional; ``G2``, ``G3``, ``G5`` are the
rigid-body modes).  The element stiffness is therefore formed directly from ``U`` with the same
shape functions (``k = B^-T [int S^T diag(EA, EI) S R ds] B^-1``), which replaces the printed
matrix ``D`` of Eqs. 3.12/3.61, 5.1/5.3, 6.19/6.21 (correction C7: its 5th column loads a rigid rotation).
The strain integrand is a trigonometric polynomial of degree 2 in ``s``; Gauss-Legendre quadrature
with ``N_GAUSS`` points is exact to rounding for the arc angles used in practice.

Kinetic energy (Eq. 3.13 / 6.20 with ``Lambda = diag(A, A, I)``, Eq. 3.64): translational inertia of
both displacement components **and** the rotary inertia ``rho I u_theta_dot^2`` of the cross-section
(the thesis includes it; pass ``rotary_inertia=False`` to drop it)::

    T = 1/2 rho int (A u_r_dot^2 + A u_tau_dot^2 + I u_theta_dot^2) R ds

Shape-function matrix: ``u = H(s) G``, ``u_nodes = B G`` so ``u = H(s) B^-1 u_nodes`` (correction C6:
Eqs. 3.67 / 6.5 print ``H B^T``).  Internally the arc coordinate is centred on the element midpoint,
which leaves the function space unchanged (it is invariant under a shift of ``s``) and keeps ``B``
better conditioned.

All functions are pure ``jax.numpy`` and differentiable with respect to every float argument.
SI units throughout: m, kg, N, rad, Pa.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

#: Gauss-Legendre points per element (exact to rounding for the degree-2 trigonometric strain
#: integrand and converged to rounding for the mass integrand at arc angles up to ~pi/2).
N_GAUSS = 16

_GL_X, _GL_W = np.polynomial.legendre.leggauss(N_GAUSS)


def j_factor(radius, area, second_moment):
    """``J = 1 + I / (A R^2)`` (Eq. 6.8 / 3.63), dimensionless.  R [m], A [m^2], I [m^4]."""
    return 1.0 + second_moment / (area * radius**2)


def _basis(s, radius, jf):
    """Rows (u_r, u_tau, u_theta, du_r/ds, d2u_r/ds2, du_tau/ds) of the six modes at local angle s.

    Returns a (6, 6) array: row i is quantity i of modes G1..G6.  ``s`` is a scalar [rad].
    """
    c = jnp.cos(s)
    sn = jnp.sin(s)
    one = jnp.ones_like(s)
    zero = jnp.zeros_like(s)
    ur = jnp.stack([one, c, sn, s * sn, zero, s * c])
    ut = jnp.stack([jf * s, sn, -c, sn - s * c, one, c + s * sn])
    dur = jnp.stack([zero, -sn, c, sn + s * c, zero, c - s * sn])
    d2ur = jnp.stack([zero, -c, -sn, 2.0 * c - s * sn, zero, -2.0 * sn - s * c])
    dut = jnp.stack([jf * one, c, sn, s * sn, zero, s * c])
    uth = (ut + dur) / radius
    return jnp.stack([ur, ut, uth, dur, d2ur, dut])


def shape_basis(s, radius, jf):
    """Matrix ``H(s)`` (3 x 6) of Eqs. 3.62 / 6.7: (u_r, u_tau, u_theta) = H(s) G.

    ``s`` [rad] local angle, ``radius`` [m], ``jf`` = J (Eq. 6.8).  Row 2 follows correction C5 of Eq. 3.18
    (``-G3 cos s``) and row 3 is ``(u_tau + u_r') / R`` [rad/m per unit G].
    """
    return _basis(s, radius, jf)[:3]


def strain_basis(s, radius, jf):
    """Strains of the six modes (2 x 6): membrane ``eps = (u_tau' - u_r)/R`` [-] and bending
    ``chi = (u_r'' + u_r)/R^2`` [1/m] per unit ``G``."""
    b = _basis(s, radius, jf)
    eps = (b[5] - b[0]) / radius
    chi = (b[4] + b[0]) / radius**2
    return jnp.stack([eps, chi])


def nodal_basis_matrix(angle, radius, jf):
    """Matrix ``B`` (6 x 6) of Eq. 3.60 mapping G to the nodal DOFs, in element-centred coordinates.

    Node 1 sits at ``s_c = -angle/2`` and node 2 at ``s_c = +angle/2`` (``angle`` = arc angle [rad]).
    """
    h = 0.5 * angle
    return jnp.concatenate([shape_basis(-h, radius, jf), shape_basis(h, radius, jf)], axis=0)


def _series(s, coeffs, first_power):
    """sum_k coeffs[k] s^(first_power + 2k) (Horner in s^2)."""
    s2 = s * s
    acc = jnp.zeros_like(s)
    for ck in reversed(coeffs):
        acc = acc * s2 + ck
    return acc * s**first_power


_NT = 12  # series terms: |error| < 1e-17 for |s| <= 1.2
# S(s) = sin s - s cos s = sum_{k>=1} (-1)^(k+1) 2k s^(2k+1) / (2k+1)!
_S_C = [(-1) ** (k + 1) * 2 * k / math.factorial(2 * k + 1) for k in range(1, _NT + 1)]
# P(s) = 2 (1 - cos s) - s sin s = sum_{k>=2} (-1)^k (2k-2) s^(2k) / (2k)!
_P_C = [(-1) ** k * (2 * k - 2) / math.factorial(2 * k) for k in range(2, _NT + 2)]
# g(s) = 2 s - 3 sin s + s cos s = sum_{k>=2} (-1)^k (2k-2) s^(2k+1) / (2k+1)!
_G_C = [(-1) ** k * (2 * k - 2) / math.factorial(2 * k + 1) for k in range(2, _NT + 2)]
# Q(s) = s - sin s = sum_{k>=1} (-1)^(k+1) s^(2k+1) / (2k+1)!
_Q_C = [(-1) ** (k + 1) / math.factorial(2 * k + 1) for k in range(1, _NT + 1)]


def _stable(s, direct, coeffs, first_power):
    """Cancellation-free evaluation: Taylor series for |s| < 1.2, the closed form beyond."""
    small = jnp.abs(s) < 1.2
    s_small = jnp.where(small, s, 0.0)
    return jnp.where(small, _series(s_small, coeffs, first_power), direct(s))


def _fun_s(s):
    return _stable(s, lambda x: jnp.sin(x) - x * jnp.cos(x), _S_C, 3)


def _fun_p(s):
    return _stable(s, lambda x: 2.0 * (1.0 - jnp.cos(x)) - x * jnp.sin(x), _P_C, 4)


def _fun_g(s):
    return _stable(s, lambda x: 2.0 * x - 3.0 * jnp.sin(x) + x * jnp.cos(x), _G_C, 5)


def _fun_q(s):
    return _stable(s, lambda x: x - jnp.sin(x), _Q_C, 3)


def _recombined(s, h, radius, delta):
    """Displacements (3 x 6) and strains (2 x 6) of a well-conditioned basis of the same six modes.

    For a short arc the thesis modes G1..G6 are nearly linearly dependent (``cos s ~ 1``, ``G1 ~ G2``
    ...): ``B`` of Eq. 3.60 reaches a condition number ~1e7 at 256 elements and forming ``B^-1``
    loses digits.  The element is therefore built on the recombination (``s`` = angle from the
    element midpoint, ``h`` = half arc angle, ``delta = I / (A R^2) = J - 1``)::

        c0 = G5                         (0, 1)                    rigid rotation
        c1 = G2                         (cos s, sin s)            rigid translation
        c2 = (G3 + G5) / h              (sin s, 1 - cos s) / h    rigid translation
        c3 = G4 / h^2                   inextensional, chi ~ cos s
        c4 = 3 (G6 - G3 - 2 G5) / h^3   inextensional, chi ~ sin s
        c5 = (2 (G1 - G2) - G4) / nu    constant extension, nu = 2 delta h + g(h)

    whose entries are O(1) on the element, and every difference that would cancel (``1 - cos s``,
    ``sin s - s cos s`` ...) is evaluated by its Taylor series (:func:`_stable`).  The spanned space,
    hence every element matrix, is the thesis's; only round-off differs.  Strains are the analytic
    ``eps = (u_tau' - u_r) / R`` and ``chi = (u_r'' + u_r) / R^2`` of each combination.
    """
    c, sn = jnp.cos(s), jnp.sin(s)
    one, zero = jnp.ones_like(s), jnp.zeros_like(s)
    omc = 2.0 * jnp.sin(0.5 * s) ** 2  # 1 - cos s
    fs, fp, fg, fq = _fun_s(s), _fun_p(s), _fun_g(s), _fun_q(s)
    nu = 2.0 * delta * h + _fun_g(h)
    h2, h3 = h * h, h * h * h
    ur = jnp.stack([zero, c, sn / h, s * sn / h2, -3.0 * fs / h3, fp / nu])
    ut = jnp.stack([one, sn, omc / h, fs / h2, -3.0 * fp / h3, (2.0 * delta * s + fg) / nu])
    # u_theta = (u_tau + u_r') / R, combined analytically
    uth = jnp.stack([one, zero, one / h, 2.0 * sn / h2, -6.0 * omc / h3, 2.0 * (delta * s + fq) / nu])
    uth = uth / radius
    eps = jnp.stack([zero, zero, zero, zero, zero, 2.0 * delta / nu * one]) / radius
    chi = jnp.stack([zero, zero, zero, 2.0 * c / h2, -6.0 * sn / h3, 2.0 * omc / nu]) / radius**2
    return jnp.stack([ur, ut, uth]), jnp.stack([eps, chi])


def _nodal_inverse(angle, radius, delta):
    """``C`` (6 x 6) mapping nodal DOFs to the coefficients of the recombined basis (``(B T)^-1``)."""
    h = 0.5 * angle
    scale = jnp.stack([1.0, 1.0, radius, 1.0, 1.0, radius])  # make the rotation rows dimensionless
    bt = jnp.concatenate([_recombined(-h, h, radius, delta)[0], _recombined(h, h, radius, delta)[0]], axis=0)
    return jnp.linalg.solve(scale[:, None] * bt, jnp.diag(scale))


def nodal_inverse(angle, radius, area, second_moment):
    """``C`` (6 x 6) of an element: nodal DOFs to the coefficients of the shape functions' basis
    (``B^-1`` of Eq. 3.20 in the recombined basis of :func:`_recombined`). It depends on the element
    only, so a caller evaluating shape functions at many points (a moving mesh, every time step) forms
    it once and passes it to :func:`element_shape_matrix`. Arguments as :func:`element_shape_matrix`."""
    return _nodal_inverse(angle, radius, second_moment / (area * radius**2))


@jax.jit
def element_shape_matrix(s, angle, radius, area, second_moment, inverse=None):
    """Shape-function matrix ``N(s) = H(s) B^-1`` (3 x 6) (Eqs. 3.20, 6.4-6.5 with corrections C5-C6).

    Args:
        s: local angle [rad] measured from node 1 of the element (0 <= s <= angle; values outside
            extrapolate the same functions).
        angle: element arc angle [rad]; radius [m]; area [m^2]; second_moment [m^4].
        inverse: the element's :func:`nodal_inverse` if already formed (else formed here).

    Returns:
        (3, 6) array; rows give (u_r [m], u_tau [m], u_theta [rad]) at ``s`` per unit nodal DOF, columns
        are ``(u_r1, u_tau1, u_theta1, u_r2, u_tau2, u_theta2)``.
    """
    delta = second_moment / (area * radius**2)
    c = _nodal_inverse(angle, radius, delta) if inverse is None else inverse
    return _recombined(s - 0.5 * angle, 0.5 * angle, radius, delta)[0] @ c


def _gauss(angle):
    """Gauss-Legendre points (centred coordinates) and weights for an arc of ``angle`` rad."""
    h = 0.5 * angle
    return jnp.asarray(_GL_X) * h, jnp.asarray(_GL_W) * h


@jax.jit
def element_stiffness(angle, radius, area, second_moment, youngs_modulus):
    """Element stiffness matrix (6 x 6) [N/m, N/rad, N m/rad] from the strain energy.

    ``k = B^-T [ int_{-a/2}^{a/2} S(s)^T diag(E A, E I) S(s) R ds ] B^-1`` with ``S`` the strains
    (eps, chi) of the modes (:func:`strain_basis`; membrane + bending of a thin ring; replaces
    Eq. 3.12 / 6.19), evaluated in the recombined basis of :func:`_recombined`.

    Args:
        angle: element arc angle [rad]; radius: centre-line radius R [m]; area: A [m^2];
        second_moment: I [m^4] (in-plane bending); youngs_modulus: E [Pa].
    """
    delta = second_moment / (area * radius**2)
    xs, ws = _gauss(angle)
    c = _nodal_inverse(angle, radius, delta)

    def integrand(s):
        st = _recombined(s, 0.5 * angle, radius, delta)[1]
        return youngs_modulus * (area * jnp.outer(st[0], st[0]) + second_moment * jnp.outer(st[1], st[1]))

    kg = jnp.einsum("q,qij->ij", ws, jax.vmap(integrand)(xs)) * radius
    k = c.T @ kg @ c
    return 0.5 * (k + k.T)


@partial(jax.jit, static_argnames="rotary_inertia")
def element_mass(angle, radius, area, second_moment, density, rotary_inertia=True):
    """Consistent element mass matrix (6 x 6) [kg, kg m, kg m^2] from the kinetic energy.

    ``m = rho R B^-T [ int H^T diag(A, A, I) H ds ] B^-1`` (Eq. 3.13 / 6.20 with Eq. 3.64).  The
    ``I`` term is the rotary inertia of the cross-section; it is dropped if ``rotary_inertia`` is
    False (a Python bool).  Arguments as :func:`element_stiffness`; density rho [kg/m^3].
    """
    delta = second_moment / (area * radius**2)
    xs, ws = _gauss(angle)
    rot = second_moment if rotary_inertia else 0.0 * second_moment
    lam = jnp.stack([area, area, rot])
    c = _nodal_inverse(angle, radius, delta)

    def integrand(s):
        h = _recombined(s, 0.5 * angle, radius, delta)[0]
        return jnp.einsum("k,ki,kj->ij", lam, h, h)

    mg = jnp.einsum("q,qij->ij", ws, jax.vmap(integrand)(xs)) * (density * radius)
    m = c.T @ mg @ c
    return 0.5 * (m + m.T)


def rigid_body_modes(angle, radius):
    """Analytic rigid-body nodal vectors (6 x 3) of an element spanning local angles [0, angle].

    Columns: translation along the chord-normal x axis (the axis through the element start,
    ``s = 0``), translation along y, and rotation about the ring centre, for unit amplitude
    (1 m, 1 m, 1 rad).  With ``u_r`` positive inward a translation ``d`` gives
    ``u_r = -d . e_r(s)``, ``u_tau = d . e_s(s)`` and no cross-section rotation; a rotation ``phi``
    gives ``u_tau = R phi``, ``u_theta = phi``.
    """
    cols = []
    for s in (0.0, angle):
        c, sn = jnp.cos(s), jnp.sin(s)
        cols.append(
            jnp.stack(
                [
                    jnp.stack([-c, -sn, 0.0 * c]),  # translation x: u_r = -cos, u_tau = -sin
                    jnp.stack([-sn, c, 0.0 * c]),  # translation y: u_r = -sin, u_tau = cos
                    jnp.stack([0.0 * c, radius + 0.0 * c, 1.0 + 0.0 * c]),  # rotation
                ],
                axis=1,
            )
        )
    return jnp.concatenate(cols, axis=0)
