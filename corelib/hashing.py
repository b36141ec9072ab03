"""sha256 of files and of JSON content, and per-section digests that say *what* changed.

Example::

    d = section_digests({"splits": {"train": ["a"], "test": ["b"]}}, depth=2)
    # {"splits.train": "...", "splits.test": "..."}
    changed_sections(d, section_digests(edited, depth=2))   # -> ["splits.test"]
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    from corelib.readfile import open_file

    h = hashlib.sha256()
    with open_file(path, kind="hashed", link_ok=True) as f:  # regular, never a FIFO's blocking read
        while True:
            b = f.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def canonical_json(obj: Any) -> bytes:
    """One byte string per JSON value: sorted keys, no spaces, NaN allowed (as in our metrics)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()


def json_sha256(obj: Any) -> str:
    return hashlib.sha256(canonical_json(obj)).hexdigest()


def _sections(obj: Any, prefix: str, depth: int, out: dict[str, str]) -> None:
    if depth > 0 and isinstance(obj, dict) and obj:
        for k in obj:
            _sections(obj[k], f"{prefix}.{k}" if prefix else str(k), depth - 1, out)
    elif (depth > 0 and isinstance(obj, list) and obj and all(isinstance(x, dict) and isinstance(x.get("name"), str)
                                                               for x in obj)):
        for x in obj:  # a list of named records (rig cameras): sections by name, not position
            _sections(x, f"{prefix}[{x['name']}]", depth - 1, out)
    else:
        out[prefix or "."] = json_sha256(obj)


def section_digests(obj: Any, depth: int = 2) -> dict[str, str]:
    """{dotted path: sha256} of `obj`'s sections down to `depth` levels (named list items by name)."""
    out: dict[str, str] = {}
    _sections(obj, "", depth, out)
    return out


def changed_sections(recorded: dict[str, str], now: dict[str, str]) -> list[str]:
    """Paths whose digest differs, plus those added or removed since `recorded`, in path order."""
    return sorted(k for k in set(recorded) | set(now) if recorded.get(k) != now.get(k))
