"""Execute the notebooks at a small size (their parameters are read from environment variables) and check that
they show their figures.

The kernel must draw with ipykernel's own default, the inline backend: CI exports ``MPLBACKEND=Agg``, and
a kernel that inherits it renders nothing, which would hide exactly the bug this test guards against
(library code that forces a non-interactive backend, so that a notebook shows no figure). So ``MPLBACKEND``
is removed from the kernel's environment.

The notebooks are committed *with* their outputs, executed at their default size (the environment variables
unset), so that a reader sees the figures without running anything; ``test_committed_outputs`` checks, without
executing anything, that every committed notebook still holds them.
"""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))
SMALL = {
    "PGTJAX_NOTEBOOK_SAMPLES": "600",
    "PGTJAX_NOTEBOOK_T_END": "0.006",
    "PGTJAX_NOTEBOOK_PERIODS": "0.02",
    "PGTJAX_NOTEBOOK_OPT_STEPS": "3",
    "PGTJAX_B2B_NOTEBOOK_T_END": "0.25",  # back_to_back: seconds of run-up (committed outputs: 1.5 s)
    "PGTJAX_NOTEBOOK_RING_SMALL": "1",  # ring: 12 elements, short windows (committed outputs: 36 elements)
}
# The names under which matplotlib reports ipykernel's inline backend: its module path up to matplotlib 3.8, its
# short name from matplotlib 3.9's backend registry (3.11.2 with matplotlib-inline 0.2.2 reports "inline"). A
# notebook switched to a non-interactive backend reports "agg" (or "Agg", "pdf", ...), which is what the test catches.
INLINE_BACKEND_NAMES = {"module://matplotlib_inline.backend_inline", "inline"}
# Figures each notebook shows (the same at every size), one image output each.
EXPECTED_FIGURES = {
    "back_to_back": 2,  # run-up stiffness/TE/acceleration panels, STFT
    "design": 6,  # bolt elasticities, convergence, bolt stiffnesses, SL/MC response, Pareto front, scaling sweep
    "gear_pair": 7,  # three regimes x (moments against time, PDF of the mesh deflection), peak mesh forces
    "planetary": 7,  # DOFs, appendix DOFs, contact point, meshing forces, their zoom, peak forces, rim sweep
    "ring": 4,  # mode shapes, contact-point and mid-node responses, speed sweep
}


def _outputs(nb):
    return [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]


def image_count(nb) -> int:
    """PNG images the executed notebook displayed (``display_data`` or a cell's ``execute_result``)."""
    return sum(
        o.output_type in ("display_data", "execute_result") and "image/png" in o.get("data", {})
        for o in _outputs(nb)
    )


def execute_reporting_backend(nb, folder: Path) -> str:
    """Execute ``nb`` in a fresh kernel (in ``folder``) and return the matplotlib backend it ended with, read by
    a last cell appended for the purpose (and removed again)."""
    nb.cells.append(nbformat.v4.new_code_cell("import matplotlib\nprint(matplotlib.get_backend())"))
    NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(folder)}}
    ).execute()
    return "".join(o.get("text", "") for o in nb.cells.pop().outputs if o.output_type == "stream").strip()


def test_the_backend_check_tells_inline_from_a_switch_away(monkeypatch, tmp_path):
    """The backend check passes a kernel left on ipykernel's default and fails one that library code switched
    to a non-interactive backend (what the notebook test exists to catch), whatever name this matplotlib gives
    the inline backend."""
    monkeypatch.delenv("MPLBACKEND", raising=False)
    plain = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("import matplotlib.pyplot as plt")])
    switched = nbformat.v4.new_notebook(
        cells=[
            nbformat.v4.new_code_cell("import matplotlib\nmatplotlib.use('Agg')\nimport matplotlib.pyplot")
        ]
    )
    assert execute_reporting_backend(plain, tmp_path) in INLINE_BACKEND_NAMES
    assert execute_reporting_backend(switched, tmp_path).lower() == "agg"
    assert "agg" not in {name.lower() for name in INLINE_BACKEND_NAMES}


def test_every_notebook_has_an_expected_figure_count():
    assert sorted(EXPECTED_FIGURES) == [p.stem for p in NOTEBOOKS]


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    for k, v in SMALL.items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel must use ipykernel's inline backend
    nb = nbformat.read(path, as_version=4)
    backend = execute_reporting_backend(nb, path.parent)
    outputs = _outputs(nb)
    errors = [o for o in outputs if o.output_type == "error"]
    assert not errors, [f"{o.ename}: {o.evalue}" for o in errors]
    images = image_count(nb)
    assert images > 0, f"{path.name} displayed no figure"
    assert images == EXPECTED_FIGURES.get(path.stem), f"{path.name}: {images} figures displayed"
    assert backend.strip() in INLINE_BACKEND_NAMES, f"{path.name} ended with the backend {backend.strip()!r}"
    stderr = "".join(o.get("text", "") for o in outputs if o.output_type == "stream" and o.name == "stderr")
    assert "IProgress not found" not in stderr


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_committed_outputs(path):
    """The committed notebook holds its executed outputs: every code cell run, in order, from one kernel; its
    figures; no error, no warning, no progress-bar fallback message, no path of the machine that ran it."""
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    counts = [c.get("execution_count") for c in code]
    assert all(isinstance(n, int) for n in counts), f"{path.name}: cells not executed: {counts}"
    assert counts == list(range(1, len(code) + 1)), f"{path.name}: not executed in order: {counts}"
    outputs = _outputs(nb)
    errors = [o for o in outputs if o.output_type == "error"]
    assert not errors, [f"{o.ename}: {o.evalue}" for o in errors]
    assert image_count(nb) == EXPECTED_FIGURES[path.stem], f"{path.name}: {image_count(nb)} figures committed"
    stderr = "".join(o.get("text", "") for o in outputs if o.output_type == "stream" and o.name == "stderr")
    for word in ("Warning", "IProgress", "Traceback"):
        assert word not in stderr, f"{path.name}: {word!r} in the committed stderr: {stderr[:500]}"
    text = "".join(
        o.get("text", "") + "".join(v for k, v in o.get("data", {}).items() if k.startswith("text/"))
        for o in outputs
    )
    for local in ("/work/", "/tmp/", "/home/", "/root/"):
        assert local not in text, f"{path.name}: a local path ({local}...) in the committed outputs"
