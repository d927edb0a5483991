"""Numerical configuration applied when pgtjax is imported.

Mesh stiffnesses are ~1e10 N/m and deflections ~1e-6 m: single precision cannot represent the
products, so pgtjax switches JAX to float64 before any array is created.
"""

import jax

jax.config.update("jax_enable_x64", True)
