"""The golden-ticket job, in stages: baselines -> search -> validation -> verdict -> the run
folder (`stages`, `folder`); and the `evaluate` command (`evaluate`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from goldenticket.config import SearchConfig
from goldenticket.evaluation import Evaluator
from goldenticket.job import folder, stages
from goldenticket.job.names import Names, checked_tasks, search_title, shared
from goldenticket.job.records import other_candidates, searched
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import NoisePolicy, identity, load_policy
from goldenticket.results import MultitaskSummary, SearchRun, Summary
from goldenticket.seeds import seeds_in
from goldenticket.ticket_search import SearchResult
from goldenticket.tickets import zero_ticket
from goldenticket.tracking import Tracker

__all__ = ["Names", "checked_tasks", "find_golden_tickets", "search_only", "shared"]


def find_golden_tickets(cfg: SearchConfig, out: str | Path) -> Summary | MultitaskSummary:
    """Run the whole job into `out`; resumes from `out/run.sqlite` if it holds the same config.
    On several tasks (a multi-task policy's), one ticket for the task-averaged objective, judged
    per task and on average. Search episodes go to the tasks in turn: seed key k runs task
    k mod T on search seed k div T, so every prefix the optimizer uses (a racing tier, say) spreads
    evenly over the tasks; one task is the case T = 1."""
    cfg.check()
    named_out, out = out, Path(out)  # the name as given: Path("") would be the current folder
    policy = load_policy(cfg.policy)
    tasks = checked_tasks(policy, cfg)
    task_names = [t.name for t in tasks]
    heldout, search_seeds = seeds_in("heldout", cfg.heldout), seeds_in("search", cfg.search_seeds)
    validation = seeds_in("validation", cfg.validation())
    keys = list(range(len(tasks) * len(search_seeds)))
    optimizer = stages.optimizer(cfg, policy.noise_shape, keys)
    names = Names.of(cfg.policy, policy, " + ".join(task_names), shared(t.max_steps for t in tasks),
                     cfg.success)
    expand = stages.expander(cfg.subspace, policy.noise_shape)
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    others = other_candidates(cfg, names, policy.noise_shape, task_names)

    def where(key: int) -> tuple[str, int]:
        return task_names[key % len(tasks)], search_seeds[key // len(tasks)]

    with Evaluator.open(cfg.policy, tasks, cfg, objective=cfg.objective, loaded=policy) as evaluator, \
            folder.open_store(named_out, cfg, names) as store, \
            Tracker(cfg, out, search_title(cfg, names)) as tracker:
        evaluator.store = store  # the engine starts first: options it refuses leave no run folder
        stages.baselines(evaluator, task_names, base, zero, heldout)
        evaluate = stages.search_evaluate(evaluator, names.fingerprint, expand, where)
        result = stages.search(cfg, evaluator, optimizer, tracker.watch(evaluate, expand, names.fingerprint),
                               len(tasks))
        top = stages.top_candidates(result, cfg, len(keys))
        candidates = [searched(cfg, names, result, c, search_seeds, expand, task_names) for c in top]
        tickets = candidates
        if validation:
            validated = stages.validate(cfg, evaluator, candidates + others, validation, task_names)
            tickets = stages.with_zero(validated.chosen, validated.of(others[0]))
            tracker.validated(validated.scored)
        per_task = stages.verdict(evaluator, tickets, zero, base, heldout, task_names)
        front, fronts = (None, {}) if not cfg.front_objective else stages.front(
            cfg, names, evaluator, result, (search_seeds, heldout), (base, zero), expand, tasks[0].max_steps,
            out)
    run = SearchRun(names.policy, cfg.method, cfg.seed, result.episodes_used, result.stopped_because,
                    (heldout[0], heldout[-1]))
    if len(tasks) > 1:
        summary = folder.multitask_summary(cfg, per_task, tickets, run, out)
    else:
        summary = folder.summary(names, per_task[task_names[0]], tickets, run, out, fronts, front)
    folder.write_summary(summary, out)
    tracker.finish(summary)
    order = {id(c): i for i, c in enumerate(result.candidates)}  # a search ticket's place in the search
    place = {ticket.id: order[id(c)] for ticket, c in zip(candidates, top, strict=True)}
    base_return = float(np.mean([r.ret for judged in per_task.values() for r in judged["base"].results]))
    folder.pictures(cfg, names, summary, result, place, bool(validation), base_return, out)
    return summary


def search_only(cfg: SearchConfig, evaluator: Evaluator, policy: NoisePolicy) -> SearchResult:
    """The job's search stage alone, on the evaluator's task: `cfg`'s method and settings over its
    sub-space, its search seeds and budget; for studies that judge the tickets in their own way."""
    cfg.check()
    search_seeds = seeds_in("search", cfg.search_seeds)
    optimizer = stages.optimizer(cfg, policy.noise_shape, search_seeds)
    expand = stages.expander(cfg.subspace, policy.noise_shape)
    evaluate = stages.search_evaluate(evaluator, identity(policy), expand)
    return stages.search(cfg, evaluator, optimizer, evaluate, 1)
