"""Worker processes that die with their parent: a sweep's run processes and a render's workers.

Ctrl-C reaches a whole process group, but SIGTERM, SIGHUP or ``kill -9`` reach the parent only: its
spawned workers would go on rendering or training with no one to collect their results (measured: two
1.7 GB training workers still running 35 minutes after a killed sweep). `die_with_parent` is the
initializer of every such pool: on Linux the kernel sends the worker SIGKILL when its parent exits
for any reason (``prctl(PR_SET_PDEATHSIG)``); a parent that is already gone when the worker starts
makes it exit at once. Elsewhere it does nothing.

Ctrl-C on a terminal reaches the workers too, and a worker that is still starting (importing torch) prints
its own ``KeyboardInterrupt`` traceback. A pool's workers started inside `sigint_held` never see SIGINT; the
parent ends them with `stop_pool` (its queued tasks cancelled by ``shutdown(cancel_futures=True)``, never
by hand: a future cancelled by hand in a pool that then breaks makes the pool's own thread raise
``InvalidStateError: CANCELLED``), and does not wait for their tasks.

Example::

    pool = ProcessPoolExecutor(n, mp_context=ctx, initializer=die_with_parent, initargs=(os.getpid(),))
    try:
        with sigint_held():
            fut = pool.submit(job)
        fut.result()
    except KeyboardInterrupt:
        stop_pool(pool)
        raise
"""
from __future__ import annotations

import os
import signal
import sys
from contextlib import contextmanager
from typing import Iterator

PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> bool:
    """Make this process receive SIGKILL when its parent exits; True when that is armed (Linux)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
        return False
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)
    return True


@contextmanager
def sigint_held() -> Iterator[None]:
    """SIGINT blocked in this thread for the block: a process started in it (a pool's spawned worker, started
    by ``submit``) inherits the blocked SIGINT through exec and never gets Ctrl-C, so it prints nothing
    when its parent is interrupted; the parent ends it (`stop_pool`). A Ctrl-C that arrives during the
    block is delivered to this process when the block ends (as ``KeyboardInterrupt``), not lost."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def stop_pool(pool) -> None:
    """End a ``ProcessPoolExecutor`` now: ``shutdown(wait=False, cancel_futures=True)`` (the pool's own thread
    cancels what is queued) and its workers terminated, their running tasks not waited for."""
    workers = list((getattr(pool, "_processes", None) or {}).values())  # CPython's pid -> Process; shutdown drops it
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        proc.terminate()


def _init(parent_pid: int, then=None) -> None:
    die_with_parent(parent_pid)
    if then is not None:
        then()


def executor(ctx, processes: int, initializer=None):
    """``ProcessPoolExecutor(processes)`` whose workers die with this process (then run ``initializer``).
    Unlike ``multiprocessing.Pool``, it notices a worker that dies (kill -9, the OOM killer): every task
    not yet returned raises ``BrokenProcessPool`` instead of waiting for ever (see `WorkerLost`).
    Left by Ctrl-C (KeyboardInterrupt) or SystemExit, its ``with`` block ends the workers at once instead of
    waiting for their running tasks (a render's sequences: tens of seconds; what they write is a ``.partial``
    that the rerun replaces)."""
    from concurrent.futures import ProcessPoolExecutor

    class _Executor(ProcessPoolExecutor):
        def __exit__(self, exc_type, exc, tb):
            if exc_type is not None and issubclass(exc_type, (KeyboardInterrupt, SystemExit)):
                for proc in list((self._processes or {}).values()):  # CPython's pid -> Process of the pool
                    proc.terminate()
                self.shutdown(wait=True, cancel_futures=True)
                return False
            return super().__exit__(exc_type, exc, tb)

    return _Executor(processes, mp_context=ctx, initializer=_init, initargs=(os.getpid(), initializer))


class WorkerLost(RuntimeError):
    """A worker process died (a signal: kill -9, the OOM killer) before its task returned; the message names
    the tasks that did not finish and says that a rerun resumes (exit 1, `corelib.exitcodes.FAILED`)."""


def lost_workers(command: str, unfinished: list[str], what: str) -> WorkerLost:
    """The `WorkerLost` of `command` whose pool broke with the tasks `unfinished` (names) not done."""
    shown = ", ".join(unfinished[:4]) + (f" (+{len(unfinished) - 4} more)" if len(unfinished) > 4 else "")
    return WorkerLost(f"{command}: a worker process died (killed by a signal, e.g. the out-of-memory killer) with "
                      f"{len(unfinished)} {what} unfinished: {shown or 'none'}; what finished is kept: run the "
                      "same command again to resume")


def manager(ctx):
    """A started ``SyncManager`` (``ctx.Manager()``) whose server process dies with this process."""
    from multiprocessing.managers import SyncManager

    m = SyncManager(ctx=ctx)
    m.start(_init, (os.getpid(),))
    return m
