"""The run folder: its store and config, claimed before anything runs; the tickets, summary.json
and pictures written once the verdict is in."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

from goldenticket.config import SearchConfig, named, to_toml
from goldenticket.errors import UserError
from goldenticket.evaluation import Judged, adjust_for_multiplicity, multitask_verdict
from goldenticket.files import open_folder, write_atomic
from goldenticket.job.plan import Names, Plan
from goldenticket.plots import arms_png, search_png, tasks_png
from goldenticket.results import FoundTicket, MultitaskSummary, ParetoFront, SearchRun, Summary
from goldenticket.store import RunStore
from goldenticket.ticket_search import SearchResult
from goldenticket.tickets import Ticket


def open_store(out: str | Path, plan: Plan) -> RunStore:
    """The run store in `out` (its name as given: Path("") would be the current folder), holding
    this config (the policy's fingerprint included: a policy retrained in place is another run)."""
    open_folder(out)
    out, cfg, names = Path(out), plan.cfg, plan.names
    store = RunStore(out / "run.sqlite")
    config = {f.name: getattr(cfg, f.name) for f in fields(cfg) if f.name not in ("max_nonfinite", "log")} | {
        "policy": names.policy, "task": names.task, "success": named(cfg.success),
        "policy_fingerprint": names.fingerprint,
        "workers": None, "backend": None, "address": None,  # where episodes run does not change them
        "halving": cfg.halves()}
    for name in ("optimizer", "halving"):  # claimed as before they could be set, while unset
        if not config[name]:
            del config[name]
    if not store.claim_config(config):
        store.close()
        raise UserError(f"{out} holds a different run; choose another output folder or the same options")
    write_atomic(out / "config.toml", to_toml(cfg))
    return store


def ticket_path(out: Path, ticket: Ticket) -> Path:
    return out / "tickets" / f"{ticket.id}.safetensors"


def save_ranked(tickets: list[Ticket], judged: dict[str, Judged], out: Path, span: tuple[int, int],
                fronts: dict[str, dict]) -> tuple[FoundTicket, ...]:
    """Save each ticket with its held-out result (and its place on the Pareto front, `fronts` by
    ticket id, if it has one); best first: by success, the zero ticket before any ticket it ties
    (it needs no search, so a tie is no evidence for the other), then by p."""
    ranked = sorted(tickets, key=lambda t: (-judged[t.id].rate.success_rate,
                                            t.record.provenance != "zero", judged[t.id].p_vs_base))
    found = []
    for t in ranked:
        row = judged[t.id].row()
        t = t.with_record(heldout=row.to_dict() | {"seeds": list(span)},
                          front=fronts.get(t.id, t.record.front))
        path = t.save(ticket_path(out, t))
        found.append(FoundTicket(t.id, str(path), t.record.search_score, row, t.record.validation_score,
                                 t.record.source, t))
    return tuple(found)


def write(plan: Plan, per_task: dict[str, dict[str, Judged]], tickets: list[Ticket], run: SearchRun,
          out: Path, fronts: dict[str, dict], front: ParetoFront | None) -> Summary | MultitaskSummary:
    """The verdict as the run's result: each ticket saved with its held-out result, and
    summary.json."""
    if len(plan.tasks) > 1:
        result = multitask_summary(plan.cfg, per_task, tickets, run, out)
    else:
        result = summary(plan.names, per_task[plan.task_names[0]], tickets, run, out, fronts, front)
    write_atomic(out / "summary.json", json.dumps(result.to_dict(), indent=2) + "\n")
    return result


def summary(names: Names, judged: dict[str, Judged], tickets: list[Ticket], run: SearchRun, out: Path,
            fronts: dict[str, dict], front: ParetoFront | None) -> Summary:
    """One task's verdict: p-values Holm-adjusted over the tickets, each ticket saved with its
    held-out result, the best first."""
    adjust_for_multiplicity(judged, [t.id for t in tickets])
    found = save_ranked(tickets, judged, out, run.heldout_seeds, fronts)
    return Summary(names.task, run, judged["base"].row(), judged["zero"].row(), found, front)


def multitask_summary(cfg: SearchConfig, per_task: dict[str, dict[str, Judged]], tickets: list[Ticket],
                      run: SearchRun, out: Path) -> MultitaskSummary:
    """Several tasks' verdict (`evaluation.multitask_verdict`), each ticket saved with its
    task-averaged and per-task held-out results and its validation score."""
    verdict = multitask_verdict(per_task, [t.id for t in tickets], cfg.no_regression)
    for ticket in tickets:
        per_task_rows = {task: verdict.tasks[task][ticket.id].to_dict() for task in per_task}
        ticket.with_record(heldout=verdict.average[ticket.id].to_dict() | {
            "seeds": list(run.heldout_seeds), "per_task": per_task_rows}).save(ticket_path(out, ticket))
    validation = {t.id: t.record.validation_score for t in tickets if t.record.validation_score is not None}
    return MultitaskSummary(verdict, run, validation)


def pictures(plan: Plan, result: Summary | MultitaskSummary, search: SearchResult, place: dict[str, int],
             base_return: float, out: Path) -> None:
    """verdict.png (per arm, or per task and on average) and search.png, with the tickets the
    job validated and judged marked (`place`: ticket id -> its place in the search)."""
    names = plan.names
    title = f"{names.policy} on {names.task}"
    if isinstance(result, MultitaskSummary):
        tasks_png(result.verdict, out / "verdict.png",
                  f"{names.policy}: one ticket for {len(result.verdict.tasks)} tasks")
        judged, best = result.verdict.tickets, result.verdict.best
    else:
        arms_png(result.rows(), out / "verdict.png", title, best=f"ticket {result.best.label}")
        judged, best = [t.id for t in result.tickets], result.best.id
    span = result.run.heldout_seeds
    search_png([c.mean_return for c in search.candidates], [c.n for c in search.candidates],
               out / "search.png", plan.title,
               validated=list(place.values()) if plan.seeds.validation else [],
               judged=[place[t] for t in judged if t in place], chosen=place.get(best),
               base=(base_return, f"held-out seeds {span[0]}:{span[1] + 1}"))
