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


# Seconds each unit of work took on a 2-core CI machine (pytest --durations=0, 2026-11-27; four files estimated
# after their tests were made cheaper the same day), the larger ones only.
# Only the order depends on them: the heaviest units start first, so that neither worker is left with a long
# unit at the end while the other idles (a file missing here runs after these, in collection order).
_COST_S = {
    "notebook-design": 310,
    "test_planetary.py": 380,
    "test_montecarlo.py": 305,
    "test_scale_out.py": 305,
    "test_design.py": 185,
    "test_design_cli.py": 210,
    "test_moments.py": 145,
    "test_cli.py": 150,
    "test_contact_laws.py": 150,
    "test_contact.py": 80,
    "notebook-planetary": 135,
    "notebook-gear_pair": 110,
    "test_back_to_back.py": 105,
    "notebook-ring": 90,
    "test_api.py": 90,
    "test_ring_moving_load.py": 85,
    "test_gear_pair.py": 75,
}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Units of work for ``--dist loadgroup`` (pyproject's addopts): a test file's tests stay together on one
    worker, as with ``--dist loadfile``, so that they share the programs JAX compiled for them; each executed
    notebook is a unit of its own (its kernel shares nothing with the other tests). Units start heaviest first
    (``_COST_S``)."""
    groups = {}
    for item in items:
        notebook = item.path.name == "test_notebooks.py" and item.originalname == "test_notebook_executes"
        groups[item] = f"notebook-{item.callspec.id}" if notebook else item.path.name
        item.add_marker(pytest.mark.xdist_group(groups[item]))
    items.sort(key=lambda item: -_COST_S.get(groups[item], 0))  # stable: ties keep the collection order
