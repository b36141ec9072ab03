"""Publish the L_con page, docs/results/lcon.md, from the committed results of the sweeps that answer it
(issue 47): never edited by hand.

    python scripts/publish_lcon.py

Reads docs/results/<part>/results.json for each part below that has been published (`scripts/publish_sweep.py
--sweep SWEEP --name <part>`; a part not published yet is said to be missing), and docs/results/lcon/preface.md
(what the numbers cannot say: commands, wall times, the machine). Writes docs/results/lcon.md and its forest
plots under docs/results/lcon/plots/, each built in a temporary folder first (whole files, never through a link).

Its row of the page table (`study.report.pages.PAGES`) names its parts; ``main`` publishes that row
(`python scripts/republish.py lcon` does the same). Parts: lcon_main (the primary comparison (b) at overlap 0.10 on the main run's worlds, configs/sweep/cpu_lcon.yaml),
lcon_pilot (the pilot that sized it), lcon_pilot_auto (the pilot's runs read at each arm's own `auto` checkpoint),
lcon_overlaps ((b) at 0.10 / 0.30 / 0.60 on the pilot's worlds), lcon_budget ((b) at 1000 steps).
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from study.report.pages import row  # noqa: E402

NAME = "lcon"
#: the sweeps it reads, in the page's order: its row's (study.report.pages.PAGES)
PARTS = row(NAME).parts


def load_part(part: str) -> dict | None:
    """docs/results/<part>/results.json, checked and upgraded; None if not published (`publish_sweep.load_part`)."""
    from publish_sweep import load_part as load

    return load(part)


def _section(title: str, part: str, results: dict | None, plot_dir: Path, missing: str) -> tuple[list[str], list]:
    from study.report.sections.lcon import format_lcon

    if results is None:
        return [f"## {title}\n", f"Not published: {missing}\n"], []
    text, plots = format_lcon(results, plot_dir)
    # the section's own heading becomes this part's; the plots are linked from the page's folder
    text = text.replace("## (b) L_con's training-time effect outside the overlap\n", "", 1)
    c = results.get("sweep_config", {})
    steps = _steps(results)
    from study.report.sections.lcon import pairs

    worlds = sorted({p["world"] for o in results["overlaps"] for p in pairs(results, o)})
    span = f"{worlds[0]}-{worlds[-1]}" if worlds and worlds == list(range(worlds[0], worlds[-1] + 1)) else \
        ", ".join(map(str, worlds))
    head = (f"## {title}\n\n`docs/results/{part}/results.json` ([its full report]({part}.md)): "
            f"{len(worlds)} worlds (data seeds {span}), {steps} fine-tuning steps, "
            f"overlaps {', '.join(f'{o:.2f}' for o in results['overlaps'])}, checkpoint `{c.get('checkpoint')}`.\n")
    links = [f"![{p.stem}]({NAME}/plots/{part}_{p.name})\n" for p in plots]
    return [head, text] + links, [(p, f"{NAME}/plots/{part}_{p.name}") for p in plots]


def _steps(results: dict) -> str:
    """The fine-tuning budget a sweep's preset states (its `train.steps=` override), or "?"."""
    c = results.get("sweep_config", {})
    return next((o.split("=", 1)[1] for o in c.get("train_overrides", []) if o.startswith("train.steps=")), "?")


def _lc(text: str) -> str:
    """A sentence of `study.report.sections.lcon.answer` continued after a colon (its first word in lower case, L_con kept)."""
    return text if text.startswith("L_con") else text[:1].lower() + text[1:]


def build(stage: Path) -> tuple[str, list[tuple[Path, str]]]:
    """The page's text and its plots [(file in ``stage``, its path under docs/results/)]: its row of
    `study.report.pages.PAGES` (call ``stage``)."""
    from study.report.pages import preface as fill_preface
    from study.report.sections.lcon import answer, format_selection, levels, pairs, reading, selection_effect
    from study.report.sections.primary import SCALINGS, plan_of
    from study.results.summary import fmt_diff

    parts = {p: load_part(p) for p in PARTS}
    br = None  # (b) at the long budget beside its control: the opening lines and its section read it
    if parts["lcon_budget"] is not None:
        from study.report.sections.lcon import budget_reading

        br = budget_reading(parts["lcon_budget"], parts["lcon_main"])
    L: list[str] = ["# Does training with L_con on a small overlap make depth better outside it?\n"]
    main = parts["lcon_main"]
    if main is not None:
        plan = plan_of(main)
        ps = pairs(main)
        n = {sc: reading(ps, sc, plan) for sc in SCALINGS}
        L.append(f"**{answer(n['median'])}** (median abs_rel on non-overlap pixels at overlap {plan['overlap']:.2f}, "
                 f"{n['median']['n_worlds']} "
                 f"worlds, positive = L_con helps; both arms at one step). Without scaling: {_lc(answer(n['none']))}. At "
                 f"`rig_median`: {_lc(answer(n['rig_median']))}. Hodges-Lehmann (median): "
                 f"{n['median']['rank']['hl']:+.4f} [{n['median']['rank']['ci'][0]:+.4f}, "
                 f"{n['median']['rank']['ci'][1]:+.4f}], Wilcoxon p = {n['median']['rank']['p']:.3f}. "
                 f"{levels(main, ps, 'median')}\n")
        budget = parts["lcon_budget"]
        if budget is not None:  # secondary: six of the main run's worlds at 1000 steps, beside the control
            b, c = br["b"]["median"], br["control"]
            L.append(f"At {_steps(budget)} steps on {b['n_worlds']} of these worlds (secondary, sized by its cost): "
                     f"{_lc(answer(b))}"
                     + (f", beside a positive control that propagates by {fmt_diff(c['median'], 4)} "
                        "(ORACLE-local emptied - filled)" if c is not None else "")
                     + f". At `rig_median` there: {_lc(answer(br['b']['rig_median']))}.\n")
        pilot = parts["lcon_pilot"]
        if pilot is not None:  # exploratory: the pilot's worlds had 8 test sequences, the main run's 32
            pooled = {sc: reading(ps + pairs(pilot), sc, plan) for sc in SCALINGS}
            L.append("Pooled with the pilot's worlds (exploratory: not the pre-stated test; the pilot's worlds have a "
                     "quarter of the test sequences): " + "; ".join(
                         f"{sc} {fmt_diff(pooled[sc], 4)} over {pooled[sc]['n_worlds']} "
                         f"worlds (MDE {pooled[sc]['mde80']:.4f})" for sc in SCALINGS) + ".\n")
    L.append("Every verdict on this page reads beside the benchmark's calibration against effects measured on real "
             "data: which of the effects found on KITTI, DDAD and nuScenes this recipe reproduces, and which it does "
             "not ([calibration.md](calibration.md)).\n")
    preface = fill_preface(row(NAME), results=RESULTS)  # its row names no values: the preface as committed
    if preface:
        L.append(preface + "\n")
    L.append("> Generated by `python scripts/publish_lcon.py` from the results.json of "
             + ", ".join(f"`docs/results/{p}/`" for p in PARTS if parts[p] is not None)
             + " and docs/results/lcon/preface.md; do not edit by hand.\n")
    plots: list = []
    plot_dir = stage / "plots"
    for title, part, missing in (
            ("The primary comparison: (b) at overlap 0.10, main run", "lcon_main", "the main run has not been published"),
            ("The pilot that sized the main run", "lcon_pilot", "no pilot published"),
            ("(b) at three overlaps (the pilot's worlds)", "lcon_overlaps", "not run in this session (see the preface)"),
            ("(b) at 1000 steps", "lcon_budget", "not run in this session (see the preface)")):
        text, pl = _section(title, part, parts[part], plot_dir / part, missing)
        L += text
        plots += pl
        if part == "lcon_budget" and parts[part] is not None:
            from study.report.sections.lcon import format_budget

            L.append("### Beside the positive control, and against 200 steps on the same worlds\n")
            L.append(format_budget(br, _steps(parts[part]), _steps(main or {})))
        if part == "lcon_pilot" and parts["lcon_pilot_auto"] is not None and parts[part] is not None:
            sel = selection_effect(parts[part], parts["lcon_pilot_auto"])
            if sel is not None:
                L.append("### The same pilot runs read at each arm's own `auto` checkpoint\n")
                L.append("Every arm of the pilot was also evaluated at the checkpoint `auto` picks (its own lowest "
                         "validation loss; for MCDP (m = 2) that loss includes λ·L_con, for the arm without it does "
                         "not): `docs/results/lcon_pilot_auto/`.\n")
                L.append(format_selection(sel))
    return "\n".join(L).rstrip() + "\n", plots


def main(argv=None) -> int:
    """``python scripts/publish_lcon.py``: this page's row of `study.report.pages.PAGES`, by `republish.publish_one`."""
    from republish import publish_one

    if argv:
        print(f"publish_lcon: takes no arguments ({len(argv)} given)", file=sys.stderr)
        return 2
    return publish_one(NAME, "publish_lcon")


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
