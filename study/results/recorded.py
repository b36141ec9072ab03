"""What each of a sweep's methods was trained with, read from its results (`study.report.compose` describes the runs from
it, not from the registry's defaults).

A row written by today's sweep records its resolved run config (``run_config``, `study.sweep.stages.run_stage`). A
results.json written before that records only each run's hash (``run_config_hash``, `mcdp.runs.run_hash`): its
config is re-resolved from the recorded sweep config (`study.sweep.config.run_config_for`: the presets, the
overrides, the pretraining's sha256) and taken only when it hashes to the recorded hash. Where neither is
there, the registry's defaults stand in (`mcdp.methods.model_config`), and the method is named as such.
"""
from __future__ import annotations

from typing import Any


def _rerun_config(results: dict, row: dict) -> dict | None:
    """The run config the recorded sweep config resolves to for this row, if it hashes to the recorded hash."""
    from corelib.configlib import config_hash, config_to_dict, hashed_dict
    from study.sweep.config import SweepConfig, run_config_for

    try:
        cfg = SweepConfig.model_validate(results["sweep_config"])
        pre = results.get("pretrain")
        rcfg, _ = run_config_for(cfg, row["method"], row["seed"], pre["weights"] if pre else None)
    except Exception:  # noqa: BLE001 (a preset gone, a key renamed since: not recoverable, said by the caller)
        return None
    d = hashed_dict(rcfg)
    if pre:
        d["model"]["init_from"] = {"sha256": pre.get("sha256")}
    return config_to_dict(rcfg) if config_hash(d) == row.get("run_config_hash") else None


def run_configs(results: dict) -> tuple[dict[str, Any], list[str]]:
    """({method: its first run's recorded `mcdp.config.ModelConfig`}, [the methods whose config was not
    recoverable, at the registry's defaults]) of the results' methods."""
    from mcdp.config import ModelConfig
    from mcdp.methods import METHODS, model_config

    out: dict[str, Any] = {}
    fallback: list[str] = []
    for m in results["methods"]:
        rows = [r for r in results.get("rows", []) if r.get("method") == m]
        rec = next((r["run_config"] for r in rows if r.get("run_config")), None)
        if rec is None and rows:
            rec = _rerun_config(results, rows[0])
        if rec is not None:
            out[m] = ModelConfig(**rec["model"])
        else:
            out[m] = model_config(METHODS[m])
            fallback.append(m)
    return out, fallback


def fallback_note(labels: list[str]) -> str:
    """What the report says of the methods `run_configs` described from the registry's defaults ('' if none)."""
    if not labels:
        return ""
    return (f" ({', '.join(labels)}: from the registry's defaults; this results.json records no run config that "
            "re-resolves to its runs' hash)")
