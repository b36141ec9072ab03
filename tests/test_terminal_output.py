"""Hardening, round four (issue 41), item 9: what a command echoes of the user's input reaches the terminal as
text. An escape sequence in a YAML key, an override key, a preset name or a path is shown escaped
(`corelib.text.printable`, through `bounded` in every error line and the log's stderr formatter), and
argparse's own errors echo a value cut to a few hundred characters (`corelib.cli.ArgumentParser`)."""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MONO2 = str(ROOT / "configs" / "train" / "tiny" / "mono2.yaml")
TINY = str(ROOT / "configs" / "data" / "tiny.yaml")
ESC = "\x1b]0;owned\x07\x1b[2J"  # retitle the terminal, then clear it


def _no_raw_controls(text: str) -> None:
    assert not any(c in text for c in "\x1b\x07\x9b"), repr(text[-500:])
    assert "\\x1b" in text, text[-500:]


@pytest.mark.parametrize("where", ["override key", "yaml key", "preset name", "path"])
def test_an_escape_sequence_in_user_input_is_shown_escaped(tmp_path, capsys, where):
    from study.cli import main as mcdp_main
    from synth.cli import main as synth_main

    if where == "override key":
        rc = synth_main(["render", TINY, "--out", str(tmp_path / "d"), f"{ESC}bad=1"])
    elif where == "yaml key":
        y = tmp_path / "c.yaml"
        y.write_text(f'"{ESC}": 1\n'.replace("\x1b", "\\e").replace("\x07", "\\a"))
        rc = mcdp_main(["train", str(y), "--data", str(tmp_path), "--out", str(tmp_path / "r")])
    elif where == "preset name":
        rc = mcdp_main(["train", f"{ESC}nope", "--data", str(tmp_path), "--out", str(tmp_path / "r")])
    else:
        rc = synth_main(["info", str(tmp_path / f"{ESC}data")])
    assert rc == 2
    out = capsys.readouterr()
    _no_raw_controls(out.out + out.err)
    assert len(out.err.strip().splitlines()) <= 3, out.err


def test_a_log_line_is_shown_escaped(capsys):
    from corelib.logs import logger

    logger("mcdp.test").warning(f"warning: {ESC} in a path")
    _no_raw_controls(capsys.readouterr().err)


def test_printable_keeps_text_and_line_breaks():
    from corelib.text import bounded, printable

    assert printable("a/b é ü 日本\n\tc") == "a/b é ü 日本\n\tc"
    assert printable("x\x1b[31my\u202ez\udce9") == "x\\x1b[31my\\u202ez\\udce9"
    assert bounded("\x1b" * 10, 8) == "\\x1b\\x1b... (32 more characters)"


@pytest.mark.parametrize("argv", [["render", TINY, "--workers", "9" * 100_000 + "x"],
                                  ["render", TINY, "--engine", "r" * 100_000],
                                  ["info", "data", "--nope" + "n" * 100_000]])
def test_argparse_errors_echo_a_bounded_escaped_value(capsys, argv):
    from synth.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err) < 2000 and "more characters" in err, err[-500:]
    assert err.strip().splitlines()[-1].startswith("synth"), err[-500:]


def test_argparse_errors_of_mcdp_are_bounded_too(capsys):
    from study.cli import main

    assert main(["eval", "run", "--data", "d", "--split", f"{ESC}" + "s" * 100_000]) == 2
    err = capsys.readouterr().err
    assert len(err) < 2000 and "more characters" in err, err[-500:]
    _no_raw_controls(err)
