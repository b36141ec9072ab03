"""The package's version, one source: pyproject.toml (through the installed metadata).

Example::

    from corelib.version import package_version
    package_version()   # "0.1.0"
"""
from __future__ import annotations

from pathlib import Path


def package_version() -> str:
    """The installed mcdp-synth's version (importlib.metadata), else the source tree's pyproject.toml."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mcdp-synth")
    except PackageNotFoundError:
        import tomllib

        pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
        return tomllib.loads(pyproject.read_text())["project"]["version"]
