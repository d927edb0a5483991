"""Small numerical helpers shared by the solvers."""

import jax.numpy as jnp


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite (zero) derivative at x <= 0: the double-``where`` trick. A plain sqrt
    has an infinite derivative at 0, and a zero cotangent times inf is NaN in reverse mode."""
    positive = x > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def materialized(x):
    """``x`` unchanged, but computed by a loop of its own and stored rather than recomputed (or re-sliced) inside
    each loop that reads it. XLA:CPU has no other way to ask for this (it drops optimization barriers before
    fusion): ``x / (1 + 0 x)`` is a division with several users, which XLA keeps in a fusion of its own rather
    than duplicate it. The divisor is exactly 1 for finite ``x``, so the result is ``x`` exactly, except that
    XLA's CPU code flushes subnormals to zero, as its arithmetic treats them anyway.
    docs/performance.md says where this paid (the normals' loops; the per-step inputs of Monte Carlo)."""
    return x / (1.0 + 0.0 * x)
