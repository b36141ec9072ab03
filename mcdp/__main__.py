"""``python -m mcdp`` (and ``torchrun ... -m mcdp train ...``): the `mcdp` command line."""
import sys

from mcdp.cli import main

sys.exit(main())
