"""``python -m synth``: the ``synth`` command line (`synth.cli.main`), as the installed ``synth`` script."""
import sys

from synth.cli import main

if __name__ == "__main__":
    sys.exit(main())
