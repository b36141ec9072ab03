"""Synthetic surround-view driving data: rig, lighting, off-screen renderer, dataset I/O, CLI.

Example::

    synth render configs/data/tiny.yaml --out data/tiny
"""
from corelib.version import package_version as _package_version

__version__ = _package_version()
