"""Embedded parameter files (TOML) of the documents' models."""

from importlib import resources
from pathlib import Path


def path(name: str) -> Path:
    """Path of an embedded parameter file, e.g. ``path("gear_pair.toml")``."""
    return Path(str(resources.files(__name__).joinpath(name)))
