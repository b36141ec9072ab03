"""Synthetic surround-view driving data: rig, lighting, off-screen renderer, dataset I/O, CLI.

Example::

    synth render configs/data/tiny.yaml --out data/tiny
"""
__version__ = "0.1.0"
