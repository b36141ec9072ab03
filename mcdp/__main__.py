"""``python -m mcdp`` (and ``torchrun ... -m mcdp train ...``): the method's commands (train, eval,
predict, pretrain); ``mcdp sweep`` belongs to the `mcdp` console script (`study.cli`)."""
import sys

from mcdp.cli import main

sys.exit(main())
