"""The golden-ticket job, in stages: baselines -> search -> validation -> verdict -> the run
folder (`plan`, `stages`, `folder`); and the `evaluate` command (`evaluate`)."""

from __future__ import annotations

from pathlib import Path

from goldenticket.config import SearchConfig
from goldenticket.evaluation import Evaluator
from goldenticket.job import folder, stages
from goldenticket.job.plan import Names, Plan, checked_tasks, shared
from goldenticket.job.records import other_candidates, searched
from goldenticket.policies import NoisePolicy, load_policy
from goldenticket.results import MultitaskSummary, SearchRun, Summary
from goldenticket.ticket_search import SearchResult
from goldenticket.tracking import Tracker

__all__ = ["Names", "Plan", "checked_tasks", "find_golden_tickets", "search_only", "shared"]


def find_golden_tickets(cfg: SearchConfig, out: str | Path) -> Summary | MultitaskSummary:
    """Run the whole job into `out`; resumes from `out/run.sqlite` if it holds the same config.
    On several tasks (a multi-task policy's), one ticket for the task-averaged objective, judged
    per task and on average (`Plan.where` spreads the search's episodes over them)."""
    cfg.check()
    out_name, out = out, Path(out)  # the name as given: Path("") would be the current folder
    policy = load_policy(cfg.policy, cfg.device, **cfg.policy_settings())
    plan = Plan.of(cfg, policy, checked_tasks(policy, cfg))
    optimizer, others = stages.optimizer(plan), other_candidates(plan)
    with Evaluator.open(cfg.policy, plan.tasks, cfg, objective=cfg.objective, loaded=policy) as evaluator, \
            folder.open_store(out_name, plan) as store, Tracker(cfg, out, plan.title) as tracker:
        evaluator.store = store  # the engine starts first: options it refuses leave no run folder
        stages.baselines(plan, evaluator)
        result = stages.search(plan, evaluator, optimizer,
                               lambda evaluate: tracker.watch(evaluate, plan.expand, plan.names.fingerprint))
        top = stages.top_candidates(plan, result)
        tickets = candidates = [searched(plan, result, c) for c in top]
        if plan.seeds.validation:
            validated = stages.validate(plan, evaluator, candidates + others)
            tickets = stages.with_zero(validated.chosen, validated.of(others[0]))
            tracker.validated(validated.scored)
        per_task = stages.verdict(plan, evaluator, tickets)
        front, fronts = stages.front(plan, evaluator, result, out) if cfg.front_objective else (None, {})
    summary = folder.write(plan, per_task, tickets, _run(plan, result), out, fronts, front)
    tracker.finish(summary)
    order = {id(c): i for i, c in enumerate(result.candidates)}  # a search ticket's place in the search
    place = {ticket.id: order[id(c)] for ticket, c in zip(candidates, top, strict=True)}
    folder.pictures(plan, summary, result, place, out)
    return summary


def _run(plan: Plan, result: SearchResult) -> SearchRun:
    cfg = plan.cfg
    return SearchRun(plan.names.policy, cfg.method, cfg.seed, result.episodes_used, result.stopped_because,
                     plan.seeds.heldout_span)


def search_only(cfg: SearchConfig, evaluator: Evaluator, policy: NoisePolicy) -> SearchResult:
    """The job's search stage alone, on the evaluator's task: `cfg`'s method and settings over its
    sub-space, its search seeds and budget; for studies that judge the tickets in their own way."""
    cfg.check()
    plan = Plan.of(cfg, policy, [evaluator.engine.task])
    return stages.search(plan, evaluator, stages.optimizer(plan))
