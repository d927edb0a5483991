"""Argument types shared by the command-line modules (argparse ``type=`` callables with clear messages)
and the parsing of comma-separated option values."""

from __future__ import annotations

import argparse
import math

from .. import AbstractCriterion, EnergyCriterion, ForceCriterion


def _number(kind, text: str, accepted: str, ok):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {accepted}, got {text!r}") from None
    if (kind is float and not math.isfinite(value)) or not ok(value):
        raise argparse.ArgumentTypeError(f"must be {accepted}, got {value}")
    return value


def seed(text: str) -> int:
    """A PRNG seed: an integer that fits in 64 bits (JAX's seeds are int64)."""
    return _number(int, text, "an integer from -2^63 to 2^63 - 1", lambda v: -(2**63) <= v < 2**63)


def element_count(text: str) -> int:
    return _number(int, text, "an integer >= 3", lambda v: v >= 3)


def nonneg_int(text: str) -> int:
    return _number(int, text, "an integer >= 0", lambda v: v >= 0)


def sample_count(text: str) -> int:
    """Monte Carlo samples of a study: 0 skips Monte Carlo; statistics need at least 2."""
    return _number(int, text, "0 (no Monte Carlo) or an integer >= 2", lambda v: v == 0 or v >= 2)


def positive_int(text: str) -> int:
    return _number(int, text, "an integer >= 1", lambda v: v >= 1)


def positive_float(text: str) -> float:
    return _number(float, text, "a number > 0", lambda v: v > 0)


def nonneg_float(text: str) -> float:
    return _number(float, text, "a number >= 0", lambda v: v >= 0)


def csv_floats(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def csv_positive_floats(text: str) -> tuple[float, ...]:
    """At least one comma-separated finite number, each > 0."""
    values = csv_floats(text)
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers > 0 (at least one), got {text!r}")
    return values


def csv_nonneg_floats(text: str) -> tuple[float, ...]:
    """Comma-separated finite numbers, each >= 0 (times in s)."""
    values = csv_floats(text)
    if values and min(values) < 0:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers >= 0, got {text!r}")
    return values


def csv_ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def csv_names(text: str) -> tuple[str, ...]:
    """``"force, energy"`` -> ``("force", "energy")`` (blank entries dropped)."""
    return tuple(c.strip() for c in text.split(",") if c.strip())


# the CLI's names of the SL criteria: the one place a name becomes a criterion object
CRITERIA = {"force": ForceCriterion, "energy": EnergyCriterion}


def criteria(text: str) -> tuple[AbstractCriterion, ...]:
    """Comma-separated SL criteria, at least one, each ``force`` or ``energy``: their objects, in order."""
    names = csv_names(text)
    if "energy_origin" in names:
        raise argparse.ArgumentTypeError(
            "'energy_origin' (thesis Eq. 4.43 as printed, the potential measured about the origin) is not "
            "offered: under a static load it overestimates k_e by (mu - b)^2 / (3 sigma^2) and its fixed point "
            "can settle on a spurious branch; 'energy' equals Eq. 4.43 wherever |mu| <= b (docs/corrections.md, C1)"
        )
    if not names or any(c not in CRITERIA for c in names):
        raise argparse.ArgumentTypeError(
            f"expected comma-separated SL criteria among {', '.join(CRITERIA)}, got {text!r}"
        )
    return tuple(CRITERIA[c]() for c in names)
