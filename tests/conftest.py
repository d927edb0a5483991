import os

import pytest

# check the package's jaxtyping annotations (shapes, float64) while the tests run: set before pgtjax is imported
os.environ["PGTJAX_TYPECHECK"] = "1"

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import pgtjax  # noqa: E402,F401


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test module: the whole suite runs in one process, and the
    executables of every earlier module (the design tests add value-and-gradient programs of the planetary
    model with their line searches) otherwise stay resident to the end. A run of the full suite crashed inside XLA's compiler
    (a segmentation fault in ``backend_compile_and_load``) late in the run while the same test passed alone."""
    yield
    jax.clear_caches()
