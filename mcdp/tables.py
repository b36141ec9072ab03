"""Human-readable tables of a metrics.json (`mcdp.evaluate.evaluate`): per camera, per region, per class
group and motion, and Dep Con (`mcdp eval` prints them).

Example::

    print(format_tables(json.load(open("runs/m2/eval/metrics.json"))))
"""
from __future__ import annotations

import numpy as np

from mcdp.evaluate import SCALINGS
from mcdp.metrics import metric_names

#: what a ``nan`` means, said once under the tables that print one
NAN_ROWS = ("nan: no valid ground-truth pixel of that row in the evaluated images (a class group or motion "
            "absent from the split, a camera without overlap)")
NAN_DEP_CON = ("nan: no valid ground-truth pixel of the target camera was hit by its neighbour's splatted "
               "prediction in any image of the split")


def _isnan(x) -> bool:
    return x is None or (isinstance(x, float) and np.isnan(x))


def _fmt(x: float) -> str:
    return "   nan" if _isnan(x) else f"{x:6.3f}"


def format_tables(metrics: dict, stage: str = "final") -> str:
    """Human-readable per-camera tables (like the paper's Tables 1/2) for one stage.

    One table per scaling (none, median, rig_median): a row per camera, then
    the camera mean and the overlap / non-overlap means (with semantic labels: a row per class group
    and per static / moving pixels, and the movers' hole); then Dep Con per camera
    and per ordered pair (unscaled predictions).

    Args:
        metrics: the dict returned by :func:`evaluate` (or loaded from metrics.json).
        stage: which stage to print.

    Returns:
        multi-line string.
    """
    if stage not in metrics.get("stages", {}):
        raise ValueError(f"stage {stage!r} not in metrics (have {list(metrics.get('stages', {}))})")
    st = metrics["stages"][stage]
    cams = list(metrics["cameras"])
    w = max([len(c) for c in cams] + [len("non_overlap"), 8])
    header = f"{'camera':<{w}} " + " ".join(f"{k:>8}" for k in metric_names())
    lines = [
        f"split={metrics['split']} samples={metrics['n_samples']} stage={stage} "
        f"depth range [{metrics['min_depth']}, {metrics['max_depth']}] m"
        + (f" ground truth: {metrics['ground_truth'].get('kind')}" if "ground_truth" in metrics else "")
    ]
    ranged = [c for c, v in metrics.get("lenses", {}).items() if v.get("depth_kind") == "range"]
    if ranged:  # metrics of a range camera are of its stored depth kind (mcdp.evaluate)
        lines.append(f"range depth (ray length, not z): {', '.join(ranged)}")
    for sc in SCALINGS:
        if sc not in st:
            continue
        s = st[sc]
        lines += ["", f"scaling: {sc}", header, "-" * len(header)]
        for c in cams:
            lines.append(f"{c:<{w}} " + " ".join(f"  {_fmt(s['per_camera'][c][k])}" for k in metric_names()))
        lines.append("-" * len(header))
        for row in ("mean", "overlap", "non_overlap"):
            lines.append(f"{row:<{w}} " + " ".join(f"  {_fmt(s[row][k])}" for k in metric_names()))
        if "classes" in s:  # a dataset with semantic labels (mcdp.label_regions)
            lines.append("-" * len(header))
            rows = [(g, s["classes"][g]) for g in s["classes"]] + [(m, s["motion"][m]) for m in s["motion"]]
            for name, v in rows:
                lines.append(f"{name[:w]:<{w}} " + " ".join(f"  {_fmt(v[k])}" for k in metric_names()))
            h = s.get("holes", {})
            lines.append(f"movers beyond {h.get('ratio', 2.0):g}x their depth: {_fmt(h.get('moving'))} of "
                         f"{h.get('moving_pixels', 0)} moving-vehicle pixels (parked: {_fmt(h.get('parked'))} of "
                         f"{h.get('parked_pixels', 0)})")
    if any(" nan" in line for line in lines[1:] if not line.startswith("movers beyond")):
        lines.append(NAN_ROWS)
    dc = st.get("dep_con")
    if dc is not None:
        lines += ["", "Dep Con (unscaled predictions; lower is better)", f"{'camera':<{w}}   dep_con"]
        for c in cams:
            lines.append(f"{c:<{w}}   {_fmt(dc['per_camera'].get(c, float('nan')))}")
        lines.append(f"{'mean':<{w}}   {_fmt(dc['mean'])}")
        if dc["per_pair"]:
            lines.append("per pair (source -> target):")
            pw = max(len(p) for p in dc["per_pair"])
            for p, v in dc["per_pair"].items():
                lines.append(f"  {p:<{pw}}   {_fmt(v)}")
        if any(_isnan(v) for v in [dc["mean"], *dc["per_pair"].values(), *(dc["per_camera"].get(c, float("nan"))
                                                                              for c in cams)]):
            lines.append(NAN_DEP_CON)
    return "\n".join(lines)
