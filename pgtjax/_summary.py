"""Units in ``summary.json``: every number a study writes carries its unit, by one rule a reader can apply.

A number's unit is named either

* by the suffix of its own key (``dt_s``, ``frequency_Hz``, ``max_std_m``, ``max_mean_error_in_se``; the
  suffixes are :data:`UNIT_SUFFIXES`), or
* by a ``"units"`` object, which maps key names to units for its own object and everything inside it
  (the nearest such mapping wins; it overrides a key's suffix), or
* by the ``"unit"`` entry (a string) of the nearest enclosing object (lists count as their key's).

A unit named by a key (suffix or mapping) also holds for everything inside that key's value, and takes
precedence there over a ``"unit"`` entry further in: name units as close to the numbers as you can.

Booleans, strings and ``null`` need none. :func:`write_summary` refuses a summary with a number that has no
unit (a programming error of the study, caught by every test that runs one).
"""

from __future__ import annotations

import numbers
from pathlib import Path

import numpy as np

from ._files import write_json

#: key suffix -> unit. Longest suffixes are tried first, so ``_N_per_m`` wins over ``_m``.
UNIT_SUFFIXES = {
    "_s": "s",
    "_ms": "ms",
    "_Hz": "Hz",
    "_hz": "Hz",
    "_rad_per_s": "rad/s",
    "_rpm": "rpm",
    "_m": "m",
    "_um": "µm",
    "_mm": "mm",
    "_rad": "rad",
    "_N": "N",
    "_kN": "kN",
    "_Nm": "N m",
    "_N_per_m": "N/m",
    "_m_per_N": "m/N",
    "_Pa": "Pa",
    "_MPa": "MPa",
    "_kg": "kg",
    "_in_se": "Monte Carlo standard errors",
    "_ratio": "1 (dimensionless ratio)",
    "_fraction": "1 (fraction)",
    "_percent": "%",
    "_probability": "1 (probability)",
    "_count": "1 (count)",
    "_dimensionless": "1",
}
_BY_LENGTH = sorted(UNIT_SUFFIXES, key=len, reverse=True)

#: the rule, written into every summary so that the file explains itself
CONVENTION = (
    "Every number's unit is named by the suffix of its key (_s seconds, _Hz or _hz hertz, _m metres, "
    "_N newtons, _Nm newton metres, _N_per_m N/m, _m_per_N m/N, _rad radians, _rad_per_s rad/s, _rpm, _kg, _Pa, _in_se Monte Carlo "
    "standard errors, _ratio/_fraction/_probability/_count/_dimensionless: 1), or by a 'units' object, which "
    "maps key names to units inside the object that holds it, or by the 'unit' entry of the nearest "
    "enclosing object."
)


def unit_of_key(key: str) -> str | None:
    """The unit a key's suffix names, or ``None``."""
    for suffix in _BY_LENGTH:
        if key.endswith(suffix) and len(key) > len(suffix):
            return UNIT_SUFFIXES[suffix]
    return None


def _is_number(value) -> bool:
    """A number JSON will write: Python's, NumPy's (0-d arrays too) and JAX scalars; not a bool."""
    if isinstance(value, bool | np.bool_):
        return False
    if isinstance(value, numbers.Number):
        return True
    dtype = getattr(value, "dtype", None)  # NumPy and JAX arrays and scalars
    return dtype is not None and np.ndim(value) == 0 and np.dtype(dtype).kind in "iuf"


def missing_units(
    data, path: str = "", inherited: str | None = None, mapping: dict | None = None
) -> list[str]:
    """Paths (``a.b[2].c``) of the numbers in ``data`` (JSON-like) whose unit is named nowhere."""
    missing = []
    mapping = dict(mapping or {})
    if isinstance(data, dict):
        own = data.get("unit") if isinstance(data.get("unit"), str) else None
        if isinstance(data.get("units"), dict):
            mapping.update({k: v for k, v in data["units"].items() if isinstance(v, str)})
        for key, value in data.items():
            if (key == "unit" and isinstance(value, str)) or (key == "units" and isinstance(value, dict)):
                continue
            unit = mapping.get(key) or unit_of_key(str(key))
            here = f"{path}.{key}" if path else str(key)
            missing += missing_units(value, here, unit or own or inherited, mapping)
    elif isinstance(data, (list, tuple)):
        for i, value in enumerate(data):
            missing += missing_units(value, f"{path}[{i}]", inherited, mapping)
    elif _is_number(data):
        if inherited is None:
            missing.append(path)
    return missing


def write_summary(path, summary: dict) -> Path:
    """Check that every number of ``summary`` carries a unit, add the convention, write it atomically."""
    summary = {"units_convention": CONVENTION, **summary}
    missing = missing_units(summary)
    if missing:
        shown = ", ".join(missing[:8]) + (f" and {len(missing) - 8} more" if len(missing) > 8 else "")
        raise ValueError(f"summary.json: numbers without a unit: {shown}")
    return write_json(path, summary)
