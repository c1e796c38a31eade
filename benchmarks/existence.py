"""The existence table: do golden tickets beat Gaussian noise (and the zero ticket) across MT10?

    python benchmarks/existence.py            # every pair, resumable; writes benchmarks/results/
    python benchmarks/existence.py --ship     # also copy golden tickets beside the bundled policies
    python benchmarks/existence.py --plot-only  # redraw existence.png from existence.json
    robomimic-venv/bin/python benchmarks/existence.py --robomimic [lift can] [--ship]  # robomimic's pairs
    ... --robomimic can --policies ddim@2      # one policy's pairs (the others' rows are kept)
    ... --method cma-es --subspace tiled       # another search (Meta-World's table: only printed)


One pair is a bundled policy on its task: flow (10 Euler steps), DDIM with 8 steps and DDIM
with 2 steps (same weights). Each pair runs `find_golden_tickets` with the settings below into
`--runs/<pair>` (resumable per episode), so the table regenerates from scratch with the same
numbers. The search's top tickets are judged on held-out seeds against the base policy and the
zero ticket; the best one is then judged again, with base and zero ticket, on two ranges of fresh
held-out seeds that no choice saw. Every pair's best ticket, golden or not, is kept in
benchmarks/results/existence_tickets/ with its verdicts. Results: benchmarks/results/existence.{md,json,png};
with `--robomimic`, the bundled robomimic policies' pairs beside the paper's robomimic rows:
benchmarks/results/robomimic_existence.{md,json,png}, rewritten as each pair ends, keeping the rows of
the pairs not run (a Lift pair took 36-63 min on 2 cores, a Can pair 55-98 min, with CMA-ES over
a tiled ticket).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from build_zoo import MT10, ROBOMIMIC
from results_files import RESULTS, write_results

from goldenticket import kernels
from goldenticket.config import EvaluateConfig, SearchConfig
from goldenticket.evaluation import BASE, ZERO, Arm
from goldenticket.job import find_golden_tickets
from goldenticket.job.evaluate import evaluate_tickets
from goldenticket.policies import BUNDLED_DIR
from goldenticket.policies.registry import split_steps
from goldenticket.report import p_vs_base, rate_text
from goldenticket.results import to_run
from goldenticket.stats import paired_exact_test, sign_test, wilson_interval
from goldenticket.store import RunStore
from goldenticket.tasks import seeds_in
from goldenticket.ticket_search import METHODS
from goldenticket.tickets import ZERO_SOURCE, Ticket
from goldenticket.zoo import policy_names

HERE = Path(__file__).parent
POLICIES = ("flow", "ddim@8", "ddim@2")
DEFAULTS = SearchConfig("", "")  # the `search` defaults, as a user gets them
SETTINGS = {name: getattr(DEFAULTS, name) for name in ("method", "budget", "seed", "search_seeds",
                                                        "subspace")} | {
    "halving": DEFAULTS.halves(), "validation_seeds": DEFAULTS.validation(), "heldout": DEFAULTS.heldout,
    "top_k": DEFAULTS.top_k}
FRESH = 200  # fresh held-out seeds for each pair's best ticket, in two ranges after the judged ones
FRESH_RANGES = ("fresh", "fresh_2")
WEAK_BASE = 0.85  # the generalisation targets are over the pairs whose base succeeds at most this often
# the paper's robomimic rows (DPPO's policies; random search, 5000 tickets x 100 envs): base, golden
PAPER_ROBOMIMIC = {"lift": (0.784, 0.962), "can": (0.428, 0.808), "square": (0.522, 0.329),
                   "transport": (0.107, 0.188)}


def pairs(tasks=MT10) -> list[tuple[str, str]]:
    return [(f"metaworld/{t}", f"metaworld/{t}/{p}") for t in tasks for p in POLICIES]


def robomimic_pairs(tasks=ROBOMIMIC) -> list[tuple[str, str]]:
    """The bundled robomimic policies on `tasks`, as `pairs` gives Meta-World's."""
    built = policy_names()
    return [(t, f"{t}/{p}") for t in tasks for p in POLICIES if f"{t}/{split_steps(p)[0]}" in built]


def paper_lines(rows: list[dict]) -> list[str]:
    """The paper's robomimic rows beside this run's best ticket per task (on its first fresh range)."""
    built = policy_names()
    lines = ["", "| task | paper: base | paper: golden | here: base | here: best ticket (fresh seeds) |",
             "|---|---|---|---|---|"]
    for task, (base, golden) in PAPER_ROBOMIMIC.items():
        mine = [r for r in rows if r["task"] == f"robomimic/{task}"]
        best = max(mine, key=lambda r: r["fresh"]["success_rate"], default=None)
        trained = any(name.startswith(f"robomimic/{task}/") for name in built)
        missing = "not run yet" if trained else "no bundled policy"
        here = (f"{best['fresh']['base']['success_rate']:.1%} | {best['fresh']['success_rate']:.1%} "
                f"({best['policy']})") if best else f"- | - ({missing})"
        lines.append(f"| {task} | {base:.1%} | {golden:.1%} | {here} |")
    return lines


def run_folder(runs: Path, policy: str) -> Path:
    return runs / policy.removeprefix("metaworld/").replace("/", "_")


def run_pair(task: str, policy: str, runs: Path, workers: int, fresh_ranges: int = len(FRESH_RANGES),
             **changed) -> dict:
    """Search and judge one pair with SETTINGS, or with the `changed` ones (e.g. a budget); its best
    ticket is then re-judged on the first `fresh_ranges` ranges of fresh held-out seeds."""
    out, start = run_folder(runs, policy), time.perf_counter()
    cfg = SearchConfig(policy, task, workers=workers, **SETTINGS | changed)
    summary = find_golden_tickets(cfg, out).to_dict() | {"halving": cfg.halves()}
    with RunStore(out / "run.sqlite") as store:
        summary["validation_episodes"] = len(store.episodes(seed_set="validation"))
    best = summary["best"]
    for i, key in enumerate(FRESH_RANGES[:fresh_ranges]):
        best[key] = fresh_check(Path(best["ticket_path"]), policy, task, out, workers, i)
    return summary | {"wall_time_s": round(time.perf_counter() - start), "workers": workers,
                      "episode_seconds": pair_episode_seconds(out, best["ticket_id"])}


def pair_episode_seconds(out: Path, ticket: str) -> int:
    """The pair's own episodes' wall times in its run folder, summed: the search's, validation's and
    verdict's, and the fresh check's of the base, the zero ticket and `ticket` (not those of a ticket
    judged beside them there). What the pair cost, however many times its run was stopped and resumed
    (its wall time counts only the last)."""
    total = 0.0
    for path in out.glob("*.sqlite"):
        with RunStore(path) as store:
            total += sum(row.wall_time for row in store.episodes()
                         if path.name == "run.sqlite" or row.ticket_id in ("base", "zero", ticket))
    return round(total)


def fresh_check(path: Path, policy: str, task: str, out: Path, workers: int, i: int = 0) -> dict:
    """Base, zero ticket and the ticket at `path` on the `i`-th range of FRESH held-out seeds after
    the judged ones: the choice of the best among the top tickets never saw them. With one-sided
    paired p-values of the ticket being below the base and below the zero ticket."""
    first = SETTINGS["heldout"] + i * FRESH
    seeds = seeds_in("heldout", first + FRESH)[first:]
    cfg = EvaluateConfig(policy, task, (str(path),), seeds, SETTINGS["seed"], workers=workers)
    with RunStore(out / f"{FRESH_RANGES[i]}.sqlite") as store:
        rows = evaluate_tickets(cfg, store)
    ticket = Ticket.load(path)
    recorded, mine = ticket.record.heldout, rows[Arm.ticket(ticket.id)]
    below = {f"p_below_{arm.key}": paired_exact_test(rows[arm].successes, mine.successes)
             for arm in (BASE, ZERO)}
    inside = {} if recorded is None else {  # a ticket made elsewhere has no held-out record
        "inside_recorded_interval": recorded["ci_low"] <= mine.rate.success_rate <= recorded["ci_high"]}
    return mine.to_dict() | below | inside | {
        "base": _rate(rows[BASE].to_dict()), "zero": _rate(rows[ZERO].to_dict()),
        "seeds": [seeds[0], seeds[-1]]}


def _rate(row: dict) -> dict:
    """An arm's success rate with its interval, without its tests."""
    return {k: row[k] for k in ("success_rate", "ci_low", "ci_high", "n")}


def table_row(s: dict) -> dict:
    best = s["best"]
    return {"task": s["task"].removeprefix("metaworld/"), "policy": s["policy"].rsplit("/", 1)[-1],
            "base": s["base"], "zero": s["zero"], "ticket": best["ticket_id"],
            "zero_ticket": best.get("source") == ZERO_SOURCE,
            "best": {k: best[k] for k in ("success_rate", "ci_low", "ci_high", "n")},
            "p_vs_base": p_vs_base(best), "p_vs_zero": best["p_vs_zero"],
            "golden": best["golden"]} | {key: best[key] for key in FRESH_RANGES if key in best} | {
            "search": f"{s['method']}, {s['search_episodes']} episodes, "
                      f"{'' if s['halving'] else 'not '}halved",
            "search_and_validation": s["search_episodes"] + s["validation_episodes"],
            "stopped_because": s["stopped_because"], "wall_time_s": s["wall_time_s"], "workers": s["workers"],
            "episode_seconds": s["episode_seconds"]}


def summary_rows(rows: list[dict]) -> dict:
    """Across pairs: significant gains, sign tests with Wilson intervals, mean gains."""
    out = {"pairs": len(rows)}
    for ref in ("base", "zero"):
        gains = [r["best"]["success_rate"] - r[ref]["success_rate"] for r in rows]
        wins, losses = sum(g > 0 for g in gains), sum(g < 0 for g in gains)
        low, high = wilson_interval(wins, wins + losses) if wins + losses else (0.0, 1.0)
        out[f"vs_{ref}"] = {"significant": sum(r[f"p_vs_{ref}"] < 0.05 for r in rows),
                            "wins": wins, "losses": losses, "ties": len(rows) - wins - losses,
                            "sign_test_p": sign_test(wins, losses), "win_rate_ci": [low, high],
                            "mean_gain": float(np.mean(gains))}
    golden = [r for r in rows if r["golden"]]
    out["fresh"] = {"golden": len(golden),
                    "inside_recorded_interval": sum(r["fresh"]["inside_recorded_interval"] for r in golden)}
    if golden:
        out["fresh"]["mean_heldout"] = float(np.mean([r["best"]["success_rate"] for r in golden]))
        out["fresh"]["mean_fresh"] = float(np.mean([r["fresh"]["success_rate"] for r in golden]))
    out["base_floor"] = [base_floor(rows, bar) for bar in (0.9, 0.97)]
    return out | target_summary(rows)


def target_summary(rows: list[dict]) -> dict:
    """The targets over the pairs of `rows` with a weak base, per seed range; over all of `rows`,
    how many best tickets are significantly below the zero ticket and the base on each fresh range,
    and the episodes search and validation spent."""
    weak = [r for r in rows if r["base"]["success_rate"] <= WEAK_BASE]
    out = {"pairs": len(weak), "judged": targets(weak, lambda r: r)} | {
        key: targets(weak, lambda r, key=key: r[key] | {"best": r[key]}) for key in FRESH_RANGES}
    for key in FRESH_RANGES:
        out[key]["below_zero"] = sum(r[key]["p_below_zero"] < 0.05 for r in rows)
        out[key]["below_base"] = sum(r[key]["p_below_base"] < 0.05 for r in rows)
        out[key]["delivered"] = targets(weak, lambda r, key=key: delivered(r, key)) | {
            "kept_base": sum(map(keeps_base, weak))}
    spent = [r["search_and_validation"] for r in rows]
    return {"targets": out, "episodes": {"mean": float(np.mean(spent)), "max": max(spent)}}


def keeps_base(row: dict) -> bool:
    """Whether the job delivers the base rather than a ticket (`results.to_run` on the judged seeds;
    the zero ticket is among the judged tickets here, so where it is run it is the best ticket)."""
    return to_run(row["best"]["success_rate"], row["zero"]["success_rate"], row["base"]["success_rate"],
                  row["golden"]) == "base"


def delivered(row: dict, key: str) -> dict:
    """Base, zero ticket and, as "best", what the job delivers on fresh range `key`: the best
    ticket, or the base (then untested: no gain, no p-value)."""
    fresh = row[key] | {"best": row[key]}
    return fresh | {"best": fresh["base"], "p_vs_base": math.nan, "p_vs_zero": math.nan} if keeps_base(row) \
        else fresh


def base_floor(rows: list[dict], bar: float, share: float = 0.9) -> dict | None:
    """The lowest base success T such that, among the pairs whose base is >= T' for every T' >= T,
    at least `share` reach `bar` with their best ticket (the paper's base floor T*); with the
    number of those pairs (n) and of those reaching the bar (k). None if no floor qualifies."""
    floors = sorted({r["base"]["success_rate"] for r in rows}, reverse=True)
    found = None
    for floor in floors:
        above = [r for r in rows if r["base"]["success_rate"] >= floor]
        k = sum(r["best"]["success_rate"] >= bar for r in above)
        if k < share * len(above):
            break
        found = {"bar": bar, "floor": floor, "n": len(above), "k": k}
    return found


def targets(rows: list[dict], arms) -> dict:
    """The generalisation targets over `rows`, with `arms(row)` giving "base", "zero", "best" rates and the
    best's p-values: significant gains over base and zero, mean failure reduction over the base."""
    picked = [arms(r) for r in rows]
    reduction = [failure_reduction(a["best"], a["base"]) for a in picked]
    return {"vs_base": sum(p_vs_base(a) < 0.05 for a in picked) / len(picked),
            "vs_zero": sum(a["p_vs_zero"] < 0.05 for a in picked) / len(picked),
            "failure_reduction": float(np.mean(reduction)),
            "mean_gain": float(np.mean([a["best"]["success_rate"] - a["base"]["success_rate"]
                                        for a in picked]))}


def failure_reduction(best: dict, base: dict) -> float:
    """The share of the base's failures that the best ticket turns into successes."""
    return (best["success_rate"] - base["success_rate"]) / (1 - base["success_rate"])


def markdown(rows: list[dict], summary: dict, wall: float | None, workers: int = 2) -> str:
    """The table and its findings; `wall`: the run's wall time on `workers` workers, None for a table
    whose rows come from several runs (each row then gives its own)."""
    lines = ["| task | policy | base | zero ticket | best ticket | p vs base | p vs zero | fresh seeds "
             "| search |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fresh = f"{r['fresh']['success_rate']:.1%} vs {r['fresh']['base']['success_rate']:.1%}" + \
            ("" if r["fresh"]["inside_recorded_interval"] else " (outside)")
        star = " **golden**" if r["golden"] else ""
        zero = " (w = 0: the zero ticket)" if r["zero_ticket"] else ""
        lines.append(f"| {r['task']} | {r['policy']} | {rate_text(r['base'])} | {rate_text(r['zero'])} | "
                     f"{rate_text(r['best'])}{zero}{star} | {r['p_vs_base']:.2g} | {r['p_vs_zero']:.2g} | "
                     f"{fresh} | {r['search']} |")
    lines.append("")
    for ref in ("base", "zero"):
        s = summary[f"vs_{ref}"]
        lines.append(
            f"- **vs {ref}**: significant gain (one-sided exact paired test, p < 0.05) in "
            f"{s['significant']} of {summary['pairs']} pairs; best ticket ahead in {s['wins']}, behind in "
            f"{s['losses']}, tied in {s['ties']}; sign test p = {s['sign_test_p']:.2g}, win proportion "
            f"95% Wilson [{s['win_rate_ci'][0]:.0%}, {s['win_rate_ci'][1]:.0%}]; mean gain "
            f"{100 * s['mean_gain']:+.1f} points.")
    zero = [r for r in rows if r["zero_ticket"]]
    if zero:
        golden = sum(r["golden"] for r in zero)
        lines.append(f"- **The zero ticket**: the best ticket is w = 0 in {len(zero)} of {summary['pairs']} "
                     f"pairs ({golden} of them golden vs base): there the gain is the zero ticket's, not a "
                     "ticket the search found.")
    f = summary["fresh"]
    if f["golden"]:
        lines.append(f"- **Fresh seeds**: {f['inside_recorded_interval']} of {f['golden']} golden tickets "
                     f"land inside their recorded interval; mean success {f['mean_fresh']:.1%} on fresh "
                     f"seeds vs {f['mean_heldout']:.1%} on the judged ones.")
    lines += target_lines(summary)
    for floor in summary["base_floor"]:
        if floor:
            lines.append(f"- **Base floor** for the bar {floor['bar']:.0%} (the paper's T*): "
                         f"{floor['floor']:.1%}. Of the {floor['n']} pairs whose base succeeds at least that "
                         f"often, {floor['k']} reach {floor['bar']:.0%} with their best ticket; at every "
                         "higher floor, at least 90% do.")
    lines.append(f"- Best ticket: the best on held-out seeds of the search's top {SETTINGS['top_k']}; its "
                 "p-values are Holm-adjusted for that choice, but the counts and mean gains above use "
                 "its held-out rate, which that choice makes optimistic. The fresh-seed column is the "
                 "unbiased check.")
    lines.append(f"- Held-out: {SETTINGS['heldout']} seeds per pair, the same for base, zero and "
                 f"ticket; fresh: the next {FRESH} held-out seeds, and the second fresh range the {FRESH} "
                 "after those, for the best ticket, the base and the zero ticket (shown: ticket vs base, "
                 "on the first fresh range)." + ("" if wall is None else f" Wall time of this run: "
                 f"{wall / 60:.0f} min ({workers} worker(s); resumed runs count only new work)."))
    return "\n".join(lines) + "\n"


def target_lines(summary: dict) -> list[str]:
    """The generalisation targets on the weak-base pairs, per seed range, and the episodes they cost."""
    t, lines = summary["targets"], []
    ranges = (("judged", "judged seeds"), ("fresh", "fresh seeds"), ("fresh_2", "second fresh range"))
    for seeds, said in ranges:
        line = (f"- **The generalisation targets** on the {t['pairs']} pairs with base <= {WEAK_BASE:.0%}, "
                f"{said}: significant gain over the base in {t[seeds]['vs_base']:.0%} (target >= 90%), over "
                f"the zero ticket in {t[seeds]['vs_zero']:.0%}; mean failure reduction "
                f"{t[seeds]['failure_reduction']:.1%} (>= 55%); mean gain {100 * t[seeds]['mean_gain']:+.1f} "
                "points (>= +18).")
        if seeds != "judged":
            line += (f" Over all {summary['pairs']} pairs, the best ticket is significantly below the zero "
                     f"ticket in {t[seeds]['below_zero']} (target 0) and below the base in "
                     f"{t[seeds]['below_base']}.")
        lines.append(line)
    spent = summary["episodes"]
    return [*lines, f"- **Episodes** per pair for search and validation: mean {spent['mean']:.0f}, at most "
            f"{spent['max']} (target <= 1250)."]


def figure(rows: list[dict]):
    """Per pair, on the fresh seeds: base, zero ticket and best ticket (left); for the pairs with a
    weak base, the failure reduction against the 55% target (right)."""
    from matplotlib.figure import Figure

    rows = sorted(rows, key=lambda r: r["base"]["success_rate"])
    labels = [f"{r['task'].removesuffix('-v3')} {r['policy']}" for r in rows]
    fig = Figure(figsize=(13, 8))
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [3, 2]})
    y = np.arange(len(rows))
    for arm, style in (("base", dict(color="0.45", marker="o")), ("zero", dict(color="tab:blue", marker="x")),
                       ("best", dict(color="goldenrod", marker="D"))):
        rates = [(r["fresh"] if arm == "best" else r["fresh"][arm])["success_rate"] for r in rows]
        left.scatter(rates, y, label="best ticket" if arm == "best" else arm, zorder=3, **style)
    for i, r in enumerate(rows):
        left.plot([r["fresh"]["base"]["success_rate"], r["fresh"]["success_rate"]], [i, i], color="0.8",
                  zorder=1)
    weak = [r for r in rows if r["base"]["success_rate"] <= WEAK_BASE]
    left.axhline(len(weak) - 0.5, color="0.6", ls=":")
    left.set_yticks(y, labels, fontsize="small")
    left.set(xlabel=f"success on {FRESH} fresh held-out seeds", xlim=(-0.02, 1.02),
             title=f"Best ticket vs base and zero ticket (below the line: judged base <= {WEAK_BASE:.0%})")
    left.legend(fontsize="small", loc="upper left")
    cut = [failure_reduction(r["fresh"], r["fresh"]["base"]) for r in weak]
    colors = ["goldenrod" if p_vs_base(r["fresh"]) < 0.05 else "0.6" for r in weak]
    right.barh(np.arange(len(weak)), cut, color=colors)
    right.axvline(0.55, color="tab:red", ls="--", label="target 55%")
    right.axvline(float(np.mean(cut)), color="k", label=f"mean {np.mean(cut):.0%}")
    right.set_yticks(np.arange(len(weak)), [labels[rows.index(r)] for r in weak], fontsize="small")
    right.set(xlabel="failure reduction over the base (fresh seeds)",
              title="Weak-base pairs\n(gold: significant on fresh seeds)")
    right.legend(fontsize="small")
    fig.tight_layout()
    return fig


def save_figure(rows: list[dict], path: Path) -> None:
    figure(rows).savefig(path, dpi=90)


def keep_best_tickets(summaries: list[dict], folder: Path) -> None:
    """Every pair's best ticket, golden or not (its metadata says), with its fresh check, in
    `folder/<policy>/` (replacing the ticket there): anyone can judge all pairs again on other seeds."""
    for s in summaries:
        kept = folder / s["policy"].removeprefix("metaworld/").replace("/", "_").replace("@", "_at")
        for old in kept.glob("*.safetensors"):
            old.unlink()
        ticket = Ticket.load(s["best"]["ticket_path"])
        ticket = ticket.with_record(extra=ticket.record.extra | {"fresh": s["best"]["fresh"]})
        ticket.save(kept / f"{ticket.id}.safetensors")


def ship(summaries: list[dict]) -> int:
    """Replace the bundled tickets of this run's policies with its golden ones (each with its fresh
    check), unless a fresh range found one significantly below the base or the zero ticket; other
    policies' tickets stay, those of the same weights with other steps too."""
    for s in summaries:
        for old in (BUNDLED_DIR / split_steps(s["policy"])[0] / "tickets").glob("*.safetensors"):
            if Ticket.load(old).record.policy == s["policy"]:
                old.unlink()
    shipped = 0
    for s in summaries:
        best = s["best"]
        if not best["golden"]:
            continue
        if worse_on_fresh_seeds(best):
            print(f"Not shipped: {s['policy']}'s golden ticket is significantly below the base or the "
                  "zero ticket on fresh seeds.")
            continue
        ticket = Ticket.load(best["ticket_path"])
        ticket = ticket.with_record(extra=ticket.record.extra | {"fresh": best["fresh"]})
        policy_dir, _ = split_steps(s["policy"])
        ticket.save(BUNDLED_DIR / policy_dir / "tickets" / f"{ticket.id}.safetensors")
        shipped += 1
    return shipped


def worse_on_fresh_seeds(best: dict) -> bool:
    """Whether a fresh range found the ticket significantly (p < 0.05) below the base or the zero ticket."""
    return any(best[key][f"p_below_{arm}"] < 0.05 for key in FRESH_RANGES for arm in ("base", "zero"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=HERE / "runs", help="resumable run folders")
    parser.add_argument("--only", nargs="*", choices=MT10, default=list(MT10), help="tasks")
    parser.add_argument("--policies", nargs="+", choices=POLICIES, default=list(POLICIES),
                        help="of each task's pairs, these policies' only (a partial Meta-World table is only "
                             "printed; robomimic's keeps the other pairs' committed rows)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--method", choices=list(METHODS), default=SETTINGS["method"],
                        help="search method (default: the `search` default)")
    parser.add_argument("--subspace", choices=("full", "tiled"), default=None,
                        help="what the search varies (default: the method's)")
    parser.add_argument("--ship", action="store_true", help="copy golden tickets into the package")
    parser.add_argument("--robomimic", nargs="*", default=None, metavar="TASK",
                        choices=[t.removeprefix("robomimic/") for t in ROBOMIMIC],
                        help="the bundled robomimic policies' pairs, on these tasks (default: all), in "
                             "robosuite's venv; the table keeps the other tasks' committed rows")
    parser.add_argument("--plot-only", action="store_true",
                        help="redraw existence.png from the committed existence.json; run no episode")
    args = parser.parse_args()
    if args.plot_only:
        save_figure(json.loads((RESULTS / "existence.json").read_text())["pairs"], RESULTS / "existence.png")
        return
    start, summaries = time.perf_counter(), []
    chosen = SearchConfig("", "", args.method, subspace=args.subspace)
    search = {"method": chosen.method, "subspace": chosen.subspace}
    settings = SETTINGS | search | {"fresh": FRESH}
    robomimic = args.robomimic is not None
    todo = robomimic_pairs([f"robomimic/{t}" for t in args.robomimic or ROBOMIMIC]) if robomimic else \
        pairs(args.only)
    todo = [(task, policy) for task, policy in todo if policy.rsplit("/", 1)[1] in args.policies]
    for i, (task, policy) in enumerate(todo, 1):
        print(f"[{i}/{len(todo)}] {policy}", flush=True)
        summaries.append(run_pair(task, policy, args.runs, args.workers, **search))
        if robomimic:  # a robomimic pair takes an hour or more: the table gains each as it ends
            write_robomimic(summaries[-1:], [table_row(summaries[-1])], args.ship, settings)
    if robomimic:
        return
    rows = [table_row(s) for s in summaries]
    summary = summary_rows(rows)
    wall = time.perf_counter() - start
    if args.only != list(MT10) or args.policies != list(POLICIES) or settings != SETTINGS | {"fresh": FRESH}:
        # a partial table, or another search's, is only printed: the committed table is the defaults'
        print(markdown(rows, summary, wall, args.workers))
        return
    record = {"settings": settings, "summary": summary, "pairs": rows, "wall_time_s": round(wall)}
    keep_best_tickets(summaries, RESULTS / "existence_tickets")
    write_results("existence", record, markdown(rows, summary, wall, args.workers),
                  lambda path: save_figure(rows, path))
    if args.ship:
        print(f"Shipped {ship(summaries)} golden tickets into {BUNDLED_DIR}.")


def write_robomimic(summaries: list[dict], rows: list[dict], ship_them: bool, settings: dict) -> None:
    """The robomimic table with these pairs and the committed rows of the others, the paper's rows
    beside it, and each pair's best ticket; `ship_them`: the golden ones into the package too."""
    path, ran = RESULTS / "robomimic_existence.json", {(r["task"], r["policy"]) for r in rows}
    committed = json.loads(path.read_text())["pairs"] if path.exists() else []
    order = [(t, p.rsplit("/", 1)[1]) for t, p in robomimic_pairs()]
    rows = sorted([r for r in committed if (r["task"], r["policy"]) not in ran] + rows,
                  key=lambda r: order.index((r["task"], r["policy"])))
    summary, wall = summary_rows(rows), sum(r["wall_time_s"] for r in rows)
    record = {"settings": settings, "summary": summary, "pairs": rows, "paper": PAPER_ROBOMIMIC,
              "wall_time_s": wall}
    table = markdown(rows, summary, None) + "\n".join(paper_lines(rows) + wall_lines(rows)) + "\n"
    keep_best_tickets(summaries, RESULTS / "robomimic_existence_tickets")
    write_results("robomimic_existence", record, table, lambda path: save_figure(rows, path))
    if ship_them:
        print(f"Shipped {ship(summaries)} golden tickets into {BUNDLED_DIR}.")


def wall_lines(rows: list[dict]) -> list[str]:
    """Each pair's wall time, and where recorded its episodes' own times summed over every part of a
    run stopped and resumed: the table's pairs may come from several runs."""
    def cost(r: dict) -> str:
        spent = f", {r['episode_seconds'] / 60:.0f} min of episodes" if "episode_seconds" in r else ""
        return (f"{r['task'].removeprefix('robomimic/')} {r['policy']} {r['wall_time_s'] / 60:.0f} min "
                f"({r['workers']} worker(s){spent})")

    return ["", "Wall time per pair (search, validation, held-out and both fresh ranges; of a resumed run, "
                "its last part), with the episodes' own times summed, one core each, where recorded: " +
            ", ".join(cost(r) for r in rows) + "."]

if __name__ == "__main__":
    kernels.restart_pinned(ROBOMIMIC if "--robomimic" in sys.argv else [])  # as the CLI pins, before any work
    main()
