"""Objectives (scalar functionals of an SL or Monte Carlo result) and design costs (functions of the
parameters). Each is a small module; a :class:`~pgtjax.design.DesignProblem` adds them up."""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import MomentResult


class Names(eqx.Module):
    """The quantity names a result will carry: DOFs, contacts (meshes) and observables."""

    dofs: tuple[str, ...] = eqx.field(static=True)
    contacts: tuple[str, ...] = eqx.field(static=True)
    observables: tuple[str, ...] = eqx.field(static=True)
    units: tuple[tuple[str, str], ...] = eqx.field(static=True)

    def unit(self, name: str) -> str:
        return dict(self.units).get(name, "")

    def kind(self, name: str) -> str:
        for kind, names in (("observable", self.observables), ("contact", self.contacts), ("dof", self.dofs)):
            if name in names:
                return kind
        raise ValueError(
            f"unknown quantity {name!r}; known: observables {list(self.observables)}, meshes/contacts "
            f"{list(self.contacts)}, DOFs {list(self.dofs[:6])}{' ...' if len(self.dofs) > 6 else ''}"
        )


# ------------------------------------------------------------------------------------ reductions over time


class AbstractReduction(eqx.Module):
    """Reduce a (n_times, n_quantities) history of a non-negative quantity to a scalar."""

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def __call__(self, times, values): ...


class TimeMean(AbstractReduction):
    """Mean over the saved times ``t >= start`` (s) and over the quantities."""

    start: float = 0.0
    name: ClassVar[str] = "time-mean"

    def __call__(self, times, values):
        weight = (times >= self.start).astype(values.dtype)[:, None]
        return jnp.sum(weight * values) / (jnp.sum(weight) * values.shape[1])


class SmoothMax(AbstractReduction):
    """``(mean x^p)^(1/p)`` over the saved times ``t >= start`` and the quantities: a smooth maximum (the
    L^p mean, between the RMS and the maximum; ``order`` p >= 2)."""

    order: float = 8.0
    start: float = 0.0
    name: ClassVar[str] = "smooth-max"

    def __check_init__(self):
        if not float(self.order) >= 2.0:
            raise ValueError(f"SmoothMax `order` must be >= 2, got {self.order!r}")

    def __call__(self, times, values):
        weight = (times >= self.start).astype(values.dtype)[:, None]
        top = jax.lax.stop_gradient(jnp.max(jnp.abs(values) * weight))
        top = jnp.where(top > 0.0, top, 1.0)  # scaled so that x^p neither overflows nor underflows
        mean = jnp.sum(weight * (jnp.abs(values) / top) ** self.order) / (jnp.sum(weight) * values.shape[1])
        return top * mean ** (1.0 / self.order)


REDUCTIONS = {"mean": TimeMean, "smooth_max": SmoothMax}


def _label(over: AbstractReduction) -> str:
    """The reduction's name with its settings (part of a problem's description, which resume compares)."""
    parts = [f"order {over.order:g}"] if isinstance(over, SmoothMax) else []
    if over.start:
        parts.append(f"t >= {over.start:g} s")
    return over.name + (f" ({', '.join(parts)})" if parts else "")


# --------------------------------------------------------------------------------------------- objectives


def _series(result, names: Names, quantity: str, what: str):
    """(n_times,) mean or std of a quantity by name."""
    kind = names.kind(quantity)
    if kind == "observable":
        i = result.observable(quantity)
        return (result.mean_obs if what == "mean" else result.std_obs)[:, i]
    if kind == "contact":
        i = result.contact(quantity)
        return (result.force_mean if what == "mean" else result.force_std)[:, i]
    i = result.dof(quantity)
    return (result.mean_u if what == "mean" else result.std_u)[:, i]


class AbstractObjective(eqx.Module):
    """A scalar response of a result (SL or Monte Carlo) to be minimized."""

    @abc.abstractmethod
    def __call__(self, result, system, names: Names): ...

    @abc.abstractmethod
    def check(self, names: Names) -> None:
        """``ValueError`` naming any quantity ``names`` lacks (run before anything is compiled)."""

    @abc.abstractmethod
    def describe(self, names: Names) -> dict:
        """Name, unit and definition, for histories and summaries."""


def _quantities(label: str, quantities) -> tuple[str, ...]:
    q = (quantities,) if isinstance(quantities, str) else tuple(quantities)
    if not q or not all(isinstance(x, str) for x in q):
        raise ValueError(f"{label} `quantities` must be a non-empty list of names, got {quantities!r}")
    return q


class Std(AbstractObjective):
    """Standard deviation of named quantities (DOFs: displacement; meshes/contacts: meshing force; or
    observables), reduced over time and quantities by ``over`` (:class:`TimeMean` or :class:`SmoothMax`)."""

    quantities: tuple[str, ...] = eqx.field(static=True, converter=lambda q: _quantities("Std", q))
    over: AbstractReduction = TimeMean()
    power: ClassVar[int] = 1

    def __call__(self, result, system, names):
        values = jnp.stack([_series(result, names, q, "std") for q in self.quantities], axis=1)
        return self.over(result.times, values**self.power)

    def check(self, names):
        for q in self.quantities:
            names.kind(q)

    def describe(self, names):
        unit = names.unit(self.quantities[0])
        stat = "std" if self.power == 1 else "variance"
        return dict(
            name=f"{_label(self.over)} {stat} of {', '.join(self.quantities)}",
            unit=unit if self.power == 1 else f"({unit})^2",
        )


class Variance(Std):
    """As :class:`Std`, of the variance."""

    power: ClassVar[int] = 2


def _check_meshes(label: str, meshes, names: Names) -> None:
    for m in meshes:
        if m not in names.contacts:
            raise ValueError(f"{label}: unknown mesh {m!r}; known: {list(names.contacts)}")


class DynamicFactor(AbstractObjective):
    """Dynamic factor of meshing forces: ``(|E F(t)| + n_sigma std F(t)) / mean_t |E F|`` of each named
    mesh (the statistical upper force against the horizon's mean load), reduced by ``over``."""

    meshes: tuple[str, ...] = eqx.field(static=True, converter=lambda q: _quantities("DynamicFactor", q))
    n_sigma: float = 3.0
    over: AbstractReduction = SmoothMax()

    def __call__(self, result, system, names):
        idx = jnp.asarray([result.contact(m) for m in self.meshes])
        mean, std = jnp.abs(result.force_mean[:, idx]), result.force_std[:, idx]
        window = (result.times >= self.over.start).astype(mean.dtype)[:, None]
        load = jnp.sum(window * mean, axis=0, keepdims=True) / jnp.sum(window)  # the window's mean load
        return self.over(result.times, (mean + self.n_sigma * std) / load)

    def check(self, names):
        _check_meshes("DynamicFactor", self.meshes, names)

    def describe(self, names):
        return dict(
            name=f"{_label(self.over)} dynamic factor (mean + {self.n_sigma:g} std) of {', '.join(self.meshes)}",
            unit="1",
        )


class ContactLoss(AbstractObjective):
    """Probability of contact loss ``P(|delta| < b)`` on the named meshes (SL: under its Gaussian
    deflection; Monte Carlo: the sample frequency), reduced by ``over``."""

    meshes: tuple[str, ...] = eqx.field(static=True, converter=lambda q: _quantities("ContactLoss", q))
    over: AbstractReduction = TimeMean()

    def __call__(self, result, system, names):
        idx = jnp.asarray([result.contact(m) for m in self.meshes])
        if isinstance(result, MomentResult):
            prob = result.contact_loss_probability(system)
        else:
            prob = result.contact_loss_probability
        return self.over(result.times, prob[:, idx])

    def check(self, names):
        _check_meshes("ContactLoss", self.meshes, names)

    def describe(self, names):
        return dict(
            name=f"{_label(self.over)} contact-loss probability of {', '.join(self.meshes)}", unit="1"
        )


class Custom(AbstractObjective):
    """Any ``fn(result, system) -> scalar`` (a JAX function of the result's arrays)."""

    fn: Callable = eqx.field(static=True)
    label: str = eqx.field(static=True, default="custom objective")
    unit: str = eqx.field(static=True, default="")

    def __call__(self, result, system, names):
        return jnp.asarray(self.fn(result, system), jnp.float64).reshape(())

    def check(self, names):
        if not callable(self.fn):
            raise ValueError(f"Custom objective: `fn` must be callable, got {self.fn!r}")

    def describe(self, names):
        return dict(name=self.label, unit=self.unit)


OBJECTIVES = {"std": Std, "variance": Variance, "dynamic_factor": DynamicFactor, "contact_loss": ContactLoss}


def as_objective(objective) -> AbstractObjective:
    if isinstance(objective, AbstractObjective):
        return objective
    if callable(objective):
        return Custom(objective)
    raise ValueError(
        f"`objective` must be a pgtjax.design objective ({', '.join(c.__name__ for c in OBJECTIVES.values())}) "
        f"or a function (result, system) -> scalar, got {objective!r}"
    )


# ------------------------------------------------------------------------------------------------- costs


class AbstractCost(eqx.Module):
    """A cost on the design (a function of the parameters), added to the objective with a weight."""

    weight: float = eqx.field(default=1.0, kw_only=True)

    def __check_init__(self):
        w = self.weight
        if (
            isinstance(w, bool)
            or not isinstance(w, (int, float, np.floating))
            or not (w >= 0 and np.isfinite(w))
        ):
            raise ValueError(f"{type(self).__name__} `weight` must be a finite number >= 0, got {w!r}")

    @abc.abstractmethod
    def __call__(self, params): ...

    @abc.abstractmethod
    def describe(self) -> dict: ...


def _leaf(params, path):
    node = params
    for part in path.split("."):
        node = getattr(node, part)
    return node


class SupportStiffness(AbstractCost):
    """Sum of the support stiffnesses at ``paths`` over every bolt (N/m): the stiffness budget."""

    paths: tuple[str, ...] = eqx.field(
        static=True, default=("ring.k_support_radial", "ring.k_support_tangential")
    )

    def __call__(self, params):
        total = 0.0
        for path in self.paths:
            leaf = jnp.asarray(_leaf(params, path), jnp.float64)
            count = len(params.ring.support_nodes) if leaf.size == 1 else 1
            total = total + count * jnp.sum(leaf)
        return total

    def describe(self):
        return dict(name=f"total support stiffness ({' + '.join(self.paths)}, all bolts)", unit="N/m")


class RimMass(AbstractCost):
    """Mass of the ring's rim, ``rho b h 2 pi R`` with the centre radius R of the parameters' ring (kg)."""

    def __call__(self, params):
        ring = params.elastic_ring if hasattr(params, "elastic_ring") else params.ring
        return ring.density * ring.face_width * ring.thickness * 2.0 * jnp.pi * ring.radius

    def describe(self):
        return dict(name="rim mass", unit="kg")


class ParameterCost(AbstractCost):
    """Any ``fn(params) -> scalar``."""

    fn: Callable = eqx.field(static=True, kw_only=True)
    label: str = eqx.field(static=True, default="parameter cost", kw_only=True)
    unit: str = eqx.field(static=True, default="", kw_only=True)

    def __call__(self, params):
        return jnp.asarray(self.fn(params), jnp.float64).reshape(())

    def describe(self):
        return dict(name=self.label, unit=self.unit)


COSTS = {"support_stiffness": SupportStiffness, "rim_mass": RimMass}


def check_costs(costs: Sequence) -> tuple[AbstractCost, ...]:
    costs = tuple(costs)
    for c in costs:
        if not isinstance(c, AbstractCost):
            raise ValueError(f"costs must be pgtjax.design costs, got {c!r}")
    return costs
