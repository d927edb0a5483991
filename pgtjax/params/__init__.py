"""Embedded parameter files (TOML) of the documents' models."""

import tomllib
from importlib import resources
from pathlib import Path


def path(name: str) -> Path:
    """Path of an embedded parameter file, e.g. ``path("gear_pair.toml")``."""
    return Path(str(resources.files(__name__).joinpath(name)))


def read_toml(path) -> dict:
    """Read a parameter file; a missing file or invalid TOML is a ``ValueError`` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"parameter file `{path}` not found: it does not exist")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"parameter file `{path}` is not valid TOML: {err}") from None
