"""Design variables: named leaves of a parameter pytree, each with bounds and a map to an unconstrained
coordinate ``z`` in which the optimizer works (see docs/design.md)."""

from __future__ import annotations

import abc
import math
import re
from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

_PATH = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def _inside(x, lower, upper):
    """``x`` kept in ``[lower, upper]`` against the last rounding of a map evaluated on a projected bound,
    with the map's own derivative (a plain clip would have zero derivative there, and a coordinate that
    reached its bound could not leave it nor show a gradient pointing inside)."""
    return x + jax.lax.stop_gradient(jnp.clip(x, lower, upper) - x)


class AbstractTransform(eqx.Module):
    """Map between a physical value ``x`` in ``[lower, upper]`` and an optimizer coordinate ``z``."""

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def to_physical(self, z, lower, upper): ...

    @abc.abstractmethod
    def to_coordinate(self, x, lower, upper): ...

    @abc.abstractmethod
    def coordinate_bounds(self, lower, upper) -> tuple[float, float]:
        """Bounds on ``z`` enforced by projection (``(-inf, inf)`` where the map itself keeps ``x`` inside)."""

    def check(self, label: str, lower: float, upper: float, initial: np.ndarray) -> None:
        """``ValueError`` naming ``label`` unless the bounds and the initial value suit this map."""


class Log(AbstractTransform):
    """``x = sqrt(lower * upper) exp(z)`` (stiffnesses, any positive scale parameter); the bounds are kept by
    projecting ``z`` on ``[log(lower / ref), log(upper / ref)]``. One unit of ``z`` is a factor e."""

    name: ClassVar[str] = "log"

    def to_physical(self, z, lower, upper):
        return _inside(jnp.sqrt(lower * upper) * jnp.exp(z), lower, upper)

    def to_coordinate(self, x, lower, upper):
        return jnp.log(x / jnp.sqrt(lower * upper))

    def coordinate_bounds(self, lower, upper):
        half = 0.5 * math.log(upper / lower)
        return -half, half

    def check(self, label, lower, upper, initial):
        if not lower > 0.0:
            raise ValueError(f"design variable {label!r}: a log variable needs `lower` > 0, got {lower!r}")


class Box(AbstractTransform):
    """``x = lower + (upper - lower) sigmoid(z)``: smooth, and ``x`` stays strictly inside the bounds
    (bounded lengths such as the rim thickness). The initial value must lie strictly inside."""

    name: ClassVar[str] = "box"

    def to_physical(self, z, lower, upper):
        return _inside(lower + (upper - lower) * jax.nn.sigmoid(z), lower, upper)

    def to_coordinate(self, x, lower, upper):
        s = (x - lower) / (upper - lower)
        return jnp.log(s) - jnp.log1p(-s)

    def coordinate_bounds(self, lower, upper):
        return -math.inf, math.inf

    def check(self, label, lower, upper, initial):
        if np.any(initial <= lower) or np.any(initial >= upper):
            raise ValueError(
                f"design variable {label!r}: a box variable's initial value must lie strictly inside "
                f"({lower!r}, {upper!r}), got {initial.tolist()!r} (use transform = 'linear' to start on a bound)"
            )


class Linear(AbstractTransform):
    """``x = lower + (upper - lower) z`` with ``z`` projected on ``[0, 1]``."""

    name: ClassVar[str] = "linear"

    def to_physical(self, z, lower, upper):
        return _inside(lower + (upper - lower) * z, lower, upper)

    def to_coordinate(self, x, lower, upper):
        return (x - lower) / (upper - lower)

    def coordinate_bounds(self, lower, upper):
        return 0.0, 1.0


TRANSFORMS = {t.name: t for t in (Log, Box, Linear)}


def as_transform(label: str, transform) -> AbstractTransform:
    if isinstance(transform, AbstractTransform):
        return transform
    if isinstance(transform, str) and transform in TRANSFORMS:
        return TRANSFORMS[transform]()
    raise ValueError(
        f"design variable {label!r}: `transform` must be one of {', '.join(TRANSFORMS)}, got {transform!r}"
    )


def _number(label: str, field: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"design variable {label!r}: `{field}` must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"design variable {label!r}: `{field}` must be finite, got {value!r}")
    return value


def get_leaf(params, path: str):
    """The leaf of ``params`` at the dotted attribute ``path`` (``ValueError`` naming it if absent)."""
    node = params
    for part in path.split("."):
        if not hasattr(node, part):
            raise ValueError(f"unknown parameter path {path!r}: {type(node).__name__} has no field {part!r}")
        node = getattr(node, part)
    return node


def _is_leaf(params, path: str) -> bool:
    """Whether ``path`` is a leaf of the pytree (a static field, such as a count, is not)."""
    try:
        eqx.tree_at(_getter(path), params, replace_fn=lambda x: x)
    except TypeError:
        return False
    return True


def _getter(path: str):
    def get(params):
        node = params
        for part in path.split("."):
            node = getattr(node, part)
        return node

    return get


class Variable(eqx.Module):
    """A design variable: the parameter leaf at ``path`` (dotted attributes, e.g.
    ``"ring.k_support_radial"``), in ``[lower, upper]`` (the leaf's units), mapped by ``transform``
    (:class:`Log`, :class:`Box`, :class:`Linear` or their names). ``size``: the leaf is broadcast to
    ``(size,)`` and each entry is a variable of its own (one stiffness per bolt, say); default: the leaf's
    own size. ``name`` labels the variable in histories and figures (default: the path)."""

    path: str = eqx.field(static=True)
    lower: float = eqx.field(static=True)
    upper: float = eqx.field(static=True)
    transform: AbstractTransform
    size: int | None = eqx.field(static=True)
    name: str = eqx.field(static=True)
    unit: str = eqx.field(static=True)

    def __init__(self, path, lower, upper, transform="log", *, size=None, name=None, unit=""):
        if not isinstance(path, str) or not _PATH.match(path):
            raise ValueError(f"design variable `path` must be a dotted attribute path, got {path!r}")
        label = path if name is None else str(name)
        self.path, self.name, self.unit = path, label, str(unit)
        self.lower = _number(label, "lower", lower)
        self.upper = _number(label, "upper", upper)
        if not self.lower < self.upper:
            raise ValueError(
                f"design variable {label!r}: `lower` ({self.lower!r}) must be below `upper` ({self.upper!r})"
            )
        if size is not None and (
            isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1
        ):
            raise ValueError(f"design variable {label!r}: `size` must be an integer >= 1, got {size!r}")
        self.size = None if size is None else int(size)
        self.transform = as_transform(label, transform)
        self.transform.check(label, self.lower, self.upper, np.array([0.5 * (self.lower + self.upper)]))


class DesignSpace(eqx.Module):
    """The variables over a base parameter pytree: ``params(z)`` puts the physical values of the flat
    coordinate vector ``z`` (n_z,) into the base; :meth:`initial` is ``z`` of the base's own values."""

    base: object
    variables: tuple[Variable, ...]
    sizes: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, base, variables: Sequence[Variable]):
        variables = tuple(variables)
        if not variables:
            raise ValueError("a design needs at least one variable")
        seen, names, sizes = set(), set(), []
        for v in variables:
            if not isinstance(v, Variable):
                raise ValueError(f"design variables must be pgtjax.design.Variable, got {type(v).__name__}")
            if v.path in seen:
                raise ValueError(f"design variable {v.name!r}: path {v.path!r} appears twice")
            seen.add(v.path)
            if v.name in names:
                raise ValueError(f"design variable name {v.name!r} appears twice (names label the history)")
            names.add(v.name)
            leaf = get_leaf(base, v.path)
            if (
                isinstance(leaf, bool)
                or not isinstance(leaf, (jax.Array, np.ndarray, float, int))
                or not _is_leaf(base, v.path)
            ):
                raise ValueError(
                    f"design variable {v.name!r}: {v.path!r} is not a numeric parameter "
                    f"(a static choice such as a count or a model name cannot be a design variable)"
                )
            value = np.asarray(leaf, dtype=np.float64)
            size = value.size if v.size is None else v.size
            if v.size is not None and value.size not in (1, v.size):
                raise ValueError(
                    f"design variable {v.name!r}: {v.path!r} holds {value.size} values, cannot be spread "
                    f"over `size` = {v.size}"
                )
            initial = np.broadcast_to(value.reshape(-1) if value.size > 1 else value.reshape(()), (size,))
            if np.any(initial < v.lower) or np.any(initial > v.upper):
                raise ValueError(
                    f"design variable {v.name!r}: the initial value {initial.tolist()!r} lies outside "
                    f"[{v.lower!r}, {v.upper!r}]"
                )
            v.transform.check(v.name, v.lower, v.upper, initial)
            sizes.append(size)
        self.sizes = tuple(sizes)
        # spread each leaf to its variable's size once, so that params(z) only replaces leaves of that shape
        self.base = eqx.tree_at(
            lambda p: [_getter(v.path)(p) for v in variables],
            base,
            [_spread(_getter(v.path)(base), n, v.size) for v, n in zip(variables, self.sizes)],
        )
        self.variables = variables

    @property
    def n(self) -> int:
        return sum(self.sizes)

    def labels(self) -> list[str]:
        """One label per coordinate: the name, with ``[i]`` for a vector variable."""
        out = []
        for v, n in zip(self.variables, self.sizes):
            out += [v.name] if n == 1 and v.size is None else [f"{v.name}[{i}]" for i in range(n)]
        return out

    def _split(self, z):
        parts, start = [], 0
        for n in self.sizes:
            parts.append(z[start : start + n])
            start += n
        return parts

    def physical(self, z: Float[Array, " n_z"]) -> list[jax.Array]:
        """The physical value of each variable, (size,) arrays."""
        return [
            v.transform.to_physical(part, v.lower, v.upper) for v, part in zip(self.variables, self._split(z))
        ]

    def params(self, z: Float[Array, " n_z"]):
        """The base parameters with the variables set from ``z``."""
        values = self.physical(z)
        shaped = [
            x if (v.size is not None or n > 1) else x.reshape(jnp.shape(_getter(v.path)(self.base)))
            for v, n, x in zip(self.variables, self.sizes, values)
        ]
        return eqx.tree_at(lambda p: [_getter(v.path)(p) for v in self.variables], self.base, shaped)

    def coordinates(self, params) -> jax.Array:
        """``z`` of the variables' values in ``params`` (the inverse of :meth:`params`)."""
        parts = []
        for v, n in zip(self.variables, self.sizes):
            x = jnp.broadcast_to(jnp.asarray(_getter(v.path)(params), jnp.float64).reshape(-1), (n,))
            parts.append(v.transform.to_coordinate(x, v.lower, v.upper))
        return jnp.concatenate(parts)

    def initial(self) -> jax.Array:
        return self.coordinates(self.base)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Coordinate bounds (lo, hi), (n_z,) each; infinite where the map keeps the bound itself."""
        lo, hi = [], []
        for v, n in zip(self.variables, self.sizes):
            a, b = v.transform.coordinate_bounds(v.lower, v.upper)
            lo += [a] * n
            hi += [b] * n
        return np.asarray(lo), np.asarray(hi)

    def project(self, z):
        lo, hi = self.bounds()
        return jnp.clip(z, lo, hi)

    def describe(self) -> list[dict]:
        return [
            dict(
                name=v.name,
                path=v.path,
                lower=v.lower,
                upper=v.upper,
                transform=v.transform.name,
                size=n,
                unit=v.unit,
            )
            for v, n in zip(self.variables, self.sizes)
        ]


def _spread(leaf, n: int, size: int | None):
    value = jnp.asarray(leaf, jnp.float64)
    if size is None:
        return value
    return jnp.broadcast_to(value.reshape(-1) if value.size > 1 else value.reshape(()), (n,))
