"""Text a command shows on a terminal: whatever it echoes of the user's input (a path, a YAML or override key, a
preset name, a value) is `printable` (control characters escaped, so an escape sequence in a name cannot move
the cursor, recolour or retitle the terminal) and `bounded` (cut, the rest counted).

Example::

    print(f"synth render: error: {bounded(str(exc))}", file=sys.stderr)
"""
from __future__ import annotations

import sys

#: the longest error message printed (characters); a longer one is cut, the rest counted
MAX_MESSAGE = 2000

#: the characters kept as they are although not printable: a message's own line breaks and tabs
_KEPT = "\n\t"


def printable(text: str) -> str:
    """`text` with every character that is not printable (C0 and C1 controls such as ESC, DEL, bidi and
    other format characters, lone surrogates of a name that is not UTF-8), except newline and tab, written as
    its Python escape (``\\x1b``, ``\\u202e``, ``\\udce9``)."""
    if text.isprintable() or all(c.isprintable() or c in _KEPT for c in text):
        return text
    return "".join(c if c.isprintable() or c in _KEPT else repr(c)[1:-1] for c in text)


def bounded(text: str, limit: int = MAX_MESSAGE) -> str:
    """`text` `printable`, cut to ``limit`` characters with the count of the rest: whatever a message echoes
    (a path, a value of the user's), the error stays a few lines and writes nothing but text."""
    text = printable(text)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text) - limit} more characters)"


def safe_streams() -> None:
    """stdout and stderr write a character their encoding lacks as its escape (``\\xe9``) instead of failing:
    under ``PYTHONIOENCODING=ascii`` (or a C locale) a non-ASCII path in a last line would otherwise end a
    finished command with exit 2."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None and getattr(stream, "errors", None) in ("strict", "surrogateescape"):
            try:
                reconfigure(errors="backslashreplace")
            except (ValueError, OSError):  # a stream that cannot change (closed, or already written to)
                pass
