"""The job's stages, each one job: baselines, search, validation, verdict (and a Pareto front),
each run from the run's Plan (with the open Evaluator where it runs episodes); none writes files
but the front's."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goldenticket.errors import OptionError
from goldenticket.evaluation import ZERO, Arm, Evaluator, Verdict, judge, judge_size
from goldenticket.files import write_atomic
from goldenticket.job.folder import ticket_path
from goldenticket.job.plan import Plan
from goldenticket.job.records import searched
from goldenticket.noise import Constant
from goldenticket.results import ParetoFront
from goldenticket.studies.pareto import pareto_study
from goldenticket.ticket_search import (
    OPTIMIZERS,
    RACE_BLOCK,
    Halved,
    Optimizer,
    Raced,
    SearchResult,
    query_evaluator,
    run_search,
)
from goldenticket.ticket_search.racing import Race, better_half, halving_sizes, in_blocks
from goldenticket.tickets import Ticket, ticket_id

Evaluate = Callable  # the driver's evaluate(queries) -> outcomes
VALIDATION_BLOCK = 10  # validation seeds a halved validation runs its tickets on between two cuts
STOPPED = {"budget": "the next tickets did not fit whole",  # why a search spent less than its budget
           "k perfect tickets": "tickets perfect on every seed"}


def run_tickets(evaluator: Evaluator, fingerprint: str) -> Callable:
    """The search adapter's runner (`ticket_search.query_evaluator`): each (ticket, seeds) job
    through `evaluator`, its episodes labelled by the ticket's id for the policy `fingerprint`."""
    def run(jobs: list[tuple[np.ndarray, list[int]]], task: str | None):
        return evaluator.run([(ticket_id(t, fingerprint), Constant(t), seeds) for t, seeds in jobs], task)
    return run


def search_evaluate(evaluator: Evaluator, fingerprint: str, expand: Callable = lambda searched: searched,
                    where: Callable = lambda key: (None, key)) -> Evaluate:
    """The driver's evaluate() over `evaluator` (`ticket_search.query_evaluator`)."""
    return query_evaluator(run_tickets(evaluator, fingerprint), expand, where)


def optimizer(plan: Plan) -> Optimizer:
    """The run's optimizer over its sub-space, fresh from its seed, on the plan's seed keys (raced or
    halved if the run says so); OptionError if the budget cannot score even the first ticket it asks for."""
    cfg, shape = plan.cfg, plan.policy.noise_shape
    built = OPTIMIZERS[cfg.method](plan.subspace.shape(shape), plan.keys, np.random.default_rng(cfg.seed),
                                   cfg.settings())
    if cfg.race is not None:
        built = Raced(built, RACE_BLOCK, cfg.race)
    elif cfg.halves():  # on fewer search seeds than a block, one block: every ticket on every seed
        built = Halved(built, min(RACE_BLOCK, len(plan.keys)))
    needed = len(copy.deepcopy(built).ask()[0].seeds)
    if cfg.budget < needed:
        raise OptionError(f"budget {cfg.budget} is too small: {cfg.method} needs {needed} episodes to score "
                          "one ticket", "budget")
    return built


def baselines(plan: Plan, evaluator: Evaluator) -> None:
    """Base and zero ticket on every task's held-out seeds (recorded; the verdict reads them back)."""
    heldout = plan.seeds.heldout
    with evaluator.progress(2 * len(heldout) * len(plan.tasks), "held-out: base and zero ticket"):
        for name in plan.task_names:
            evaluator.run([("base", plan.base, heldout), ("zero", plan.zero, heldout)], name)


def search(plan: Plan, evaluator: Evaluator, optimizer: Optimizer,
           watch: Callable[[Evaluate], Evaluate] = lambda evaluate: evaluate) -> SearchResult:
    """The search itself, within the budget (`watch` wraps the driver's evaluate: a tracker's); the
    bar ends at the episodes spent and says why."""
    cfg = plan.cfg
    evaluate = search_evaluate(evaluator, plan.names.fingerprint, plan.expand, plan.where)
    several = f", {len(plan.tasks)} tasks" if len(plan.tasks) > 1 else ""
    with evaluator.progress(cfg.budget, f"search ({cfg.method}{several})") as bar:
        result = run_search(optimizer, watch(evaluate), budget=cfg.budget,
                            stop_after_perfect=cfg.stop_after_perfect, max_tickets=cfg.max_tickets)
        if result.episodes_used < cfg.budget:
            bar.set_postfix_str(f"{result.episodes_used} of {cfg.budget} spent: "
                                + STOPPED.get(result.stopped_because, result.stopped_because))
    return result


def top_candidates(plan: Plan, result: SearchResult) -> list:
    """The best search candidates: top_k, or 3 x top_k to choose from on validation seeds."""
    k = plan.cfg.top_k * (3 if plan.seeds.validation else 1)
    if plan.cfg.halves():  # most tickets stopped before the last search seed: all ranked, their means shrunk
        return result.top(k, shrink=RACE_BLOCK)
    return result.top(k, min_episodes=len(plan.keys)) or result.top(k)


@dataclass(frozen=True)
class Validated:
    """Validation's outcome: every ticket that ran there, with its score, and the chosen top_k."""

    scored: list[Ticket]
    chosen: list[Ticket]

    def of(self, ticket: Ticket) -> Ticket:
        """`ticket` with its validation score."""
        return next(t for t in self.scored if t.id == ticket.id)


def validate(plan: Plan, evaluator: Evaluator, tickets: list[Ticket], top_k: int | None = None) -> Validated:
    """The `top_k` (default: the config's) of `tickets` by mean return on the validation seeds of
    every task (ties: search rank): a selection on states neither the search nor the held-out
    verdict uses. With the run's `halving`, the tickets race on VALIDATION_BLOCK seeds at a time and
    the better half goes on while that half is more than `top_k` (`racing.halving_sizes`); each is
    scored on the seeds it ran."""
    seeds, tasks, k = plan.seeds.validation, plan.task_names, top_k or plan.cfg.top_k
    blocks = in_blocks(seeds, VALIDATION_BLOCK if plan.cfg.halves() else len(seeds))
    sizes = halving_sizes(len(tickets), k, len(blocks))
    race = Race(len(tickets), better_half, _score, len(sizes))
    with evaluator.progress(len(tasks) * sum(n * len(b) for n, b in zip(sizes, blocks, strict=False)),
                            "validation: search's best tickets"):
        while not race.over:
            jobs = [(tickets[i].id, Constant(tickets[i].noise), blocks[race.round]) for i in race.alive]
            per_task = [evaluator.run(jobs, task) for task in tasks]
            race.record([[[r.ret for r in results] for results in ticket]
                         for ticket in zip(*per_task, strict=True)])
    scored = [t.with_record(validation_score=_score(rounds),
                            validation_seeds=(seeds[0], blocks[len(rounds) - 1][-1]))  # its last seed
              for t, rounds in zip(tickets, race.results, strict=True)]
    return Validated(scored, [scored[i] for i in race.ranked()[:k]])  # ranked: ties keep search rank


def _score(rounds: list[list[list[float]]]) -> float:
    """A ticket's validation score from its rounds (each its returns per task): its mean return per
    task, averaged over the tasks."""
    return float(np.mean([np.mean([r for run in runs for r in run]) for runs in zip(*rounds, strict=True)]))


def with_zero(tickets: list[Ticket], zero: Ticket) -> list[Ticket]:
    """The tickets the verdict judges after validation: `tickets`, and the zero ticket after them if
    it is not among them. It is a constant noise like any ticket, so the job delivers it wherever it
    is best on the held-out seeds."""
    return tickets if any(t.id == zero.id for t in tickets) else [*tickets, zero]


def verdict(plan: Plan, evaluator: Evaluator, tickets: list[Ticket]) -> dict[str, Verdict]:
    """Base, zero ticket and `tickets` judged on the held-out seeds of each task (p-values
    Holm-adjusted over the tickets there)."""
    heldout = plan.seeds.heldout
    sources = {ZERO: plan.zero} | {Arm.ticket(t.id): Constant(t.noise) for t in tickets}
    with evaluator.progress(judge_size(sources, len(heldout)) * len(plan.tasks), "held-out: top tickets"):
        return {name: judge(evaluator, sources, heldout, plan.base, name) for name in plan.task_names}


def front(plan: Plan, evaluator: Evaluator, result: SearchResult, out: Path) -> tuple[ParetoFront, dict]:
    """The Pareto front of the search's tickets for (objective, front objective), judged on the
    held-out seeds; its tickets saved, front.json and front.png written. Returns the front and each
    front ticket's front record by id."""
    cfg, scored, fronts = plan.cfg, {}, {}
    for candidate in result.candidates:
        if candidate.n >= len(plan.seeds.search):
            noise = plan.expand(candidate.ticket)
            scored[ticket_id(noise, plan.names.fingerprint)] = (Constant(noise), candidate)

    def save(candidate, front_record: dict) -> str:
        ticket = searched(plan, result, candidate)
        fronts[ticket.id] = front_record
        return str(ticket.with_record(front=front_record).save(ticket_path(out, ticket)))

    with evaluator.progress(None, "Pareto front"):  # its size is known only once found
        study = pareto_study(evaluator, scored, (cfg.objective, cfg.front_objective),
                             max_steps=plan.tasks[0].max_steps, heldout=plan.seeds.heldout, base=plan.base,
                             zero=plan.zero, save=save, out=out)
    write_atomic(out / "front.json", json.dumps(study.to_dict(), indent=2) + "\n")
    return study, fronts
