"""Where the optional ``viz`` extra lives: the one line a command says when it is missing.

rerun-sdk 0.41 (``synth view``, ``mcdp predict --rrd``) requires numpy >= 2 and the nuScenes devkit of
the ``nuscenes`` extra numpy < 2, so ``bash scripts/setup.sh --test`` installs ``viz`` into a second
environment, ``.venv-viz``, beside ``.venv`` (README, "Dependency choices"). The hint names that
environment first: ``pip install -e '.[viz]'`` into ``.venv`` would replace the devkit's numpy.

Example::

    raise ViewError(f"the Rerun recording needs the optional extra 'viz' (rerun-sdk): {VIZ_INSTALL}")
"""
from __future__ import annotations

VIZ_ENV = ".venv-viz"
VIZ_INSTALL = (f"run the command from {VIZ_ENV}, the environment that has it ({VIZ_ENV}/bin/synth, "
               f"{VIZ_ENV}/bin/mcdp; made by `bash scripts/setup.sh --test`), or pip install -e '.[viz]' into an "
               "environment without the nuscenes extra (rerun-sdk needs numpy >= 2, nuscenes-devkit numpy < 2)")

__all__ = ["VIZ_ENV", "VIZ_INSTALL"]
