"""The presets that ship in ``configs/``, by kind: listed by ``mcdp presets`` / ``synth presets``, and named
in the one-line error when a preset path does not exist.

Shell completion (`corelib.cli`'s ``--print-completion``) completes a preset argument with the presets of
its kind (`complete_presets`) and with file names.

Example::

    preset_path("configs/train/mcdp_m3.yaml", "train")
    # ConfigError: training preset configs/train/mcdp_m3.yaml does not exist (looked in ... and ...);
    #              training presets: configs/train/fsm.yaml, ... (list them: mcdp presets train)
"""
from __future__ import annotations

from pathlib import Path

from corelib.configlib import PROJECT_ROOT, ConfigError, resolve_path

#: kind -> (what the error calls it, its folder under the project root, the command that lists it)
KINDS = {
    "train": ("training preset", "configs/train", "mcdp presets train"),
    "sweep": ("sweep preset", "configs/sweep", "mcdp presets sweep"),
    "pretrain": ("pretraining config", "configs/pretrain", "mcdp presets pretrain"),
    "data": ("data preset", "configs/data", "synth presets"),
}


def list_presets(kind: str) -> list[str]:
    """The preset files of ``kind`` (paths relative to the project root, sub-folders included, sorted)."""
    folder = PROJECT_ROOT / KINDS[kind][1]
    if not folder.is_dir():
        return []
    return sorted(str(p.relative_to(PROJECT_ROOT)) for p in folder.rglob("*.yaml"))


def preset_path(path: str | Path, kind: str) -> Path:
    """``path`` resolved as `corelib.configlib.resolve_path` does (the working directory, then the project
    root); a path that does not exist is a ConfigError that lists the presets of ``kind``."""
    label, _, command = KINDS[kind]
    try:
        return resolve_path(path, label)
    except ConfigError as exc:
        names = list_presets(kind)
        listed = ", ".join(names) if names else "none found"
        raise ConfigError(f"{exc}; {label}s: {listed} (list them: {command})") from None


def format_presets(kinds: list[str]) -> str:
    """One block per kind: its folder, then one preset per line."""
    out = []
    for k in kinds:
        out.append(f"{KINDS[k][0]}s ({KINDS[k][1]}):")
        out += [f"  {p}" for p in list_presets(k)]
    return "\n".join(out)


def _completer(kind: str) -> str:
    """The name of the shell function that completes a preset of ``kind`` (`completion_preamble`)."""
    return f"_mcdp_synth_presets_{kind}"


def complete_presets(action, kind: str):
    """Mark ``action`` (an argparse positional that takes a preset path) to complete with the presets of
    ``kind`` and file names, in the scripts of ``--print-completion`` (shtab's ``.complete``); returns it."""
    action.complete = {"bash": _completer(kind), "zsh": _completer(kind)}
    return action


def completion_preamble() -> dict[str, str]:
    """{shell: the functions `complete_presets` names}: each offers the presets of its kind as they are
    now (paths relative to the project root, which every preset argument also resolves against), then
    file names."""
    bash, zsh = [], []
    for kind in KINDS:
        names = " ".join(list_presets(kind))
        bash.append(f'{_completer(kind)}() {{\n  compgen -W "{names}" -- "$1"\n  compgen -f -- "$1"\n}}')
        zsh.append(f"{_completer(kind)}() {{\n  compadd -- {names}\n  _files\n}}")
    return {"bash": "\n".join(bash), "zsh": "\n".join(zsh)}
