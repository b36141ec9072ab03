"""The publish scripts and the benchmarks speak as the CLIs do (issue 49, items 5 and 6): what they echo of the
user's words is cut and escaped (`corelib.cli.ArgumentParser`, `corelib.text.bounded`), and publish_sweep refuses a
schema-1 results.json that lacks the sweep's record in one line instead of a KeyError traceback."""
from __future__ import annotations

import importlib
import json
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROP = ROOT / "docs" / "results" / "propagation"
ESC = "\x1b]0;pwned\x07\x1b[31m"


@pytest.fixture
def publish(tmp_path, monkeypatch):
    """scripts/publish_sweep.py writing into an empty temporary docs/results/."""
    mod = importlib.import_module("scripts.publish_sweep")
    monkeypatch.setattr(mod, "RESULTS", tmp_path / "docs" / "results")
    (tmp_path / "docs" / "results").mkdir(parents=True)
    return mod


def _err(capsys) -> str:
    return capsys.readouterr().err


# --------------------------------------------------------------------------- item 5: cut and escaped
@pytest.mark.parametrize("argv", [
    ["--name", "x" * 100_000],
    ["--name", "r", "--sweep", "s" * 100_000],
    ["--name", "r", "--sweep", f"/nowhere/{ESC}"],
    ["--name", ESC],
])
def test_publish_sweep_echoes_a_long_or_escaping_argument_cut_and_escaped(publish, capsys, argv):
    assert publish.main(argv) == 2
    err = _err(capsys)
    assert len(err.splitlines()) == 1 and len(err) < 2200 and "\x1b" not in err and "\x07" not in err, err[:300]
    assert err.startswith("publish_sweep: error: ")


def test_publish_sweep_names_an_escaping_sweep_folder_with_its_escapes_shown(publish, capsys):
    assert publish.main(["--name", "r", "--sweep", f"/nowhere/{ESC}"]) == 2
    assert "/nowhere/\\x1b]0;pwned\\x07\\x1b[31m" in _err(capsys)


#: the arguments a script requires, so that its parser gets as far as the unknown option
REQUIRED = {"publish_sweep": ["--name", "r"], "publish_bench": ["--name", "r"], "learning_curves": ["--data", "d"],
            "refinement_signal": ["run", "--data", "d"], "sweep_variants": ["--base", "b", "--root", "r"]}


@pytest.mark.parametrize("script", ["publish_sweep", "publish_bench"])
def test_an_unknown_option_of_a_publish_script_is_cut_and_escaped(script, capsys):
    mod = importlib.import_module(f"scripts.{script}")
    with pytest.raises(SystemExit) as e:
        mod.main(REQUIRED[script] + [f"--{ESC}" + "y" * 100_000])
    assert e.value.code == 2
    err = _err(capsys)
    assert "\x1b" not in err and len(err) < 1200 and "\\x1b]0;pwned" in err, err[:300]


BENCHMARKS = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py") if not p.name.startswith("_"))


@pytest.mark.parametrize("name", BENCHMARKS)
def test_every_benchmark_cuts_and_escapes_an_unknown_option(name, capsys):
    mod = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as e:
        mod.main(REQUIRED.get(name, []) + [f"--{ESC}" + "y" * 100_000])
    assert e.value.code == 2
    err = _err(capsys)
    assert "\x1b" not in err and len(err) < 2500 and "\\x1b]0;pwned" in err, err[:300]


def test_sweep_variants_cuts_and_escapes_a_bad_variant(tmp_path, capsys):
    mod = importlib.import_module("benchmarks.sweep_variants")
    with pytest.raises(SystemExit) as e:
        mod.main(["--base", "x.yaml", "--source", str(tmp_path), "--root", str(tmp_path), "--only-table",
                  "--variant", f"../{ESC}" + "v" * 100_000 + ": a=1"])
    msg = str(e.value.code)
    assert msg.startswith("--variant '../\\x1b]0;pwned") and len(msg) < 400 and "\x1b" not in msg, msg[:300]


# --------------------------------------------------------------------------- item 6: the schema-1 fixture
def test_publish_sweep_refuses_the_schema_1_fixture_in_one_line(publish, tmp_path, capsys):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    shutil.copy(ROOT / "tests" / "study" / "data" / "results_v1.json", sweep / "results.json")
    assert publish.main(["--name", "v1", "--sweep", str(sweep)]) == 2  # before: KeyError: 'sweep_config'
    err = _err(capsys)
    assert err == (f"publish_sweep: error: {sweep / 'results.json'}: field 'sweep_config' is missing; not a sweep's "
                   "results (a schema-1 results.json, without the record of the sweep a report describes)\n"), err
    assert list(publish.RESULTS.iterdir()) == []


def test_publish_sweep_names_a_missing_sweep_config_key(publish, tmp_path, capsys):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    from study.results.files import read_results

    results = read_results(PROP / "results.json")  # the whole results (the committed file is compact)
    del results["sweep_config"]["eval"], results["previews"]
    (sweep / "results.json").write_text(json.dumps(results))
    assert publish.main(["--name", "p", "--sweep", str(sweep)]) == 2
    assert "field 'sweep_config.eval' is missing; not a sweep's results" in _err(capsys)
    assert list(publish.RESULTS.iterdir()) == []
