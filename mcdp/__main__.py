"""``python -m mcdp`` (and ``torchrun ... -m mcdp train ...``): the ``mcdp`` console script, every
command included (train, eval, predict, and the study's pretrain and sweep).

The console script's entry point (``[project.scripts]`` in pyproject.toml: `study.cli.main`) is looked
up by name at run time, so this package does not import the layer above it; without an installed
project only the method's own commands (`mcdp.cli.main`) are there.
"""
import sys
from importlib.metadata import entry_points


def console_main():
    """The installed ``mcdp`` console script's main, else `mcdp.cli.main`."""
    for ep in entry_points(group="console_scripts", name="mcdp"):
        return ep.load()
    from mcdp.cli import main

    return main


if __name__ == "__main__":
    sys.exit(console_main()())
