"""The package's version, one source: pyproject.toml (through the installed metadata); and the code
version every cached artefact records (`code_version`), with the one warning when other code reuses it.

Example::

    from corelib.version import code_version, package_version, warn_other_code
    package_version()   # "0.1.0"
    code_version()      # "0.1.0+src.3f9a1c0b2d4e"
    warn_other_code("dataset sweeps/ci/data/overlap_0.20", manifest.get("code_version"), log)
"""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Callable

#: the packages whose sources make the code version (pyproject.toml's [tool.setuptools.packages.find])
PACKAGES = ("corelib", "scenes", "synth", "mcdp", "study")


def package_version() -> str:
    """The installed mcdp-synth's version (importlib.metadata), else the source tree's pyproject.toml."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mcdp-synth")
    except PackageNotFoundError:
        import tomllib

        pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
        return tomllib.loads(pyproject.read_text())["project"]["version"]


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``<package_version>+src.<12 hex>``: the version and the sha256 of the sources that run (every
    ``*.py`` of `PACKAGES`, relative path and bytes, in path order), computed once per process.

    Why the sources' digest and not the git commit: it needs no git and no checkout (an installed
    package has its sources beside it), it tells apart uncommitted edits (the code that actually ran,
    which a commit id does not), and it costs one read of under 1 MB. Why not the version alone:
    pyproject's version is rarely bumped, so two different codes would read the same. Any edit, a
    comment's too, changes it: the warning it feeds says "other code", not "different results"."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(f for pkg in PACKAGES for f in (root / pkg).rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    return f"{package_version()}+src.{h.hexdigest()[:12]}"


def warn_other_code(what: str, recorded: object, log: Callable[[str], None]) -> bool:
    """One warning line through `log` when the cached artefact `what` was made by other code than this
    (its recorded `code_version` differs); True if so. Not an error: the artefact is still reused (its
    config hash, which says what made it, is unchanged). An artefact without a record (written before
    code versions were recorded) is reused without a word: there is no version to name."""
    if not isinstance(recorded, str) or recorded == code_version():
        return False
    log(f"warning: {what} was made by code {recorded[:60]}, this is {code_version()}; reused as its config "
        "is unchanged (delete it to make it again with this code)")
    return True
