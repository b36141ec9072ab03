"""``python -m mcdp`` (and ``torchrun ... -m mcdp train ...``): the ``mcdp`` console script, every
command included (train, eval, predict, pretrain, sweep).

The command line lives in the top layer (`study.cli`, `study.method_commands`), not in this method library.
The console script's entry point (``[project.scripts]`` in pyproject.toml: `study.cli.main`) is looked up
by name at run time, so this package does not import the layer above it.
"""
import sys
from importlib.metadata import entry_points


def console_main():
    """The installed ``mcdp`` console script's main; exit 2 with one line when the project is not installed."""
    for ep in entry_points(group="console_scripts", name="mcdp"):
        return ep.load()
    print("python -m mcdp: error: the mcdp-synth project is not installed (pip install -e .): no 'mcdp' "
          "console script", file=sys.stderr)
    sys.exit(2)


if __name__ == "__main__":
    sys.exit(console_main()())
