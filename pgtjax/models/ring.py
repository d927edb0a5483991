"""Elastic ring gear as a closed ring of curved-beam finite elements (thesis Sec. 3.2.3, Ch. 5, Sec. 6.2).

The ring (centre-line radius ``R``, rectangular rim section ``A = b h``, ``I = b h^3 / 12``) is cut
into ``L`` identical two-node arc elements (:mod:`pgtjax.models.curved_beam`); node ``k``
(0-based, ``k = 0..L-1``) sits at angle ``theta_k = 2 pi k / L`` counter-clockwise from the global x
axis and the last element closes the ring onto node 0 (thesis: node ``L+1`` == node 1).

Global DOF vector (Eqs. 5.9 / 6.26 without the duplicated closing node)::

    U = (u_r0, u_tau0, u_theta0, u_r1, u_tau1, u_theta1, ..., u_theta_{L-1})

in each node's own polar frame, with the element's conventions: ``u_r`` [m] positive **inward**
(towards the ring centre), ``u_tau`` [m] positive counter-clockwise, ``u_theta`` [rad] positive
counter-clockwise (see :mod:`pgtjax.models.curved_beam`).  DOF names: ``"ring_node{k}_radial"``,
``"ring_node{k}_tangential"``, ``"ring_node{k}_rotation"``.

Supports (bolts, Eq. 6.24): at each node of ``support_nodes`` three grounded springs
``k_r`` [N/m], ``k_tau`` [N/m], ``k_theta`` [N m/rad] on that node's three DOFs (``k_theta = 0`` is a
pin).

Model II tooth masses (Ch. 5, Eqs. 5.10-5.12, 5.16-5.18; docs/corrections.md C8: Eq. 5.14 is garbled): tooth ``j``
(``j = 0..Z-1``) is a point mass ``m_T`` [kg] with rotary inertia ``J_T`` [kg m^2] attached to the rim
centre line at ``theta_j = 2 pi j / Z``.  It is added *consistently* through the shape functions,
``M_T += m_T (a_r^T a_r + a_tau^T a_tau) + J_T a_theta^T a_theta`` with ``a = N(theta_j)`` the
interpolation rows; when ``L == Z`` every tooth sits on a node and this is exactly the thesis's nodal
lumped ``diag(m_T, m_T, J_T)`` at every node.  The offset of the tooth centroid from the rim centre
line is neglected (as in the thesis).

Moving loads (Eqs. 3.20-3.23, 6.11-6.15): :func:`ring_interpolation` returns the rows ``a(theta)``
(3 x n_dof) of the global shape-function matrix at any angle, so that the ring displacement at the
contact point is ``a @ U`` and the work-equivalent nodal force of a point load is ``a[:2].T @ (F_r,
F_tau)``.  Everything is branch-free in ``theta`` (jit / vmap / grad safe).

Compilation: the element kernels (:mod:`~pgtjax.models.curved_beam`) are jitted with the arc angle
as a traced argument, so they compile once for every mesh; the public functions here are plain
Python compositions (wrap your own time loop in ``jax.jit``; they trace inside it).

SI units: m, kg, N, rad, Pa, Hz.
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pgtjax._modal import symmetric_eigen
from pgtjax._validate import check_range
from pgtjax.models import curved_beam as cb

__all__ = [
    "RingParams",
    "validate",
    "ring_element_matrices",
    "ring_matrices",
    "ring_dof_names",
    "assemble_ring",
    "support_stiffness_matrix",
    "tooth_mass_matrix",
    "ring_nodal_inverse",
    "without_supports",
    "ring_shape_at",
    "ring_interpolation",
    "ring_load_vector",
    "ring_displacement_at",
    "natural_frequencies",
    "ring_natural_frequencies",
    "nodal_diameter",
    "thin_ring_inextensional_frequency",
    "thin_ring_fourier_frequencies",
]


class RingParams(eqx.Module):
    """Parameters of the elastic ring (Table 5.1, Sec. 6.4, Sec. 3.2.3).

    Array leaves (float64 scalars; the support stiffnesses may also be one value per support) are
    differentiable; ``n_elements``, ``n_teeth``, ``support_nodes`` and ``rotary_inertia`` are static.
    Values are checked in ``__check_init__`` (``ValueError`` naming the parameter and its range); traced
    values (a RingParams built inside ``jit``/``grad``) cannot be checked and are passed through.

    Attributes:
        radius: centre-line (mean) radius of the rim R [m], > 0.
        thickness: radial rim thickness h [m], 0 < h < 2 R.
        face_width: axial face width b [m], > 0.
        youngs_modulus: E [Pa], > 0.
        density: rho [kg/m^3], > 0.
        tooth_mass: m_T [kg] per tooth, >= 0 (0 = Model I smooth ring).
        tooth_inertia: J_T [kg m^2] per tooth about the axial axis, >= 0.
        k_support_radial, k_support_tangential: bolt spring stiffnesses [N/m], >= 0.
        k_support_torsional: bolt rotational stiffness [N m/rad], >= 0 (0 = pin).
        n_elements: L, number of curved-beam elements (= number of nodes), >= 3.
        n_teeth: Z, number of teeth (positions of the Model II tooth masses), >= 0.
        support_nodes: 0-based node indices of the bolts (distinct, in [0, L)).
        rotary_inertia: include the cross-section rotary inertia rho I in the consistent mass
            (thesis Lambda = diag(A, A, I), Eq. 3.64).  Default True.
    """

    radius: jax.Array
    thickness: jax.Array
    face_width: jax.Array
    youngs_modulus: jax.Array
    density: jax.Array
    tooth_mass: jax.Array
    tooth_inertia: jax.Array
    k_support_radial: jax.Array
    k_support_tangential: jax.Array
    k_support_torsional: jax.Array
    n_elements: int = eqx.field(static=True)
    n_teeth: int = eqx.field(static=True)
    support_nodes: tuple = eqx.field(static=True)
    rotary_inertia: bool = eqx.field(static=True)

    def __init__(
        self,
        radius,
        thickness,
        face_width,
        youngs_modulus=205e9,
        density=7858.0,
        *,
        n_elements: int,
        n_teeth: int = 0,
        tooth_mass=0.0,
        tooth_inertia=0.0,
        support_nodes=(),
        k_support_radial=0.0,
        k_support_tangential=0.0,
        k_support_torsional=0.0,
        rotary_inertia: bool = True,
    ):
        if isinstance(n_elements, bool) or not isinstance(n_elements, (int, np.integer)) or n_elements < 3:
            raise ValueError(f"`n_elements` must be an integer >= 3, got {n_elements!r}")
        if isinstance(n_teeth, bool) or not isinstance(n_teeth, (int, np.integer)) or n_teeth < 0:
            raise ValueError(f"`n_teeth` must be an integer >= 0, got {n_teeth!r}")
        try:
            nodes = tuple(int(k) for k in support_nodes)
        except (TypeError, ValueError):
            raise ValueError(f"`support_nodes` must be a tuple of integers, got {support_nodes!r}") from None
        if any(k < 0 or k >= n_elements for k in nodes) or len(set(nodes)) != len(nodes):
            raise ValueError(
                f"`support_nodes` must be distinct node indices in [0, {n_elements - 1}], "
                f"got {support_nodes!r}"
            )

        def f(name, x):
            try:
                return jnp.asarray(x, dtype=jnp.float64)
            except (TypeError, ValueError):
                raise ValueError(f"`{name}` must be a number or an array of numbers, got {x!r}") from None

        self.radius = f("radius", radius)
        self.thickness = f("thickness", thickness)
        self.face_width = f("face_width", face_width)
        self.youngs_modulus = f("youngs_modulus", youngs_modulus)
        self.density = f("density", density)
        self.tooth_mass = f("tooth_mass", tooth_mass)
        self.tooth_inertia = f("tooth_inertia", tooth_inertia)
        self.k_support_radial = f("k_support_radial", k_support_radial)
        self.k_support_tangential = f("k_support_tangential", k_support_tangential)
        self.k_support_torsional = f("k_support_torsional", k_support_torsional)
        self.n_elements = int(n_elements)
        self.n_teeth = int(n_teeth)
        self.support_nodes = nodes
        self.rotary_inertia = bool(rotary_inertia)

    def __check_init__(self):
        validate(self)

    # -- derived quantities -------------------------------------------------------------------------
    @property
    def area(self):
        """Rim cross-section area A = b h [m^2]."""
        return self.face_width * self.thickness

    @property
    def second_moment(self):
        """In-plane second moment of area I = b h^3 / 12 [m^4]."""
        return self.face_width * self.thickness**3 / 12.0

    @property
    def element_angle(self):
        """Arc angle of one element 2 pi / L [rad] (Python float)."""
        return 2.0 * math.pi / self.n_elements

    @property
    def n_dof(self) -> int:
        """Number of ring DOFs, 3 L."""
        return 3 * self.n_elements


def without_supports(p: RingParams) -> RingParams:
    """``p`` without its bolts (no support nodes, zero support stiffnesses): all that the rim's shape functions
    (:func:`ring_shape_at`, :func:`ring_interpolation`) read. Objects that interpolate the rim at every time step
    hold this copy: the support nodes are static, so a copy with them would make models that differ only in
    their bolts (a support-count sweep) compile a solver each."""
    return dataclasses.replace(
        p, support_nodes=(), k_support_radial=0.0, k_support_tangential=0.0, k_support_torsional=0.0
    )


def validate(r: RingParams, prefix: str = "") -> None:
    """``ValueError`` naming the parameter (``prefix`` + attribute name, e.g. ``ring.thickness``) and its
    range; counts and node indices are converted and checked in ``RingParams.__init__``, traced values pass.
    Also called by the models that hold a ring, since ``eqx.tree_at`` bypasses ``__check_init__``."""
    check_range(f"{prefix}thickness", r.thickness, lo=0.0, lo_closed=False, unit="m")
    check_range(f"{prefix}radius", r.radius, lo=0.0, lo_closed=False, unit="m")
    check_range(f"{prefix}face_width", r.face_width, lo=0.0, lo_closed=False, unit="m")
    check_range(f"{prefix}youngs_modulus", r.youngs_modulus, lo=0.0, lo_closed=False, unit="Pa")
    check_range(f"{prefix}density", r.density, lo=0.0, lo_closed=False, unit="kg/m^3")
    check_range(f"{prefix}tooth_mass", r.tooth_mass, lo=0.0, lo_closed=True, unit="kg")
    check_range(f"{prefix}tooth_inertia", r.tooth_inertia, lo=0.0, lo_closed=True, unit="kg m^2")
    check_range(f"{prefix}k_support_radial", r.k_support_radial, lo=0.0, lo_closed=True, unit="N/m")
    check_range(f"{prefix}k_support_tangential", r.k_support_tangential, lo=0.0, lo_closed=True, unit="N/m")
    check_range(f"{prefix}k_support_torsional", r.k_support_torsional, lo=0.0, lo_closed=True, unit="N m/rad")
    # (a model built by the planetary train derives the radius from the thickness, which makes this hold)
    if not any(isinstance(x, jax.core.Tracer) or np.ndim(x) for x in (r.thickness, r.radius)):
        h, radius = float(r.thickness), float(r.radius)
        if h >= 2.0 * radius:
            raise ValueError(
                f"`{prefix}thickness` must be < 2 * {prefix}radius = {2.0 * radius:g} m, got {h}"
            )
    for name, val in (
        ("k_support_radial", r.k_support_radial),
        ("k_support_tangential", r.k_support_tangential),
        ("k_support_torsional", r.k_support_torsional),
    ):
        shape = np.shape(val)
        if shape not in ((), (len(r.support_nodes),)):
            raise ValueError(
                f"`{prefix}{name}` must be a scalar or have shape ({len(r.support_nodes)},) (one per support), got {shape}"
            )


def ring_element_matrices(p: RingParams):
    """Element stiffness and consistent mass (6 x 6 each) shared by all elements of the ring.

    Returns ``(k_e, m_e)`` from :func:`pgtjax.models.curved_beam.element_stiffness` /
    :func:`~pgtjax.models.curved_beam.element_mass` (energy-based replacements of Eqs. 3.12-3.13).
    """
    a = p.element_angle
    k = cb.element_stiffness(a, p.radius, p.area, p.second_moment, p.youngs_modulus)
    m = cb.element_mass(a, p.radius, p.area, p.second_moment, p.density, p.rotary_inertia)
    return k, m


def _element_dofs(n_elements: int) -> np.ndarray:
    """(L, 6) global DOF indices of every element (closing element wraps onto node 0)."""
    e = np.arange(n_elements)
    n1 = 3 * e[:, None] + np.arange(3)[None, :]
    n2 = 3 * ((e + 1) % n_elements)[:, None] + np.arange(3)[None, :]
    return np.concatenate([n1, n2], axis=1)


@partial(jax.jit, static_argnums=1)
def _assemble(block, n_elements: int):
    idx = _element_dofs(n_elements)
    n = 3 * n_elements
    rows = np.broadcast_to(idx[:, :, None], (n_elements, 6, 6))
    cols = np.broadcast_to(idx[:, None, :], (n_elements, 6, 6))
    blocks = jnp.broadcast_to(block, (n_elements, 6, 6))
    return jnp.zeros((n, n), dtype=block.dtype).at[rows, cols].add(blocks)


def support_stiffness_matrix(p: RingParams):
    """Grounded bolt springs ``K_S`` (3L x 3L) of Eq. 6.24: diag(k_r, k_tau, k_theta) at each support node."""
    n = p.n_dof
    ks = jnp.zeros((n,), dtype=jnp.float64)
    if p.support_nodes:
        ns = len(p.support_nodes)
        nodes = np.asarray(p.support_nodes)
        vals = jnp.stack(
            [
                jnp.broadcast_to(p.k_support_radial, (ns,)),
                jnp.broadcast_to(p.k_support_tangential, (ns,)),
                jnp.broadcast_to(p.k_support_torsional, (ns,)),
            ],
            axis=1,
        )
        idx = 3 * nodes[:, None] + np.arange(3)[None, :]
        ks = ks.at[idx].add(vals)
    return jnp.diag(ks)


def ring_nodal_inverse(p: RingParams):
    """The elements' (identical) :func:`~pgtjax.models.curved_beam.nodal_inverse`, (6, 6): form it once
    and pass it to :func:`ring_shape_at` / :func:`ring_interpolation` when evaluating at many angles."""
    return cb.nodal_inverse(p.element_angle, p.radius, p.area, p.second_moment)


def ring_shape_at(p: RingParams, theta, nodal_inverse=None):
    """Element DOFs and shape-function matrix at global angle ``theta`` [rad] (any real, wraps 2 pi).

    Returns ``(dofs, n)``: ``dofs`` (6,) int global DOF indices of the element containing ``theta``
    and ``n`` (3, 6) the rows (u_r, u_tau, u_theta) of ``N = H B^-1`` (Eq. 3.20) at that point.  A
    point exactly on a node gives the unit rows of that node.  Branch-free (``floor``/``mod``).
    ``nodal_inverse``: :func:`ring_nodal_inverse` of ``p`` if already formed (else formed here).
    """
    L = p.n_elements
    a = p.element_angle
    th = jnp.mod(jnp.asarray(theta, dtype=jnp.float64), 2.0 * math.pi)
    e = jnp.clip(jnp.floor(th / a), 0, L - 1)
    s = th - e * a
    e = e.astype(jnp.int32)
    dofs = jnp.concatenate([3 * e + jnp.arange(3), 3 * jnp.mod(e + 1, L) + jnp.arange(3)])
    n = cb.element_shape_matrix(s, a, p.radius, p.area, p.second_moment, nodal_inverse)
    return dofs, n


def ring_interpolation(p: RingParams, theta, nodal_inverse=None):
    """Dense rows ``a(theta)`` (3 x 3L) of the global shape-function matrix (Eqs. 6.4, 6.15).

    ``a @ U`` = (u_r [m], u_tau [m], u_theta [rad]) of the rim at ``theta``; ``a[:2].T @ (F_r, F_tau)``
    = work-equivalent nodal forces of a point load (Eq. 6.11). ``nodal_inverse`` as :func:`ring_shape_at`.
    """
    dofs, n = ring_shape_at(p, theta, nodal_inverse)
    return jnp.zeros((3, p.n_dof), dtype=n.dtype).at[:, dofs].add(n)


def ring_load_vector(p: RingParams, theta, f_radial, f_tangential, nodal_inverse=None):
    """Global nodal force vector (3L,) [N, N, N m] of a point load at angle ``theta`` [rad].

    ``f_radial`` [N] acts along the element's ``u_r`` direction (positive **inward**, towards the
    centre) and ``f_tangential`` [N] counter-clockwise; the result is ``a_r^T f_r + a_tau^T f_tau``
    (Eq. 6.11 / 3.21: work-equivalent, ``F . U = f_r u_r(theta) + f_tau u_tau(theta)`` for every ``U``).
    Note Eqs. 6.13-6.14 and 3.21 use different sign conventions for the mesh-force components
    (docs/corrections.md C9); the caller projects the mesh force onto (radial-inward, tangential-ccw) itself.
    ``nodal_inverse`` as :func:`ring_shape_at`.
    """
    dofs, n = ring_shape_at(p, theta, nodal_inverse)
    loc = n[0] * f_radial + n[1] * f_tangential
    return jnp.zeros((p.n_dof,), dtype=loc.dtype).at[dofs].add(loc)


def ring_displacement_at(p: RingParams, theta, u):
    """(u_r, u_tau, u_theta) [m, m, rad] of the rim at angle ``theta`` from nodal DOFs ``u`` (3L,)."""
    dofs, n = ring_shape_at(p, theta)
    return n @ u[dofs]


@jax.jit
def tooth_mass_matrix(p: RingParams):
    """Model II tooth mass matrix ``M_T`` (3L x 3L) (Eqs. 5.16-5.18), consistent point masses.

    Tooth ``j`` at ``theta_j = 2 pi j / Z`` contributes ``m_T (a_r^T a_r + a_tau^T a_tau) + J_T
    a_theta^T a_theta``; with ``L == Z`` this is ``diag(m_T, m_T, J_T)`` at every node.
    """
    n = p.n_dof
    if p.n_teeth == 0:
        return jnp.zeros((n, n), dtype=jnp.float64)
    thetas = 2.0 * math.pi * jnp.arange(p.n_teeth, dtype=jnp.float64) / p.n_teeth
    dofs, nn = jax.vmap(lambda t: ring_shape_at(p, t))(thetas)  # (Z,6), (Z,3,6)
    w = jnp.stack([p.tooth_mass, p.tooth_mass, p.tooth_inertia])
    blocks = jnp.einsum("k,zki,zkj->zij", w, nn, nn)
    rows = jnp.broadcast_to(dofs[:, :, None], blocks.shape)
    cols = jnp.broadcast_to(dofs[:, None, :], blocks.shape)
    return jnp.zeros((n, n), dtype=blocks.dtype).at[rows, cols].add(blocks)


def ring_matrices(p: RingParams):
    """Global mass and stiffness ``(M, K)`` (3L x 3L, float64) of the supported ring (Eqs. 3.24, 5.16, 6.23).

    ``M`` = assembled consistent rim mass + tooth masses (Model II); ``K`` = assembled rim stiffness
    + bolt springs (Eq. 6.24).  Pure and differentiable in every array leaf of ``p``; jit-compatible
    (its pieces are jitted separately so that the element matrices compile once for every ``L``).
    """
    k_e, m_e = ring_element_matrices(p)
    K = _assemble(k_e, p.n_elements) + support_stiffness_matrix(p)
    M = _assemble(m_e, p.n_elements) + tooth_mass_matrix(p)
    return 0.5 * (M + M.T), 0.5 * (K + K.T)


def ring_dof_names(p: RingParams) -> list[str]:
    """DOF names in global order: ``ring_node{k}_radial``, ``..._tangential``, ``..._rotation``."""
    return [f"ring_node{k}_{d}" for k in range(p.n_elements) for d in ("radial", "tangential", "rotation")]


def assemble_ring(p: RingParams):
    """``(M, K, dof_names)``: :func:`ring_matrices` plus :func:`ring_dof_names` (not jittable as a whole)."""
    M, K = ring_matrices(p)
    return M, K, ring_dof_names(p)


@jax.jit
def natural_frequencies(M, K):
    """Undamped natural frequencies [Hz] and M-orthonormal mode shapes of ``K x = w^2 M x``.

    Solved as a standard symmetric problem after the Cholesky transform ``M = C C^T``:
    ``C^-1 K C^-T y = w^2 y``, ``x = C^-T y``.  Returns ``(f, X)`` with ``f`` ascending (n,) (negative
    round-off eigenvalues of rigid-body modes are clipped to 0) and ``X`` (n, n) columns normalised
    to ``X^T M X = I``.
    """
    lam, x, _, _ = symmetric_eigen(M, K)
    pos = lam > 0.0
    w = jnp.where(pos, jnp.sqrt(jnp.where(pos, lam, 1.0)), 0.0)  # NaN-free gradient at lam <= 0
    return w / (2.0 * math.pi), x


def ring_natural_frequencies(p: RingParams):
    """:func:`natural_frequencies` of :func:`ring_matrices` ``(p)``: ``(f [Hz], modes)``."""
    M, K = ring_matrices(p)
    return natural_frequencies(M, K)


def nodal_diameter(mode, n_elements: int | None = None) -> int:
    """Circumferential wave number n of a ring mode shape (number of nodal diameters).

    The radial and tangential nodal components are Fourier analysed around the ring and the harmonic
    with the largest energy ``|U_r(n)|^2 + |U_tau(n)|^2`` is returned (0: rotation / breathing,
    1: rigid translation, n >= 2: flexural or extensional n-lobed mode).  Host-side (numpy) helper.
    """
    v = np.asarray(mode, dtype=float).reshape(-1, 3)
    if n_elements is not None and v.shape[0] != n_elements:
        raise ValueError(f"`mode` must have 3 * n_elements = {3 * n_elements} entries, got {v.size}")
    spec = np.abs(np.fft.rfft(v[:, 0])) ** 2 + np.abs(np.fft.rfft(v[:, 1])) ** 2
    return int(np.argmax(spec))


def thin_ring_inextensional_frequency(p: RingParams, n):
    """Classical inextensional in-plane flexural frequency [Hz] of a free thin ring, n >= 2.

    ``w_n^2 = E I n^2 (n^2 - 1)^2 / (rho A R^4 (n^2 + 1))`` (Hoppe 1871; the classical result found in
    e.g. W. Soedel, *Vibrations of Shells and Plates*, chapter on rings, and R.D. Blevins, *Formulas
    for Natural Frequency and Mode Shape*, chapter on rings), with rotary inertia, shear and extension
    of the centre line neglected.
    """
    n = jnp.asarray(n, dtype=jnp.float64)
    w2 = (
        p.youngs_modulus
        * p.second_moment
        * n**2
        * (n**2 - 1) ** 2
        / (p.density * p.area * p.radius**4 * (n**2 + 1))
    )
    return jnp.sqrt(w2) / (2.0 * math.pi)


def thin_ring_fourier_frequencies(p: RingParams, n):
    """Exact free-ring frequencies [Hz] of the element's continuum theory for wave number n.

    Substituting ``u_r = a cos(n s)``, ``u_tau = b sin(n s)`` into the strain energy and kinetic energy
    of :mod:`pgtjax.models.curved_beam` gives the 2 x 2 problem (per unit ``pi R``)::

        K2 = [[E A / R^2 + E I (n^2-1)^2 / R^4, -n E A / R^2], [-n E A / R^2, n^2 E A / R^2]]
        M2 = rho [[A + c I n^2 / R^2, -c I n / R^2], [-c I n / R^2, A + c I / R^2]]

    (``c`` = 1 with rotary inertia, else 0).  Returns ``(f_flexural, f_extensional)``.  No supports,
    no tooth masses.  The FE model converges to these values as L grows.
    """
    n = jnp.asarray(n, dtype=jnp.float64)
    E, A, I, R, rho = p.youngs_modulus, p.area, p.second_moment, p.radius, p.density
    c = 1.0 if p.rotary_inertia else 0.0
    k11 = E * A / R**2 + E * I * (n**2 - 1) ** 2 / R**4
    k12 = -n * E * A / R**2
    k22 = n**2 * E * A / R**2
    m11 = rho * (A + c * I * n**2 / R**2)
    m12 = -rho * c * I * n / R**2
    m22 = rho * (A + c * I / R**2)
    # det(K - w2 M) = 0  ->  a w2^2 + b w2 + d = 0
    qa = m11 * m22 - m12**2
    qb = -(k11 * m22 + k22 * m11 - 2.0 * k12 * m12)
    qd = k11 * k22 - k12**2
    disc = jnp.sqrt(qb**2 - 4.0 * qa * qd)
    w2_lo = 2.0 * qd / (-qb + disc)  # stable small root
    w2_hi = (-qb + disc) / (2.0 * qa)
    return jnp.sqrt(w2_lo) / (2.0 * math.pi), jnp.sqrt(w2_hi) / (2.0 * math.pi)
