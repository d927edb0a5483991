import os

# check the package's jaxtyping annotations (shapes, float64) while the tests run: set before pgtjax is imported
os.environ["PGTJAX_TYPECHECK"] = "1"

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import pgtjax  # noqa: E402,F401
