"""Free vibration of the Table 5.1 ring gear (thesis Ch. 5, Tables 5.1, 5.3, 5.4), Models I and II.

Data of Table 5.1: outer radius 201.14 mm, root radius 182.8 mm, m_T = 0.028 kg, J_T = 554.8e-9
kg m^2 (printed "kg.m^3"), rho = 7858 kg/m^3, E = 205 GPa, Z = 64 teeth.

Values the thesis does not give, and what is assumed here (all are arguments):

* **Pitch radius** (inner radius of the Model I ring): 176.0 mm.  A standard internal gear with
  Z = 64 and dedendum 1.25 m has root radius 33.25 m = 182.8 mm -> module m = 5.5 mm, pitch radius
  32 m = 176 mm (tip radius 170.5 mm, whole depth 12.3 mm).
* **Face width**: 33.5 mm.  Estimated from the tooth data: a tooth of module 5.5 is about
  ``pi m / 2 = 8.64 mm`` thick and 12.3 mm deep (area ~106 mm^2), so ``m_T / (rho * 106 mm^2) ~ 33.5 mm``;
  the same 8.64 mm x 12.3 mm rectangle gives ``J_T = m_T (8.64^2 + 12.3^2) mm^2 / 12 = 5.3e-7 kg m^2``,
  within 5 % of the tabulated 5.548e-7, which supports the reading.  For the free smooth ring
  (Model I) the face width cancels; for Model II it sets the tooth-to-rim mass ratio.
* Free ring (no supports): Table 5.3 lists six frequencies and "rigid body motion [is] ignored"; the
  ratios of the thesis's Model I values (1811/641 = 2.825 ...) are those of the n = 2, 3, ... flexural
  pairs of a free ring, so row i of Table 5.3 is taken as wave number n = i + 1.
* L = Z = 64 elements (thesis: "number of elements ... equal to the number of teeth"), so every tooth
  sits on a node (nodal lumped masses, Eqs. 5.16-5.18); rotary inertia of the rim included.

Outcome (see :func:`ring_gear_free_vibration_table`): with this geometry the computed frequencies are
*well below* the thesis's.  Model I (R = 188.57 mm, h = 25.14 mm): 444, 1253, 2390, 3840, 5590,
7625 Hz against 641, 1811, 3474, 5631, 8309, 11527 Hz (ratio 1.44 at n = 2 rising to 1.51 at n = 7);
Model II: 274, 773, 1479, 2384, 3484, 4774 Hz against 601 ... 10390 Hz.  The FE values agree with
the closed-form solution of the same ring theory to < 0.02 % (Model I), and the classical formula
``w^2 = E I n^2 (n^2-1)^2 / (rho A R^4 (n^2+1))`` alone gives 445 Hz for Model I at n = 2, so the
gap lies in the thesis's numbers or geometry, not in the discretisation.  The thesis's own ANSYS
values (590 Hz at n = 2) are also about twice what an 18.3 mm rim of this radius gives (313 Hz
without teeth), which suggests the analysed ring had a thicker rim than Table 5.1 states: Model I
reaches the thesis's 641 Hz with an outer radius of about 215 mm, Model II its 601 Hz with about
225 mm (its n = 3..7 values are then 0.6-4.2 % below the thesis's Model II).  The frequency
*spacing* of Model I (f_3/f_2, f_4/f_2) matches the thesis's to < 1 %, and Model II lies below
Model I as in the thesis, but by much more (factor ~0.62 instead of ~0.94), because the Model II rim
here is much thinner than the Model I ring (18.3 vs 25.1 mm).

Table 5.2 (supported rings of Wu & Parker 2006) cannot be reproduced: the support stiffnesses and
ring dimensions are not given.

:func:`chapter6_ring_params` gives the wind-turbine ring of Sec. 6.4 (complete data in the thesis).
"""

from __future__ import annotations

import numpy as np

from pgtjax._files import write_text
from pgtjax.models.ring import RingParams, nodal_diameter, ring_natural_frequencies

#: one line on why the computed frequencies lie 30-55 % below Table 5.3 (module docstring), printed under the
#: table and under the figures' titles
DISAGREEMENT_NOTE = (
    "Computed frequencies are 30-55 % below Table 5.3: Table 5.1's 18.3 mm rim (and the assumed pitch radius) "
    "gives them; the FE matches closed-form ring theory to 0.02 %, so the gap lies in the thesis's geometry "
    "(see the module docstring of pgtjax.studies.ring_free_vibration)"
)

#: the files :func:`write_outputs` writes (fnmatch pattern -> one line), for the output folder's README.txt
FILE_INDEX = {
    "table_5_3.json": "frequencies (Hz) of Models I and II for wave numbers n = 2..7 against thesis Table 5.3 "
    "(model_I, model_II, thesis_*: Hz; rel_diff_*: computed / thesis - 1)",
    "modes_model_I.png": "six lowest elastic mode shapes of Model I (smooth free ring), frequencies in Hz "
    "(thesis ch. 5, Model I of Table 5.3)",
    "modes_model_II.png": "six lowest elastic mode shapes of Model II (rim + 64 tooth masses), frequencies in "
    "Hz (thesis ch. 5, Model II of Table 5.3)",
}

#: Table 5.3 of the thesis [Hz], rows = first six elastic frequencies (taken as n = 2..7).
THESIS_TABLE_5_3 = {
    "ansys": np.array([590.0, 1650.0, 3129.0, 4977.0, 7166.0, 9652.0]),
    "model_I": np.array([641.0, 1811.0, 3474.0, 5631.0, 8309.0, 11527.0]),
    "model_II": np.array([601.0, 1697.0, 3242.0, 5216.0, 7605.0, 10390.0]),
}

#: Table 5.1 data (SI).
TABLE_5_1 = {
    "outer_radius": 201.14e-3,
    "root_radius": 182.8e-3,
    "tooth_mass": 0.028,
    "tooth_inertia": 554.8e-9,
    "density": 7858.0,
    "youngs_modulus": 205e9,
    "n_teeth": 64,
}


def table_5_1_params(
    model: str,
    *,
    pitch_radius: float = 176.0e-3,
    face_width: float = 33.5e-3,
    n_elements: int = 64,
    rotary_inertia: bool = True,
) -> RingParams:
    """RingParams of the Table 5.1 ring gear.

    ``model="I"``: smooth ring from the pitch radius to the outer radius, no tooth masses.
    ``model="II"``: smooth ring from the root radius to the outer radius plus Z tooth masses
    ``m_T``, ``J_T``.  ``pitch_radius`` [m] and ``face_width`` [m] are assumptions (module docstring).
    """
    d = TABLE_5_1
    if model == "I":
        ri, mt, jt = pitch_radius, 0.0, 0.0
    elif model == "II":
        ri, mt, jt = d["root_radius"], d["tooth_mass"], d["tooth_inertia"]
    else:
        raise ValueError(f"`model` must be 'I' or 'II', got {model!r}")
    ro = d["outer_radius"]
    if not 0.0 < ri < ro:
        raise ValueError(f"`pitch_radius` must be > 0 m and < {ro} m (outer radius), got {ri}")
    return RingParams(
        0.5 * (ri + ro),
        ro - ri,
        face_width,
        d["youngs_modulus"],
        d["density"],
        n_elements=n_elements,
        n_teeth=d["n_teeth"],
        tooth_mass=mt,
        tooth_inertia=jt,
        rotary_inertia=rotary_inertia,
    )


def flexural_frequencies(p: RingParams, wave_numbers) -> np.ndarray:
    """Lowest natural frequency [Hz] whose mode has wave number n, for each n in ``wave_numbers``."""
    f, x = ring_natural_frequencies(p)
    f = np.asarray(f)
    ns = np.array([nodal_diameter(x[:, i]) for i in range(f.size)])
    out = []
    for n in wave_numbers:
        hits = np.flatnonzero(ns == n)
        if hits.size == 0:
            raise ValueError(f"no mode with wave number {n} (n must be <= n_elements / 2)")
        out.append(f[hits[0]])
    return np.array(out)


def ring_gear_free_vibration_table(
    *,
    pitch_radius: float = 176.0e-3,
    face_width: float = 33.5e-3,
    n_elements: int = 64,
    rotary_inertia: bool = True,
) -> dict:
    """Frequencies [Hz] of Models I and II of the Table 5.1 ring gear for n = 2..7, with Table 5.3.

    Returns a dict with ``n`` (wave numbers), ``model_I``, ``model_II`` (computed),
    ``thesis_model_I``, ``thesis_model_II``, ``thesis_ansys`` (Table 5.3) and the relative
    differences ``rel_diff_I`` / ``rel_diff_II`` (computed / thesis - 1).  See the module docstring
    for the assumed values and why the computed frequencies are ~30-55 % below the thesis's.
    """
    n = np.arange(2, 8)
    kw = dict(
        pitch_radius=pitch_radius, face_width=face_width, n_elements=n_elements, rotary_inertia=rotary_inertia
    )
    f1 = flexural_frequencies(table_5_1_params("I", **kw), n)
    f2 = flexural_frequencies(table_5_1_params("II", **kw), n)
    t = THESIS_TABLE_5_3
    return {
        "n": n,
        "model_I": f1,
        "model_II": f2,
        "thesis_model_I": t["model_I"],
        "thesis_model_II": t["model_II"],
        "thesis_ansys": t["ansys"],
        "rel_diff_I": f1 / t["model_I"] - 1.0,
        "rel_diff_II": f2 / t["model_II"] - 1.0,
    }


def chapter6_ring_params(n_elements: int = 36, rotary_inertia: bool = True) -> RingParams:
    """Wind-turbine ring gear of thesis Sec. 6.4 on six equally spaced bolts.

    E = 210 GPa, rho = 7800 kg/m^3, outer radius 520 mm, root radius 492.5 mm (rim h = 27.5 mm,
    centre-line R = 506.25 mm), face width 230 mm, bolts k_r = k_tau = 1.362e12 N/m,
    k_theta = 3.405e10 N m/rad at nodes 0, L/6, ..., 5L/6 (``n_elements`` must be a multiple of 6;
    the thesis uses 36).  Smooth ring, no tooth masses.
    """
    if n_elements % 6 != 0 or n_elements < 6:
        raise ValueError(f"`n_elements` must be a positive multiple of 6, got {n_elements}")
    ro, ri = 0.520, 0.4925
    return RingParams(
        0.5 * (ro + ri),
        ro - ri,
        0.230,
        210e9,
        7800.0,
        n_elements=n_elements,
        support_nodes=tuple(range(0, n_elements, n_elements // 6)),
        k_support_radial=1.362e12,
        k_support_tangential=1.362e12,
        k_support_torsional=3.405e10,
        rotary_inertia=rotary_inertia,
    )


def format_table(table: dict) -> str:
    """Plain-text Table 5.3 comparison of :func:`ring_gear_free_vibration_table` (Hz and % difference)."""
    lines = [
        "natural frequencies (Hz) of the free ring gear by mode number n (flexural waves around the ring): "
        "computed, Table 5.3's, and their difference",
        f"{'n':>2s} {'Model I':>9s} {'thesis I':>9s} {'diff':>7s} {'Model II':>9s} {'thesis II':>9s} "
        f"{'diff':>7s} {'ANSYS':>7s}",
    ]
    for i, n in enumerate(table["n"]):
        lines.append(
            f"{int(n):2d} {table['model_I'][i]:9.1f} {table['thesis_model_I'][i]:9.1f} "
            f"{100 * table['rel_diff_I'][i]:6.1f}% {table['model_II'][i]:9.1f} {table['thesis_model_II'][i]:9.1f} "
            f"{100 * table['rel_diff_II'][i]:6.1f}% {table['thesis_ansys'][i]:7.0f}"
        )
    return "\n".join(lines)


def json_table(table: dict) -> dict:
    """:func:`ring_gear_free_vibration_table` as plain Python numbers (``json.dumps``-ready lists; n as integers)."""
    return {k: [int(v) if k == "n" else float(v) for v in vals] for k, vals in table.items()}


def write_outputs(outdir, **kw) -> list:
    """Write the Table 5.3 comparison (``table_5_3.json``) and mode-shape figures of Models I and II (the
    deformed free rings, :func:`pgtjax.studies.ring_moving_load.mode_shape_figure`) into ``outdir``.
    Keywords as :func:`ring_gear_free_vibration_table`."""
    import json
    from pathlib import Path

    from .. import plots

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    table = ring_gear_free_vibration_table(**kw)
    path = outdir / "table_5_3.json"
    write_text(path, json.dumps(json_table(table), indent=2))
    written = [path]
    for model in ("I", "II"):
        p = table_5_1_params(model, **kw)
        # a free ring: the 3 lowest modes are rigid-body motions; show modes 4..9 (n = 2..4 pairs)
        fig = _elastic_mode_figure(p, f"Model {model} (free ring): lowest elastic modes")
        written.append(plots.save(fig, outdir / f"modes_model_{model}.png"))
    return written


def _elastic_mode_figure(p: RingParams, title: str, n_show: int = 6, amplitude: float = 0.15):
    import math

    import jax.numpy as jnp

    from .. import plots
    from ..models.ring import natural_frequencies, ring_matrices
    from .ring_moving_load import ring_shape_points

    f, x = natural_frequencies(*ring_matrices(p))
    f, x = np.asarray(f), np.asarray(x)
    elastic = [k for k in range(f.size) if nodal_diameter(x[:, k]) >= 2][:n_show]
    R = float(p.radius)
    with plots.plt.rc_context(plots.STYLE):
        fig, axes = plots.plt.subplots(2, 3, figsize=(7.2, 5.0))
        for ax, k in zip(axes.ravel(), elastic):
            u = x[:, k]
            peak = np.max(np.abs(u.reshape(-1, 3)[:, :2]))
            xs, ys = ring_shape_points(p, jnp.asarray(u), amplitude * R / max(peak, 1e-300))
            th = np.linspace(0, 2 * math.pi, 200)
            ax.plot(R * np.cos(th), R * np.sin(th), color="0.6", ls="--", lw=0.8)
            plots.closed_curve(ax, xs, ys, edgecolor="tab:blue")
            ax.set_aspect("equal")
            ax.axis("off")
            ax.set_title(f"{f[k]:.0f} Hz, n = {nodal_diameter(u)}")
        import textwrap

        fig.suptitle(title + "\n" + textwrap.fill(DISAGREEMENT_NOTE, 100), fontsize=9)
        fig.tight_layout()
    return fig
