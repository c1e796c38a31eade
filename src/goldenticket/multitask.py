"""Tickets across tasks: the transfer matrix (every task's ticket on every task) with its greedy
cover. (One ticket for a multi-task policy's task-averaged success is the job itself, on several
tasks: `job.find_golden_tickets`.)

Every task uses the same search and held-out seed numbers; the seed sets are disjoint, so no
task's held-out states were searched on, whichever task a ticket came from.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from goldenticket.config import SearchConfig
from goldenticket.errors import UserError
from goldenticket.evaluation import ALPHA, BASE, ZERO, Arm, Evaluator, Verdict, VerdictRow, judge, judge_size
from goldenticket.files import write_atomic
from goldenticket.job import Plan, checked_tasks, find_golden_tickets
from goldenticket.job.folder import open_store
from goldenticket.noise import Constant, Gaussian
from goldenticket.plots import transfer_png
from goldenticket.policies import find_ticket, load_policy
from goldenticket.results import Cover, TransferCell, TransferStudy
from goldenticket.seeds import seeds_in
from goldenticket.tickets import Ticket, zero_ticket


def transfer(cfg: SearchConfig, out: Path, ticket_refs: list[str] | None = None) -> TransferStudy:
    """Find one ticket per task (a single-task search each, in `out/search/<task>`; or take
    `ticket_refs`), run every ticket on every task's held-out seeds, and write the matrix
    (transfer.json, transfer.csv), its heatmap (transfer.png) and the greedy cover; every matrix
    episode is kept in `out/run.sqlite`, so a rerun resumes."""
    cfg.check()
    policy = load_policy(cfg.policy, cfg.device, **cfg.policy_settings())
    tasks = checked_tasks(policy, cfg)
    heldout = seeds_in("heldout", cfg.heldout)
    plan = Plan.of(cfg, policy, tasks)
    names = plan.names
    if ticket_refs:
        tickets = [Ticket.load(find_ticket(ref), expected_shape=policy.noise_shape) for ref in ticket_refs]
        for ref, ticket in zip(ticket_refs, tickets, strict=True):
            if ticket.record.policy_fingerprint not in (None, names.fingerprint):
                raise UserError(f"{ref}: ticket {ticket.id} was found for policy "
                                f"{ticket.record.policy}, not {names.policy} ({names.fingerprint})")
        found_on = {t.id: list(t.record.tasks or [t.record.task or "given"]) for t in tickets}
    else:
        found = {task.name: _searched_ticket(cfg, task.name, out) for task in tasks}
        tickets = list(found.values())
        found_on = {t.id: [task for task, f in found.items() if f.id == t.id] for t in tickets}
    tickets = list({t.id: t for t in tickets}.values())  # several tasks' searches may find one ticket
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    sources = {ZERO: zero} | {Arm.ticket(t.id): Constant(t.noise) for t in tickets}
    with Evaluator.open(cfg.policy, tasks, cfg, loaded=policy) as evaluator, \
            open_store(out, plan) as store, \
            evaluator.progress(judge_size(sources, cfg.heldout) * len(tasks), "transfer matrix"):
        evaluator.store = store  # the engine starts first: options it refuses leave no run folder
        per_task = {t.name: judge(evaluator, sources, heldout, base, t.name) for t in tasks}
    study = matrix(per_task, found_on, names.policy, heldout)
    write_atomic(out / "transfer.json", json.dumps(study.to_dict(), indent=2) + "\n")
    write_atomic(out / "transfer.csv", transfer_csv(study))
    transfer_png(study, out / "transfer.png")
    return study


def _searched_ticket(cfg: SearchConfig, task: str, out: Path) -> Ticket:
    """The top search ticket of a single-task search on `task` (judged there on the held-out seeds)."""
    folder = out / "search" / task.replace("/", "_")
    single = replace(cfg, task=task, top_k=1, no_regression=False, validation_seeds=cfg.validation())
    return find_golden_tickets(single, folder).best.ticket


def matrix(per_task: dict[str, Verdict], found_on: dict[str, list[str]], policy: str,
           heldout: list[int]) -> TransferStudy:
    """Each ticket (with the tasks it was found on) on each task: success, gain over base, p vs
    base Holm-adjusted over the tickets on that task (the task's verdict); and the greedy cover."""
    cells: dict[str, dict[str, TransferCell]] = {}
    for task, verdict in per_task.items():
        base_rate = verdict.rows[BASE].rate.success_rate
        for ticket in found_on:
            row = verdict.rows[Arm.ticket(ticket)]
            cells.setdefault(ticket, {})[task] = TransferCell(row.rate.success_rate,
                                                              row.rate.success_rate - base_rate,
                                                              row.p_vs_base, row.p_vs_base < ALPHA)
    baselines = {task: {arm: verdict.rows[arm] for arm in (BASE, ZERO)} for task, verdict in per_task.items()}
    return TransferStudy(policy, (heldout[0], heldout[-1]), found_on, baselines, cells,
                         greedy_cover(cells, {task: rows[BASE] for task, rows in baselines.items()}))


def greedy_cover(cells: dict[str, dict[str, TransferCell]], bases: dict[str, VerdictRow]) -> Cover:
    """The smallest set of tickets (greedy set cover) such that every task a ticket significantly
    improves has one that does; every other task gets the ticket with the highest success there if
    it beats the base's rate (`bases`: each task's base row), else the base. The table gives each
    task's arm to run with its cell."""
    wins = {ticket: {task for task, cell in row.items() if cell.significant} for ticket, row in cells.items()}
    uncovered, chosen, table = set().union(*wins.values()), [], {}
    while uncovered:
        ticket = max(wins, key=lambda t: (len(wins[t] & uncovered),
                                          sum(cells[t][task].gain for task in wins[t] & uncovered)))
        chosen.append(ticket)
        for task in sorted(wins[ticket] & uncovered):
            table[task] = (Arm.ticket(ticket), cells[ticket][task])
        uncovered -= wins[ticket]
    for task, base in bases.items():
        if task in table:
            continue
        best = max(cells, key=lambda t: cells[t][task].success_rate)
        if cells[best][task].gain > 0:
            table[task] = (Arm.ticket(best), cells[best][task])
        else:
            table[task] = (BASE, TransferCell(base.rate.success_rate, 0.0, None, False))
    uses = {use.key for use, _ in table.values() if use.candidate}
    return Cover(tuple(chosen), tuple(sorted(uses - set(chosen))), {task: table[task] for task in bases})


def transfer_csv(study: TransferStudy) -> str:
    """One row per (ticket, task): success, gain over base, Holm-adjusted p, significance."""
    lines = ["ticket,found_on,task,success_rate,base_rate,gain,p_vs_base,significant"]
    for ticket, found_on in study.tickets.items():
        for task, cell in study.cells[ticket].items():
            base = study.baselines[task][BASE].rate.success_rate
            lines.append(f"{ticket},{'+'.join(found_on)},{task},{cell.success_rate:.4f},{base:.4f},{cell.gain:.4f},"
                         f"{cell.p_vs_base:.4g},{cell.significant}")
    return "\n".join(lines) + "\n"
