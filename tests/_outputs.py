"""Checks shared by the tests of the studies' output folders."""

from pathlib import Path


def assert_readme_lists_every_file(folder: Path) -> None:
    """The folder's README.txt names every file in it, each with a description."""
    readme = (Path(folder) / "README.txt").read_text()
    assert "(no description)" not in readme
    listed = {
        line.split()[0] for line in readme.splitlines()[3:] if line and not line.startswith("previous-run")
    }
    on_disk = {p.name for p in Path(folder).iterdir() if p.is_file()}
    assert on_disk <= listed, on_disk - listed
