"""Array annotations (jaxtyping) shared by the package, and the switch that checks them.

Dimension names used throughout: ``n_times`` (saved times), ``n_dof``, ``n_contacts``, ``n_obs``
(observables), ``n_cov`` (2 m, the selected DOFs' displacements then velocities), ``n_noise``, ``n_bins``.
``Float64[...]`` also states the package's float64 policy.

The annotated classes are checked at construction (shapes consistent across fields, float64 dtypes) when the
environment variable ``PGTJAX_TYPECHECK=1`` is set before ``pgtjax`` is imported, as the test suite does
(``tests/conftest.py``); otherwise the annotations are documentation and cost nothing.
"""

from __future__ import annotations

import os

from jaxtyping import Array, Bool, Float64, Int, jaxtyped

__all__ = ["Array", "Bool", "Float64", "Int", "TYPECHECK", "typechecked"]

TYPECHECK = os.environ.get("PGTJAX_TYPECHECK", "") == "1"


def typechecked(obj):
    """Check ``obj``'s jaxtyping annotations with beartype when :data:`TYPECHECK` is on (a class: its fields
    at construction; a function: its arguments and return value); else ``obj`` unchanged."""
    if not TYPECHECK:
        return obj
    from beartype import beartype  # a test-time dependency only

    return jaxtyped(typechecker=beartype)(obj)
