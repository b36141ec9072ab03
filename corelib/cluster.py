"""Ray, optional: one way to import it and to join or start the instance that `--engine ray` uses.

Ray comes with the ``cluster`` extra (``pip install -e '.[cluster]'``); without it
`import_ray` raises `EngineUnavailable` (a `ConfigError`: the commands print one line and
exit 2). `ray_session` is where every ``--engine ray`` command gets its Ray:

- Ray already initialised in this process (a test, a notebook): used as it is, left running;
- ``RAY_ADDRESS`` set (``auto``, ``HOST:6379``, ``ray://HOST:10001``): that cluster is joined
  (``ray.init(address=...)``; the cluster's own resources, none given here); on a multi-node
  cluster every path the tasks read or write must be the same shared folder on every node;
- otherwise a private local instance is started (``ray.init(address="local")``: never a stray
  ``ray start`` instance) with `num_cpus` CPUs (None: the machine's cores), no dashboard, and
  shut down when the session ends (a joined cluster is disconnected from, not stopped).

Example::

    with ray_session(num_cpus=2) as ray:
        print(ray.get(ray.remote(lambda: 1).remote()))
"""
from __future__ import annotations

import contextlib
import os
from typing import Callable, Iterator

from corelib.configlib import ConfigError

RAY_MISSING = "--engine ray needs Ray, which is not installed: install the extra: pip install -e '.[cluster]'"


class EngineUnavailable(ConfigError):
    """The Ray engine was asked for and Ray is not importable."""


def import_ray():
    """The ``ray`` module, or `EngineUnavailable` with the one line that says how to install it."""
    try:
        import ray
    except ImportError:
        raise EngineUnavailable(RAY_MISSING) from None
    return ray


@contextlib.contextmanager
def ray_session(num_cpus: int | None = None, log: Callable[[str], None] | None = None) -> Iterator:
    """Yield the ``ray`` module, initialised as the module docstring says; shut down only what was started here."""
    ray = import_ray()
    log = log or (lambda s: None)
    if ray.is_initialized():
        yield ray
        return
    address = os.environ.get("RAY_ADDRESS")
    if address:
        ray.init(address=address)
        log(f"[ray] joined the cluster at RAY_ADDRESS={address}: {_resources(ray)}")
    else:
        ray.init(address="local", num_cpus=num_cpus or os.cpu_count() or 1, include_dashboard=False)
        log(f"[ray] started a local Ray instance: {_resources(ray)}")
    try:
        yield ray
    finally:
        ray.shutdown()  # a joined cluster is only disconnected from; it keeps running


def error_line(exc: BaseException) -> str:
    """``Type: first line`` of an error; for a Ray error, of the task's own exception where Ray kept it."""
    cause = getattr(exc, "cause", None) or exc
    text = str(cause).strip().splitlines()
    return f"{type(cause).__name__}: {text[0] if text else ''}"


def _resources(ray) -> str:
    r = ray.cluster_resources()
    return f"{r.get('CPU', 0):g} CPU(s), {r.get('GPU', 0):g} GPU(s)"
