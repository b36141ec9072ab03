"""The sweep preset (`SweepConfig`) and the data / run / eval configs it resolves for each run.

Example::

    cfg = load_sweep_config("configs/sweep/ci.yaml", ["seeds=[0,1]"])
    dcfg = data_config_for(cfg, 0.3)                 # synth DataConfig with rig.overlap=0.30
    rcfg, preset = run_config_for(cfg, "mcdp_m2", seed=0)
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from corelib.configlib import ConfigError, StrictModel, added_key, config_to_dict, load_config, override_key, resolve_path
from mcdp.config import EVAL_MAX_DEPTH, EVAL_MIN_DEPTH
from mcdp.methods import METHODS, PAPER_METHODS, check_run
from study.sweep.pretrain import PretrainConfig



SPLIT = "test"


class SweepEvalConfig(StrictModel):
    """Evaluation settings applied to every run (see `mcdp.evaluate.EvalConfig`; depths in metres)."""

    min_depth: float = Field(EVAL_MIN_DEPTH, gt=0.0, le=1000.0, allow_inf_nan=False)
    max_depth: float = Field(EVAL_MAX_DEPTH, gt=0.0, le=1000.0, allow_inf_nan=False)
    frame_stride: int = Field(1, ge=1, le=10_000)
    skip_ends: bool = True

    @model_validator(mode="after")
    def _range(self) -> "SweepEvalConfig":
        if self.min_depth >= self.max_depth:
            raise ValueError(f"eval.min_depth ({self.min_depth}) must be < eval.max_depth ({self.max_depth})")
        return self


#: the plan's regions (`SweepPlan.region`) -> the section of a results row's metrics that holds them ("all": every
#: valid pixel, the metrics' ``mean`` section)
PLAN_REGIONS = {"all": "mean", "overlap": "overlap", "non_overlap": "non_overlap"}
#: the plan's scalings (`SweepPlan.scaling`; `study.report.sections.primary.SCALINGS` reads every one beside the primary)
PLAN_SCALINGS = ("median", "none", "rig_median")
#: how the words of a page name a region (`region_words`)
_REGION_WORDS = {"all": "all pixels", "overlap": "overlap pixels", "non_overlap": "non-overlap pixels"}


def region_words(region: str) -> str:
    """How a page names a plan's region: 'non-overlap pixels', 'all pixels', 'overlap pixels'."""
    return _REGION_WORDS[region]


class SweepPlan(StrictModel):
    """The analysis stated in the preset before the run (issues 47, 60), saved with the run (the resolved config,
    results.json's ``sweep_config.plan``) and read from there by the report (`study.report.sections.primary.plan_of`). Every key
    added after runs were recorded has today's behaviour as its default, so a result recorded before it reads
    as it was analysed.

    arms: the primary comparison's two arms, [base, changed] (each one of the sweep's ``methods``): the paired
        difference is base - changed on a lower-is-better metric, **positive = the change helps** (docs/DESIGN.md,
        the one sign convention). The sensor study compares two arms' changes between conditions: the changed
        arm's change - the base arm's (`study.report.sections.sensor`). null: no single primary pair (the page reads its own
        fixed comparisons, every one exploratory or named in the header).
    metric: the primary metric (a row of `mcdp.metrics.METRICS`).
    scaling: the primary scaling (``median``: per-image median scaling; ``none``; ``rig_median``); the page gives the
        others beside it.
    region: the pixels the primary metric is read on: ``non_overlap``, ``overlap`` or ``all``.
    overlap: the overlap of the primary comparisons (one of the sweep's ``overlaps``).
    delta: the equivalence bound of a primary null, in the primary metric (TOST at 95 %).
    stopping: ``one_look`` (the primary test read once, at the end) or ``obrien_fleming`` (two looks, at
        ``first_look`` and ``worlds``, with O'Brien-Fleming bounds: `study.stats.design.sequential_look`);
        not stated: ``obrien_fleming`` where ``first_look`` is given, as plans recorded before the key were read).
    worlds / first_look: how many worlds the primary comparison needs, and where the two-look design looks first
        (only with ``stopping: obrien_fleming``).
    tuning_worlds: the tuning/test split: the worlds (data seeds) that chose a setting and so are no test of it;
        empty (default): every world the sweep reads is a test world.
    why: what sized it.
    """

    arms: list[str] | None = added_key(None, min_length=2, max_length=2)
    metric: str = added_key("abs_rel", min_length=1, max_length=40)
    scaling: Literal["median", "none", "rig_median"] = added_key("median")
    region: Literal["all", "overlap", "non_overlap"] = added_key("non_overlap")
    overlap: float = added_key(0.10, ge=0.10, le=0.60, allow_inf_nan=False)
    delta: float = added_key(0.005, gt=0.0, le=1.0, allow_inf_nan=False)
    stopping: Literal["one_look", "obrien_fleming"] = added_key("one_look")
    worlds: int | None = Field(None, ge=2, le=10_000)
    first_look: int | None = Field(None, ge=2, le=10_000)
    tuning_worlds: list[int] = added_key(default_factory=list)
    why: str = Field("", max_length=300)

    @model_validator(mode="before")
    @classmethod
    def _stopping_of_a_recorded_plan(cls, data):
        """A plan recorded before ``stopping`` existed that names a first look was read with the two looks."""
        if isinstance(data, dict) and "stopping" not in data and data.get("first_look") is not None:
            return {**data, "stopping": "obrien_fleming"}
        return data

    @model_validator(mode="after")
    def _look(self) -> "SweepPlan":
        from mcdp.metrics import metric_names

        if self.arms is not None and self.arms[0] == self.arms[1]:
            raise ValueError(f"plan.arms: base and changed arm are both {self.arms[0]!r}; name two methods")
        if self.metric not in metric_names():
            raise ValueError(f"plan.metric: {self.metric!r} is not a metric (one of {', '.join(metric_names())})")
        if self.first_look is not None and (self.worlds is None or self.first_look >= self.worlds):
            raise ValueError(f"plan.first_look ({self.first_look}) must be below plan.worlds ({self.worlds})")
        if self.stopping == "obrien_fleming" and self.first_look is None:
            raise ValueError("plan.stopping: obrien_fleming needs plan.worlds and plan.first_look (its two looks)")
        if self.stopping == "one_look" and self.first_look is not None:
            raise ValueError(f"plan.stopping: one_look, but plan.first_look is {self.first_look} (a first look is "
                             "the obrien_fleming rule's)")
        if len(set(self.tuning_worlds)) != len(self.tuning_worlds) or any(
                not 0 <= w <= 2**32 - 1 for w in self.tuning_worlds):
            raise ValueError(f"plan.tuning_worlds: must be distinct data seeds in [0, 2^32 - 1], got "
                             f"{str(self.tuning_worlds)[:200]}")
        return self


class SweepConfig(StrictModel):
    """One overlap sweep; every default here, a preset lists what differs.

    data: data preset YAML (relative paths: to the working directory, else to the project root).
    data_overrides: dotted overrides for the data config (``rig.overlap``/``rig.overlap_mode`` are set per overlap).
    overlaps: target overlaps (shared fraction of hfov of adjacent cameras), each in [0.10, 0.60].
    overlap_mode: ``spacing`` (fixed intrinsics, yaw spacing solved: the clean experiment) or ``fov``.
    methods: registered methods (`mcdp.methods`; default the paper's five rows), each trained from
        ``<train_presets_dir>/<method>.yaml`` over the method's registry defaults.
    train_overrides: dotted overrides applied to every run (e.g. ``train.steps=200``).
    seeds: training seeds (``train.seed``); the dataset seed comes from the data preset.
    worlds: ``shared``: every seed trains on the same world per overlap (the data preset's seed);
        ``per_seed``: seed k trains on a world of its own, rendered at every overlap from data seed
        (preset seed + k), so a (world, seed) pair is still one pair across overlaps and methods, and
        the report's paired intervals cover the scene sample as well as the training seed.
    seeds_per_world: with ``worlds: per_seed``, how many training seeds share a world (crossed design:
        the i-th seed of ``seeds`` trains on world i // seeds_per_world, rendered from data seed preset seed +
        that world's index), so the report can split a paired difference's spread into a world part and a
        seed part (`study.stats.power`). 1 (default): seed k on world k, as above.
    eval: evaluation settings for every run.
    checkpoint: which checkpoint is evaluated: ``auto`` (best val loss, else last), ``best``, ``last``.
    workers: rendering processes (engine ``local``).
    jobs: runs (train + eval) at once, each in its own process (engine ``local``); on a CPU give
        each job ``train.threads`` cores (jobs x threads <= cores). Progress bars are off when > 1.
    engine: ``local`` (this machine: ``workers`` render processes, ``jobs`` run processes) or
        ``ray`` (every sequence of every render and every run is a Ray task, scheduled by Ray;
        `study.sweep.engines`, docs/SCALING.md); ``mcdp sweep --engine`` overrides it. Same results,
        resumption and skipping either way.
    ray_cpus: CPUs of the local Ray instance the sweep starts for ``engine: ray`` (null = the
        machine's cores); unused when ``RAY_ADDRESS`` names a cluster to join.
    device: training / inference device.
    preview: write a preview sheet of one rig at the smallest and largest overlap.
    plan: the pre-stated analysis (`SweepPlan`: the primary arms, metric, scaling, region and overlap, the
        equivalence bound delta, the stopping rule with its planned worlds and first look, the tuning/test split);
        the report reads it from the recorded config (null: today's defaults, 0.10 and 0.005, and no sequential
        reading).
    pretrain: a shared self-supervised pretraining (`study.sweep.pretrain.PretrainConfig`) that every
        run starts from (``model.init_from``), made once into ``SWEEP/pretrain/<hash>/`` and
        reused by its config hash; null = every run from scratch.
    keep_last: keep every run's ``checkpoints/last.pt`` (weights + Adam state: about three
        quarters of a run's disk). ``false`` removes it once the run is trained and its
        ``best.pt`` has been evaluated (only then), and the pretraining's ``run/checkpoints/last.pt``
        once the pretraining is finished (the runs start from its ``pretrained.pt``, which stays);
        the results, ``best.pt`` and rerun skipping are unaffected, but such a run can no longer be
        resumed with more steps (the sweep refuses, naming the run folder to delete).
    keep_best: keep every run's evaluated checkpoint (``best.pt``: its networks, no optimiser).
        ``false`` (needs ``keep_last: false``) removes it, and whatever checkpoint the run still has,
        once its evaluation is recorded (``metrics_test.json`` + ``sweep_status.json``), and the
        pretraining's ``run/checkpoints/best.pt`` (never read: the runs start from ``pretrained.pt``).
        Each such folder says what it had: ``checkpoints/removed.json`` (file, step, size, why), and
        a run's ``sweep_status.json`` ``best_removed``. A rerun still skips the run (from its recorded
        metrics); one that would evaluate or train it again (other eval settings, ``checkpoint``, a
        changed run config) is refused, naming the run folder to delete; ``mcdp eval`` / ``predict``
        on it says the checkpoint was removed. For sweeps whose numbers are all that is kept (the
        smoke sweep).
    """

    data: str = "configs/data/tiny.yaml"
    data_overrides: list[str] = Field(default_factory=list)
    overlaps: list[float] = Field(default_factory=lambda: [0.10, 0.20, 0.30, 0.40, 0.50, 0.60])
    overlap_mode: Literal["spacing", "fov"] = "spacing"
    methods: list[str] = Field(default_factory=lambda: list(PAPER_METHODS))
    train_presets_dir: str = "configs/train"
    train_overrides: list[str] = Field(default_factory=list)
    seeds: list[int] = Field(default_factory=lambda: [0])
    worlds: Literal["shared", "per_seed"] = added_key("shared")
    seeds_per_world: int = added_key(1, ge=1, le=16)
    eval: SweepEvalConfig = Field(default_factory=SweepEvalConfig)
    checkpoint: Literal["auto", "best", "last"] = "auto"
    workers: int = Field(2, ge=1, le=256)
    jobs: int = Field(1, ge=1, le=64)
    engine: Literal["local", "ray"] = "local"
    ray_cpus: int | None = Field(None, ge=1, le=4096)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    preview: bool = True
    keep_last: bool = True
    keep_best: bool = added_key(True)
    plan: SweepPlan | None = added_key(None)
    pretrain: PretrainConfig | None = None

    @model_validator(mode="after")
    def _keep(self) -> "SweepConfig":
        if not self.keep_best and self.keep_last:
            raise ValueError("keep_best: false needs keep_last: false (a run kept to be resumed keeps the "
                             "checkpoint it was evaluated with)")
        if self.seeds_per_world > 1:
            if self.worlds != "per_seed":
                raise ValueError("seeds_per_world > 1 needs worlds: per_seed")
            if len(self.seeds) % self.seeds_per_world:
                raise ValueError(f"seeds_per_world: {self.seeds_per_world} must divide the number of seeds "
                                 f"({len(self.seeds)})")
        if self.plan is not None and not any(abs(self.plan.overlap - o) < 1e-9 for o in self.overlaps):
            raise ValueError(f"plan.overlap: {self.plan.overlap:g} is not one of the swept overlaps "
                             f"({', '.join(f'{o:g}' for o in self.overlaps)})")
        for arm in (self.plan.arms or []) if self.plan is not None else []:
            if arm not in self.methods:
                raise ValueError(f"plan.arms: {arm!r} is not one of the methods ({', '.join(self.methods)})")
        return self

    @field_validator("overlaps")
    @classmethod
    def _overlaps(cls, v: list[float]) -> list[float]:
        if not v:
            raise ValueError("must list at least one overlap in [0.10, 0.60]")
        bad = [o for o in v if not 0.10 - 1e-9 <= o <= 0.60 + 1e-9]
        if bad:
            raise ValueError(f"overlaps must be in [0.10, 0.60], got {bad}")
        keys = [f"{o:.2f}" for o in v]
        if len(set(keys)) != len(keys):
            raise ValueError(f"overlaps must be distinct at 2 decimals, got {v}")
        return sorted(v)

    @field_validator("methods")
    @classmethod
    def _methods(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError(f"must list at least one of {', '.join(METHODS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"methods must be distinct, got {v}")
        unknown = [m for m in v if m not in METHODS]
        if unknown:
            raise ValueError(f"unknown method(s) {', '.join(map(str, unknown))[:200]}; registered "
                             f"(mcdp/methods/__init__.py): {', '.join(METHODS)}")
        return [m for m in METHODS if m in v]  # canonical (table) order

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: list[int]) -> list[int]:
        if not v:
            raise ValueError("must list at least one seed")
        if len(set(v)) != len(v) or any(not 0 <= s <= 2**32 - 1 for s in v):
            raise ValueError(f"seeds must be distinct and in [0, 2^32 - 1] (train.seed), got {str(v)[:200]}")
        return v

    @field_validator("data_overrides")
    @classmethod
    def _no_overlap_override(cls, v: list[str]) -> list[str]:
        for key in map(override_key, v):
            if key in ("rig.overlap", "rig.overlap_mode"):
                raise ValueError(f"{key} is set by the sweep (use overlaps / overlap_mode), not by data_overrides")
        return v

    @field_validator("train_overrides")
    @classmethod
    def _no_seed_override(cls, v: list[str]) -> list[str]:
        for key in map(override_key, v):
            if key == "train.seed":
                raise ValueError("train.seed is set by the sweep (use seeds), not by train_overrides")
            if key.startswith("eval."):
                raise ValueError(f"{key}: set evaluation settings in the sweep's eval section")
        return v


def overlap_key(o: float) -> str:
    return f"overlap_{o:.2f}"


def load_sweep_config(path: str | Path | None, overrides=(), values: dict | None = None) -> SweepConfig:
    """A preset, then ``key=value`` overrides, then `values` (the command line's own flags, e.g. ``--engine``)."""
    return load_config(SweepConfig, path, overrides, values)


def data_config_for(cfg: SweepConfig, overlap: float, world: int | None = None):
    """The resolved data config of one overlap (and, with ``worlds: per_seed``, of the world of seed
    ``world``: the data preset's seed + ``world``)."""
    from synth.config import DataConfig

    path = resolve_path(cfg.data, "data preset")
    values = {"rig.overlap": round(overlap, 2), "rig.overlap_mode": cfg.overlap_mode}
    if world is not None:
        base = load_config(DataConfig, path, cfg.data_overrides)
        values["seed"] = int(base.seed) + int(world)
    return load_config(DataConfig, path, cfg.data_overrides, values)


def worlds_of(cfg: SweepConfig) -> list[int | None]:
    """The worlds rendered per overlap: [None] (one shared world), one per seed (seed k: world k), or with
    ``seeds_per_world`` S > 1 worlds 0 .. len(seeds) / S - 1."""
    if cfg.worlds != "per_seed":
        return [None]
    if cfg.seeds_per_world == 1:
        return list(cfg.seeds)
    return list(range(len(cfg.seeds) // cfg.seeds_per_world))


def world_of_seed(cfg: SweepConfig, seed: int) -> int | None:
    """The world a training seed trains on (`worlds_of`): None (shared), the seed itself, or its block."""
    if cfg.worlds != "per_seed":
        return None
    if cfg.seeds_per_world == 1:
        return int(seed)
    return list(cfg.seeds).index(seed) // cfg.seeds_per_world


def world_key(overlap: float, world: int | None) -> str:
    """The folder name of one overlap's world: ``overlap_0.30`` (shared) or ``overlap_0.30_w2`` (seed 2's)."""
    return overlap_key(overlap) + ("" if world is None else f"_w{world}")


def run_config_for(cfg: SweepConfig, method: str, seed: int, init_from: str | None = None):
    """The resolved RunConfig of one (method, seed): preset + train_overrides + seed + eval + device
    (+ ``model.init_from``, the sweep's pretraining)."""
    from mcdp.config import RunConfig

    own = Path(cfg.train_presets_dir) / f"{method}.yaml"  # a method needs no preset: base.yaml + its row
    try:
        preset = resolve_path(own, "training preset")
    except ConfigError:
        preset = resolve_path(Path(cfg.train_presets_dir) / "base.yaml", f"training preset (no {own.name}, and)")
    values = {"train.seed": seed, "train.device": cfg.device, "eval": config_to_dict(cfg.eval)}
    if init_from is not None:
        values["model.init_from"] = init_from
    base = dict(METHODS[method].defaults)
    return load_config(RunConfig, preset, cfg.train_overrides, values, base=base), preset


def check_nested_configs(cfg: SweepConfig, yes: bool = False) -> dict:
    """Resolve every config the sweep will build (the pretraining's data and run configs, each overlap's
    data config, each (method, seed)'s run config), so that a wrong key or value in ``data_overrides`` /
    ``train_overrides`` (or the pretraining's) is a ConfigError naming it before anything is rendered;
    and the size of every render it will do (`synth.config.render_size`), all together refused above
    `synth.config.MAX_RENDER_BYTES` unless `yes`. Returns that total size."""
    from synth.config import check_render_size, render_size, total_render_size

    where = "pretrain"
    try:  # every config first, then what the networks need of them (that imports torch)
        worlds = []
        if cfg.pretrain is not None:
            from study.sweep.pretrain import resolved_configs

            worlds.append(resolved_configs(cfg.pretrain, check_network=False)[0])
        where = "data_overrides"
        worlds += [data_config_for(cfg, o, w) for o in cfg.overlaps for w in worlds_of(cfg)]
        where = "train_overrides"
        init_from = "pretrained.pt" if cfg.pretrain is not None else None
        runs = [run_config_for(cfg, method, seed, init_from)[0] for method in cfg.methods for seed in cfg.seeds]
        where = "pretrain"
        if cfg.pretrain is not None:
            resolved_configs(cfg.pretrain)
        where = "train_overrides"
        for rcfg in runs:
            check_run(rcfg)  # the network's keys and the method's own method_params
    except ConfigError as exc:
        raise ConfigError(f"sweep {where}: {exc}") from None
    size = total_render_size(render_size(w) for w in worlds)
    check_render_size(size, yes, f"sweep: its {len(worlds)} world(s) ({len(cfg.overlaps)} overlap(s) of {cfg.data}"
                      + (" and the pretraining's" if cfg.pretrain is not None else "") + ")",
                      "dataset.sequences / dataset.frames / camera.* in data_overrides (and pretrain.data_overrides)")
    return size


def eval_config_for(cfg: SweepConfig):
    """The `mcdp.evaluate.EvalConfig` every run and the reference are evaluated with."""
    from mcdp.evaluate import EvalConfig
    from corelib.configlib import build_config

    return build_config(EvalConfig, config_to_dict(cfg.eval), "sweep eval")
