"""Result files: atomic writes, the returned path, and clear errors for anything that is not a result."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import pgtjax as pg


def small_result():
    system = pg.System(
        mass=[[1.0]], stiffness=[[4.0]], damping=[[0.2]], noise_input=[[1.0]], spectral_density=1e-3
    )
    return pg.solve_moments(system, dt=1e-2, n_steps=20, save_every=10)


def test_path_without_suffix_returns_the_file_written(tmp_path):
    path = pg.save_results(tmp_path / "run", small_result())
    assert path == tmp_path / "run.npz" and path.exists()
    assert pg.load_results(path)[0].std_u.dtype == np.float64
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]  # no temporary file left


@pytest.mark.parametrize(
    "content, what",
    [
        (b"", "empty"),
        (b"PK\x03\x04 truncated zip", "truncated"),
        (b"hello, not numpy", "foreign"),
    ],
)
def test_unreadable_files_raise_value_error_naming_the_file(tmp_path, content, what):
    bad = tmp_path / f"{what}.npz"
    bad.write_bytes(content)
    with pytest.raises(ValueError, match=f"{what}.npz"):
        pg.load_results(bad)


def test_foreign_npz_and_missing_file(tmp_path):
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.arange(3))
    with pytest.raises(ValueError, match="foreign.npz.*not a readable pgtjax result"):
        pg.load_results(foreign)
    with pytest.raises(ValueError, match="missing.npz.*does not exist"):
        pg.load_results(tmp_path / "missing.npz")
    good = pg.save_results(tmp_path / "good.npz", small_result())
    raw = good.read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="cut.npz"):
        pg.load_results(tmp_path / "cut.npz")


@pytest.mark.slow
def test_a_process_killed_while_overwriting_leaves_the_old_file_loadable(tmp_path):
    target = tmp_path / "result.npz"
    pg.save_results(target, small_result(), version="old")
    script = textwrap.dedent(
        f"""
        import numpy as np, pgtjax as pg
        # a large result (many saved times, a full covariance), written over and over
        system = pg.System(mass=np.eye(40), stiffness=np.eye(40) * 4.0, damping=np.eye(40) * 0.2,
                           noise_input=np.eye(40)[:, :1], spectral_density=1e-3)
        res = pg.solve_moments(system, dt=1e-3, n_steps=4000, save_every=1, covariance_dofs="all")
        print("ready", flush=True)
        while True:
            pg.save_results({str(target)!r}, res, version="new")
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    for delay in (0.05, 0.13, 0.31):  # kill at a few points of the write cycle
        time.sleep(delay)
        _, attributes = pg.load_results(target)  # readable at any moment
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    result, attributes = pg.load_results(target)
    assert attributes["version"] in ("old", "new") and result.std_u.dtype == np.float64
    assert os.path.getsize(target) > 0


def _assert_same_result(a, b):
    assert type(a) is type(b)
    for name in a.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, dict):
            assert x.keys() == y.keys(), name
            for key in x:
                np.testing.assert_array_equal(np.asarray(x[key]), np.asarray(y[key]))
        elif hasattr(x, "dtype"):
            assert np.asarray(x).dtype == np.asarray(y).dtype, name
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=name)
        else:
            assert x == y, name


@pytest.mark.slow
def test_deflection_lag_round_trips_with_its_unit(tmp_path):
    """An SL result with each deflection's, displacement's and observable's covariance with the step before
    (solve_moments(deflection_lag=True)) read back equal from .npz and .nc, the .nc variables with their units;
    one without them reads back with None."""
    import xarray as xr

    from pgtjax.models import gear_pair

    system = gear_pair.build()
    observables = pg.Observables([[1.0, -1.0, 0.0]], names=["y1_minus_y2"])
    with_lag = pg.solve_moments(system, dt=1e-5, n_steps=40, deflection_lag=True, observables=observables)
    assert with_lag.cov_obs_lag.shape == (41, 1) and with_lag.cov_obs_lag.dtype == np.float64
    assert with_lag.cov_delta_lag.shape == (41, 1) and with_lag.cov_delta_lag.dtype == np.float64
    assert with_lag.cov_u_lag.shape == (41, system.n_dof) and with_lag.cov_u_lag.dtype == np.float64
    for suffix in (".npz", ".nc"):
        back, _ = pg.load_results(pg.save_results(tmp_path / f"sl{suffix}", with_lag))
        _assert_same_result(with_lag, back)
    with xr.open_dataset(tmp_path / "sl.nc", engine="h5netcdf") as ds:
        assert ds["cov_delta_lag"].dims == ("time", "contact") and ds["cov_delta_lag"].attrs["units"] == "m^2"
        assert ds["cov_obs_lag"].dims == ("time", "observable")
        assert ds["cov_obs_lag"].attrs["units"] == "the observable's, squared"
        assert (
            ds["cov_u_lag"].dims == ("time", "dof")
            and ds["cov_u_lag"].attrs["units"] == "see dof_unit, squared"
        )
    back, _ = pg.load_results(pg.save_results(tmp_path / "plain.npz", small_result()))
    assert back.cov_delta_lag is None and back.cov_u_lag is None and back.cov_obs_lag is None


def test_netcdf_round_trip_and_labelled_dataset(tmp_path):
    """A Monte Carlo result with histograms and a covariance, an SL result and a trajectory written as .nc
    read back equal to the bit; the file opened by xarray alone (no pgtjax) has named dimensions, labels and
    units."""
    import jax
    import xarray as xr  # a dev dependency (the netcdf extra)
    from _mc_worker import run

    from pgtjax.models import gear_pair

    mc = run(key=jax.random.key(3), peak_start=5e-4)  # a static field: the peaks' start (s)
    assert mc.peak_start == pytest.approx(5e-4, abs=1e-15)
    system = gear_pair.build()
    trajectory = pg.simulate(system, dt=1e-5, n_steps=30, save_every=10)
    for name, result in [("mc", mc), ("sl", small_result()), ("trajectory", trajectory)]:
        path = pg.save_results(tmp_path / f"{name}.nc", result, dt_s=1e-5, note=name)
        assert path.suffix == ".nc"
        back, attributes = pg.load_results(path)
        _assert_same_result(result, back)
        assert attributes == {"dt_s": 1e-5, "note": name}
    with xr.open_dataset(tmp_path / "mc.nc", engine="h5netcdf") as ds:
        assert ds["std_u"].dims == ("time", "dof") and ds["force_mean"].dims == ("time", "contact")
        assert list(ds["dof"].values) == list(mc.dof_names) and ds["time"].attrs["units"] == "s"
        assert ds["force_std"].attrs["units"] == "N" and ds["covariance"].dims == (
            "time",
            "cov_row",
            "cov_col",
        )
        np.testing.assert_array_equal(ds["std_u"].sel(dof=mc.dof_names[0]).values, np.asarray(mc.std_u[:, 0]))
        assert ds["std_u"].dtype == np.float64
        units = {
            v.attrs["long_name"]: v.attrs["units"] for v in ds.data_vars.values() if "long_name" in v.attrs
        }
        assert units["peak_edges['delta:mesh']"].startswith("the quantity's")
        assert units["peak_histograms['delta:mesh']"] == "1 (count)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mc.nc", "sl.nc", "trajectory.nc"]
    with pytest.raises(ValueError, match="not a readable pgtjax result"):
        (tmp_path / "bad.nc").write_bytes(b"not netcdf")
        pg.load_results(tmp_path / "bad.nc")
