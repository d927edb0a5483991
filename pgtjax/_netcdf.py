"""Results as labelled ``xarray.Dataset`` objects and netCDF files, which xarray, ncview, Panoply, MATLAB's
``ncread`` or ParaView open without pgtjax.

Dimensions: ``time`` (s), ``dof`` (with the coordinate ``dof_unit``), ``contact``, ``observable``, and for a
covariance ``cov_row``/``cov_col`` (``covariance_dofs``' displacements then velocities). Every variable has a
``units`` attribute. A Dataset keeps what :func:`pgtjax.load_results` needs to rebuild the result (attribute
``pgtjax_meta``), so ``save_results(path.nc)`` / ``load_results(path.nc)`` round-trip exactly, as ``.npz`` does.

xarray and h5netcdf are optional: ``pip install "pgtjax[netcdf]"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

_DOF_FIELDS = ("mean_u", "std_u", "mean_v", "std_v", "u", "v", "cov_u_lag")
_CONTACT_FIELDS = {
    "mean_delta": "m",
    "std_delta": "m",
    "force_mean": "N",
    "force_std": "N",
    "force": "N",
    "delta": "m",
    "k_e": "N/m",
    "f_0": "N",
    "contact_loss_probability": "1",
    "cov_delta_lag": "m^2",
}
_TIME_FIELDS = {"iterations": "1", "residual": "1", "converged": "1"}


def _xarray():
    try:
        import xarray
    except ImportError:
        raise ImportError(
            'netCDF results and to_xarray need xarray and h5netcdf: pip install "pgtjax[netcdf]"'
        ) from None
    return xarray


def _units(name: str, value) -> str:
    if name == "cov_u_lag":
        return "see dof_unit, squared"
    if name in _DOF_FIELDS:
        return "see dof_unit" + ("; per second" if name.endswith("v") else "")
    if name in _CONTACT_FIELDS:
        return _CONTACT_FIELDS[name]
    if name in ("mean_obs", "std_obs"):
        return "the observable's (a combination of the DOFs: m for the ring's displacements)"
    if name == "cov_obs_lag":
        return "the observable's, squared"
    if name == "covariance":
        return "products of the cov_row and cov_col DOFs' units (velocities: per second)"
    if name in ("times", "histogram_times"):
        return "s"
    return _TIME_FIELDS.get(name, "1")


def to_xarray(result, **attributes):
    """``result`` (``MomentResult``, ``MonteCarloResult`` or ``Trajectory``) as an ``xarray.Dataset`` with
    named dimensions and units; ``attributes`` (JSON-serialisable) are kept in ``attrs``."""
    from ._results import _to_numpy_dict

    xr = _xarray()
    arrays, meta = _to_numpy_dict(result)
    meta["attributes"] = attributes
    n_times = arrays["times"].shape[0]
    cov_names = [f"{n}_u" for n in meta.get("covariance_dofs", ())] + [
        f"{n}_v" for n in meta.get("covariance_dofs", ())
    ]
    coords = {
        "time": ("time", arrays["times"], {"units": "s"}),
        "dof": ("dof", np.asarray(meta["dof_names"], dtype=str)),
        "dof_unit": ("dof", np.asarray(meta["dof_units"], dtype=str)),
        "contact": ("contact", np.asarray(meta["contact_names"], dtype=str)),
    }
    if meta.get("observable_names"):
        coords["observable"] = ("observable", np.asarray(meta["observable_names"], dtype=str))
    if cov_names:
        coords["cov_row"] = ("cov_row", np.asarray(cov_names, dtype=str))
        coords["cov_col"] = ("cov_col", np.asarray(cov_names, dtype=str))
    variables, dict_keys = {}, {}
    for name, value in arrays.items():
        if name == "times":
            continue
        if "/" in name:  # an entry of a dict field (Monte Carlo histograms): numbered, keys in the meta
            field, key = name.split("/", 1)
            keys = dict_keys.setdefault(field, [])
            keys.append(key)
            var = f"{field}_{len(keys) - 1}"
            dims = tuple(f"{var}_dim{i}" for i in range(value.ndim))
            unit = (
                "the quantity's (m for deflections, N for forces)"
                if field in ("histogram_edges", "peak_edges")
                else "1 (count)"
            )
            variables[var] = (dims, value, {"units": unit, "long_name": f"{field}[{key!r}]"})
            continue
        if name in _DOF_FIELDS:
            dims = ("time", "dof")
        elif name in _CONTACT_FIELDS and value.ndim == 2 and value.shape[0] == n_times:
            dims = ("time", "contact")
        elif name in ("mean_obs", "std_obs", "cov_obs_lag"):
            dims = ("time", "observable")
        elif name == "covariance":
            dims = ("time", "cov_row", "cov_col")
        elif value.ndim == 1 and value.shape[0] == n_times:
            dims = ("time",)
        else:
            dims = tuple(f"{name}_dim{i}" for i in range(value.ndim))
        if value.dtype == bool:
            value = value.astype(np.int8)
            meta.setdefault("booleans", []).append(name)
        variables[name] = (dims, value, {"units": _units(name, value)})
    meta["dict_keys"] = dict_keys
    attrs = {
        "title": f"pgtjax {meta['class']}",
        "pgtjax_meta": json.dumps(meta),
        "pgtjax_attributes": json.dumps(attributes),
    }
    return xr.Dataset(variables, coords=coords, attrs=attrs)


def write_netcdf(path: Path, result, attributes: dict) -> None:
    """:func:`to_xarray` written to ``path`` (netCDF-4 through h5netcdf)."""
    to_xarray(result, **attributes).to_netcdf(path, engine="h5netcdf")


def read_netcdf(path: Path) -> tuple[dict, dict]:
    """``(arrays, meta)`` of a file written by :func:`write_netcdf`, as :func:`pgtjax.load_results` reads an
    ``.npz`` file's."""
    xr = _xarray()
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        meta = json.loads(ds.attrs["pgtjax_meta"])
        arrays = {"times": np.asarray(ds["time"].values, dtype=np.float64)}
        for field, keys in meta.pop("dict_keys", {}).items():
            for i, key in enumerate(keys):
                arrays[f"{field}/{key}"] = np.asarray(ds[f"{field}_{i}"].values)
        booleans = set(meta.pop("booleans", []))
        for name in ds.data_vars:
            if name.rsplit("_", 1)[0] in meta.get("dicts", []) and name.rsplit("_", 1)[-1].isdigit():
                continue
            value = np.asarray(ds[name].values)
            arrays[name] = value.astype(bool) if name in booleans else value
    return arrays, meta
