"""The overlap sweep: config validation, and configs/sweep/ci.yaml end to end (render, train, eval,
report), then a rerun that skips everything, then a longer training that resumes from the checkpoint."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from corelib.configlib import ConfigError
from study import cli as study_cli
from study.sweep import config as sweep
from study.sweep.pretrain import load_pretrain_config, resolved_configs
from study.sweep.stages import STATUS



def _evs(res: dict) -> str:
    """The rows' evaluations ({variant: entry}) as JSON: NaN-safe equality (NaN != NaN in a plain ==)."""
    return json.dumps([r["evaluations"] for r in res["rows"]], sort_keys=True)

def sweep_main(argv):
    """`mcdp sweep ARGV` (the console script is study.cli.main)."""
    return study_cli.main(["sweep", *argv])

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"


# --------------------------------------------------------------------------- config (fast)
def test_presets_load():
    for name in ("ci", "cpu", "gpu", "cpu_propagation"):
        cfg = sweep.load_sweep_config(ROOT / "configs" / "sweep" / f"{name}.yaml")
        assert cfg.overlap_mode == "spacing"
        assert all(0.10 <= o <= 0.60 for o in cfg.overlaps)
        for m in cfg.methods:  # every method preset resolves
            sweep.run_config_for(cfg, m, cfg.seeds[0])
        sweep.data_config_for(cfg, cfg.overlaps[0])
        if cfg.pretrain is not None:  # and its pretraining (model.mono_head on the full architecture)
            resolved_configs(cfg.pretrain)
    for p in sorted((ROOT / "configs" / "pretrain").glob("*.yaml")):
        resolved_configs(load_pretrain_config(p))


def test_default_overlaps_and_methods():
    cfg = sweep.SweepConfig()
    assert cfg.overlaps == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    assert cfg.methods == ["mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2"]
    assert cfg.seeds == [0]


@pytest.mark.parametrize(
    "override, key",
    [
        ("overlaps=[0.05,0.2]", "overlaps"),
        ("overlaps=[0.7]", "overlaps"),
        ("overlaps=[]", "overlaps"),
        ("methods=[mono3]", "methods"),
        ("data_overrides=[rig.overlap=0.3]", "data_overrides"),
        ("train_overrides=[train.seed=3]", "train_overrides"),
        ("seeds=[1,1]", "seeds"),
        ("nonsense=1", "nonsense"),
        ("eval.min_depth=90", "eval"),
    ],
)
def test_bad_config_names_key(override, key):
    with pytest.raises(ConfigError, match=key):
        sweep.load_sweep_config(CI, [override])


def test_seeds_per_world_crosses_worlds_and_seeds():
    """The i-th seed trains on world i // seeds_per_world (rendered from the data preset's seed + that world);
    the default (1) keeps seed k on world k, and a shared world is None for every seed."""
    per_seed = ["worlds=per_seed", "seeds=[0,1,2,3,4,5]"]
    cfg = sweep.load_sweep_config(CI, [*per_seed, "seeds_per_world=2"])
    assert sweep.worlds_of(cfg) == [0, 1, 2]
    assert [sweep.world_of_seed(cfg, s) for s in cfg.seeds] == [0, 0, 1, 1, 2, 2]
    assert sweep.world_of_seed(cfg, 3) == 1
    base = sweep.data_config_for(cfg, 0.5).seed
    assert sweep.data_config_for(cfg, 0.5, sweep.world_of_seed(cfg, 3)).seed == base + 1
    three = sweep.load_sweep_config(CI, [*per_seed, "seeds_per_world=3"])
    assert sweep.worlds_of(three) == [0, 1]
    assert [sweep.world_of_seed(three, s) for s in three.seeds] == [0, 0, 0, 1, 1, 1]
    # by position in seeds, not by the seed's value
    odd = sweep.load_sweep_config(CI, ["worlds=per_seed", "seeds=[7,3,5,1]", "seeds_per_world=2"])
    assert sweep.worlds_of(odd) == [0, 1] and [sweep.world_of_seed(odd, s) for s in odd.seeds] == [0, 0, 1, 1]
    one = sweep.load_sweep_config(CI, per_seed)
    assert one.seeds_per_world == 1
    assert sweep.worlds_of(one) == [0, 1, 2, 3, 4, 5]
    assert [sweep.world_of_seed(one, s) for s in one.seeds] == [0, 1, 2, 3, 4, 5]
    shared = sweep.load_sweep_config(CI, ["seeds=[0,1]"])
    assert sweep.worlds_of(shared) == [None] and sweep.world_of_seed(shared, 1) is None
    # the preset that uses it: 3 worlds x 2 seeds
    prop = sweep.load_sweep_config(ROOT / "configs" / "sweep" / "cpu_propagation.yaml")
    assert prop.seeds_per_world == 2 and sweep.worlds_of(prop) == [0, 1, 2]
    assert [sweep.world_of_seed(prop, s) for s in prop.seeds] == [0, 0, 1, 1, 2, 2]


@pytest.mark.parametrize("overrides, said", [
    (["seeds=[0,1]", "seeds_per_world=2"], "seeds_per_world > 1 needs worlds: per_seed"),
    (["seeds=[0,1,2]", "worlds=per_seed", "seeds_per_world=2"],
     "seeds_per_world: 2 must divide the number of seeds (3)"),
    (["seeds=[0,1]", "worlds=per_seed", "seeds_per_world=0"],
     "seeds_per_world: Input should be greater than or equal to 1"),
])
def test_a_bad_seeds_per_world_is_one_error_line_naming_the_key(overrides, said):
    with pytest.raises(ConfigError) as e:
        sweep.load_sweep_config(CI, overrides)
    head, *errors = str(e.value).splitlines()
    assert head.startswith("invalid config (") and len(errors) == 1 and said in errors[0], str(e.value)


def test_seeds_per_world_at_its_default_keeps_the_sweep_hash():
    """An `added_key`: at its default (1) a preset's config hash is the hash of its config without the key, as
    before the key existed (every cached render and run kept); set, it changes it."""
    from corelib.configlib import config_hash, config_to_dict
    from corelib.hashing import json_sha256

    for args in ([], ["worlds=per_seed", "seeds=[0,1]"]):  # worlds itself an added key, hashed when set
        cfg = sweep.load_sweep_config(CI, [*args, "seeds_per_world=1"])
        before = config_to_dict(cfg)
        assert before.pop("seeds_per_world") == 1
        assert before.pop("plan") is None  # an added key at its default (issue 47): not hashed
        if not args:
            assert before.pop("worlds") == "shared"  # at its default: not hashed either
        assert config_hash(cfg) == config_hash(sweep.load_sweep_config(CI, args)) == json_sha256(before)
    crossed = ["worlds=per_seed", "seeds=[0,1]"]
    assert config_hash(sweep.load_sweep_config(CI, [*crossed, "seeds_per_world=2"])) != \
        config_hash(sweep.load_sweep_config(CI, crossed))


def test_overlaps_sorted_and_run_config_gets_seed_and_eval():
    cfg = sweep.load_sweep_config(CI, ["overlaps=[0.5,0.2]", "seeds=[3]", "eval.max_depth=60.0"])
    assert cfg.overlaps == [0.2, 0.5]
    rcfg, _ = sweep.run_config_for(cfg, "mcdp_m1", 3)
    assert rcfg.train.seed == 3 and rcfg.train.steps == 2 and rcfg.eval.max_depth == 60.0
    dcfg = sweep.data_config_for(cfg, 0.5)
    assert dcfg.rig.overlap == 0.5 and dcfg.rig.overlap_mode == "spacing" and dcfg.dataset.frames == 4


def test_cli_usage_error_returns_2(tmp_path, capsys):
    assert sweep_main([str(CI), "--out", str(tmp_path / "s"), "overlaps=[0.9]"]) == 2
    err = capsys.readouterr().err
    assert "overlaps must be in [0.10, 0.60]" in err and "unrecognized" not in err


def test_the_command_line_resolves_the_nested_configs_once(tmp_path, monkeypatch):
    """study/cli.py checks (resolves and sizes) every nested config before it says the size; run_sweep is told
    so and does not resolve them again (issue 42, item 7); called alone, run_sweep checks them itself."""
    import study.sweep_command as sw

    calls, seen = [], {}
    real = sweep.check_nested_configs
    monkeypatch.setattr(sweep, "check_nested_configs", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(sw, "check_nested_configs", sweep.check_nested_configs)
    monkeypatch.setattr(sw, "run_sweep", lambda cfg, out, **kw: seen.update(kw) or {"counters": {}, "rows": []})
    sweep_main([str(CI), "--out", str(tmp_path / "s"), "--no-progress"])
    assert calls == [1] and seen["checked"] is True


def test_overrides_may_follow_options():
    from corelib.cli import build_parser, parse_command_line

    parser = build_parser("mcdp", "", study_cli.COMMANDS)
    args = parse_command_line(parser, ["sweep", "p.yaml", "a=1", "--out", "d", "--no-progress", "b=2", "c=[0.2,0.3]"])
    assert (args.preset, args.out, args.no_progress, args.overrides) == ("p.yaml", "d", True, ["a=1", "b=2", "c=[0.2,0.3]"])
    assert args._run is study_cli.run_sweep_command


# --------------------------------------------------------------------------- end to end (ci preset)
def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


@pytest.mark.slow
def test_ci_sweep_end_to_end_rerun_and_resume(tmp_path, capsys, mini_sweep):
    out = tmp_path / "sweep"
    # ci.yaml's keep_last / keep_best: false (its 14 runs kept would hold 6 GB); the resume below keeps one run
    cfg = sweep.load_sweep_config(CI, [])
    n = len(cfg.overlaps) * len(cfg.methods) * len(cfg.seeds)
    assert sweep_main([str(CI), "--out", str(out), "--no-progress"]) == 0
    # overall progress (study.sweep.progress; jobs=2: runs reported as they finish): one line per stage and per run
    err = capsys.readouterr().err.splitlines()
    prog = [ln for ln in err if ln.startswith("[sweep] progress: ")]
    stages = [ln.rsplit("stage: ", 1)[1] for ln in prog]
    assert stages[:4] == ["pretraining", "render of overlap 0.20", "render of overlap 0.50", "yardsticks"]
    runs = [int(ln.split("progress: ")[1].split("/")[0]) for ln in prog if ln.endswith("stage: runs")]
    assert runs == list(range(n + 1)) and all(f"/{n} runs done" in ln for ln in prog)
    assert "ETA after the first run" in prog[4] and " s/run over 1 run(s))" in prog[5]
    assert err[-1].startswith(f"[sweep] finished: {n}/{n} runs in ") and err[-1].endswith(f"report: {out / 'report.md'}")

    for f in ["report.md", "results.csv", "results.json", "sweep_config.yaml",
              "plots/abs_rel_vs_overlap.png", "plots/dep_con_vs_overlap.png",
              "plots/overlap_vs_non_overlap_abs_rel.png", "plots/measured_overlap.png",
              "preview_overlap_0.20.png", "preview_overlap_0.50.png"]:
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f

    res = json.loads((out / "results.json").read_text())
    c = res["counters"]
    assert (c["rendered"], c["trained"], c["evaluated"], c["diverged"]) == (2, n, n, 0)
    assert (c["render_skipped"], c["train_skipped"], c["eval_skipped"]) == (0, 0, 0)
    assert res["seeds"] == [0]
    for d in res["data"]:
        assert _finite(d["measured"]["measured_mean"]) and d["measured"]["target"] == pytest.approx(d["overlap"])
        assert _finite(d["render_s"])
    seen = set()
    for r in res["rows"]:
        seen.add((r["overlap"], r["method"]))
        assert r["status"] == "ok"
        m = r["evaluations"]["trained"]["metrics"]
        for sc in ("none", "median"):
            assert _finite(m[sc]["mean"]["abs_rel"]), (r["overlap"], r["method"], sc)
            assert _finite(m[sc]["non_overlap"]["abs_rel"]), (r["overlap"], r["method"], sc)
        assert _finite(m["dep_con"]["mean"]), (r["overlap"], r["method"])
        assert _finite(r["train_s"]) and _finite(r["eval_s"])
        run = Path(r["run_dir"])
        assert (run / "config.yaml").is_file() and (run / "metrics_test.json").is_file()
        assert not (run / "checkpoints" / "last.pt").exists() and (run / "checkpoints" / "removed.json").is_file()
    assert seen == {(o, m) for o in cfg.overlaps for m in cfg.methods}

    for d in res["data"]:  # the constant-depth reference of every overlap
        ref = d["reference"]
        assert ref["depth_m"] > 0.5 and _finite(ref["metrics"]["median"]["mean"]["abs_rel"])
        assert _finite(ref["metrics"]["none"]["mean"]["abs_rel"]) and _finite(ref["metrics"]["dep_con"]["mean"])
    assert (c["reference_evaluated"], c["reference_skipped"]) == (2, 0)

    for d in res["data"]:  # and the flat-road prior
        assert d["prior"]["far_m"] == d["reference"]["depth_m"]
        assert _finite(d["prior"]["metrics"]["median"]["mean"]["abs_rel"])
    pre = res["pretrain"]  # the shared pretraining every run started from
    assert Path(pre["weights"]).is_file() and pre["step"] == 2
    for r in res["rows"]:
        rec = json.loads((Path(r["run_dir"]) / "run.json").read_text())["init_from"]
        assert rec["path"] == str(Path(pre["weights"]).resolve()) and rec["sha256"] == pre["sha256"]

    rows = list(csv.DictReader((out / "results.csv").open()))
    # beside each run (variant trained): variants oracle and oracle_overlap (the ORACLE weights fitted on all
    # pixels and on the overlap only) for every method with bases, cut for every one whose network reads
    # its neighbours at inference (MCDP with refinement, SurroundDepth; not FSM: nothing to cut), and
    # oracle_spread (the propagation ceiling) for every one that reads no other camera (Mono2, FSM, MCDP m0)
    with_bases = [m for m in cfg.methods if m.startswith("mcdp")]
    refined = [m for m in with_bases if m != "mcdp_m0"]
    cut = refined + ["surround"]
    alone = [m for m in cfg.methods if m not in cut]
    assert alone == ["mono2", "fsm", "mcdp_m0"]
    n_rows = n + len(cfg.overlaps) * len(cfg.seeds) * (2 * len(with_bases) + len(cut) + len(alone))
    assert len(rows) == n_rows + 2 * len(cfg.overlaps)
    assert {(r["method"], r["variant"]) for r in rows[:n_rows]} == (
        {(m, "trained") for m in cfg.methods} | {(m, "oracle") for m in with_bases}
        | {(m, "oracle_overlap") for m in with_bases} | {(m, "cut") for m in cut}
        | {(m, "oracle_spread") for m in alone})
    assert [r["method"] for r in rows[n_rows:]] == (["constant_reference"] * len(cfg.overlaps)
                                                     + ["flat_road_prior"] * len(cfg.overlaps))
    for row in rows[:n_rows]:  # every refined run records how much its refinement acted
        if row["method"] in refined and row["variant"] == "trained":
            assert float(row["refine.weight_move"]) >= 0 and float(row["refine.depth_change_m"]) >= 0
            assert row["refine.inert"] in ("True", "False")
    for row in rows:
        for k in ("none.mean.abs_rel", "median.mean.abs_rel", "dep_con.mean", "measured_overlap"):
            assert math.isfinite(float(row[k])), (row["overlap"], row["method"], k)

    report = (out / "report.md").read_text()
    for o in ("0.20", "0.50"):
        assert f"## Overlap {o}" in report
    for label in ("Mono2", "FSM", "SurroundDepth", "MCDP (m = 0)", "MCDP (w/o L_con, m = 1)", "MCDP (m = 1)", "MCDP (m = 2)"):
        assert label in report
    assert "Dep Con per camera" in report and "non-overlap" in report and "Time per stage" in report
    assert "seeds: [0]" in report
    assert report.count("Constant depth (ref.)") >= 1 + 4 * len(cfg.overlaps)  # setup + summary/Table 1/2/regions
    assert report.count("Flat-road prior (ref.)") >= 1 + 3 * len(cfg.overlaps)
    assert "Which mechanism gains from the overlap?" in report and "shared self-supervised pretraining" in report
    assert "Does the refinement act, use the neighbours, and propagate?" in report and "Inert refinements" in report

    # rerun: a no-op that skips every stage and reports the same numbers
    assert sweep_main([str(CI), "--out", str(out), "--no-progress"]) == 0
    res2 = json.loads((out / "results.json").read_text())
    c2 = res2["counters"]
    assert (c2["rendered"], c2["trained"], c2["evaluated"]) == (0, 0, 0)
    assert (c2["render_skipped"], c2["train_skipped"], c2["eval_skipped"], c2["reference_skipped"]) == (2, n, n, 2)
    assert _evs(res2) == _evs(res)

    # more steps for one run kept to be resumed: training resumes from its checkpoint (step 2 -> 3), nothing is
    # re-rendered (the session's rendered overlap 0.50 and pretraining, tests/study/conftest.py)
    one = tmp_path / "resume"
    mini_sweep.copy_to(one, "data", "pretrain")
    kept = ["--out", str(one), "--no-progress", "methods=[mono2]", "overlaps=[0.5]", "jobs=1", "keep_last=true",
            "keep_best=true"]
    assert sweep_main([str(CI), *kept]) == 0
    steps3 = [s.replace("train.steps=2", "train.steps=3") for s in cfg.train_overrides]
    assert sweep_main([str(CI), *kept, "train_overrides=[" + ",".join(steps3) + "]"]) == 0
    res3 = json.loads((one / "results.json").read_text())
    c3 = res3["counters"]
    assert (c3["render_skipped"], c3["trained"], c3["train_resumed"], c3["evaluated"]) == (1, 1, 1, 1)
    assert res3["rows"][0]["steps"] == 3

    # its checkpoints deleted by hand (not by keep_*: false, which records it): a rerun says what to do
    for f in (one / "runs" / "overlap_0.50" / "mono2_s0" / "checkpoints").glob("*.pt"):
        f.unlink()
    capsys.readouterr()
    assert sweep_main([str(CI), *kept, "train_overrides=[" + ",".join(steps3) + "]"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "has no checkpoint" in err[-1] and "removed by hand is not recorded" in err[-1], err[-3:]
    assert "delete the run folder to retrain it" in err[-1] and "Traceback" not in "\n".join(err)


@pytest.mark.slow
def test_parallel_jobs_give_the_same_numbers_as_sequential(mini_sweep, tmp_path):
    """jobs=2 (spawned processes) and jobs=1 (in process) train and evaluate identically."""
    common = ["--no-progress", "overlaps=[0.5]", "methods=[mono2,mcdp_m1]"]
    # both start from the session's rendered overlap 0.50 and pretraining (tests/study/conftest.py), reused
    # (what a rerun does): the engines' jobs are the runs, which each sweep trains and evaluates itself
    for name in ("seq", "par"):
        mini_sweep.copy_to(tmp_path / name, "data", "pretrain")
    assert sweep_main([str(CI), "--out", str(tmp_path / "seq"), "jobs=1", *common]) == 0
    assert sweep_main([str(CI), "--out", str(tmp_path / "par"), "jobs=2", *common]) == 0
    seq = json.loads((tmp_path / "seq" / "results.json").read_text())
    par = json.loads((tmp_path / "par" / "results.json").read_text())
    assert [(r["method"], r["status"]) for r in par["rows"]] == [("mono2", "ok"), ("mcdp_m1", "ok")]
    assert par["counters"]["trained"] == 2 and par["counters"]["evaluated"] == 2
    assert (par["counters"]["rendered"], par["counters"]["render_skipped"]) == (0, 1)
    assert par["pretrain"]["sha256"] == seq["pretrain"]["sha256"] == mini_sweep.results["pretrain"]["sha256"]
    for a, b in zip(seq["rows"], par["rows"]):
        assert a["method"] == b["method"]
        assert json.dumps(a["evaluations"], sort_keys=True) == json.dumps(b["evaluations"], sort_keys=True), a["method"]
    # the smoke sweep stays under the size the README states (68 MB for its 14 runs: the pretraining's 57 MB
    # pretrained.pt, and per run its numbers and logs, at most 0.53 MB, no checkpoint): per run and in all,
    # scaled to these two runs (one 108 MB best.pt or 324 MB last.pt left behind fails both)
    runs = sorted((tmp_path / "par" / "runs").glob("*/*"))
    assert len(runs) == 2 and all(_du(r) < 2e6 for r in runs), [(r.name, _du(r)) for r in runs]
    assert [f.name for f in (tmp_path / "par").rglob("*.pt")] == ["pretrained.pt"]
    assert _du(tmp_path / "par") < 70e6 + len(runs) * 2e6, _du(tmp_path / "par")


def _du(path: Path) -> int:
    """Bytes of the regular files under ``path``."""
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())


def test_the_smoke_sweep_keeps_no_checkpoint():
    """The README's smoke sweep deletes each run's last.pt (its 14 runs kept 6.0 GB of them) and best.pt (1.4 GB)
    once evaluated; keep_best: false alone (a run kept to be resumed) is refused; the key is hashed only when set."""
    from corelib.configlib import config_hash

    cfg = sweep.load_sweep_config(CI)
    assert cfg.keep_last is False and cfg.keep_best is False
    assert sweep.load_sweep_config(CI, ["keep_last=true", "keep_best=true"]).keep_last is True
    with pytest.raises(ConfigError, match="keep_best: false needs keep_last: false"):
        sweep.load_sweep_config(CI, ["keep_last=true"])
    assert config_hash(sweep.SweepConfig()) == config_hash(sweep.SweepConfig(keep_best=True)) \
        != config_hash(sweep.SweepConfig(keep_last=False, keep_best=False))


@pytest.mark.slow  # a whole sweep (the session's mini_sweep, conftest) and its reruns
def test_keep_last_false_removes_last_pt_after_eval_and_refuses_to_extend(mini_sweep, tmp_path, capsys):
    out = tmp_path / "sweep"
    mini_sweep.copy_to(out, "data", "pretrain")  # the session's rendered overlap 0.50 and pretraining, reused
    common = ["--out", str(out), "--no-progress", "overlaps=[0.5]", "methods=[mono2]", "jobs=1", "keep_last=false",
              "keep_best=true"]
    assert sweep_main([str(CI), *common]) == 0
    run = out / "runs" / "overlap_0.50" / "mono2_s0"
    assert not (run / "checkpoints" / "last.pt").exists() and (run / "checkpoints" / "best.pt").is_file()
    assert json.loads((run / STATUS).read_text())["last_removed"] is True
    first = json.loads((out / "results.json").read_text())
    assert first["rows"][0]["checkpoint"].endswith("best.pt")

    assert sweep_main([str(CI), *common]) == 0  # rerun: skipped, same numbers from the kept files
    again = json.loads((out / "results.json").read_text())
    assert (again["counters"]["train_skipped"], again["counters"]["eval_skipped"]) == (1, 1)
    assert _evs(again) == _evs(first)

    cfg = sweep.load_sweep_config(CI)
    steps3 = [s.replace("train.steps=2", "train.steps=3") for s in cfg.train_overrides]
    capsys.readouterr()
    assert sweep_main([str(CI), *common, "train_overrides=[" + ",".join(steps3) + "]"]) == 2
    err = capsys.readouterr().err
    assert str(run) in err and "keep_last: false" in err and "cannot resume" in err


@pytest.mark.slow  # a whole sweep (the session's mini_sweep, conftest) and its reruns
def test_keep_best_false_removes_the_checkpoints_after_eval_and_a_rerun_skips_from_the_record(mini_sweep, tmp_path,
                                                                                            capsys):
    """ci.yaml's keep_best: false: each run keeps its numbers and a record of the checkpoints it had, not the
    checkpoints; the pretraining keeps pretrained.pt only; a rerun trains and evaluates nothing; `mcdp eval`
    on such a run and a rerun that would evaluate it again each say why in one line."""
    from mcdp.runs import REMOVED

    # ci.yaml at one overlap, one method, in process (tests/study/conftest.py), run once for the session from
    # an empty folder: its copy, and what that sweep wrote to stderr
    out = mini_sweep.copy_to(tmp_path / "sweep")
    common = ["--out", str(out), *mini_sweep.args]
    assert common[2:] == ["--no-progress", "overlaps=[0.5]", "methods=[mono2]", "jobs=1", "workers=1",
                          "preview=false", "pretrain.workers=1"]
    err = mini_sweep.err
    run = out / "runs" / "overlap_0.50" / "mono2_s0"
    assert not list((run / "checkpoints").glob("*.pt")) and (run / "metrics_test.json").is_file()
    status = json.loads((run / STATUS).read_text())
    assert status["best_removed"] is True and status["last_removed"] is True and status["checkpoint_step"] == 2
    assert Path(status["checkpoint"]).name == "best.pt"
    files = json.loads((run / "checkpoints" / REMOVED).read_text())["files"]
    assert set(files) == {"best.pt", "last.pt"} and files["best.pt"]["step"] == 2 and files["best.pt"]["bytes"] > 1e6
    assert "keep_last: false" in files["last.pt"]["reason"] and "keep_best: false" in files["best.pt"]["reason"]
    line = [ln for ln in err.splitlines() if "mono2 seed 0: removed " in ln]
    assert len(line) == 1 and "checkpoints/last.pt (" in line[0] and "MB, keep_last: false)" in line[0] \
        and "checkpoints/best.pt (" in line[0] and "MB, keep_best: false)" in line[0], line
    pre = next((out / "pretrain").iterdir())
    assert (pre / "pretrained.pt").is_file() and not list((pre / "run" / "checkpoints").glob("*.pt"))
    assert set(json.loads((pre / "run" / "checkpoints" / REMOVED).read_text())["files"]) == {"best.pt", "last.pt"}
    assert "[sweep] pretraining: removed checkpoints/last.pt (" in err
    first = json.loads((out / "results.json").read_text())

    assert sweep_main([str(CI), *common]) == 0  # rerun: nothing trained or evaluated, the recorded numbers
    assert "removed" not in capsys.readouterr().err
    again = json.loads((out / "results.json").read_text())
    c = again["counters"]
    assert (c["trained"], c["evaluated"], c["train_skipped"], c["eval_skipped"]) == (0, 0, 1, 1)
    assert _evs(again) == _evs(first)
    assert again["rows"][0]["checkpoint"] == first["rows"][0]["checkpoint"]

    data = out / "data" / "overlap_0.50"
    assert study_cli.main(["eval", str(run), "--data", str(data), "--out", str(tmp_path / "m.json"),
                           "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"mcdp eval: error: run folder {run}: its checkpoint "
                                               "checkpoints/best.pt (step 2) was removed by the sweep's keep_best: "
                                               "false"), err

    # would train it again (the eval settings are in the run's config) or evaluate it again: refused, naming it
    assert sweep_main([str(CI), *common, "eval.max_depth=60.0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert str(run) in err and "best.pt by keep_best: false" in err and "cannot resume" in err, err
    assert sweep_main([str(CI), *common, "checkpoint=best"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert str(run) in err and "(keep_best: false)" in err and "cannot be evaluated again" in err, err
    assert not list((run / "checkpoints").glob("*.pt")) and (run / "metrics_test.json").is_file()
