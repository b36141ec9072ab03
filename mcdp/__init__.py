"""MCDP: multi-camera collaborative depth prediction (training, geometry, losses, evaluation).

Example::

    mcdp train configs/train/mcdp_m2.yaml --data data/default --out runs/m2
    mcdp eval runs/m2 --data data/default --split test
    mcdp sweep configs/sweep/ci.yaml --out sweeps/ci
"""
from corelib.version import package_version as _package_version

__version__ = _package_version()
