"""The run folder: its store and config, claimed before anything runs; the tickets, summary.json
and pictures written once the verdict is in."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

from goldenticket.config import RECORDED_SETTINGS, SearchConfig, named, to_toml
from goldenticket.errors import UserError
from goldenticket.evaluation import BASE, ZERO, Arm, Verdict, VerdictRow, multitask_verdict
from goldenticket.files import open_folder, write_atomic
from goldenticket.job.plan import Names, Plan
from goldenticket.options import changes_results
from goldenticket.plots import arms_png, search_png, tasks_png
from goldenticket.results import FoundTicket, MultitaskSummary, ParetoFront, SearchRun, Summary
from goldenticket.store import RunStore
from goldenticket.ticket_search import SearchResult
from goldenticket.tickets import Ticket


def open_store(out: str | Path, plan: Plan) -> RunStore:
    """The run store in `out` (its name as given: Path("") would be the current folder), holding
    this config's options that change results (`options.changes_results`) and the policy's
    fingerprint (a policy retrained in place is another run);
    UserError for a symbolic link in place of tickets/, which would put the tickets elsewhere."""
    open_folder(out)
    out, cfg, names = Path(out), plan.cfg, plan.names
    if (out / "tickets").is_symlink():
        raise UserError(f"{out / 'tickets'} is a symbolic link; a run writes its tickets only inside its "
                        "output folder (replace the link with a folder, or choose another output folder)")
    store = RunStore(out / "run.sqlite")
    config = {f.name: getattr(cfg, f.name) for f in fields(cfg) if changes_results(f)} | {
        "policy": names.policy, "task": names.task, "success": named(cfg.success),
        "policy_fingerprint": names.fingerprint, "halving": cfg.halves(),
        "workers": None, "backend": None, "address": None}  # as every run store spells them: old runs resume
    for name in ("optimizer", "halving", *RECORDED_SETTINGS):  # unset: as before they existed
        if not config[name]:
            del config[name]
    if not store.claim_config(config):
        store.close()
        raise UserError(f"{out} holds a different run; choose another output folder or the same options")
    write_atomic(out / "config.toml", to_toml(cfg))
    return store


def ticket_path(out: Path, ticket: Ticket) -> Path:
    return out / "tickets" / f"{ticket.id}.safetensors"


def save_ranked(tickets: list[Ticket], rows: dict[Arm, VerdictRow], out: Path, span: tuple[int, int],
                fronts: dict[str, dict]) -> tuple[FoundTicket, ...]:
    """Save each ticket with its held-out result (its verdict row in `rows`, and its place on the
    Pareto front, `fronts` by ticket id, if it has one); best first: by success, the zero ticket
    before any ticket it ties (it needs no search, so a tie is no evidence for the other), then by p."""
    judged = {t.id: rows[Arm.ticket(t.id)] for t in tickets}
    ranked = sorted(tickets, key=lambda t: (-judged[t.id].rate.success_rate,
                                            t.record.provenance != "zero", judged[t.id].p_vs_base))
    found = []
    for t in ranked:
        row = judged[t.id]
        t = t.with_record(heldout=row.to_dict() | {"seeds": list(span)},
                          front=fronts.get(t.id, t.record.front))
        path = t.save(ticket_path(out, t))
        found.append(FoundTicket(t.id, str(path), t.record.search_score, row, t.record.validation_score,
                                 t.record.source, t))
    return tuple(found)


def write(plan: Plan, per_task: dict[str, Verdict], tickets: list[Ticket], run: SearchRun,
          out: Path, fronts: dict[str, dict], front: ParetoFront | None) -> Summary | MultitaskSummary:
    """The verdict as the run's result: each ticket saved with its held-out result, and
    summary.json."""
    if len(plan.tasks) > 1:
        result = multitask_summary(plan.cfg, per_task, tickets, run, out)
    else:
        result = summary(plan.names, per_task[plan.task_names[0]], tickets, run, out, fronts, front)
    write_atomic(out / "summary.json", json.dumps(result.to_dict(), indent=2) + "\n")
    return result


def summary(names: Names, verdict: Verdict, tickets: list[Ticket], run: SearchRun, out: Path,
            fronts: dict[str, dict], front: ParetoFront | None) -> Summary:
    """One task's verdict (p-values Holm-adjusted over the tickets), each ticket saved with its
    held-out result, the best first."""
    found = save_ranked(tickets, verdict.rows, out, run.heldout_seeds, fronts)
    return Summary(names.task, run, verdict.rows[BASE], verdict.rows[ZERO], found, front)


def multitask_summary(cfg: SearchConfig, per_task: dict[str, Verdict], tickets: list[Ticket],
                      run: SearchRun, out: Path) -> MultitaskSummary:
    """Several tasks' verdict (`evaluation.multitask_verdict`), each ticket saved with its
    task-averaged and per-task held-out results and its validation score."""
    verdict = multitask_verdict(per_task, cfg.no_regression)
    for ticket in tickets:
        arm = Arm.ticket(ticket.id)
        per_task_rows = {task: verdict.tasks[task][arm].to_dict() for task in per_task}
        ticket.with_record(heldout=verdict.average[arm].to_dict() | {
            "seeds": list(run.heldout_seeds), "per_task": per_task_rows}).save(ticket_path(out, ticket))
    validation = {t.id: t.record.validation_score for t in tickets if t.record.validation_score is not None}
    return MultitaskSummary(verdict, run, validation)


def pictures(plan: Plan, result: Summary | MultitaskSummary, search: SearchResult, place: dict[str, int],
             out: Path) -> None:
    """verdict.png (per arm, or per task and on average) and search.png, with the tickets the
    job validated and judged marked (`place`: ticket id -> its place in the search) beside the
    held-out rows that chose among them (on average over the tasks)."""
    names = plan.names
    title = f"{names.policy} on {names.task}"
    if isinstance(result, MultitaskSummary):
        tasks_png(result.verdict, out / "verdict.png",
                  f"{names.policy}: one ticket for {len(result.verdict.tasks)} tasks")
        verdict = result.verdict
        judged, best = [t.key for t in verdict.tickets], verdict.best and verdict.best.key
        rows = {arm.label: row for arm, row in verdict.average.items()}
        chosen = verdict.best and verdict.best.label
    else:
        rows, chosen = result.table().rows(), result.best.label
        arms_png(rows, out / "verdict.png", title, best=chosen)
        judged, best = [t.id for t in result.tickets], result.best.id
    span = result.run.heldout_seeds
    search_png([c.mean_return for c in search.candidates], [c.n for c in search.candidates],
               out / "search.png", plan.title,
               validated=list(place.values()) if plan.seeds.validation else [],
               judged=[place[t] for t in judged if t in place], chosen=place.get(best),
               heldout=(rows, chosen, f"held-out seeds {span[0]}:{span[1] + 1}"))
