"""The sweep's worlds: render (or reuse) each overlap's dataset, its measured overlap, its two yardsticks
(constant depth, flat-road prior), and the record of an overlap over its worlds (``worlds: per_seed``).

Example::

    rec = render_stage(cfg, 0.30, sweep_dir, Counters(), print, False, world=1)
    rec["reference"], rec["prior"] = reference_stage(cfg, rec, sweep_dir, Counters(), print)
"""
from __future__ import annotations

import time
from pathlib import Path

from corelib.configlib import ConfigError, config_hash, config_to_dict
from corelib.version import code_version, warn_other_code
from study.sweep.config import SPLIT, SweepConfig, data_config_for, eval_config_for, world_key
from study.sweep.records import Counters, finite, read_json, summarize_metrics, write_json
from synth.overlap import OverlapKnob, target_pair_mean


def measured_overlap(ov: dict) -> dict:
    """Target and measured pixel overlap of a dataset (from its overlap record, `synth.dataset.Dataset.overlap`).

    ``measured_mean``: mean measured overlap over the adjacent pairs whose geometric
    target equals the sweep's target. In ``spacing`` mode the ring does not close, so
    the two pairs that take up the remaining angle (side cameras) have another target
    (a gap or a small overlap); they are listed per pair but not averaged.
    ``measured_all``: mean over every adjacent pair.
    """
    pp = ov.get("per_pair_measured", {})
    target = ov.get("target")
    knob = OverlapKnob.of(ov)
    mean_at_target, n_at_target = target_pair_mean(pp, knob.pair_target) if isinstance(pp, dict) else (float("nan"), 0)
    allm = [v["measured"] for v in pp.values() if finite(v.get("measured"))]
    return {
        "target": target,
        "mode": ov.get("mode"),
        "knob": knob.knob,
        "geometric": ov.get("geometric", target),
        "hfov_deg": ov.get("hfov_deg"),
        "yaw_spacing_deg": ov.get("yaw_spacing_deg"),
        "measured_mean": mean_at_target,
        "measured_all": sum(allm) / len(allm) if allm else float("nan"),
        "pairs_at_target": n_at_target,
        "pairs": len(pp),
        "per_pair": {k: {"target": v.get("target"), "measured": v.get("measured")} for k, v in pp.items()},
    }


def _mean_tree(trees: list):
    """Leaf by leaf mean of equally shaped JSON trees (numbers: mean of the finite ones; anything else: the first's)."""
    first = trees[0]
    if isinstance(first, dict):
        return {k: _mean_tree([t[k] for t in trees if isinstance(t, dict) and k in t]) for k in first}
    if isinstance(first, (int, float)) and not isinstance(first, bool):
        v = [float(t) for t in trees if finite(t)]
        return sum(v) / len(v) if v else float("nan")
    return first


def combine_worlds(recs: list[dict]) -> dict:
    """One overlap's record over its worlds (``worlds: per_seed``): the worlds' own records under ``worlds``;
    measured overlap and the two yardsticks averaged over the worlds (each yardstick is a property of a world,
    so its mean over the worlds is the yardstick of the pairs' mean); render time summed."""
    out = {k: recs[0][k] for k in ("overlap", "path", "config_hash", "splits")}
    out.update(world="per_seed", worlds=recs, data_seeds=[r["data_seed"] for r in recs],
               render_s=sum(r["render_s"] for r in recs if finite(r["render_s"])),
               render_skipped=all(r["render_skipped"] for r in recs),
               measured=_mean_tree([r["measured"] for r in recs]))
    for which in ("reference", "prior"):
        out[which] = _mean_tree([r[which] for r in recs])
    return out



def _rendered(out: Path):
    """The dataset rendered into `out` (a `synth.dataset.Dataset`), or None when there is none to reuse: no
    manifest (never rendered, or interrupted) or one that does not open (rendering again repairs it)."""
    from synth.dataset import MANIFEST
    from synth.open import open_dataset
    from synth.files import DatasetError

    if not (out / MANIFEST).is_file():
        return None
    try:
        return open_dataset(out)
    except DatasetError:
        return None


def render_stage(cfg: SweepConfig, overlap: float, sweep_dir: Path, counters: Counters, log, progress: bool,
                 world: int | None = None) -> dict:
    """Render (or reuse / resume) the dataset of one overlap (and world: `study.sweep.config.worlds_of`); its record."""
    from synth.open import open_dataset
    from synth.protocol import SPLITS
    from synth.render import render_dataset

    dcfg = data_config_for(cfg, overlap, world)
    h = config_hash(dcfg)
    wkey = world_key(overlap, world)
    out = sweep_dir / "data" / wkey
    ds = _rendered(out)
    status = read_json(out.parent / f"{wkey}.status.json", root=sweep_dir) or {}  # never through a link
    if ds is not None and ds.config_hash == h:
        counters.bump("render_skipped")
        log(f"[sweep] {wkey}: dataset {out} is complete (config hash {h[:12]}), reused")
        warn_other_code(f"dataset {out}", ds.code_version, lambda line: log(f"[sweep] {wkey}: {line}"))
        render_s, skipped = status.get("render_s", float("nan")), True
    else:
        if ds is not None:
            raise ConfigError(
                f"{out} holds a dataset with another config (hash {str(ds.config_hash)[:12]}, "
                f"requested {h[:12]}); the sweep's data settings changed: use a new --out or delete {out}")
        log(f"[sweep] {wkey}: rendering {dcfg.dataset.sequences} sequences x {dcfg.dataset.frames} "
            f"frames at {dcfg.camera.width}x{dcfg.camera.height} into {out}")
        t0 = time.perf_counter()
        summary = render_dataset(dcfg, out, workers=cfg.workers, engine=cfg.engine, progress=progress,
                                 log=lambda *a: log("[sweep]   " + " ".join(str(x) for x in a)))
        if not summary["complete"]:
            raise RuntimeError(f"render of {out} did not complete: {summary}")
        render_s = time.perf_counter() - t0  # this invocation only (an interrupted earlier part is not counted)
        skipped = False
        counters.bump("rendered")
        if summary.get("skipped_sequences"):
            counters.bump("render_resumed")
        ds = open_dataset(out)
        write_json(out.parent / f"{wkey}.status.json", {"config_hash": h, "render_s": render_s})
    ov = measured_overlap(ds.overlap)
    log(f"[sweep] {wkey}: target {ov['target']:.2f}, measured pixel overlap {ov['measured_mean']:.3f} "
        f"(mean of the {ov['pairs_at_target']}/{ov['pairs']} pairs at the target)")
    return {"overlap": overlap, "world": world, "data_seed": int(dcfg.seed), "path": str(out), "config_hash": h,
            "render_s": render_s, "render_skipped": skipped, "measured": ov, "splits": {k: len(ds.split(k)) for k in SPLITS}}


def reference_stage(cfg: SweepConfig, d: dict, sweep_dir: Path, counters: Counters, log) -> dict:
    """Evaluate the constant-depth reference on one overlap's test split (cached beside the dataset).

    The constant is the median ground-truth depth of the train split
    (`mcdp.priors.median_gt_depth`): a depth map with no structure at all. With median
    scaling its value does not matter (every image is scaled to its ground-truth median).
    A method worse than this reference has learnt no usable depth structure.
    """
    from mcdp.evaluate import evaluate
    from mcdp.priors import constant_depth_predictor, flat_road_predictor, median_gt_depth
    from synth.open import open_dataset

    o = d["overlap"]
    path = sweep_dir / "data" / f"{world_key(o, d.get('world'))}.reference.json"
    key = config_hash({"data": d["config_hash"], "eval": config_to_dict(cfg.eval),
                       "reference": "constant_train_median+flat_road+labels"})
    cached = read_json(path, root=sweep_dir)
    if cached is not None and cached.get("key") == key:
        counters.bump("reference_skipped")
        warn_other_code(f"yardsticks {path}", cached.get("code_version"), lambda line: log(f"[sweep] {line}"))
        return cached["reference"], cached["prior"]
    ds = open_dataset(d["path"])
    ecfg = eval_config_for(cfg)
    t0 = time.perf_counter()
    depth = median_gt_depth(ds, "train", ecfg)
    metrics = evaluate(ds, constant_depth_predictor(ds, depth), SPLIT, ecfg, progress=False)
    ref = {"kind": "constant depth = median ground-truth depth of the train split", "depth_m": depth,
           "metrics": summarize_metrics(metrics), "eval_s": time.perf_counter() - t0}
    t0 = time.perf_counter()
    metrics = evaluate(ds, flat_road_predictor(ds, depth), SPLIT, ecfg, progress=False)
    prior = {"kind": "flat-road prior: road-plane depth from the rig geometry, capped at the constant", "far_m": depth,
             "metrics": summarize_metrics(metrics), "eval_s": time.perf_counter() - t0}
    write_json(path, {"key": key, "reference": ref, "prior": prior, "code_version": code_version()})
    counters.bump("reference_evaluated")
    for name, r in (("constant-depth reference", ref), ("flat-road prior", prior)):
        log(f"[sweep] overlap {o:.2f}: {name} ({depth:.2f} m): abs_rel metric "
            f"{r['metrics']['none']['mean']['abs_rel']:.4f}, median {r['metrics']['median']['mean']['abs_rel']:.4f}, "
            f"dep_con {r['metrics']['dep_con']['mean']:.4f}")
    return ref, prior


def data_seeds(results: dict) -> dict[tuple[float, int], int]:
    """{(overlap, training seed): the data seed of the world that seed trained on}, from the sweep's recorded
    data (one world per overlap, or ``worlds: per_seed`` with ``seeds_per_world``), for results whose rows
    predate their ``world`` field."""
    cfg = results.get("sweep_config", {})
    seeds = list(results.get("seeds", []))
    per = int(cfg.get("seeds_per_world", 1) or 1)
    out = {}
    for d in results.get("data", []):
        worlds = d.get("worlds")
        for i, s in enumerate(seeds):
            if not worlds:
                if "data_seed" in d:
                    out[d["overlap"], s] = d["data_seed"]
                continue
            w = s if per == 1 else i // per   # study.sweep.config.world_of_seed
            rec = next((r for r in worlds if r.get("world") == w), None)
            if rec is not None and "data_seed" in rec:
                out[d["overlap"], s] = rec["data_seed"]
    return out
