"""Shell completion (issue 33): ``mcdp`` / ``synth --print-completion bash|zsh`` print a static script made
by shtab from the argparse parsers (every subcommand, its options, and preset names for a preset argument);
bash, given the script, completes with it; without shtab the flag is one line naming the install command."""
from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from corelib.cli import NO_SHTAB
from corelib.presets import list_presets
from study import cli as mcdp_cli
from synth import cli as synth_cli

MCDP = ["train", "eval", "predict", "presets", "pretrain", "sweep", "calibrate"]
SYNTH = ["render", "info", "presets", "verify", "preview", "merge", "export", "view"]


def _script(main, shell: str, capsys) -> str:
    capsys.readouterr()
    assert main(["--print-completion", shell]) == 0
    out = capsys.readouterr()
    assert out.err == ""
    return out.out


@pytest.mark.parametrize("main, prog, commands", [(mcdp_cli.main, "mcdp", MCDP), (synth_cli.main, "synth", SYNTH)])
def test_the_bash_and_zsh_scripts_name_every_subcommand(capsys, main, prog, commands):
    bash = _script(main, "bash", capsys)
    assert f"_shtab_{prog}_subparsers=({' '.join(commands)})" in bash
    assert bash.rstrip().endswith(f"complete -o bashdefault -F _shtab_{prog} {prog}")
    zsh = _script(main, "zsh", capsys)
    assert zsh.startswith(f"#compdef {prog}") and all(f"\n    {c}:'" in zsh for c in commands)


def _complete(script: str, words: list[str], tmp_path) -> list[str]:
    """What bash completes for ``words`` (the last is being typed) with ``script`` sourced, run in an empty
    folder (no file name matches)."""
    (tmp_path / "c.bash").write_text(script)
    cmd = (f"source c.bash; COMP_WORDS=({' '.join(repr(w) for w in words)}); COMP_CWORD={len(words) - 1}; "
           f"_shtab_{words[0]}; printf '%s\\n' \"${{COMPREPLY[@]}}\"")
    out = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
def test_bash_completes_subcommands_options_and_preset_names(tmp_path, capsys):
    script = _script(mcdp_cli.main, "bash", capsys)
    assert _complete(script, ["mcdp", ""], tmp_path) == MCDP
    assert _complete(script, ["mcdp", "sw"], tmp_path) == ["sweep"]
    assert "--print-config" in _complete(script, ["mcdp", "sweep", "--"], tmp_path)
    ci = [p for p in list_presets("sweep") if p.startswith("configs/sweep/c")]
    assert ci and _complete(script, ["mcdp", "sweep", "configs/sweep/c"], tmp_path) == ci
    assert _complete(script, ["mcdp", "train", "configs/train/tiny/mono"], tmp_path) == \
        ["configs/train/tiny/mono2.yaml"]
    assert _complete(script, ["mcdp", "--print-completion", ""], tmp_path) == ["bash", "zsh"]
    synth = _script(synth_cli.main, "bash", capsys)
    assert _complete(synth, ["synth", "render", "configs/data/ti"], tmp_path) == ["configs/data/tiny.yaml"]


def test_without_shtab_the_flag_is_one_line_naming_the_install(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "shtab", None)  # import shtab -> ImportError
    capsys.readouterr()
    assert mcdp_cli.main(["--print-completion", "bash"]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.splitlines() == [f"mcdp: error: {NO_SHTAB}"]
    assert "bash scripts/setup.sh" in NO_SHTAB and "pip install 'shtab>=" in NO_SHTAB


@pytest.mark.skipif(shutil.which("zsh") is None, reason="no zsh")
@pytest.mark.parametrize("main, prog", [(mcdp_cli.main, "mcdp"), (synth_cli.main, "synth")])
def test_the_zsh_script_parses_and_registers_its_completer(tmp_path, capsys, main, prog):
    (tmp_path / "c.zsh").write_text(_script(main, "zsh", capsys))  # as the README enables it: eval "$(...)"
    cmd = ("autoload -U compinit; compinit -u -D; eval \"$(<c.zsh)\"; print -r -- ${_comps[" + prog + "]}; "
           "whence -w _mcdp_synth_presets_data")
    out = subprocess.run(["zsh", "-fc", cmd], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:2] == [f"_shtab_{prog}", "_mcdp_synth_presets_data: function"], out.stdout
