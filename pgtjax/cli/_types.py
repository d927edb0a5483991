"""Argument types shared by the command-line modules (argparse ``type=`` callables with clear messages)
and the parsing of comma-separated option values."""

from __future__ import annotations

import argparse


def _number(kind, text: str, accepted: str, ok):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {accepted}, got {text!r}") from None
    if not ok(value):
        raise argparse.ArgumentTypeError(f"must be {accepted}, got {value}")
    return value


def nonneg_int(text: str) -> int:
    return _number(int, text, "an integer >= 0", lambda v: v >= 0)


def positive_int(text: str) -> int:
    return _number(int, text, "an integer >= 1", lambda v: v >= 1)


def positive_float(text: str) -> float:
    return _number(float, text, "a number > 0", lambda v: v > 0)


def nonneg_float(text: str) -> float:
    return _number(float, text, "a number >= 0", lambda v: v >= 0)


def csv_floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def csv_ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def csv_names(text: str) -> tuple[str, ...]:
    """``"force, energy"`` -> ``("force", "energy")`` (blank entries dropped)."""
    return tuple(c.strip() for c in text.split(",") if c.strip())
