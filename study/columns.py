"""What each variant adds to a run's flat rows (``Variant.columns`` in `study.variants`, named there as
"study.columns:<function>"; `study.results.flat_rows` calls them): ``columns(base, own, entry)`` writes into the
as-trained row ``base`` and the variant's own row ``own`` from the variant's entry."""
from __future__ import annotations

import math

from study.results import INERT_M, number, flat_row


def trained_columns(base: dict, own: dict, entry: dict) -> None:
    """Variant ``trained``'s columns: how much the refinement acted, and its init stage's numbers and gain."""
    ref = entry.get("refinement") or {}
    base["refine.weight_move"] = number(ref.get("weight_move"))
    base["refine.depth_change_m"] = number(ref.get("depth_change_m"))
    base["refine.oracle_weight_move"] = number(ref.get("oracle_weight_move"))
    if math.isfinite(base["refine.depth_change_m"]):
        base["refine.inert"] = bool(base["refine.depth_change_m"] < INERT_M)
    if entry.get("init"):
        init = flat_row({"metrics": entry["init"]})
        for k in ("median.mean.abs_rel", "median.overlap.abs_rel", "median.non_overlap.abs_rel"):
            base[f"init.{k}"] = init.get(k, float("nan"))
        base["refine.gain"] = base["init.median.mean.abs_rel"] - base.get("median.mean.abs_rel", float("nan"))


def oracle_columns(base: dict, own: dict, entry: dict) -> None:
    """Variant ``oracle``'s columns on the as-trained row: its abs_rel and the refinement's headroom to it."""
    base["oracle.median.mean.abs_rel"] = own.get("median.mean.abs_rel", float("nan"))
    init = base.get("init.median.mean.abs_rel", base.get("median.mean.abs_rel", float("nan")))
    gap = init - base["oracle.median.mean.abs_rel"]
    base["refine.headroom"] = gap
    base["refine.headroom_closed"] = ((init - base.get("median.mean.abs_rel", float("nan"))) / gap
                                      if gap > 1e-9 else float("nan"))


def cut_columns(base: dict, own: dict, entry: dict) -> None:
    """Variant ``cut``'s columns: how much the refinement acted when cut, and (on the as-trained row) the mean
    |as trained - cut| depth, metres."""
    rc = entry.get("refinement") or {}
    own["refine.weight_move"] = number(rc.get("weight_move"))
    own["refine.depth_change_m"] = number(rc.get("depth_change_m"))
    base["cut.depth_change_m"] = number(rc.get("cut_change_m"))
