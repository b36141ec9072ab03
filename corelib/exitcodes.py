"""Exit codes of every command (`synth`, `mcdp`): one meaning each, whichever command returns it.

The README's table lists them for users, with the commands that return each (tests/test_cli_errors.py
checks it).
"""
OK = 0
FAILED = 1  # the command ran and found a problem (synth verify), or an unexpected run-time failure
USAGE = 2  # a user error: config, dataset, run folder, output folder (the message names which), and a file
#            the operating system refuses: permission denied, read-only file system, a name too long, a path
#            through a file (corelib.atomic.USER_ERRNOS; one line naming the file)
DIVERGED = 3  # training diverged (NaN/inf loss or gradient), also a sweep with a diverged run
DISK_FULL = 4  # no space left (ENOSPC, EDQUOT): free space and run the same command again
RUN_FAILED = 5  # mcdp sweep: some run failed (engine ray: twice); the others finished
NO_BACKEND = 6  # no usable OpenGL back end on this machine: synth render, mcdp pretrain / sweep (they render)
INTERRUPTED = 130
