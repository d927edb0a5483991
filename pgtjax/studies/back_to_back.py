"""Paper study (Hammami et al., section 5): the back-to-back bench in a stationary regime (A) and in a run-up (B).

For each regime the bench (:mod:`pgtjax.models.back_to_back`) is integrated by :func:`pgtjax.simulate`
(average-acceleration Newmark with a Newton solve of the 12 mesh contacts per step; the paper's Eqs. 34-42 are
the same scheme with Newton on all DOFs) from its quasi-static state, and we extract over time: the Hertzian
stiffness of every mesh (sum over the pairs in contact of Eq. 13's secant ``F_h / delta_h``, and the tangent),
the total mesh stiffness ``dF/d delta``, the transmission error ``delta - b`` and the mesh forces (Eq. 38), the
ring accelerations (from the equation of motion at the saved states), the carrier speed and the motor torque;
then short-time Fourier transforms (STFT) of the ring acceleration and of a transmission error.

Why the test-ring acceleration shows ``3 f_m`` and not ``f_m``: the three planets are equally spaced and
``Z_r / 3`` and ``Z_s / 3`` are not integers, so the planets mesh with phases 0, 1/3, 2/3 (Parker & Lin 2004);
in a purely torsional model the ring's rotation is driven by the sum of the three ring-mesh forces, in which
every harmonic of ``f_m`` that is not a multiple of 3 cancels. A ring-mounted accelerometer also sees the
planets passing (amplitude modulation), which the torsional model does not describe. The fundamental ``f_m``
is in every single mesh: the STFT of a transmission error shows it.

The STFT is written with numpy (Hann window, zero padding, one-sided amplitude spectrum); the ridge of a line
is the peak in a band around its expected frequency, refined by parabolic interpolation of the log magnitude.

Comparison with the paper's mean Hertzian stiffness (1.13e9 -> 1.234e9 N/m sun-planet 1, 2.102e9 -> 2.243e9 N/m
ring-planet 1): :func:`hertz_comparison` (quasi-static, over a mesh cycle) and the dynamic means of the regimes.
Assumptions: face width 20 mm (= Hertz contact length), the circulating torque of each zone (the paper's Figs.
4-5 are lost), Harsha's fit in mm and N (see :mod:`pgtjax.models.mesh_stiffness`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import Trajectory, modal_analysis, plots, save_results, simulate
from .. import params as _params
from .._files import write_atomic
from .._summary import write_summary
from ..models import back_to_back as bb
from ..models.mesh_stiffness import HARSHA_DEFLECTION_EXP

PAPER_HS_SUN = (1.13e9, 1.234e9)  # N/m, mean Hertzian stiffness sun-planet 1, zone A -> end of run-up
PAPER_HS_RING = (2.102e9, 2.243e9)  # N/m, ring-planet 1

#: the files :func:`write_outputs` writes (fnmatch pattern -> one line), for the output folder's README.txt
FILE_INDEX = {
    "*_trajectory.npz": "simulated displacements u = r_b theta (m), velocities and mesh deflections of the 12 "
    "DOF over time, one regime (pgtjax.load_results)",
    "*_mesh.npz": "mesh histories of the regime: phase, transmission error, mesh forces, Hertzian and mesh "
    "stiffness, pairs in contact, accelerations, speeds and torques (units in the 'units' entry)",
    "*_operating.png": "motor and test-carrier speed, circulating and motor torque, and mesh frequency Z_r f_c "
    "over time (the operating conditions of bench-paper section 5)",
    "*_stiffness.png": "Hertzian and total mesh stiffness of sun-planet 1 and ring-planet 1 over time with a "
    "20 ms running mean and the paper's mean Hertzian stiffness (bench paper section 5)",
    "*_te_force_acceleration.png": "transmission error and mesh force of ring-planet 1 and the test-ring "
    "acceleration over time",
    "*_stft_ring_T_acceleration.png": "STFT (dB) of the test-ring acceleration with the lines k Z_r f_c, "
    "k = 3, 6, 9 (bench paper's spectrogram of the ring acceleration)",
    "*_stft_te_ring_planet1.png": "STFT (dB) of the ring-planet 1 transmission error with k Z_r f_c, "
    "k = 1, 2, 3",
}


# ------------------------------------------------------------------------------------------------ STFT


def stft(x, fs: float, window_s: float, hop_s: float | None = None, nfft: int | None = None):
    """Short-time Fourier transform of a real signal (numpy).

    ``x`` (n,) sampled at ``fs`` [Hz]; Hann window of ``window_s`` [s], hop ``hop_s`` [s] (default a quarter
    window), FFT length ``nfft`` (default the next power of two >= 4 windows: zero padding for a finer grid).
    Returns ``(times [s] of the frame centres, frequencies [Hz], amplitude (n_frames, n_freq))``; the
    amplitude of a sinusoid of amplitude A is A at its frequency. The mean of each frame is removed.
    """
    x = np.asarray(x, dtype=np.float64)
    n_win = int(round(window_s * fs))
    if n_win < 8 or n_win > x.size:
        raise ValueError(
            f"`window_s` must span between 8 samples and the signal ({x.size} samples); got {window_s!r}"
        )
    hop = max(int(round((hop_s if hop_s is not None else window_s / 4) * fs)), 1)
    nfft = nfft or int(2 ** math.ceil(math.log2(4 * n_win)))
    if nfft < n_win:
        raise ValueError(f"`nfft` must be >= the window length ({n_win}); got {nfft}")
    w = np.hanning(n_win)
    starts = np.arange(0, x.size - n_win + 1, hop)
    frames = np.stack([x[s : s + n_win] for s in starts])
    frames = (frames - frames.mean(axis=1, keepdims=True)) * w[None, :]
    amp = np.abs(np.fft.rfft(frames, n=nfft, axis=1)) * (2.0 / w.sum())
    times = (starts + 0.5 * (n_win - 1)) / fs
    return times, np.fft.rfftfreq(nfft, 1.0 / fs), amp


def ridge(freqs, amp, expected, rel_band: float = 0.25):
    """Peak frequency per frame [Hz] within ``expected * (1 +- rel_band)`` (parabolic refinement in log).

    ``expected`` (n_frames,) [Hz] only sets the search band; the band must exclude the neighbouring harmonics
    (``rel_band`` < 1/3 for lines at k f and (k +- 1) f with k <= 2).
    """
    freqs = np.asarray(freqs)
    out = np.empty(len(expected))
    for i, (row, fe) in enumerate(zip(np.asarray(amp), np.asarray(expected))):
        band = np.nonzero((freqs >= fe * (1 - rel_band)) & (freqs <= fe * (1 + rel_band)))[0]
        j = band[np.argmax(row[band])]
        if 0 < j < len(row) - 1:
            a, b, c = np.log(row[j - 1 : j + 2] + 1e-300)
            shift = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) != 0 else 0.0
        else:
            shift = 0.0
        out[i] = freqs[j] + shift * (freqs[1] - freqs[0])
    return out


def frame_average(times, values, frame_times, window_s):
    """Mean of ``values`` over each STFT frame (centre ``frame_times``, length ``window_s``)."""
    times, values = np.asarray(times), np.asarray(values)
    return np.array([values[np.abs(times - tc) <= 0.5 * window_s].mean() for tc in frame_times])


# ------------------------------------------------------------------------------------------------ regimes


@dataclass
class RegimeResult:
    """One simulated regime with its derived quantities (SI units; see :mod:`pgtjax.models.back_to_back`)."""

    name: str
    model: bb.BenchModel
    trajectory: Trajectory
    mesh: bb.MeshHistory
    acceleration: np.ndarray  # (n_t, 12) m/s^2
    carrier_frequency: np.ndarray  # (n_t,) Hz, test carrier, from the simulated velocity
    motor_speed: np.ndarray  # (n_t,) rad/s, prescribed
    motor_torque: np.ndarray  # (n_t,) N m
    circulating_torque: np.ndarray  # (n_t,) N m, prescribed
    dt: float
    wall_s: float

    @property
    def times(self) -> np.ndarray:
        return np.asarray(self.trajectory.times)

    @property
    def mesh_frequency(self) -> np.ndarray:
        """Z_r f_c from the simulated carrier speed [Hz] (corrected Eq. 2, docs/corrections.md C12)."""
        return self.model.params.z_ring * self.carrier_frequency


def run_regime(
    params: bb.BackToBackParams,
    name: str,
    *,
    t_end: float,
    dt: float = 1e-4,
    save_every: int = 1,
    t0: float | None = None,
) -> RegimeResult:
    """Integrate the bench from its quasi-static state at ``t0`` (default half a step, so that no step lands
    exactly on a contact entry of a commensurate mesh period) to ``t0 + t_end``."""
    if not (np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"`t_end` must be > 0 s; got {t_end!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"`dt` must be > 0 s; got {dt!r}")
    t0 = 0.5 * dt if t0 is None else t0
    n_steps = int(round(t_end / dt))
    n_steps = max(save_every * (n_steps // save_every), save_every)
    model = bb.build_model(params)
    start = time.perf_counter()
    u0, v0 = bb.initial_state(model, t0)
    traj = simulate(
        model.system,
        t0=t0,
        dt=dt,
        n_steps=n_steps,
        initial_displacement=u0,
        initial_velocity=v0,
        save_every=save_every,
    )
    jax.block_until_ready(traj.u)
    wall = time.perf_counter() - start
    if int(traj.unconverged):
        raise ValueError(f"{int(traj.unconverged)} contact solves did not converge; reduce `dt`")
    times = traj.times
    mesh = bb.mesh_history(model, times, traj.delta)
    acc = bb.accelerations(model, times, traj.u, traj.v, traj.force)
    j = bb.DOF_NAMES.index("carrier_T")
    f_c = np.asarray(traj.v[:, j] / model.radii[j]) / (2.0 * np.pi)
    torque = bb.motor_torque(model, times, traj.u, traj.v)
    return RegimeResult(
        name,
        model,
        traj,
        mesh,
        np.asarray(acc),
        f_c,
        np.asarray(model.profile.speed(times)),
        np.asarray(torque),
        np.asarray(model.profile.torque(times)),
        dt,
        wall,
    )


def load_params(
    path=None,
    *,
    torque: float | None = None,
    torque_end: float | None = None,
    speed_start_rpm: float | None = None,
    speed_end_rpm: float | None = None,
    ramp_start: float | None = None,
    ramp_duration: float | None = None,
    face_width: float | None = None,
) -> bb.BackToBackParams:
    """Bench parameters from a TOML file (layout of ``back_to_back.toml``; ``None``: the embedded one) with
    the operating point overridden where given: circulating torque at the start / end of the run-up (N m),
    motor speeds (rpm), ramp start and duration (s), and the face width (m) of both stages' meshes."""
    overrides = {}
    for value, name, scale in (
        (speed_start_rpm, "speed_start", bb.RPM),
        (speed_end_rpm, "speed_end", bb.RPM),
        (ramp_start, "ramp_start", 1.0),
        (ramp_duration, "ramp_duration", 1.0),
        (torque, "sun_torque", 1.0),
        (torque_end, "torque_end", 1.0),
    ):
        if value is not None:
            overrides[name] = value * scale
    params = bb.load_params(path, **overrides)
    if face_width is not None:
        params = params.replace(
            sun_planet=_with_width(params.sun_planet, face_width),
            ring_planet=_with_width(params.ring_planet, face_width),
        )
    return params


def _with_width(mesh, width):
    return dataclasses.replace(mesh, face_width=jnp.asarray(width, jnp.float64))


def run_up_end(params: bb.BackToBackParams) -> float:
    """End of the run-up ramp, ``ramp_start + ramp_duration`` (s): the CLI's default simulated length."""
    return float(params.ramp_start + params.ramp_duration)


def format_header(params: bb.BackToBackParams, *, dt: float, t_end: float) -> str:
    """One line describing a :func:`run_study` call (the CLI's first line)."""
    return (
        f"pgtjax back-to-back bench (bench paper, Hammami et al.): 12 DOF, 12 Hertzian meshes, dt = {dt:g} s; "
        f"run-up {float(params.speed_start) / bb.RPM:.0f} -> {float(params.speed_end) / bb.RPM:.0f} rpm, "
        f"torque {float(params.sun_torque):g} -> {float(params.torque_end):g} N m, {t_end:g} s"
    )


@dataclass
class BackToBackStudy:
    regimes: list[RegimeResult]
    hertz: dict
    modes: list[dict]
    ridges: dict
    settings: dict = field(default_factory=dict)


def run_study(
    params: bb.BackToBackParams | None = None,
    *,
    t_end: float | None = None,
    dt: float = 1e-4,
    stationary_t_end: float = 0.2,
    save_every: int = 1,
    stft_window: float = 0.1,
    progress: bool = True,
) -> BackToBackStudy:
    """Stationary regime (A) at ``speed_start``/``sun_torque`` for ``stationary_t_end`` s, then the run-up
    profile of the parameters (A then B) for ``t_end`` s (default: ``[run_up] t_end_s`` of the embedded
    ``back_to_back.toml``, read by :func:`pgtjax.params.read_toml`)."""
    p = bb.default_params() if params is None else params
    if t_end is None:
        t_end = float(_params.read_params(None, "back_to_back")["run_up"]["t_end_s"])
    window = check_stft_window(
        stft_window, dt=dt, save_every=save_every, t_end=t_end, stationary_t_end=stationary_t_end
    )
    ramp_start = float(p.ramp_start)
    if t_end <= ramp_start:  # the "run-up" would be a second stationary run, reported as a run-up
        raise ValueError(
            f"`--t-end` (t_end) must exceed the run-up's start, {ramp_start:g} s (--ramp-start), for the speed "
            f"and torque to ramp within the run; got {t_end:g} s (the ramp ends at {run_up_end(p):g} s)"
        )
    say = print if progress else (lambda *a, **k: None)
    if window < stft_window:
        say(f"  STFT window {window:g} s: half the run-up, shorter than the {stft_window:g} s asked for")
    regimes = []
    say(
        f"  stationary regime: {float(p.speed_start) / bb.RPM:.0f} rpm, {float(p.sun_torque):g} N m, "
        f"{stationary_t_end:g} s at dt = {dt:g} s ...",
        flush=True,
    )
    regimes.append(
        run_regime(bb.stationary(p), "stationary", t_end=stationary_t_end, dt=dt, save_every=save_every)
    )
    say(f"    {regimes[-1].wall_s:.1f} s")
    say(
        f"  run-up: {float(p.speed_start) / bb.RPM:.0f} -> {float(p.speed_end) / bb.RPM:.0f} rpm from "
        f"t = {float(p.ramp_start):g} s over {float(p.ramp_duration):g} s, torque {float(p.sun_torque):g} -> "
        f"{float(p.torque_end):g} N m, {t_end:g} s ...",
        flush=True,
    )
    regimes.append(run_regime(p, "run_up", t_end=t_end, dt=dt, save_every=save_every))
    say(f"    {regimes[-1].wall_s:.1f} s")
    say("  Hertzian stiffness comparison and modal analysis ...", flush=True)
    hertz = hertz_comparison(p, regimes[-1])
    modes = modal_table(p)
    window = min(stft_window, 0.5 * float(regimes[-1].times[-1] - regimes[-1].times[0]))
    ridges = {r.name: ridge_check(r, window) for r in regimes}
    return BackToBackStudy(
        regimes,
        hertz,
        modes,
        ridges,
        settings=dict(
            dt_s=dt,
            t_end_s=t_end,
            stationary_t_end_s=stationary_t_end,
            save_every=save_every,
            stft_window_s=window,
        ),
    )


def _saved_count(t_end: float, dt: float, save_every: int) -> int:
    """Number of saved times of :func:`run_regime` (its rounding of ``t_end`` to whole saves)."""
    n_steps = int(round(t_end / dt))
    n_steps = max(save_every * (n_steps // save_every), save_every)
    return n_steps // save_every + 1


def check_stft_window(
    stft_window: float, *, dt: float, save_every: int, t_end: float, stationary_t_end: float
) -> float:
    """``ValueError`` naming ``--stft-window`` and its accepted range unless the STFT window (after
    :func:`run_study`'s clamp to half the run-up) spans at least 8 saved samples and at most the shorter
    regime; called before any simulation. Returns the window used."""
    for name, value in (("--t-end", t_end), ("--stationary-t-end", stationary_t_end), ("--dt", dt)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"`{name}` must be a finite number of seconds > 0, got {value!r}")
    if not (isinstance(stft_window, int | float) and math.isfinite(stft_window) and stft_window > 0):
        raise ValueError(
            f"`--stft-window` (stft_window) must be a finite number of seconds > 0, got {stft_window!r}"
        )
    step = dt * save_every
    n_stat, n_run = _saved_count(stationary_t_end, dt, save_every), _saved_count(t_end, dt, save_every)
    window = min(stft_window, 0.5 * (n_run - 1) * step)
    lo, hi = 8 * step, min(n_stat, n_run) * step
    if not (8 <= int(round(window / step)) <= min(n_stat, n_run)):
        clamp = (
            f"; the run-up ({(n_run - 1) * step:g} s, --t-end) limits it to half its length, {window:g} s"
            if window < stft_window
            else ""
        )
        raise ValueError(
            f"`--stft-window` (stft_window) must lie between {lo:g} s (8 saved samples of dt x save_every = "
            f"{step:g} s) and {hi:g} s (the shorter regime: --stationary-t-end or --t-end), got "
            f"{stft_window:g} s{clamp}"
        )
    return window


# ------------------------------------------------------------------------------------------------ analyses


def ridge_check(reg: RegimeResult, window_s: float = 0.1) -> dict:
    """STFT ridges against ``k Z_r f_c`` (f_c from the simulated carrier speed, averaged over each frame):
    the fundamental in the transmission error of ring-planet 1 (test set) and the 3rd harmonic in the
    test-ring acceleration. Returns the frame times, ridges, expectations and the largest relative errors."""
    t = reg.times
    fs = 1.0 / float(t[1] - t[0])
    fm = reg.mesh_frequency
    out = {}
    te = np.asarray(reg.mesh.transmission_error[:, bb.CONTACT_NAMES.index("ring-planet1_T")])
    acc = reg.acceleration[:, bb.DOF_NAMES.index("ring_T")]
    for label, signal, order in (
        ("transmission_error_ring-planet1_T", te, 1),
        ("ring_T_acceleration", acc, 3),
    ):
        ft, f, a = stft(signal, fs, window_s)
        expected = order * frame_average(t, fm, ft + t[0], window_s)
        found = ridge(f, a, expected, rel_band=0.15)
        err = np.abs(found - expected) / expected
        out[label] = dict(
            order=order,
            frame_times_s=(ft + t[0]).tolist(),
            ridge_hz=found.tolist(),
            expected_hz=expected.tolist(),
            max_relative_error=float(err.max()),
        )
    return out


def harmonic_amplitudes(reg: RegimeResult, signal, orders=(1, 2, 3, 6), last_s: float | None = None) -> dict:
    """Amplitude of ``signal`` at ``k f_m`` (stationary regime; Hann-windowed FFT of the last ``last_s`` s)."""
    t = reg.times
    fs = 1.0 / float(t[1] - t[0])
    n = len(t) if last_s is None else int(round(last_s * fs))
    x = np.asarray(signal)[-n:]
    x = (x - x.mean()) * np.hanning(n)
    spec = np.abs(np.fft.rfft(x)) * 2.0 / np.hanning(n).sum()
    f = np.fft.rfftfreq(n, 1.0 / fs)
    fm = float(np.mean(reg.mesh_frequency[-n:]))
    return {k: float(spec[np.argmin(np.abs(f - k * fm))]) for k in orders}


def hertz_comparison(
    params: bb.BackToBackParams, run_up: RegimeResult | None = None, n_points: int = 128
) -> dict:
    """Mean Hertzian stiffness of sun-planet 1 and ring-planet 1 against the paper.

    Quasi-static: the mesh law over one mesh cycle at the mesh load of ``sun_torque`` (zone A) and of
    ``torque_end`` (end of the run-up). Dynamic (if ``run_up`` is given): time means over the first mesh
    periods of zone A and over the last 0.05 s. Also: the load factor the Harsha law needs to reproduce the
    paper's relative rise (``K_h ~ F^(0.08/1.08)`` per pair), and the face width that would bring the
    quasi-static zone-A sun value to the paper's (``K_h ~ W^(0.92/1.08)`` at fixed load per pair)."""
    p = params
    law = bb.hertzian_mesh_law(p)
    js, jr = bb.CONTACT_NAMES.index("sun-planet1_T"), bb.CONTACT_NAMES.index("ring-planet1_T")
    qs = {}
    for label, torque in (("zone_A", p.sun_torque), ("end_of_run_up", p.torque_end)):
        st = bb.quasi_static_mesh(law, bb.nominal_mesh_load(p, torque), n_points)
        qs[label] = dict(
            torque_Nm=float(torque),
            mesh_load_N=float(bb.nominal_mesh_load(p, torque)),
            sun_planet=dict(
                hertz_secant=float(jnp.mean(st.hertz_secant[:, js])),
                hertz_tangent=float(jnp.mean(st.hertz_tangent[:, js])),
                mesh=float(jnp.mean(st.mesh_stiffness[:, js])),
            ),
            ring_planet=dict(
                hertz_secant=float(jnp.mean(st.hertz_secant[:, jr])),
                hertz_tangent=float(jnp.mean(st.hertz_tangent[:, jr])),
                mesh=float(jnp.mean(st.mesh_stiffness[:, jr])),
            ),
        )
    p_h = HARSHA_DEFLECTION_EXP
    expo = (p_h - 1.0) / p_h  # d ln K_h / d ln F of one pair = 0.08/1.08
    out = dict(
        assumptions=dict(
            face_width_m=float(p.sun_planet.face_width),
            hertz_law="F = 56065.703 l^0.92 d^1.08 (N, mm) = 5.6065703e10 l^0.92 d^1.08 (SI)",
            stiffness="Eq. 13 secant F_h/d_h summed over "
            "the pairs in contact (tangent = 1.08 x secant also given)",
        ),
        paper=dict(sun_planet=PAPER_HS_SUN, ring_planet=PAPER_HS_RING),
        quasi_static=qs,
        load_factor_for_paper_rise=dict(
            sun_planet=float((PAPER_HS_SUN[1] / PAPER_HS_SUN[0]) ** (1.0 / expo)),
            ring_planet=float((PAPER_HS_RING[1] / PAPER_HS_RING[0]) ** (1.0 / expo)),
        ),
        face_width_for_paper_zone_A_sun_m=float(p.sun_planet.face_width)
        * float((PAPER_HS_SUN[0] / qs["zone_A"]["sun_planet"]["hertz_secant"]) ** (1.08 / 0.92)),
        paper_ring_to_sun_ratio=PAPER_HS_RING[0] / PAPER_HS_SUN[0],
        model_ring_to_sun_ratio=qs["zone_A"]["ring_planet"]["hertz_secant"]
        / qs["zone_A"]["sun_planet"]["hertz_secant"],
    )
    if run_up is not None:
        t = run_up.times
        fm0 = float(run_up.mesh_frequency[0])
        a = t <= t[0] + min(10.0 / fm0, float(p.ramp_start))
        b = t >= t[-1] - 0.05
        hs = np.asarray(run_up.mesh.hertz_secant)
        out["dynamic"] = dict(
            zone_A=dict(sun_planet=float(hs[a, js].mean()), ring_planet=float(hs[a, jr].mean())),
            end=dict(sun_planet=float(hs[b, js].mean()), ring_planet=float(hs[b, jr].mean())),
            windows_s=[[float(t[a][0]), float(t[a][-1])], [float(t[b][0]), float(t[b][-1])]],
        )
    return out


def _dominant(names, shape) -> str:
    """The DOF of largest amplitude; DOFs tied with it (to 1e-6) are named together: ``planets_T`` for the
    three planets of one set moving alike, else joined by ``/``."""
    amplitude = np.abs(np.asarray(shape))
    tied = [n for n, a in zip(names, amplitude) if a >= (1.0 - 1e-6) * amplitude.max()]
    sets = {n.rsplit("_", 1)[-1] for n in tied}
    if len(tied) > 1 and len(sets) == 1 and all(n.startswith("planet") for n in tied):
        return f"planets_{sets.pop()}"
    return "/".join(tied)


def modal_table(params: bb.BackToBackParams | None = None, *, motor: bool = False) -> list[dict]:
    """Natural frequencies [Hz] and mass-normalised shapes of the bench with the meshes at their mean
    stiffness (:func:`back_to_back.linear_system`); ``motor=False``: free bench (one rigid rotation)."""
    modes = modal_analysis(bb.linear_system(params, motor=motor))
    rows = []
    for i, f in enumerate(np.asarray(modes.frequencies_hz)):
        shape = np.asarray(modes.shapes[:, i])
        rows.append(
            dict(
                mode=i + 1,
                frequency_hz=float(f),
                dominant_dof=_dominant(modes.dof_names, shape),
                shape=dict(zip(modes.dof_names, map(float, shape))),
            )
        )
    return rows


def format_modal_table(rows: list[dict]) -> str:
    names = list(rows[0]["shape"])
    lines = [
        "rotations of the reaction set (_R, free ring loaded by the arm) and the test set (_T, ring bolted); "
        "dominant: the DOF of largest amplitude (planets_T: the three planets alike)",
        f"{'mode':>4s} {'f (Hz)':>10s}  {'dominant':12s} shape ({', '.join(names)})",
    ]
    for r in rows:
        lines.append(
            f"{r['mode']:4d} {r['frequency_hz']:10.2f}  {r['dominant_dof']:12s} "
            + " ".join(f"{v:+.2e}" for v in r["shape"].values())
        )
    return "\n".join(lines)


def format_ridges(ridges: dict) -> str:
    """Plain-text lines of the STFT ridge checks of a study (``BackToBackStudy.ridges``)."""
    return "\n".join(
        f"STFT ridge {name:10s} {label:36s} order {c['order']}: max |ridge - k Z_r f_c| / (k Z_r f_c) = "
        f"{100 * c['max_relative_error']:.2f} %"
        for name, checks in ridges.items()
        for label, c in checks.items()
    )


def format_hertz(h: dict) -> str:
    qa, qb = h["quasi_static"]["zone_A"], h["quasi_static"]["end_of_run_up"]
    lines = [
        f"mean Hertzian stiffness in N/m (Eq. 13 secant, summed over pairs), W = "
        f"{h['assumptions']['face_width_m'] * 1e3:g} mm; A: the paper's zone A (start of the run-up), end: the "
        "end of the run-up",
        f"{'':14s} {'model A':>10s} {'model end':>10s} {'paper A':>10s} {'paper end':>10s}",
    ]
    for key, paper in (("sun_planet", h["paper"]["sun_planet"]), ("ring_planet", h["paper"]["ring_planet"])):
        lines.append(
            f"{key:14s} {qa[key]['hertz_secant']:10.3e} {qb[key]['hertz_secant']:10.3e} "
            f"{paper[0]:10.3e} {paper[1]:10.3e}   (quasi-static, {qa['torque_Nm']:g} -> {qb['torque_Nm']:g} N m)"
        )
        if "dynamic" in h:
            d = h["dynamic"]
            lines.append(f"{'  dynamic':14s} {d['zone_A'][key]:10.3e} {d['end'][key]:10.3e}")
    lines.append(
        f"load factor the paper's rise needs: sun {h['load_factor_for_paper_rise']['sun_planet']:.2f}, "
        f"ring {h['load_factor_for_paper_rise']['ring_planet']:.2f}; face width matching the paper's zone-A "
        f"sun value: {h['face_width_for_paper_zone_A_sun_m'] * 1e3:.1f} mm"
    )
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ outputs


def _mesh_arrays(reg: RegimeResult) -> dict:
    m = reg.mesh
    return dict(
        times=reg.times,
        phase=np.asarray(m.phase),
        transmission_error=np.asarray(m.transmission_error),
        force=np.asarray(m.force),
        mesh_stiffness=np.asarray(m.mesh_stiffness),
        hertz_secant=np.asarray(m.hertz_secant),
        hertz_tangent=np.asarray(m.hertz_tangent),
        pairs_in_contact=np.asarray(m.pairs_in_contact),
        acceleration=reg.acceleration,
        carrier_frequency=reg.carrier_frequency,
        motor_speed=reg.motor_speed,
        motor_torque=reg.motor_torque,
        circulating_torque=reg.circulating_torque,
        contact_names=np.array(bb.CONTACT_NAMES),
        dof_names=np.array(bb.DOF_NAMES),
    )


MESH_UNITS = dict(
    times="s",
    phase="-",
    transmission_error="m",
    force="N",
    mesh_stiffness="N/m",
    hertz_secant="N/m",
    hertz_tangent="N/m",
    pairs_in_contact="-",
    acceleration="m/s^2",
    carrier_frequency="Hz",
    motor_speed="rad/s",
    motor_torque="N m",
    circulating_torque="N m",
)


def hertz_note(h: dict) -> str:
    """One line on why the model's mean Hertzian stiffness lies below the paper's (module docstring)."""
    qa = h["quasi_static"]["zone_A"]
    qb = h["quasi_static"]["end_of_run_up"]
    return (
        f"Below the paper's values: its face width and zone torques are not given (Figs. 4-5 lost); with the "
        f"assumed {h['assumptions']['face_width_m'] * 1e3:g} mm and {qa['torque_Nm']:g} -> {qb['torque_Nm']:g} "
        f"N m, Harsha's law gives these; {h['face_width_for_paper_zone_A_sun_m'] * 1e3:.0f} mm would match the "
        f"zone-A sun value, and the paper's rise needs {h['load_factor_for_paper_rise']['sun_planet']:.1f}x "
        f"the load; its ring/sun ratio ({h['paper_ring_to_sun_ratio']:.2f}, here "
        f"{h['model_ring_to_sun_ratio']:.2f}) is not explained by either"
    )


def _stiffness_units(d: dict) -> dict:
    """``{hertz_secant, hertz_tangent, mesh}`` (N/m) with the unit in every key."""
    return {f"{k}_stiffness_N_per_m" if k == "mesh" else f"{k}_N_per_m": v for k, v in d.items()}


def _hertz_summary(h: dict) -> dict:
    """:func:`hertz_comparison` with a unit in every key (summary.json)."""
    out = dict(
        note=hertz_note(h),
        assumptions=h["assumptions"],
        paper=dict(
            unit="N/m",
            values="mean Hertzian stiffness in zone A and at the end of the run-up",
            sun_planet=list(h["paper"]["sun_planet"]),
            ring_planet=list(h["paper"]["ring_planet"]),
        ),
        quasi_static={
            zone: dict(
                torque_Nm=q["torque_Nm"],
                mesh_load_N=q["mesh_load_N"],
                sun_planet=_stiffness_units(q["sun_planet"]),
                ring_planet=_stiffness_units(q["ring_planet"]),
            )
            for zone, q in h["quasi_static"].items()
        },
        load_factor_for_paper_rise=dict(unit="1 (ratio of mesh loads)", **h["load_factor_for_paper_rise"]),
        face_width_for_paper_zone_A_sun_m=h["face_width_for_paper_zone_A_sun_m"],
        paper_ring_to_sun_ratio=h["paper_ring_to_sun_ratio"],
        model_ring_to_sun_ratio=h["model_ring_to_sun_ratio"],
    )
    if "dynamic" in h:
        d = h["dynamic"]
        out["dynamic"] = dict(
            unit="N/m",
            zone_A=dict(d["zone_A"]),
            end=dict(d["end"]),
            windows_s=d["windows_s"],
        )
    return out


def summary_dict(study: BackToBackStudy) -> dict:
    """The content of ``summary.json`` (every number with its unit, :mod:`pgtjax._summary`)."""
    settings = dict(study.settings)
    return dict(
        settings=dict(
            dt_s=settings.get("dt_s"),
            t_end_s=settings.get("t_end_s"),
            stationary_t_end_s=settings.get("stationary_t_end_s"),
            save_every_count=settings.get("save_every"),
            stft_window_s=settings.get("stft_window_s"),
        ),
        hertz=_hertz_summary(study.hertz),
        ridges=dict(
            unit="1 (order k of the line k Z_r f_c)",
            definition="largest |ridge - k Z_r f_c| / (k Z_r f_c) over the STFT frames",
            **{
                k: {
                    kk: dict(order=vv["order"], max_relative_error_ratio=vv["max_relative_error"])
                    for kk, vv in v.items()
                }
                for k, v in study.ridges.items()
            },
        ),
        modes_free_bench=dict(
            unit="1 (mode number)",
            rows=[
                dict(mode=r["mode"], frequency_hz=r["frequency_hz"], dominant_dof=r["dominant_dof"])
                for r in study.modes
            ],
        ),
        wall_s={r.name: r.wall_s for r in study.regimes},
    )


def write_outputs(study: BackToBackStudy, outdir) -> list[Path]:
    """Trajectories (``save_results``), mesh histories (``.npz`` with names and ``units``), summary JSON, PNGs."""
    import matplotlib.pyplot as plt

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    for reg in study.regimes:
        p = reg.model.params
        attrs = dict(
            regime=reg.name,
            dt_s=reg.dt,
            coordinates="u = r_b theta (m); theta = u / radius",
            radii_m=[float(x) for x in reg.model.radii],
            speed_rpm=[float(p.speed_start) / bb.RPM, float(p.speed_end) / bb.RPM],
            circulating_torque_Nm=[float(p.sun_torque), float(p.torque_end)],
            ramp_s=[float(p.ramp_start), float(p.ramp_duration)],
            half_backlash_m=float(p.half_backlash),
        )
        written.append(save_results(outdir / f"{reg.name}_trajectory.npz", reg.trajectory, **attrs))
        path = outdir / f"{reg.name}_mesh.npz"
        arrays = _mesh_arrays(reg)
        write_atomic(path, lambda p: np.savez_compressed(p, units=np.array(json.dumps(MESH_UNITS)), **arrays))
        written.append(path)
        written += _figures(reg, outdir, study.settings.get("stft_window_s", 0.1), study.hertz)
    written.append(write_summary(outdir / "summary.json", summary_dict(study)))
    plt.close("all")
    return written


def envelope_window(t) -> float:
    """20 ms (several mesh periods), shortened for a short run: the window of :func:`draw_per_window`."""
    return min(0.02, float(t[-1] - t[0]) / 4.0)


def draw_per_window(ax, t, x, window: float, color: str, label: str = "") -> None:
    """A signal of many mesh periods, which a line would draw as a solid band with moiré: per ``window`` (s)
    its range (shaded) and mean (line), or the signal itself when it spans few windows."""
    t, x = np.asarray(t, float), np.asarray(x, float)
    if t[-1] - t[0] < plots.MAX_DRAWN_CYCLES * window:
        ax.plot(t, x, lw=0.6, color=color, label=label or "instantaneous")
        return
    tc, lo, hi, avg = plots.cycle_envelope(t, x, window)
    what = f"{label}: " if label else ""
    ax.fill_between(tc, lo, hi, color=color, alpha=0.3, lw=0, label=f"{what}range per {window * 1e3:.0f} ms")
    ax.plot(
        tc, avg, color="tab:red" if not label else color, lw=1.2, label=f"{what}{window * 1e3:.0f} ms mean"
    )


def _figures(reg: RegimeResult, outdir: Path, window_s: float, hertz: dict | None = None) -> list[Path]:
    import textwrap

    import matplotlib.pyplot as plt

    t = reg.times
    js, jr = bb.CONTACT_NAMES.index("sun-planet1_T"), bb.CONTACT_NAMES.index("ring-planet1_T")
    regime = reg.name.replace("_", "-")
    out = []
    with plt.rc_context(plots.STYLE):
        fig, ax = plt.subplots(3, 1, figsize=(6.0, 6.0), sharex=True, layout="constrained")
        ax[0].plot(
            t,
            reg.carrier_frequency * 60.0 / bb.carrier_ratio(reg.model.params),
            color="tab:orange",
            lw=0.6,
            label="test carrier × (Z_s+Z_r)/Z_s",
        )
        ax[0].plot(
            t, reg.motor_speed / bb.RPM, color="tab:blue", lw=1.4, zorder=3, label="motor (prescribed)"
        )
        ax[0].set_ylabel("speed (rpm)")
        ax[1].plot(t, reg.circulating_torque, label="circulating (test sun)")
        ax[1].plot(t, reg.motor_torque, lw=0.6, label="motor shaft")
        ax[1].set_ylabel("torque (N m)")
        ax[2].plot(t, reg.mesh_frequency)
        ax[2].set_ylabel("mesh frequency Z_r f_c (Hz)")
        ax[2].set_xlabel("time (s)")
        for a in ax[:2]:
            a.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        for a in ax:
            a.ticklabel_format(axis="y", useOffset=False)
        fig.suptitle(f"{regime}: operating conditions (test carrier from the simulated speed)", fontsize=9)
        out.append(plots.save(fig, outdir / f"{reg.name}_operating.png"))

        fig, ax = plt.subplots(2, 2, figsize=(8.0, 5.6), sharex=True, layout="constrained")
        window = envelope_window(t)
        paper = {js: PAPER_HS_SUN, jr: PAPER_HS_RING}
        for col, (j, name) in enumerate(((js, "sun-planet 1"), (jr, "ring-planet 1"))):
            for row, series in enumerate((reg.mesh.hertz_secant, reg.mesh.mesh_stiffness)):
                draw_per_window(ax[row, col], t, np.asarray(series[:, j]) * 1e-9, window, "tab:blue")
            values = paper[j] if reg.name == "run_up" else paper[j][:1]
            for k, v in enumerate(values):
                ax[0, col].axhline(
                    v * 1e-9,
                    color="k",
                    ls="--" if k == 0 else ":",
                    lw=1.0,
                    label=("paper mean, zone A" if k == 0 else "paper mean, end of run-up"),
                )
            ax[0, col].set_title(f"{name} (test set)")
            ax[0, col].set_ylabel("Hertzian stiffness (GN/m)")
            ax[1, col].set_ylabel("mesh stiffness (GN/m)")
            ax[1, col].set_xlabel("time (s)")
        handles, labels = ax[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), frameon=False)
        title = (
            f"{regime}: mesh stiffness of the test set (Hertzian: Eq. 13 secant summed over pairs in contact)"
        )
        if hertz is not None:
            title += "\n" + textwrap.fill(hertz_note(hertz).replace(" N m", "\u00a0N\u00a0m"), 130)
        fig.suptitle(title, fontsize=9)
        out.append(plots.save(fig, outdir / f"{reg.name}_stiffness.png"))

        fig, ax = plt.subplots(3, 1, figsize=(6.4, 6.0), sharex=True, layout="constrained")
        draw_per_window(ax[0], t, np.asarray(reg.mesh.transmission_error[:, jr]) * 1e6, window, "tab:blue")
        ax[0].set_ylabel("TE (µm)")
        draw_per_window(ax[1], t, np.asarray(reg.mesh.force[:, jr]) * 1e-3, window, "tab:blue")
        ax[1].set_ylabel("mesh force (kN)")
        for (name, label), color in zip(
            (("ring_T", "test ring (ring_T)"), ("ring_R", "reaction ring (ring_R)")),
            ("tab:blue", "tab:orange"),
        ):
            draw_per_window(ax[2], t, reg.acceleration[:, bb.DOF_NAMES.index(name)], window, color, label)
        ax[2].set_ylabel("acceleration (m/s²)")
        ax[2].set_xlabel("time (s)")
        handles, labels = ax[0].get_legend_handles_labels()
        more, more_labels = ax[2].get_legend_handles_labels()
        labels = [f"TE and force: {label}" for label in labels]  # which panels each entry belongs to
        more_labels = [f"acceleration, {label}" for label in more_labels]
        fig.legend(handles + more, labels + more_labels, loc="outside lower center", ncol=2, frameon=False)
        for a in ax:
            a.ticklabel_format(axis="y", useOffset=False)
        fig.suptitle(
            f"{regime}: transmission error and mesh force of ring-planet 1 (test set), ring accelerations "
            "(tangential, at the base radius)",
            fontsize=9,
        )
        out.append(plots.save(fig, outdir / f"{reg.name}_te_force_acceleration.png"))

        fs = 1.0 / float(t[1] - t[0])
        for label, signal, orders, what in (
            (
                "ring_T_acceleration",
                reg.acceleration[:, bb.DOF_NAMES.index("ring_T")],
                (3, 6, 9),
                "test-ring acceleration",
            ),
            (
                "te_ring_planet1",
                np.asarray(reg.mesh.transmission_error[:, jr]),
                (1, 2, 3),
                "transmission error ring-planet 1",
            ),
        ):
            ft, f, a = stft(signal, fs, window_s)
            fig, axs = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
            top = min(fs / 2, 1.3 * max(orders) * float(reg.mesh_frequency.max()))
            keep = f <= top
            db = 20 * np.log10(a[:, keep].T + 1e-30)
            db = db - db.max()
            mesh = axs.pcolormesh(ft + t[0], f[keep], db, shading="auto", vmin=-60.0, vmax=0.0)
            fig.colorbar(mesh, ax=axs, label="amplitude (dB re maximum)")
            fm = frame_average(t, reg.mesh_frequency, ft + t[0], window_s)
            for i, k in enumerate(orders):
                axs.plot(
                    ft + t[0],
                    k * fm,
                    "w--",
                    lw=0.5,
                    alpha=0.5,
                    label="k Z_r f_c (frame means)" if i == 0 else None,
                )
                axs.annotate(
                    f"k = {k}",
                    (ft[0] + t[0], k * fm[0]),
                    xytext=(3, 3),
                    textcoords="offset points",
                    color="w",
                    fontsize=7,
                )
            axs.grid(False)
            axs.set_xlim(ft[0] + t[0], ft[-1] + t[0])
            axs.set_xlabel("time (s), frame centres")
            axs.set_ylabel("frequency (Hz)")
            axs.set_title(
                f"{regime}: STFT of the {what}, {window_s * 1e3:.0f} ms Hann window; dashed: k Z_r f_c"
            )
            out.append(plots.save(fig, outdir / f"{reg.name}_stft_{label}.png"))
    return out
