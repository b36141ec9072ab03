"""Publish the camera-model page, docs/results/camera_models.md, from committed data: never edited by hand (issue 59).

    python scripts/publish_camera_models.py --collect sweeps/camera_models   # once, after the runs -> values.json
    python scripts/publish_camera_models.py                                  # the page from values.json

The study (its plan: configs/sweep/cpu_camera_models.yaml, stated before any run): Mono2, FSM and MCDP (m = 2) at
the L_con recipe's scale, one sweep folder per arm under the study's folder (`scripts/camera_models.sh`):

- ``<method>_lens``: the six-camera rig with mild radial-tangential distortion (configs/data/distorted.yaml),
  trained through its lens (``model.lens=rig``, the default);
- ``<method>_pinhole``: the same worlds, trained as if the cameras were pinhole (``model.lens=pinhole``: the
  distortion dropped in the run's warps), evaluated through the true lens like every run;
- ``<method>_fisheye``: the four-camera 190 degree Kannala-Brandt rig (configs/data/fisheye.yaml) at its native
  overlap, through its lens (depth there is range, the ray length).

``--collect`` keeps, per arm and world, only the columns the page reads, the yardsticks (a constant depth, the
flat-road prior: no training) and each rig's distortion size (how far the lens moves a pixel from where a pinhole
with the same K puts it, from the rendered rig.json). The page reads that file and
docs/results/camera_models/preface.md. Sign: the project's one convention, positive = the change helps.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

RESULTS = ROOT / "docs" / "results"
DIR = RESULTS / "camera_models"
VALUES = DIR / "values.json"
METHODS = ("mono2", "fsm", "mcdp_m2")
WORDS = {"mono2": "Mono2", "fsm": "FSM", "mcdp_m2": "MCDP (m = 2)"}
RIGS = {"lens": "distorted (radtan), through its lens", "pinhole": "distorted (radtan), as if pinhole",
        "fisheye": "fisheye (Kannala-Brandt, 190 deg), through its lens"}
COLUMNS = ("median.mean.abs_rel", "median.overlap.abs_rel", "median.non_overlap.abs_rel", "none.mean.abs_rel",
           "dep_con.mean")
YARDSTICKS = ("constant_reference", "flat_road_prior")
PRIMARY = ("mono2", "median.mean.abs_rel")


def _distortion_px(data_dir: Path) -> dict:
    """{camera: the largest distance (px) over the image's pixel centres between where the lens images a pixel's
    ray and where a pinhole with the same K would}: how strong the distortion is that ``model.lens=pinhole`` drops."""
    import numpy as np

    from corelib.readfile import read_text_inside
    from synth import camera

    rig = json.loads(read_text_inside(data_dir / "rig.json", data_dir, 1 << 20))
    out = {}
    for c in rig["cameras"]:
        if c.get("model", "pinhole") == "pinhole":
            out[c["name"]] = 0.0
            continue
        K = np.asarray(c["K"], np.float64)
        names = camera.model(c["model"]).dist_names
        cam = camera.Intrinsics(c["model"], K, tuple(float(c["dist"][n]) for n in names))
        if camera.depth_kind(cam) == "range":  # a fisheye has no pinhole image of its field of view to compare with
            continue
        W, H = int(c["width"]), int(c["height"])
        r = camera.rays(cam, H, W)
        ok = np.isfinite(r).all(0)
        uv, front = camera.project(K, r[:, ok])
        v, u = np.divmod(np.flatnonzero(ok), W)
        out[c["name"]] = float(np.hypot(uv[0] - (u + 0.5), uv[1] - (v + 0.5)).max())
    return out


def collect(folder: Path) -> dict:
    """{"arms": {arm: {world: {column: value}}}, "yardsticks": {rig: {name: {column: mean over worlds}}},
    "distortion_px": {rig: {camera: px}}, "train_s": {arm: [...]}}."""
    from study.report.sections.calibration import arm_train_seconds, arm_values

    out: dict = {"arms": {}, "yardsticks": {}, "distortion_px": {}, "train_s": {}}
    for m in METHODS:
        for rig in RIGS:
            sub = folder / f"{m}_{rig}"
            if not (sub / "results.csv").is_file():
                continue
            out["arms"][f"{m}_{rig}"] = {str(w): v for w, v in sorted(arm_values(sub, set(COLUMNS), m).items())}
            out["train_s"][f"{m}_{rig}"] = arm_train_seconds(sub, m)
            key = "fisheye" if rig == "fisheye" else "distorted"
            if key not in out["yardsticks"]:
                out["yardsticks"][key] = {y: arm_values(sub, set(COLUMNS), y).get(-1, {}) for y in YARDSTICKS}
                data = sorted(p for p in (sub / "data").glob("overlap_*") if (p / "rig.json").is_file())
                if data and key == "distorted":
                    out["distortion_px"][key] = _distortion_px(data[0])
    return out


def _diff(values: dict, base: str, changed: str, col: str) -> dict:
    """base - changed over the worlds both arms have (positive = the change helps for a lower-better column)."""
    from study.report.sections.calibration import paired

    a, b = values["arms"].get(base, {}), values["arms"].get(changed, {})
    worlds = sorted(set(a) & set(b), key=int)
    d = [a[w][col] - b[w][col] for w in worlds if math.isfinite(a[w][col]) and math.isfinite(b[w][col])]
    return {**paired(d), "worlds": len(d)}


def _level(values: dict, arm: str, col: str) -> str:
    v = [x[col] for x in values["arms"].get(arm, {}).values() if math.isfinite(x[col])]
    return f"{sum(v) / len(v):.3f}" if v else "—"


def _power_line(diffs: list[float]) -> str:
    """What the primary could have seen: its MDE at 80 % power and the equivalence test against the preset's bound
    (``plan.delta`` of the camera-model preset), from the one reading over worlds."""
    from study.stats.design import reading_over_worlds
    from study.sweep.config import load_sweep_config

    delta = load_sweep_config(ROOT / "configs" / "sweep" / "cpu_camera_models.yaml").plan.delta
    if len(diffs) < 2:
        return f"What the primary could see: not measured ({len(diffs)} world; an interval needs 2).\n"
    r = reading_over_worlds({w: [x] for w, x in enumerate(diffs)}, {"delta": delta})
    t = r["tost"]
    verdict = (f"equivalent to 0 within ±{delta:g}" if t["equivalent"] else
               f"not shown equivalent to 0 within ±{delta:g}")
    return (f"What the primary could see, at {r['n_worlds']} worlds: an effect of ±{r['mde80']:.4f} at 80 % power; "
            f"{verdict} (two one-sided tests, p = {t['p']:.3f}; the bound is the preset's `plan.delta`, stated "
            f"before the runs).\n")


def build(values: dict) -> str:
    from study.results.summary import fmt_diff

    def cell(d: dict) -> str:
        if not d["worlds"]:
            return "—"
        word = ("helps" if d["mean"] > 0 else "hurts") if d["n"] >= 2 and abs(d["mean"]) > d["half"] else \
            "unresolved"
        return f"{fmt_diff({'mean': d['mean'], 'ci95': d['half']})} ({d['worlds']} worlds; {word})"

    lines = ["# Camera models: what modelling the lens is worth, and a fisheye rig trained through its lens\n",
             "> Generated by `python scripts/publish_camera_models.py` from `docs/results/camera_models/values.json`; "
             "never edited by hand.\n"]
    m, col = PRIMARY
    p = _diff(values, f"{m}_pinhole", f"{m}_lens", col)
    if p["worlds"]:
        lines.append(f"**Primary (stated before the runs): {WORDS[m]} on the distorted rig, trained through its lens "
                     f"against trained as if pinhole, median-scaled abs_rel over the six cameras: {cell(p)}.** "
                     "Positive = modelling the lens helps (as-if-pinhole - through the lens), the project's one sign "
                     "convention; ± the 95 % t interval over worlds; every arm is evaluated through the true lens.\n")
        lines.append(_power_line(p["diffs"]))
        ref = values.get("yardsticks", {}).get("distorted", {}).get("constant_reference", {}).get(col)
        lines.append(f"Its level: {WORDS[m]} through the lens {_level(values, f'{m}_lens', col)}, as if pinhole "
                     f"{_level(values, f'{m}_pinhole', col)} (mean over the worlds); a constant depth on the same rig "
                     + (f"{ref:.3f}" if isinstance(ref, (int, float)) and math.isfinite(ref) else "—")
                     + " (no training; the table below has every level).\n")
    dist = values.get("distortion_px", {})
    if dist.get("distorted"):
        px = dist["distorted"]
        lines.append(f"What is dropped: on the distorted rig the lens moves a pixel by up to {max(px.values()):.2f} px "
                     f"(at 96x64; the image corners) from where a pinhole with the same K puts it.\n")
    yard = values.get("yardsticks", {})
    lines += ["## Levels and yardsticks\n",
              "| rig | arm | median abs_rel | overlap | non-overlap | unscaled abs_rel | Dep Con |",
              "|---|---|---|---|---|---|---|"]
    for rig, words in RIGS.items():
        for meth in METHODS:
            arm = f"{meth}_{rig}"
            if arm in values["arms"]:
                lines.append(f"| {words} | {WORDS[meth]} ({len(values['arms'][arm])} worlds) | "
                             + " | ".join(_level(values, arm, c) for c in COLUMNS) + " |")
    for key, ys in yard.items():
        for y, v in ys.items():
            if v:
                lines.append(f"| {key} | {y} (no training) | " + " | ".join(
                    f"{v[c]:.3f}" if isinstance(v.get(c), float) and math.isfinite(v[c]) else "—" for c in COLUMNS)
                    + " |")
    lines += ["\n## Through the lens against as if pinhole (distorted rig; as-if-pinhole - through the lens)\n",
              "| method | median abs_rel | overlap | non-overlap | Dep Con |", "|---|---|---|---|---|"]
    for meth in METHODS:
        if f"{meth}_lens" in values["arms"] and f"{meth}_pinhole" in values["arms"]:
            lines.append(f"| {WORDS[meth]} | " + " | ".join(
                cell(_diff(values, f"{meth}_pinhole", f"{meth}_lens", c))
                for c in ("median.mean.abs_rel", "median.overlap.abs_rel", "median.non_overlap.abs_rel",
                          "dep_con.mean")) + " |")
    fish = [meth for meth in METHODS if f"{meth}_fisheye" in values["arms"]]
    if "mono2" in fish and len(fish) > 1:
        lines += ["\n## The fisheye rig: each multi-camera method against Mono2 (Mono2 - method)\n",
                  "| method | median abs_rel | overlap | non-overlap | Dep Con |", "|---|---|---|---|---|"]
        for meth in fish:
            if meth != "mono2":
                lines.append(f"| {WORDS[meth]} | " + " | ".join(
                    cell(_diff(values, "mono2_fisheye", f"{meth}_fisheye", c))
                    for c in ("median.mean.abs_rel", "median.overlap.abs_rel", "median.non_overlap.abs_rel",
                              "dep_con.mean")) + " |")
    lines += ["\n## Every world (median-scaled abs_rel; a run at or above its rig's constant depth has not learned depth)\n"]
    for rig, words in RIGS.items():
        arms = [f"{meth}_{rig}" for meth in METHODS if f"{meth}_{rig}" in values["arms"]]
        if not arms:
            continue
        worlds = sorted({w for a in arms for w in values["arms"][a]}, key=int)
        const = yard.get("fisheye" if rig == "fisheye" else "distorted", {}).get("constant_reference", {})
        lines += [f"\n{words}:\n", "| method | " + " | ".join(f"world {w}" for w in worlds) + " |",
                  "|---|" + "---|" * len(worlds)]
        for a in arms:
            v = values["arms"][a]
            lines.append(f"| {WORDS[a.rsplit('_', 1)[0]]} | " + " | ".join(
                f"{v[w]['median.mean.abs_rel']:.3f}" if w in v else "—" for w in worlds) + " |")
        if isinstance(const.get("median.mean.abs_rel"), float):
            lines.append(f"\n(constant depth, mean over these worlds: {const['median.mean.abs_rel']:.3f})")
    times = values.get("train_s", {})
    if times:
        tot = sum(sum(v) for v in times.values())
        lines.append(f"\nTraining time: {tot / 60:.1f} CPU-thread minutes over {sum(len(v) for v in times.values())} "
                     "runs (one thread each).\n")
    pre = DIR / "preface.md"
    if pre.is_file():
        from corelib.readfile import read_text_inside

        lines += ["", read_text_inside(pre, DIR, 1 << 20).rstrip("\n")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from corelib.atomic import atomic_write_text

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--collect", help="the study's folder: one sweep folder per arm (scripts/camera_models.sh)")
    args = p.parse_args(argv)
    DIR.mkdir(parents=True, exist_ok=True)
    if args.collect:
        atomic_write_text(VALUES, json.dumps(collect(Path(args.collect)), indent=1, sort_keys=True) + "\n")
    if not VALUES.is_file():
        print(f"publish_camera_models: {VALUES} is missing; run with --collect FOLDER first", file=sys.stderr)
        return 2
    from republish import publish_one  # the page from its row of study.report.pages.PAGES, as `republish.py camera_models`

    return publish_one("camera_models", "publish_camera_models")


if __name__ == "__main__":
    sys.exit(main())
