"""Tickets across tasks: one ticket searched for a multi-task policy's task-averaged success, and
the transfer matrix (every task's ticket on every task) with its greedy cover.

Every task uses the same search and held-out seed numbers; the seed sets are disjoint, so no
task's held-out states were searched on, whichever task a ticket came from.
"""

from __future__ import annotations

import functools
import json
from dataclasses import replace
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.evaluation import (
    ALPHA,
    Evaluator,
    Judged,
    adjust_for_multiplicity,
    judge,
    p_value_note,
    pooled,
    regressions,
)
from goldenticket.files import write_atomic
from goldenticket.noise import Constant, Gaussian
from goldenticket.plots import tasks_png, transfer_png
from goldenticket.policies import find_ticket, for_task, load_policy
from goldenticket.rollout import Engine
from goldenticket.stats import holm_adjust
from goldenticket.tasks import get_task, seeds_in
from goldenticket.ticket_search import run_search
from goldenticket.ticket_search.subspace import Subspace
from goldenticket.tickets import Ticket, zero_ticket
from goldenticket.workflow import (
    Names,
    SearchConfig,
    _open_store,
    _ticket,
    _top,
    find_golden_tickets,
    progress_bar,
    query_evaluator,
)


def _tasks(policy, cfg_task, max_steps: int | None) -> list:
    """The named tasks, each one the policy can act on and whose reset(seed) fixes the initial
    state (UserError now, not mid-run)."""
    tasks = [get_task(name, max_steps) for name in cfg_task]
    if len({t.name for t in tasks}) < len(tasks):
        raise UserError("a --task is given twice")
    for task in tasks:
        for_task(policy, task.name)
        task.check()
    return tasks


def _names(cfg: SearchConfig, policy, tasks: list) -> Names:
    """The run's names; its tickets record the tasks' step limit when they share one."""
    limits = {t.max_steps for t in tasks}
    return Names.of(cfg.policy, policy, " + ".join(t.name for t in tasks),
                    limits.pop() if len(limits) == 1 else None)


def find_multitask_tickets(cfg: SearchConfig, out: Path) -> dict:
    """One search over all of `cfg.task`'s tasks for the task-averaged objective, then base, zero
    and the top tickets judged per task and on average. Search episodes go to the tasks in turn:
    seed key k runs task k mod T on search seed k div T, so every prefix the optimizer uses (a
    racing tier, say) spreads evenly over the tasks."""
    cfg.check()
    policy = load_policy(cfg.policy)
    tasks = _tasks(policy, cfg.task, cfg.max_steps)
    names = [t.name for t in tasks]
    heldout, search_seeds = seeds_in("heldout", cfg.heldout), seeds_in("search", cfg.search_seeds)
    keys = list(range(len(tasks) * len(search_seeds)))
    optimizer = cfg.optimizer(policy.noise_shape, keys)
    run_names = _names(cfg, policy, tasks)
    expand = functools.partial(Subspace.parse(cfg.subspace, policy.noise_shape).expand,
                               noise_shape=policy.noise_shape)
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    with Engine(cfg.policy, tasks, objective=cfg.objective, workers=cfg.workers, backend=cfg.backend,
                address=cfg.address, loaded=policy) as engine, \
            _open_store(out, cfg, run_names) as store:
        evaluator = Evaluator(engine, store, max_nonfinite=cfg.max_nonfinite)
        with progress_bar(evaluator, 2 * cfg.heldout * len(tasks), "held-out: base and zero ticket"):
            for name in names:
                evaluator.run([("base", base, heldout), ("zero", zero, heldout)], name)
        def where(key: int) -> tuple[str, int]:
            return names[key % len(names)], search_seeds[key // len(names)]

        with progress_bar(evaluator, cfg.budget, f"search ({cfg.method}, {len(tasks)} tasks)") as bar:
            result = run_search(optimizer, query_evaluator(evaluator, run_names.fingerprint, expand, where),
                                budget=cfg.budget, stop_after_perfect=cfg.stop_after_perfect,
                                max_tickets=cfg.max_tickets)
            bar.total = result.episodes_used
        tickets = [_ticket(cfg, run_names, result, c, search_seeds, expand)
                   for c in _top(result, cfg, len(keys))]
        for ticket in tickets:
            ticket.metadata["tasks"] = names
        sources = {"zero": zero} | {t.id: Constant(t.noise) for t in tickets}
        with progress_bar(evaluator, cfg.heldout * (len(tickets) + 2) * len(tasks), "held-out: top tickets"):
            per_task = {name: judge(evaluator, sources, heldout, base, name) for name in names}
    summary = verdict(per_task, [t.id for t in tickets], cfg.no_regression)
    for ticket in tickets:
        per_task_rows = {n: summary["tasks"][n][ticket.id] for n in names}
        ticket.metadata["heldout"] = summary["average"][ticket.id] | {"seeds": [heldout[0], heldout[-1]],
                                                                      "per_task": per_task_rows}
        ticket.save(out / "tickets" / f"{ticket.id}.safetensors")
    summary |= {"policy": run_names.policy, "method": cfg.method, "seed": cfg.seed,
                "search_episodes": result.episodes_used, "stopped_because": result.stopped_because,
                "heldout_seeds": [heldout[0], heldout[-1]], "p_value_note": p_value_note(len(tickets))}
    write_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    tasks_png(summary, out / "verdict.png", f"{run_names.policy}: one ticket for {len(tasks)} tasks")
    return summary


def verdict(per_task: dict[str, dict[str, Judged]], ticket_ids: list[str], no_regression: bool) -> dict:
    """Per task and on average: base, zero and each ticket with p-values (Holm-adjusted over the
    tickets), the tasks each ticket significantly regresses on, and the best ticket: the highest
    average success, among tickets that regress nowhere if `no_regression` (None if none is left)."""
    average = pooled(per_task)
    for judged in [*per_task.values(), average]:
        adjust_for_multiplicity(judged, ticket_ids)
    regressing = {t: regressions(per_task, t) for t in ticket_ids}
    allowed = [t for t in ticket_ids if not (no_regression and regressing[t])]
    ranked = sorted(allowed, key=lambda t: (-average[t].rate.success_rate, average[t].p_value))
    return {"tasks": {name: {label: j.to_dict() for label, j in judged.items()}
                      for name, judged in per_task.items()},
            "average": {label: j.to_dict() for label, j in average.items()},
            "tickets": ticket_ids, "regressions": regressing, "no_regression": no_regression,
            "best": ranked[0] if ranked else None}


def transfer(cfg: SearchConfig, out: Path, ticket_refs: list[str] | None = None) -> dict:
    """Find one ticket per task (a single-task search each, in `out/search/<task>`; or take
    `ticket_refs`), run every ticket on every task's held-out seeds, and write the matrix
    (transfer.json, transfer.csv), its heatmap (transfer.png) and the greedy cover; every matrix
    episode is kept in `out/run.sqlite`, so a rerun resumes."""
    cfg.check()
    policy = load_policy(cfg.policy)
    tasks = _tasks(policy, cfg.task, cfg.max_steps)
    heldout = seeds_in("heldout", cfg.heldout)
    names = _names(cfg, policy, tasks)
    if ticket_refs:
        tickets = [Ticket.load(find_ticket(ref), expected_shape=policy.noise_shape) for ref in ticket_refs]
        for ref, ticket in zip(ticket_refs, tickets, strict=True):
            if ticket.metadata.get("policy_fingerprint", names.fingerprint) != names.fingerprint:
                raise UserError(f"{ref}: ticket {ticket.id} was found for policy "
                                f"{ticket.metadata.get('policy')}, not {names.policy} ({names.fingerprint})")
        found_on = {t.id: t.metadata.get("tasks", [t.metadata.get("task", "given")]) for t in tickets}
    else:
        found = {task.name: _searched_ticket(cfg, task.name, out) for task in tasks}
        tickets = list(found.values())
        found_on = {t.id: [task for task, f in found.items() if f.id == t.id] for t in tickets}
    tickets = list({t.id: t for t in tickets}.values())  # several tasks' searches may find one ticket
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    sources = {"zero": zero} | {t.id: Constant(t.noise) for t in tickets}
    with Engine(cfg.policy, tasks, workers=cfg.workers, backend=cfg.backend, address=cfg.address,
                loaded=policy) as engine, \
            _open_store(out, cfg, names) as store:
        evaluator = Evaluator(engine, store, max_nonfinite=cfg.max_nonfinite)
        with progress_bar(evaluator, cfg.heldout * len(sources) * len(tasks) + cfg.heldout * len(tasks),
                          "transfer matrix"):
            per_task = {t.name: judge(evaluator, sources, heldout, base, t.name) for t in tasks}
    study = matrix(per_task, found_on)
    study |= {"policy": names.policy, "heldout_seeds": [heldout[0], heldout[-1]]}
    write_atomic(out / "transfer.json", json.dumps(study, indent=2) + "\n")
    write_atomic(out / "transfer.csv", transfer_csv(study))
    transfer_png(study, out / "transfer.png")
    return study


def _searched_ticket(cfg: SearchConfig, task: str, out: Path) -> Ticket:
    """The top search ticket of a single-task search on `task` (judged there on the held-out seeds)."""
    folder = out / "search" / task.replace("/", "_")
    single = replace(cfg, task=task, top_k=1, no_regression=False, validation_seeds=cfg.validation())
    summary = find_golden_tickets(single, folder)
    return Ticket.load(Path(summary["best"]["ticket_path"]))


def matrix(per_task: dict[str, dict[str, Judged]], found_on: dict[str, list[str]]) -> dict:
    """Each ticket (with the tasks it was found on) on each task: success, gain over base, p vs
    base Holm-adjusted over the tickets on that task; and the greedy cover."""
    cells = {}
    for task, judged in per_task.items():
        adjusted = holm_adjust([judged[t].p_value for t in found_on])
        for ticket, p in zip(found_on, adjusted, strict=True):
            rate, base_rate = judged[ticket].rate.success_rate, judged["base"].rate.success_rate
            cells.setdefault(ticket, {})[task] = {"success_rate": rate, "gain": rate - base_rate,
                                                  "p_value": p, "significant": p < ALPHA}
    baselines = {task: {arm: judged[arm].to_dict() for arm in ("base", "zero")}
                 for task, judged in per_task.items()}
    return {"tasks": list(per_task), "tickets": found_on, "baselines": baselines, "cells": cells,
            "cover": greedy_cover(cells, baselines)}


def greedy_cover(cells: dict[str, dict[str, dict]], baselines: dict[str, dict]) -> dict:
    """The smallest set of tickets (greedy set cover) such that every task a ticket significantly
    improves has one that does; every other task gets the ticket with the highest success there if
    it beats the base's rate, else the base. Returns the cover's tickets, the other tickets the
    table uses (`fallbacks`) and the task -> ticket table."""
    wins = {ticket: {task for task, cell in row.items() if cell["significant"]}
            for ticket, row in cells.items()}
    uncovered, chosen, table = set().union(*wins.values()), [], {}
    while uncovered:
        ticket = max(wins, key=lambda t: (len(wins[t] & uncovered),
                                          sum(cells[t][task]["gain"] for task in wins[t] & uncovered)))
        chosen.append(ticket)
        for task in sorted(wins[ticket] & uncovered):
            table[task] = {"use": ticket, "significant": True} | cells[ticket][task]
        uncovered -= wins[ticket]
    for task in baselines:
        if task in table:
            continue
        best = max(cells, key=lambda t: cells[t][task]["success_rate"])
        if cells[best][task]["gain"] > 0:
            table[task] = {"use": best} | cells[best][task]
        else:
            table[task] = {"use": "base", "significant": False, "gain": 0.0, "p_value": None,
                           "success_rate": baselines[task]["base"]["success_rate"]}
    uses = {row["use"] for row in table.values()} - {"base"}
    return {"tickets": chosen, "fallbacks": sorted(uses - set(chosen)),
            "table": {task: table[task] for task in baselines}}


def transfer_csv(study: dict) -> str:
    """One row per (ticket, task): success, gain over base, Holm-adjusted p, significance."""
    lines = ["ticket,found_on,task,success_rate,base_rate,gain,p_value,significant"]
    for ticket, found_on in study["tickets"].items():
        for task, cell in study["cells"][ticket].items():
            base = study["baselines"][task]["base"]["success_rate"]
            lines.append(f"{ticket},{'+'.join(found_on)},{task},{cell['success_rate']:.4f},{base:.4f},{cell['gain']:.4f},"
                         f"{cell['p_value']:.4g},{cell['significant']}")
    return "\n".join(lines) + "\n"

