"""Embedded parameter files (TOML) of the documents' models."""

import copy
import json
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any


def path(name: str) -> Path:
    """Path of an embedded parameter file, e.g. ``path("gear_pair.toml")``."""
    return Path(str(resources.files(__name__).joinpath(name)))


def read_toml(path) -> dict:
    """Read a parameter file; a missing file or invalid TOML is a ``ValueError`` naming the file."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"parameter file `{path}` is a folder, not a TOML file")
    if not path.is_file():
        raise ValueError(f"parameter file `{path}` not found: it does not exist")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"parameter file `{path}` is not valid TOML: {err}") from None


#: the embedded parameter file of each schema
EMBEDDED = {
    "planetary": "planetary.toml",
    "gear_pair": "gear_pair.toml",
    "ring_ch6": "ring_ch6.toml",
    "back_to_back": "back_to_back.toml",
}


def read_params(source, kind: str, overrides: Mapping[str, Any] | None = None) -> dict:
    """A parameter set checked against its schema (:mod:`pgtjax.params._schema`): ``source`` is a TOML file
    (str or Path), the dict of one, or None (the embedded file of ``kind``: ``"planetary"``, ``"gear_pair"``,
    ``"ring_ch6"``, ``"back_to_back"``); ``overrides`` maps dotted names to new values
    (``{"ring.rim_thickness": 0.1}``), applied before the check. Returns the checked dict, optional entries'
    defaults filled in. An unknown key, a missing one, a wrong type, a value out of range or an inconsistent
    combination is a ``ValueError`` naming the file and every offending ``table.key``."""
    from .._config import require_x64
    from ._schema import validate

    require_x64("reading parameters")
    if kind not in EMBEDDED:
        raise ValueError(f"`kind` must be one of {sorted(EMBEDDED)}, got {kind!r}")
    if source is None:
        source = path(EMBEDDED[kind])
    if isinstance(source, str | Path):
        data, where = read_toml(source), f"parameter file `{source}`"
    elif isinstance(source, Mapping):
        data, where = dict(source), "parameters"
    else:
        raise ValueError(
            f"parameters must be a TOML file path, a dict of its tables or None (the embedded {EMBEDDED[kind]}), "
            f"got {type(source).__name__}"
        )
    if overrides:
        data = with_overrides(data, overrides)
        where += " with " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in overrides.items())
    return validate(kind, data, where=where)


def with_overrides(data: dict, overrides: Mapping[str, Any]) -> dict:
    """A copy of the parameter dict ``data`` with ``{"table.key": value}`` set (a missing table is created;
    whether the key exists is for the schema to say, with the nearest known key)."""
    data = copy.deepcopy(data)
    for name, value in overrides.items():
        parts = name.split(".") if isinstance(name, str) else []
        if not parts or not all(p.strip() for p in parts):
            raise ValueError(
                f"a parameter override needs a dotted name such as ring.rim_thickness, got {name!r}"
            )
        table = data
        for i, part in enumerate(parts[:-1]):
            table = table.setdefault(part, {})
            if not isinstance(table, dict):
                raise ValueError(f"override `{name}`: `{'.'.join(parts[: i + 1])}` is a value, not a table")
        table[parts[-1]] = value
    return data


def parse_assignment(text: str) -> tuple[str, Any]:
    """``"ring.rim_thickness=0.1"`` -> ``("ring.rim_thickness", 0.1)``: the value is read as TOML (``0.1``,
    ``"rigid"``, ``[1e9, 2e9]``, ``true``), or kept as a string where it is not TOML (``rigid``)."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise ValueError(f"expected TABLE.KEY=VALUE, e.g. ring.rim_thickness=0.1, got {text!r}")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()
    return name.strip(), parsed


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)  # shortest text that reads back to the same double
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):  # an inline table
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise ValueError(f"cannot write {value!r} ({type(value).__name__}) to a parameter file")


def _is_table_array(value) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _table_lines(name: str, table: dict, brackets: str) -> list[str]:
    lines = ["", f"{brackets[0]}{name}{brackets[1]}"]
    for key, value in table.items():
        if _is_table_array(value):
            raise ValueError(f"an array of tables inside a table ({name}.{key}) is not supported")
        lines.append(f"{key} = {_toml_value(value)}")
    return lines


def dumps_toml(data: dict, header: str = "") -> str:
    """TOML text of a parameter dict (top-level values, then one table per sub-dict and an array of tables
    per list of dicts; numbers, strings, booleans and lists of them): what :func:`read_toml` reads back to
    the same dict."""
    lines = [f"# {line}" for line in header.splitlines()]
    for key, value in data.items():
        if not isinstance(value, dict) and not _is_table_array(value):
            lines.append(f"{key} = {_toml_value(value)}")
    for name, value in data.items():
        if isinstance(value, dict):
            lines += _table_lines(name, value, "[]")
        elif _is_table_array(value):
            for table in value:
                lines += _table_lines(name, table, ("[[", "]]"))
    return "\n".join(lines) + "\n"
