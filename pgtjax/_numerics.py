"""Small numerical helpers shared by the solvers."""

import jax.numpy as jnp


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite (zero) derivative at x <= 0: the double-``where`` trick. A plain sqrt
    has an infinite derivative at 0, and a zero cotangent times inf is NaN in reverse mode."""
    positive = x > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)
