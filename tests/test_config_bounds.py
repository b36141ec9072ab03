"""Hardening, round two (issue 20, items 4, 5, 7): numbers that make training nonsense or allocate
until the machine gives out are refused, naming the key, before a run folder is created; a sweep
resolves every nested override before it renders or pretrains anything."""
from __future__ import annotations

from pathlib import Path

import pytest

from corelib.configlib import ConfigError, config_hash, load_config

ROOT = Path(__file__).resolve().parents[1]
MONO2 = ROOT / "configs" / "train" / "tiny" / "mono2.yaml"
CI_SWEEP = ROOT / "configs" / "sweep" / "ci.yaml"


@pytest.mark.parametrize("override, key, said", [
    ("train.grad_clip=-1", "train.grad_clip", "greater than 0"),      # torch would flip the gradient
    ("train.grad_clip=.inf", "train.grad_clip", "(got inf)"),
    ("train.lr=.inf", "train.lr", "finite"),
    ("train.lr=-1e-4", "train.lr", "greater than 0"),
    ("train.lr=10", "train.lr", "less than or equal to 1"),
    ("model.max_depth=.inf", "model.max_depth", "finite"),
    ("model.max_depth=.nan", "model.max_depth", "finite"),
    ("model.init_depth=.inf", "model.init_depth", "(got inf)"),
    ("loss.consistency_weight=.inf", "loss.consistency_weight", "finite"),
    ("train.steps=1000000000000000", "train.steps", "less than or equal to 10000000"),
    ("train.height=32000", "train.height", "less than or equal to 2048"),
    ("train.width=32000", "train.width", "less than or equal to 4096"),
    ("train.batch_size=100000", "train.batch_size", "less than or equal to 256"),
    ("model.weight_channels=100000", "model.weight_channels", "less than or equal to 512"),
    ("model.weight_fc=1000000000", "model.weight_fc", "less than or equal to 4096"),
    ("eval.max_depth=.inf", "eval.max_depth", "finite"),
])
def test_train_refuses_a_nonsense_or_unbounded_number_before_writing(tmp_path, capsys, override, key, said):
    from study.method_commands import main

    run = tmp_path / "run"
    assert main(["train", str(MONO2), "--data", str(tmp_path / "nodata"), "--out", str(run), override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) <= 3 and any(key in line and said in line for line in err), err
    assert not run.exists()


def test_the_pixels_of_a_step_are_bounded_with_their_size_named():
    from mcdp.config import RunConfig

    with pytest.raises(ConfigError, match=r"train.batch_size x height x width = 64 x 1024 x 2048 = 134217728 "
                                          r"pixels .* above the limit 16777216: the float32 input alone would "
                                          r"be 29.0 GB"):
        load_config(RunConfig, None, ["train.batch_size=64", "train.height=1024", "train.width=2048"])
    cfg = load_config(RunConfig, None, ["train.batch_size=16", "train.height=384", "train.width=640"])
    assert cfg.train.batch_size * cfg.train.height * cfg.train.width == 3_932_160  # a real GPU run: accepted


def test_bounds_leave_the_default_configs_hash_unchanged():
    """A cached pretraining is keyed on the resolved config hash: bounds must not change it."""
    from mcdp.config import RunConfig

    assert config_hash(load_config(RunConfig, None)) == \
        "40acb517a855e5d88416d417bbe901d140190ed543363e37e1febedaf0dd59f3"


@pytest.mark.parametrize("override, where, key", [
    ("train_overrides=[train.stepz=2]", "train_overrides", "train.stepz: unknown key"),
    ("data_overrides=[dataset.frames=1]", "data_overrides", "dataset.frames"),
    ("pretrain.train_overrides=[train.lr=-1]", "pretrain", "train.lr"),
])
def test_a_sweep_refuses_a_bad_nested_override_before_it_renders(tmp_path, capsys, override, where, key):
    from study.cli import main

    out = tmp_path / "sweep"
    assert main(["sweep", str(CI_SWEEP), "--out", str(out), "--no-progress", override]) == 2
    err = capsys.readouterr().err
    assert f"sweep {where}: invalid config" in err and key in err, err
    assert not out.exists()


# --------------------------------------------------------------------------- every numeric key, every config
def _numeric_fields():
    """(model class, field name, its annotation) of every int / float / tuple-of-float key of every config
    section (every `StrictModel` subclass of the five packages). Every module of the five is imported first,
    so the set is the same whether this file is collected alone or after others (issue 42, item 8)."""
    import importlib
    import typing

    from corelib.configlib import StrictModel

    for pkg in ("corelib", "scenes", "synth", "mcdp", "study"):  # by file: study's folders have no __init__.py,
        for path in sorted((ROOT / pkg).rglob("*.py")):             # which pkgutil.walk_packages does not enter
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] != "__main__":
                importlib.import_module(".".join(parts[:-1] if parts[-1] == "__init__" else parts))

    def numeric(ann) -> bool:
        return ann in (int, float) or any(numeric(a) for a in typing.get_args(ann))

    seen, stack, out = set(), list(StrictModel.__subclasses__()), []
    while stack:
        cls = stack.pop()
        if cls in seen:
            continue
        seen.add(cls)
        stack += cls.__subclasses__()
        if cls.__module__.split(".")[0] not in ("corelib", "scenes", "synth", "mcdp", "study"):
            continue  # a test's own model
        out += [(cls, name, f.annotation) for name, f in cls.model_fields.items()
                if numeric(f.annotation) and f.annotation is not bool]
    return sorted(out, key=lambda t: (t[0].__module__, t[0].__name__, t[1]))


NUMERIC = _numeric_fields()


def test_the_walk_finds_the_numeric_keys():
    names = {f"{c.__name__}.{n}" for c, n, _ in NUMERIC}
    assert len(NUMERIC) >= 70 and {"TrainConfig.lr", "DatasetConfig.sequences", "SweepEvalConfig.max_depth",
                                    "SceneConfig.family_weights", "LidarConfig.mount_xyz_m",
                                    "SweepConfig.seeds"} <= names


@pytest.mark.slow
def test_the_walk_is_the_same_alone_and_in_the_suite():
    """A fresh interpreter that imports only this file finds the same keys as this process, whatever the suite
    imported before it."""
    import subprocess
    import sys

    code = ("import sys; sys.path.insert(0, 'tests'); import test_config_bounds as t; "
            "print(sorted(f'{c.__module__}.{c.__name__}.{n}' for c, n, _ in t.NUMERIC))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == str(sorted(f"{c.__module__}.{c.__name__}.{n}" for c, n, _ in NUMERIC))


def _is_int(ann) -> bool:
    import typing

    return any(a is int for a in (ann, *typing.get_args(ann)))


#: (class, key, annotation, a value out of any real range): ints get +-10^18 (a float is refused by strict typing)
OUT_OF_RANGE = [(c, n, a, bad) for c, n, a in NUMERIC
                for bad in ([10**18, -10**18] if _is_int(a) else [1e18, -1e18, float("inf"), float("-inf"), float("nan")])]


@pytest.mark.parametrize("cls, name, ann, bad", OUT_OF_RANGE, ids=[f"{c.__name__}.{n}={b}" for c, n, _, b in OUT_OF_RANGE])
def test_every_numeric_key_has_a_finite_range(cls, name, ann, bad):
    """Every number a config takes has a lower and an upper bound a real run could use, and is finite: a
    value out of them is refused naming the key (whatever the section, a list or tuple element too)."""
    from pydantic import ValidationError

    default = cls.model_fields[name].get_default(call_default_factory=True)
    value = bad
    if isinstance(default, (list, tuple)):  # one element out of range (the length kept)
        value = type(default)([bad, *list(default)[1:]]) if default else [bad]
    with pytest.raises(ValidationError) as err:
        cls.model_validate({name: value}, strict=False)
    assert name in str(err.value), str(err.value)[:500]


@pytest.mark.parametrize("text, said", [
    ("a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\nconfig: [*b, *b, *b, *b]\n",
     "aliases"),                                                        # a billion laughs, shortened
    ("config:\n" + "".join(" " * (2 * i + 2) + f"k{i}:\n" for i in range(1000)), "nested more than"),
    ("config: [" + ", ".join(["1"] * 20_000) + "]\n", "more than 10000 keys"),
    ("config: {a: 1\n", "not valid YAML"),
])
def test_a_sweep_reads_its_saved_config_with_the_bounds_and_only_notes_one_it_cannot(tmp_path, text, said):
    """SWEEP/sweep_config.yaml (a rerun compares it with the resolved config, for a note) is read with the
    project's loader, as every config is: one it cannot read is a note naming why, and the sweep goes on."""
    from study.sweep_command import _note_config_change

    prev = tmp_path / "sweep_config.yaml"
    prev.write_text(text)
    lines = []
    _note_config_change(prev, {"data": "configs/data/tiny.yaml"}, lines.append)
    assert len(lines) == 1 and lines[0].startswith("[sweep] note: the saved sweep config is not read (") \
        and said in lines[0] and lines[0].endswith("; it is rewritten"), lines
    prev.write_text("config: {data: configs/data/other.yaml}\n")
    lines.clear()
    _note_config_change(prev, {"data": "configs/data/tiny.yaml"}, lines.append)
    assert len(lines) == 1 and "differs from the saved one in: data" in lines[0], lines
