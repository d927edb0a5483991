"""Atomic file writes: a temporary name in the target's folder, renamed into place, so that an interrupted
run leaves the previous file (or none), never a truncated one under the final name."""

from __future__ import annotations

import datetime
import fnmatch
import hashlib
import json
import os
import platform
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path


def _pid_is_gone(pid: int) -> bool:
    if os.name == "nt":  # there os.kill(pid, 0) would end the process: assume it lives
        return False
    try:
        os.kill(pid, 0)  # raises if there is no such process
    except (ProcessLookupError, OverflowError):  # no such process (none has a number beyond a C long)
        return True
    except OSError:  # another user's process, or a platform without signals: assume it lives
        return False
    return False


#: a temporary file untouched this long, of a process that no longer exists here, is debris: the age guards
#: against a live writer on another host of a shared file system (or in another pid namespace)
ABANDONED_AFTER_S = 3600.0


def _remove_dead_partials(path: Path) -> None:
    """Remove the temporary files of earlier writes of ``path`` whose process was killed outright."""
    prefix = f".{path.stem}.partial-"
    for old in path.parent.glob(f"{prefix}*{path.suffix}"):
        pid = old.name[len(prefix) : len(old.name) - len(path.suffix)]
        try:
            stale = time.time() - old.stat().st_mtime > ABANDONED_AFTER_S
        except OSError:  # gone meanwhile
            continue
        if stale and pid.isdigit() and _pid_is_gone(int(pid)):
            old.unlink(missing_ok=True)


def _fsync(path: Path, directory: bool = False) -> None:
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except OSError:  # e.g. folders cannot be opened on Windows
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomic(path, write: Callable[[Path], None]) -> Path:
    """Call ``write(temporary_path)`` and rename the result to ``path``; returns ``path``. The file is flushed
    to disk before the rename, so that a crash cannot leave an empty file under the final name; temporary
    files of earlier writes of ``path`` by processes that no longer exist are removed."""
    path = Path(path)
    _remove_dead_partials(path)
    partial = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        write(partial)
        _fsync(partial)
        os.replace(partial, path)
        _fsync(path.parent, directory=True)
    finally:
        partial.unlink(missing_ok=True)
    return path


def write_text(path, text: str) -> Path:
    return write_atomic(path, lambda p: p.write_text(text))


def write_json(path, data) -> Path:
    return write_text(path, json.dumps(data, indent=2, default=float) + "\n")


MANIFEST = "manifest.json"
PREVIOUS = "previous-run"

#: the folder a run is writing now and the output folder being replaced: what an interrupt must report
_state: dict[str, Path | None] = {"staging": None, "publishing": None}


def _digest(path: Path) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def _manifest(out: Path, files: list[Path], in_place: list[Path], status: str, command) -> dict:
    from . import __version__

    def entry(path: Path, kept: bool) -> dict:
        try:
            name = path.resolve().relative_to(out.resolve()).as_posix()
        except ValueError:  # written elsewhere (a checkpoint named on the command line)
            name = str(path.resolve())
        info = {"name": name, "bytes": path.stat().st_size, "sha256": _digest(path)}
        return {**info, "written_during_the_run": True} if kept else info

    return {
        "status": status,
        "command": list(sys.argv) if command is None else list(command),
        "pgtjax": __version__,
        "python": platform.python_version(),
        "written": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "files": [entry(p, False) for p in files] + [entry(p, True) for p in in_place],
    }


def _previous_files(out: Path) -> list[Path]:
    """The files the previous run's manifest lists as its own outputs (not those written in place)."""
    try:
        listed = json.loads((out / MANIFEST).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [out / f["name"] for f in listed if isinstance(f, dict) and not f.get("written_during_the_run")]


def _remove_abandoned_staging(out: Path) -> None:
    """Remove the staging folders of runs that were killed (their process no longer exists)."""
    for folder in out.glob(".partial-*"):
        pid = folder.name.rsplit("-", 1)[-1]
        if pid.isdigit() and _pid_is_gone(int(pid)):
            shutil.rmtree(folder, ignore_errors=True)


#: one line for the files every run writes beside its own (see :func:`publish`'s ``index``)
COMMON_FILES = {
    "README.txt": "this list",
    MANIFEST: "written last: status, command line, pgtjax version, every file with its size and SHA-256",
    "parameters.toml": "every parameter of the run (defaults filled in, --set applied); --params reproduces it",
    "summary.json": "the run's figures of merit; every number with its unit (key suffix or 'unit' entry)",
}


def index_text(title: str, names: list[str], index: dict[str, str]) -> str:
    """``README.txt``: ``title`` and one line per file name, from the first fnmatch pattern of ``index`` (or
    :data:`COMMON_FILES`) that matches it."""
    lines = [title, "=" * len(title), ""]
    width = max(map(len, names), default=0)
    for name in names:
        line = next(
            (text for pattern, text in {**COMMON_FILES, **index}.items() if fnmatch.fnmatch(name, pattern)),
            "(no description)",
        )
        lines.append(f"{name.ljust(width)}  {line}")
    lines += ["", f"{PREVIOUS}/: the previous run's files, if a run wrote into this folder before", ""]
    return "\n".join(lines)


def publish(
    out,
    write: Callable[[Path], list[Path]],
    *,
    command=None,
    index: dict[str, str] | None = None,
    title: str = "",
) -> list[Path]:
    """Write a run's outputs into the folder ``out`` so that no interrupted or failed run leaves a set that
    looks complete. ``write(folder)`` writes the files into a hidden staging folder inside ``out`` and returns
    their paths (paths it returns outside that folder, e.g. a checkpoint written during the run, are listed
    but not moved). Then ``manifest.json`` is marked incomplete, the files of the previous run (those its
    manifest lists) are moved to ``out/previous-run/``, the new files are moved in, and ``manifest.json``
    (status, command line, version, and every file with its size and SHA-256) is written last. Returns the
    final paths. A failure before the move leaves ``out`` as it was; one during the move keeps the staging
    folder and says where everything is. With ``index`` ({fnmatch pattern: one line}), a ``README.txt`` headed
    ``title`` lists every file of the run with its line."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _remove_abandoned_staging(out)
    staging = out / f".partial-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    _state["staging"] = staging
    moving = False
    try:
        written = [Path(p) for p in write(staging)]
        missing = [str(p) for p in written if not p.is_file()]
        if missing:
            raise RuntimeError(f"publish: the run reported files it did not write: {missing}")
        if index is not None:
            names = {"README.txt", MANIFEST}
            for p in written:  # staged files, and those written in place inside ``out`` (a checkpoint)
                for folder in (staging.resolve(), out.resolve()):
                    if folder in p.resolve().parents:
                        names.add(p.resolve().relative_to(folder).as_posix())
                        break
            text = index_text(title or out.name, sorted(names), index)
            written.append(write_text(staging / "README.txt", text))
        staged = [p for p in written if staging.resolve() in p.resolve().parents]
        in_place = [p for p in written if p not in staged]
        old = [p for p in _previous_files(out) if p.is_file()]  # read before it is marked incomplete
        old = [p for p in old if out.resolve() in p.resolve().parents]  # never move anything outside out
        moving = True
        _state["publishing"] = out
        write_json(
            out / MANIFEST, {"status": "incomplete: a new run is replacing these outputs", "files": []}
        )
        previous = out / PREVIOUS
        if old:
            shutil.rmtree(previous, ignore_errors=True)
            for path in old:
                target = previous / path.relative_to(out)
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(path, target)
        final = []
        for path in staged:
            target = out / path.relative_to(staging)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, target)
            final.append(target)
        write_json(out / MANIFEST, _manifest(out, final, in_place, "complete", command))
        moving = False
        return final + in_place
    except Exception as err:
        if moving:  # keep what is not moved yet, and say where everything is
            raise OSError(
                f"writing the outputs into {str(out)!r} failed midway ({type(err).__name__}: {err}); its "
                f"manifest.json marks them incomplete, the previous run's files are in {str(out / PREVIOUS)!r} and "
                f"the new files not yet moved in {str(staging)!r}"
            ) from err
        raise
    finally:
        if not moving:
            shutil.rmtree(staging, ignore_errors=True)
        _state["staging"] = _state["publishing"] = None


def interrupted_message(resumable: bool = False, kept=()) -> str:
    """What an interrupt leaves behind, in one line (for the CLI's Ctrl-C handler; the staging folder of a
    run that had not started moving its files is removed). ``resumable``: the command can continue from a
    checkpoint or history; ``kept``: the files of that kind that this run wrote or resumed from (none if it
    was interrupted before its first)."""
    staging, publishing = _state["staging"], _state["publishing"]
    if publishing is not None:
        return (
            f"interrupted while replacing the outputs in {str(publishing)!r}: its manifest.json marks them "
            f"incomplete; the previous run's files are in {PREVIOUS}/, the new ones not yet moved in {staging.name}/"
        )
    if staging is not None:
        shutil.rmtree(staging, ignore_errors=True)
    if resumable and kept:
        names = ", ".join(repr(str(p)) for p in kept)
        return (
            f"interrupted: no results written (earlier results unchanged); {names} kept: the same command "
            "with --resume continues from it"
        )
    if resumable:
        return (
            "interrupted before the first checkpoint was written: no results written (earlier results "
            "unchanged) and nothing to resume; run the same command again without --resume"
        )
    return "interrupted: no output files written (earlier outputs unchanged)"
