"""The one table of training methods: each is a row of the paper's Table 1 and of every report.

A method is an entry here: its name (the row key in sweeps and reports, and the name of its
presets ``configs/train/<name>.yaml`` and ``configs/train/tiny/<name>.yaml``), its display
label, the config values that make it this method (``defaults``: dotted keys, applied under
the preset and the user's overrides; the presets must agree with them, tested), and the class of
its depth network (which checks what it needs of ``ModelConfig``: ``check_config``, and holds the
method's own loss terms: ``loss_terms``). Table order = report order.

The package: this table (read before torch is imported: a row names its network and params model as
"module:Class" strings, imported when first built or checked), the contract (`mcdp.methods.base`) and
one module per network family (`mcdp.methods.mcdp`: MCDP and Mono2; `mcdp.methods.fsm`,
`mcdp.methods.surround`, `mcdp.methods.local`, `mcdp.methods.oracle_local`).

The depth network's contract is one class, `mcdp.methods.base.DepthNetwork`: every method's network
subclasses it (most through `mcdp.methods.mcdp.DepthModel`; `network_class` refuses anything else) and
overrides what differs. Its declared members, read as attributes and never probed:
``__init__(ModelConfig, params=None)`` (``params``: the validated ``method_params``), ``check_config(cfg)``
(classmethod: ConfigError naming the key), ``.cfg``,
``.stages`` (stage names, the last is evaluated), ``n_out`` (decoder depth channels), ``has_bases`` (n
bases combined by weights), ``uses_neighbours`` (the depth reads other cameras at inference: the sweep
also evaluates it cut), ``joint_pose`` (the pose network moves the rig as one), ``reads_overlap_truth``
(an ORACLE whose input holds the overlap's ground truth), ``fresh_parameters()`` (the layers no
pretraining initialises: they learn at ``train.weight_lr_mult`` x the rate), ``loss_terms(outputs,
batch, ctx)`` (the method's own terms, below) and ``forward(rgb, K, T_ego_cam, mask, nbr,
oracle_gt_median=None, scales=None, refine_scales=None, overlap_truth=None) -> {("disp" | "depth",
stage, scale): (B*N, 1, h, w), "stages": [...], "scale": (B*N,)}``. tests/mcdp/test_methods.py checks
every registered method against it.

A method's own loss terms: the network's ``loss_terms(outputs, batch, ctx) -> {name: scalar}``, each
scalar already weighted; `mcdp.system.SelfSupervisedSystem` adds them to the step's loss and logs
each under its name (the val loss that picks ``best.pt`` stays L_p + lambda L_con). ``outputs`` are
the depth network's own; what the terms read of the step besides them is the frozen
`mcdp.methods.base.LossContext` ``ctx``: ``cfg``, ``poses`` ({-1, +1}: (B*N, 4, 4) T_src_tgt, the camera
motions of the temporal warps: predicted, or the odometry's under ``scale.source=odometry``),
``pairs`` ((P,), (P,) int64: the directed adjacent camera pairs (tgt, src)) and ``step``, e.g. for
`mcdp.methods.fsm`.

A method's own parameters (e.g. FSM's loss weights): a pydantic model named in its row's ``params``;
the run config's ``method_params:`` section holds the keys a run sets, validated against that model
(`method_params`, `check_run`: an unknown key or a bad value is one ConfigError naming
``method_params.<key>``; a method without a model refuses any key), and the validated model reaches the
loss terms as ``ctx.params`` and the network's constructor as ``params`` (what sizes its own layers:
`mcdp.methods.surround.SurroundParams`). Left empty the section is not hashed, so runs that set nothing keep their
hashes (`corelib.configlib.added_key`).

A report reads a method through its row and network class, never its name: ``has_bases`` and
``fresh_layers(model_config(row))`` (`study.report.warm_start_line`), and the row's report flags: ``role``
(the paired ``baseline``, a ``method`` or a ``yardstick``), ``short`` (its label in a table column),
``nocon_of`` (the row it is trained without L_con) and ``reach`` (what `study.reach`, `study.primary` and
the distance figure read of it); tests/study/test_method_rows.py registers a toy mechanism that reaches them.

To add a method: write its network (its loss terms and its params model with it) in one module, then
add one line to `METHODS` below (or call `register` from your own code before training; `unregister`
removes it, e.g. in a test's teardown: tests/mcdp/test_toy_method.py does all of this)::

    register(Method("toy", "Toy net", {"model.method": "toy"}, ToyDepth, params=ToyParams))
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
    defaults: Mapping[str, Any] = field(default_factory=dict)
    #: the network's class (or any builder), or its "module:name", imported when first built or checked
    build: Callable[[ModelConfig], nn.Module] | str = "mcdp.methods.mcdp:DepthModel"
    #: the pydantic model of the method's own parameters (the run config's ``method_params`` section), or its
    #: "module:name", or None (then ``method_params`` must stay empty)
    params: type[BaseModel] | str | None = None
    #: what the row is in a report (`study`): "baseline" (the row every other is paired against: the paired
    #: figure, the "vs" columns; `baseline`), "method", or "yardstick" (reads ground truth: an ORACLE)
    role: str = "method"
    #: a shorter label where the report names it in a table's column or a comparison (default: ``label``)
    short: str = ""
    #: the name of the row this one is trained without L_con (its twin): the training-time propagation of
    #: L_con is this row's cut minus that row's cut (`study.reach`, `study.primary`)
    nocon_of: str | None = None
    #: what the report's reach section reads of the row (`study.reach`): "mechanism" (a propagation mechanism
    #: the experiment tests: its gain over the baseline, and, evaluated cut, its propagation at inference, in
    #: the tables, the distance figure and the primary comparisons), "reader" (only its propagation at
    #: inference), "global" (its bases give the global yardstick, variant ``oracle_overlap``), "local" (the local
    #: yardstick: its cut empties the ground truth it is given)
    reach: tuple[str, ...] = ()

    @property
    def short_label(self) -> str:
        return self.short or self.label

    @property
    def model(self) -> str:
        """The ``model.method`` value this method trains."""
        return str(self.defaults.get("model.method", self.name))

    @property
    def params_model(self) -> type[BaseModel] | None:
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
    Method("mono2", "Mono2", {"model.method": "mono2", "model.refine_steps": 0, "loss.consistency_weight": 0.0},
           "mcdp.methods.mcdp:MonoDepthModel", role="baseline"),
    Method("fsm", "FSM", {"model.method": "fsm", "model.refine_steps": 0, "loss.consistency_weight": 0.0},
           "mcdp.methods.fsm:FsmDepthModel", params="mcdp.methods.fsm:FsmParams", reach=("mechanism",)),
    Method("surround", "SurroundDepth", {"model.method": "surround", "model.refine_steps": 0,
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
    Method("mcdp_local", "MCDP-local (m = 2)", {"model.method": "mcdp_local", "model.refine_steps": 2,
                                                "loss.consistency_weight": PAPER_LAMBDA},
           "mcdp.methods.local:LocalDepthModel", short="MCDP-local", reach=("mechanism",)),
    # a yardstick, not a method: Mono2 + the ground-truth depth of the overlap pixels as input (filled / emptied)
    Method("oracle_local", "ORACLE-local (GT overlap input)", {"model.method": "oracle_local", "model.refine_steps": 0,
                                                              "loss.consistency_weight": 0.0},
           "mcdp.methods.oracle_local:OracleLocalModel", role="yardstick", short="ORACLE-local", reach=("local",)),
):
    register(_m)

#: the paper's rows (the sweep's default)
PAPER_METHODS = ("mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2")


def names() -> list[str]:
    return list(METHODS)


def baseline() -> str:
    """The name of the row every other is paired against (``role="baseline"``, the first such)."""
    return next(m.name for m in METHODS.values() if m.role == "baseline")


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
    """The method that trains ``cfg.method`` (the first registered one); ConfigError if none does."""
    for m in METHODS.values():
        if m.model == cfg.method:
            return m
    models = sorted({m.model for m in METHODS.values()})
    raise ConfigError(f"model.method {cfg.method!r} is not a registered method's model (registered: "
                      f"{', '.join(models)}; see mcdp/methods/__init__.py)")


def network_class(method: Method) -> type:
    """The method's network class: a subclass of `mcdp.methods.base.DepthNetwork`, the one contract (its declared
    members: ``stages``, ``n_out``, ``has_bases``, ``uses_neighbours``, ``joint_pose``,
    ``reads_overlap_truth``, ``fresh_parameters()``, ``check_config(cfg)``, ``check_rig(params, n_cameras)``,
    ``loss_terms``, ``forward``); TypeError otherwise."""
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
    """The run's method parameters: ``cfg.method_params`` validated against its method's params model
    (unset keys at the model's defaults), or None for a method without one. ConfigError, one line naming
    ``method_params.<key>``, for an unknown key or a bad value."""
    method = method_of(cfg.model)
    model, given = method.params_model, dict(cfg.method_params)
    if model is None:
        if given:
            raise ConfigError(f"method_params.{sorted(given)[0]}: method {method.name!r} has no parameters of its "
                              "own (leave method_params empty)")
        return None
    known = sorted(model.model_fields)
    for key in given:
        if key not in model.model_fields:
            raise ConfigError(f"method_params.{key}: unknown key for method {method.name!r} (its parameters: "
                              f"{', '.join(known)})")
    try:
        return model.model_validate(given)
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


def build_depth_model(cfg: ModelConfig, params: BaseModel | None = None) -> nn.Module:
    """The depth network for ``cfg.method`` (the builder of the first method that trains it), given the run's
    `method_params` (None: the params model's defaults, for a method that has one)."""
    return network_class(method_of(cfg))(cfg, params)
