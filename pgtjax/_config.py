"""Numerical configuration applied when pgtjax is imported.

Mesh stiffnesses are ~1e10 N/m and deflections ~1e-6 m: single precision cannot represent the
products, so pgtjax switches JAX to float64 before any array is created.
"""

import jax

jax.config.update("jax_enable_x64", True)


def require_x64(what: str) -> None:
    """``ValueError`` saying so plainly if float64 was switched off after pgtjax was imported."""
    if not jax.config.jax_enable_x64:
        raise ValueError(
            f"{what}: pgtjax needs 64-bit floats, but `jax_enable_x64` was switched off after pgtjax was imported "
            "(mesh stiffness times deflection is beyond float32); call jax.config.update('jax_enable_x64', True)"
        )
