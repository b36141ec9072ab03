"""Variants of one sweep recipe side by side: the consistency-weight table, the budget (learning-curve)
table, and probes of the refinement's knobs, all from ONE shared pretraining and the same datasets.

Feeds: docs/results/consistency_weight.md, docs/results/budget.md, docs/results/refinement.md
Record: ``--record PATH.csv`` also writes the table's rows to PATH (the CSV `scripts/publish_bench.py` reads).

Each variant is the base sweep preset plus its own training overrides, run by `mcdp sweep` into
``ROOT/<variant>/`` (so every number comes from the sweep's own evaluation: as trained, cut, ORACLE
weights, refinement acting). The source sweep's pretraining and datasets are hard-linked into each
variant's folder first, so they are made once (the sweep reuses them by their config hashes).

    python benchmarks/sweep_variants.py --base configs/sweep/cpu.yaml --source /work/sweeps/cpu \\
        --root /work/sweeps/lambda --set 'overlaps=[0.3]' 'methods=[mcdp_m2]' 'seeds=[0,1,2]' \\
        --variant 'lam0: loss.consistency_weight=0' --variant 'lam1e-3: loss.consistency_weight=1e-3' \\
        [--table lambda|budget] [--out docs/results/consistency_weight.md]

Rerunning resumes (finished runs are skipped). The table prints per variant, overlap and method the
mean over seeds ± 95 % t half-width of: median-scaled abs_rel (all / overlap / non-overlap), Dep Con
(ratio), depth spread (p90/p10), mean |w - 1/n| and |refined - init| (m), the propagation
(as trained - cut on non-overlap pixels, paired), the headroom closed ((init - final) / (init -
ORACLE)), and, where Mono2 is in the variant, MCDP - Mono2 (paired).
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from study.results.paired import paired_difference  # noqa: E402
from study.results.summary import evaluations, method_agg  # noqa: E402
from study.results.files import read_results  # noqa: E402
from study.sweep.variants import CUT, ORACLE, Evaluation  # noqa: E402
from benchmarks._table import markdown, show  # noqa: E402
from corelib.text import bounded  # noqa: E402


def link_tree(src: Path, dst: Path) -> None:
    """Hard-link every file of src into dst (same layout); existing files are kept."""
    for p in src.rglob("*"):
        q = dst / p.relative_to(src)
        if p.is_dir():
            q.mkdir(parents=True, exist_ok=True)
        elif p.is_file() and not p.is_symlink() and not q.exists() and p.name != ".lock":  # locks stay apart
            q.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(p, q)
            except OSError:
                shutil.copy2(p, q)


def share(source: Path, out: Path, link_methods: list[str] = ()) -> None:
    """The source sweep's pretraining (weights and record only) and datasets, linked into out; and the
    finished runs of ``link_methods`` (a variant whose runs of those methods are the source's own:
    same resolved config, so the sweep skips them; a changed config is refused by the sweep)."""
    for pre in sorted((source / "pretrain").glob("*")):
        dst = out / "pretrain" / pre.name
        dst.mkdir(parents=True, exist_ok=True)
        for name in ("pretrain.json", "pretrained.pt", "pretrain.config.json"):
            if (pre / name).is_file() and not (dst / name).exists():
                os.link(pre / name, dst / name)
    if (source / "data").is_dir():
        link_tree(source / "data", out / "data")
    for m in link_methods:
        for run in sorted((source / "runs").glob(f"*/{m}_s*")):
            if run.name.rsplit("_s", 1)[0] == m:
                link_tree(run, out / "runs" / run.parent.name / run.name)


def run_variant(base: str, root: Path, source: Path | None, name: str, train: list[str], sets: list[str],
                link_methods: list[str] = ()) -> Path:
    out = root / name
    if source is not None:
        from corelib.rundir import claim

        claim(out, "sweep").release()  # a sweep folder (refused if it is something else), then shared inputs
        share(source, out, link_methods)
    from study.sweep.config import load_sweep_config

    cfg = load_sweep_config(base, sets)
    overrides = list(cfg.train_overrides) + train
    args = [sys.executable, "-m", "study.cli", "sweep", base, "--out", str(out), "--no-progress",
            *sets, "train_overrides=[" + ",".join(overrides) + "]"]
    log = root / f"{name}.log"
    print(f"[variants] {name}: {' '.join(train) or '(base)'} -> {out}", flush=True)
    with open(log, "a") as fh:
        rc = subprocess.call(args, cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT)
    if rc != 0:
        raise SystemExit(bounded(f"[variants] {name}: mcdp sweep exited {rc}; see {log}"))
    return out


def _ms(a: dict, digits: int = 3) -> str:
    mu, hw = a.get("mean", math.nan), a.get("ci95", math.nan)
    if not (isinstance(mu, (int, float)) and math.isfinite(mu)):
        return "—"
    return f"{mu:.{digits}f}" + (f" ± {hw:.{digits}f}" if isinstance(hw, float) and math.isfinite(hw) else "")


def _pd(pd: dict, digits: int = 3) -> str:
    if not math.isfinite(pd["mean"]):
        return "—"
    mark = {-1: " (lower)", 1: " (higher)", 0: ""}[pd["differs"]]
    return f"{pd['mean']:+.{digits}f} ± {pd['ci95']:.{digits}f}{mark}"


def with_reference(res: dict, ref: dict | None) -> dict:
    """res with the reference sweep's Mono2 rows added at res's overlaps (same seeds pair the runs),
    so that a variant without Mono2 (e.g. a lambda that Mono2 does not have) is compared with it."""
    if ref is None or "mono2" in res["methods"]:
        return res
    mono2 = Evaluation("mono2")
    add = [f for f in ref["flat"] if mono2.matches(f) and f["overlap"] in res["overlaps"]
           and f["seed"] in res["seeds"]]
    if not add:
        return res
    aggs = [a for a in ref["aggregate"] if mono2.matches(a) and a["overlap"] in res["overlaps"]]
    return {**res, "flat": res["flat"] + add, "aggregate": res["aggregate"] + aggs,
            "methods": ["mono2"] + list(res["methods"])}


HEADER = ["variant", "overlap", "method", "abs_rel all", "overlap px", "non-overlap px", "Dep Con", "spread",
          "abs(w − 1/n)", "abs(refined − init) m", "propagation (trained − cut, non-overlap)",
          "direct use (trained − cut, overlap)", "headroom closed", "− Mono2 (all)", "− Mono2 (non-overlap)"]


def table_rows(rows: list[tuple[str, dict]]) -> list[list[str]]:
    """The table's rows (cells as printed) for the variants `rows` ((name, results) each), under HEADER."""
    L = []
    for name, res in rows:
        for o in res["overlaps"]:
            for m in res["methods"]:
                g = lambda k, d=3: _ms(method_agg(res, o, m, k), d)  # noqa: E731
                cut = Evaluation(m, CUT)
                has_cut = cut in evaluations(res)
                prop = _pd(paired_difference(res, o, m, cut, "median.non_overlap.abs_rel")) if has_cut else "—"
                direct = _pd(paired_difference(res, o, m, cut, "median.overlap.abs_rel")) if has_cut else "—"
                vs = lambda k: (_pd(paired_difference(res, o, m, "mono2", k))  # noqa: E731
                                if m != "mono2" and "mono2" in res["methods"] else "—")
                L.append([name, f"{o:.2f}", m, g("median.mean.abs_rel"), g("median.overlap.abs_rel"),
                          g("median.non_overlap.abs_rel"), g("dep_con.mean"), g("spread.ratio", 2),
                          g("refine.weight_move", 4), g("refine.depth_change_m"), prop, direct,
                          g("refine.headroom_closed", 2), vs("median.mean.abs_rel"), vs("median.non_overlap.abs_rel")])
            for m in res["methods"]:
                if Evaluation(m, ORACLE) in evaluations(res):
                    oracle = _ms(method_agg(res, o, Evaluation(m, ORACLE), "median.mean.abs_rel"))
                    L.append([name, f"{o:.2f}", f"*{m} ORACLE weights*", oracle] + [""] * (len(HEADER) - 4))
    return L


def table(rows: list[tuple[str, dict]]) -> str:
    """The Markdown table of the variants `rows`."""
    return markdown(HEADER, table_rows(rows))


def main(argv=None) -> None:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="sweep preset every variant starts from")
    ap.add_argument("--root", required=True, type=Path, help="folder of the variants' sweeps")
    ap.add_argument("--source", type=Path, help="a sweep folder whose pretraining and datasets are shared")
    ap.add_argument("--set", nargs="*", default=[], help="sweep-level overrides for every variant (key=value)")
    ap.add_argument("--variant", action="append", default=[],
                    help="'NAME: key=value key=value [| link=m1,m2]' (train overrides; link: reuse the source's runs) "
                         "or 'NAME: | source' (the source sweep's own runs at the --set overlaps and methods)")
    ap.add_argument("--only-table", action="store_true", help="do not run; tabulate finished variants")
    ap.add_argument("--reference", type=Path, help="a sweep's results.json whose Mono2 runs (same overlap and "
                    "seeds) are the comparison for variants without Mono2")
    ap.add_argument("--out", type=Path, help="also write the table (markdown) here")
    ap.add_argument("--record", type=Path, metavar="PATH",
                    help="also write the table's rows to PATH (CSV, the data file of docs/results/<doc>/)")
    args = ap.parse_args(argv)

    rows = []
    for v in args.variant:
        name, _, rest = v.partition(":")
        name = name.strip()
        rest, _, link = rest.partition("|")
        if link.strip() == "source":  # the source sweep's own runs are this variant (no run: its init_from differs)
            from study.sweep.config import load_sweep_config

            want = load_sweep_config(args.base, args.set)
            src = read_results(args.source / "results.json")
            ref = read_results(args.reference) if args.reference else None
            sub = {**src, "overlaps": [o for o in src["overlaps"] if o in want.overlaps],
                   "methods": [m for m in src["methods"] if m in want.methods]}
            rows.append((name, with_reference(sub, ref)))
            continue
        link_methods = [m for m in link.strip().removeprefix("link=").split(",") if m]
        if not name or "/" in name or name.startswith("."):
            raise SystemExit(bounded(f"--variant {v!r}: give 'NAME: overrides' with a plain NAME", 300))
        out = args.root / name
        if not args.only_table:
            out = run_variant(args.base, args.root, args.source, name, rest.split(), args.set, link_methods)
        res_path = out / "results.json"
        if res_path.is_file():
            ref = read_results(args.reference) if args.reference else None
            rows.append((name, with_reference(read_results(res_path), ref)))
    text = show(HEADER, table_rows(rows), record=args.record)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
