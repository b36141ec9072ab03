"""The one table of training methods: each is a row of the paper's Table 1 and of every report.

A method is a row here (`Method`): its name (the row key in sweeps and reports), its display label, the
config values that make it this method (``defaults``: dotted keys applied under a preset and the user's
overrides; ``model.method`` is the row's name unless the row says otherwise, as the MCDP rows, which share
one network, do), the class of its depth network, and the pydantic class of its own parameters. Table
order = report order. A row needs no preset file of its own: ``configs/train/base.yaml`` (and
``configs/train/tiny/base.yaml``) under the row's defaults is its config (`mcdp train
configs/train/tiny/base.yaml --method NAME`, and the sweep for a method without a preset); the paper
rows' presets are that, written out (tested).

The network's contract is one class, `mcdp.methods.base.DepthNetwork` (its docstring is the contract):
every row's network subclasses it (`network_class` refuses anything else). This table is read before
torch is imported: a row may name its network and params class as "module:Class" strings, imported when
first built or checked. One module per network family: `mcdp.methods.depth_bases` (MCDP and Mono2),
`mcdp.methods.fsm`, `mcdp.methods.surround`, `mcdp.methods.local`, `mcdp.methods.oracle_local`.

A method's own parameters (e.g. FSM's loss weights): a pydantic class named in its row's ``params``; the
run config's ``method_params:`` section holds the keys a run sets, validated against that class
(`method_params`, `check_run`: an unknown key or a bad value is one ConfigError naming
``method_params.<key>``; a method without one refuses any key), and the validated parameters reach the
loss terms as ``ctx.params`` and the network's constructor as ``params``. Left empty the section is not
hashed, so runs that set nothing keep their hashes (`corelib.configlib.added_key`).

A method's own inputs: the `mcdp.inputs.InputField`s its network declares (``DepthNetwork.inputs``);
`fields_of` is what a run's data reader fills.

A report reads a method through its row and network class, never its name: ``has_bases`` and
``fresh_layers(model_config(row))`` (`study.sweep.pretrain.warm_start_line`), and the row's report flags: ``baseline``
(the row every other is paired against; a row's ``role``, "baseline", "method" or "yardstick", is derived: a
row whose network reads ground truth, ``reads_ground_truth()``, is a yardstick), ``short`` (its label in a table column),
``nocon_of`` (the row it is trained without L_con) and ``reach`` (what `study.report.sections.reach`, `study.report.sections.primary` and
the distance figure read of it); tests/study/test_method_rows.py registers a toy mechanism that reaches them.

To add a method: write its network (its loss terms, params class and input fields with it) in one
module, then add one line to `METHODS` below (or call `register` from your own code before training;
`unregister` removes it, e.g. in a test's teardown: tests/mcdp/test_toy_method.py does all of this)::

    register(Method("toy", "Toy net", {"model.refine_steps": 0}, ToyDepth, params=ToyParams))
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping

from pydantic import BaseModel, ValidationError

from corelib.configlib import ConfigError
from mcdp.config import LossConfig, ModelConfig, RunConfig

if TYPE_CHECKING:  # this table is read before torch is imported (a config is checked first)
    import torch.nn as nn

@dataclass(frozen=True)
class Method:
    name: str
    label: str
    #: the config values that make it this method; ``model.method`` defaults to ``name``
    defaults: Mapping[str, Any] = field(default_factory=dict)
    #: the network's class (a `mcdp.methods.base.DepthNetwork`), or its "module:name", imported when first built
    build: Callable[[ModelConfig], nn.Module] | str = "mcdp.methods.depth_bases:DepthModel"
    #: the pydantic class of the method's own parameters (the run config's ``method_params`` section), or its
    #: "module:name", or None (then ``method_params`` must stay empty)
    params: type[BaseModel] | str | None = None
    #: the row every other is paired against in a report (`study`: the paired figure, the "vs" columns, the prose
    #: that names it; `baseline`); its `role` is then "baseline"
    baseline: bool = False
    #: a shorter label where the report names it in a table's column or a comparison (default: ``label``)
    short: str = ""
    #: the name of the row this one is trained without L_con (its twin): the training-time propagation of
    #: L_con is this row's cut minus that row's cut (`study.report.sections.reach`, `study.report.sections.primary`)
    nocon_of: str | None = None
    #: what the report's reach section reads of the row (`study.report.sections.reach`): "mechanism" (a propagation mechanism
    #: the experiment tests: its gain over the baseline, and, evaluated cut, its propagation at inference, in
    #: the tables, the distance figure and the primary comparisons), "reader" (only its propagation at
    #: inference), "global" (its bases give the global yardstick, variant ``oracle_overlap``), "local" (the local
    #: yardstick: its cut empties the ground truth it is given)
    reach: tuple[str, ...] = ()

    @property
    def short_label(self) -> str:
        return self.short or self.label

    @property
    def role(self) -> str:
        """What the row is in a report: "baseline" (``baseline=True``), "yardstick" (its network reads ground truth,
        ``reads_ground_truth()``: an ORACLE, derived, never restated here) or "method". Imports the network's
        module when it was named as "module:name"."""
        if self.baseline:
            return "baseline"
        return "yardstick" if network_class(self).reads_ground_truth() else "method"

    def __post_init__(self) -> None:
        object.__setattr__(self, "defaults", {"model.method": self.name, **dict(self.defaults)})

    @property
    def params_class(self) -> type[BaseModel] | None:
        """`params`, imported if it was given as "module:name"."""
        return None if self.params is None else _resolve(self.params)

    @property
    def builder(self) -> Callable[[ModelConfig], nn.Module]:
        """`build`, imported if it was given as "module:name" (so this table never imports torch)."""
        return _resolve(self.build)


def _resolve(obj):
    """``obj`` itself, or the object a "module:name" string names."""
    if isinstance(obj, str):
        module, name = obj.split(":")
        return getattr(importlib.import_module(module), name)
    return obj


METHODS: dict[str, Method] = {}

#: L_con's weight of the MCDP rows: the one default in `mcdp.config.LossConfig` (the paper's 1e-3)
PAPER_LAMBDA = float(LossConfig.model_fields["consistency_weight"].default)


def register(method: Method) -> Method:
    """Add (or replace) a method; it appears in reports after the ones registered before it."""
    METHODS[method.name] = method
    return method


def unregister(name: str) -> Method:
    """Remove a registered method (e.g. a test's own, in its fixture's teardown); KeyError if none is so named."""
    return METHODS.pop(name)


for _m in (
    Method("mono2", "Mono2", {"model.refine_steps": 0, "loss.consistency_weight": 0.0},
           "mcdp.methods.depth_bases:MonoDepthModel", baseline=True),
    Method("fsm", "FSM", {"model.refine_steps": 0, "loss.consistency_weight": 0.0},
           "mcdp.methods.fsm:FsmDepthModel", params="mcdp.methods.fsm:FsmParams", reach=("mechanism",)),
    Method("surround", "SurroundDepth", {"model.refine_steps": 0,
                                         "loss.consistency_weight": 0.0}, "mcdp.methods.surround:SurroundDepthModel",
           params="mcdp.methods.surround:SurroundParams", reach=("reader",)),
    Method("mcdp_m0", "MCDP (m = 0)", {"model.method": "mcdp", "model.refine_steps": 0,
                                       "loss.consistency_weight": PAPER_LAMBDA}),
    Method("mcdp_m1_nocon", "MCDP (w/o L_con, m = 1)", {"model.method": "mcdp", "model.refine_steps": 1,
                                                         "loss.consistency_weight": 0.0}, nocon_of="mcdp_m1"),
    Method("mcdp_m1", "MCDP (m = 1)", {"model.method": "mcdp", "model.refine_steps": 1,
                                       "loss.consistency_weight": PAPER_LAMBDA}),
    Method("mcdp_m2", "MCDP (m = 2)", {"model.method": "mcdp", "model.refine_steps": 2,
                                       "loss.consistency_weight": PAPER_LAMBDA}, reach=("mechanism", "global")),
    # the training-time propagation baseline of mcdp_m2: the same network trained without L_con
    Method("mcdp_m2_nocon", "MCDP (w/o L_con, m = 2)", {"model.method": "mcdp", "model.refine_steps": 2,
                                                         "loss.consistency_weight": 0.0}, nocon_of="mcdp_m2"),
    # per-pixel basis weights fed the neighbours' warped features and depth: built to propagate locally
    Method("mcdp_local", "MCDP-local (m = 2)", {"model.refine_steps": 2,
                                                "loss.consistency_weight": PAPER_LAMBDA},
           "mcdp.methods.local:LocalDepthModel", short="MCDP-local", reach=("mechanism",)),
    # a yardstick, not a method: Mono2 + the ground-truth depth of the overlap pixels as input (filled / emptied)
    Method("oracle_local", "ORACLE-local (GT overlap input)", {"model.refine_steps": 0,
                                                              "loss.consistency_weight": 0.0},
           "mcdp.methods.oracle_local:OracleLocalModel", short="ORACLE-local", reach=("local",)),
):
    register(_m)

#: the paper's rows (the sweep's default)
PAPER_METHODS = ("mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2")


def names() -> list[str]:
    return list(METHODS)


def baseline() -> str:
    """The name of the row every other is paired against (``baseline=True``, the first such)."""
    return next(m.name for m in METHODS.values() if m.baseline)


def reading(what: str) -> list[str]:
    """The names of the rows whose ``reach`` holds ``what`` (`Method.reach`), table order."""
    return [m.name for m in METHODS.values() if what in m.reach]


def nocon_twins(name: str) -> list[str]:
    """The names of the rows that are row ``name`` trained without L_con (``nocon_of``), table order."""
    return [m.name for m in METHODS.values() if m.nocon_of == name]


def short_label(name: str) -> str:
    return METHODS[name].short_label if name in METHODS else name


def label(name: str) -> str:
    return METHODS[name].label if name in METHODS else name


def method_of(cfg: ModelConfig) -> Method:
    """The method that trains ``cfg.method`` (the first registered row whose ``model.method`` it is); ConfigError
    if none does."""
    for m in METHODS.values():
        if m.defaults["model.method"] == cfg.method:
            return m
    models = sorted({m.defaults["model.method"] for m in METHODS.values()})
    raise ConfigError(f"model.method {cfg.method!r} is not a registered method's model (registered: "
                      f"{', '.join(models)}; see mcdp/methods/__init__.py)")


def network_class(method: Method) -> type:
    """The method's network class: a subclass of `mcdp.methods.base.DepthNetwork`, the one contract; TypeError
    otherwise."""
    from mcdp.methods.base import DepthNetwork

    net = method.builder
    if not (isinstance(net, type) and issubclass(net, DepthNetwork)):
        raise TypeError(f"method {method.name!r}: its network {net!r} must be a subclass of "
                        "mcdp.methods.base.DepthNetwork (the contract every trainer, predictor and report reads)")
    return net


def model_config(method: Method) -> ModelConfig:
    """The ``model`` section a method's registry defaults make (every other key at `ModelConfig`'s default):
    what a report reads of a method without a run, e.g. ``network_class(m).fresh_layers(model_config(m))``."""
    return ModelConfig(**{k.split(".", 1)[1]: v for k, v in method.defaults.items() if k.startswith("model.")})


def check_model(cfg: ModelConfig) -> None:
    """ConfigError, naming the key, when ``cfg.method``'s network cannot be built from ``cfg`` (without building it)."""
    network_class(method_of(cfg)).check_config(cfg)


def method_params(cfg: RunConfig) -> BaseModel | None:
    """The run's method parameters: ``cfg.method_params`` validated against its method's params class
    (unset keys at the class's defaults), or None for a method without one. ConfigError, one line naming
    ``method_params.<key>``, for an unknown key or a bad value."""
    method = method_of(cfg.model)
    params_class, given = method.params_class, dict(cfg.method_params)
    if params_class is None:
        if given:
            raise ConfigError(f"method_params.{sorted(given)[0]}: method {method.name!r} has no parameters of its "
                              "own (leave method_params empty)")
        return None
    known = sorted(params_class.model_fields)
    for key in given:
        if key not in params_class.model_fields:
            raise ConfigError(f"method_params.{key}: unknown key for method {method.name!r} (its parameters: "
                              f"{', '.join(known)})")
    try:
        return params_class.model_validate(given)
    except ValidationError as err:
        e = err.errors()[0]
        where = "".join(f".{p}" for p in e["loc"])  # () for a check across keys (the section as a whole)
        raise ConfigError(f"method_params{where}: {e['msg']} (got {str(e.get('input'))[:80]!r})") from None


def check_run(cfg: RunConfig, n_cameras: int | None = None) -> None:
    """ConfigError, naming the key, when ``cfg``'s network cannot be built or its method_params are wrong, or
    (given ``n_cameras``) it cannot take a rig of that many cameras (``check_rig``)."""
    check_model(cfg.model)
    params = method_params(cfg)
    if n_cameras is not None:
        network_class(method_of(cfg.model)).check_rig(params, n_cameras)


def build_network(cfg: ModelConfig, params: BaseModel | None = None) -> nn.Module:
    """The depth network for ``cfg.method`` (the network of the first method that trains it), given the run's
    `method_params` (None: the params class's defaults, for a method that has one)."""
    return network_class(method_of(cfg))(cfg, params)


def fields_of(cfg: RunConfig) -> tuple:
    """The optional input fields (`mcdp.inputs.InputField`) a run's data reader fills: its network's declared
    ``inputs``, and `mcdp.methods.base.GT_MEDIAN` when the run is scaled by the ORACLE (``scale.source=
    oracle_gt_median``)."""
    from mcdp.methods.base import GT_MEDIAN

    declared = tuple(network_class(method_of(cfg.model)).inputs)
    return declared + ((GT_MEDIAN,) if cfg.scale.oracle and GT_MEDIAN not in declared else ())
