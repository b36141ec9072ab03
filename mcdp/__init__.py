"""MCDP: multi-camera collaborative depth prediction (training, geometry, losses, evaluation).

Example::

    mcdp eval --run runs/mcdp_tiny --data data/tiny
"""
