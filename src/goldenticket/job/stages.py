"""The job's stages, each one job: baselines, search, validation, verdict (and a Pareto front).
Each takes the open Evaluator and returns typed results; none writes files but the front's."""

from __future__ import annotations

import copy
import functools
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goldenticket.config import SearchConfig
from goldenticket.errors import OptionError
from goldenticket.evaluation import Evaluator, Judged, judge, judge_size
from goldenticket.files import write_atomic
from goldenticket.job.names import Names
from goldenticket.job.records import searched
from goldenticket.noise import Constant, NoiseSource
from goldenticket.results import ParetoFront
from goldenticket.studies.pareto import pareto_study
from goldenticket.ticket_search import OPTIMIZERS, Optimizer, SearchResult, query_evaluator, run_search
from goldenticket.ticket_search.subspace import Subspace
from goldenticket.tickets import Ticket, ticket_id


def run_tickets(evaluator: Evaluator, fingerprint: str) -> Callable:
    """The search adapter's runner (`ticket_search.query_evaluator`): each (ticket, seeds) job
    through `evaluator`, its episodes labelled by the ticket's id for the policy `fingerprint`."""
    def run(jobs: list[tuple[np.ndarray, list[int]]], task: str | None):
        return evaluator.run([(ticket_id(t, fingerprint), Constant(t), seeds) for t, seeds in jobs], task)
    return run


def search_evaluate(evaluator: Evaluator, fingerprint: str, expand: Callable = lambda searched: searched,
                    where: Callable = lambda key: (None, key)) -> Callable:
    """The driver's evaluate() over `evaluator` (`ticket_search.query_evaluator`)."""
    return query_evaluator(run_tickets(evaluator, fingerprint), expand, where)


def expander(subspace: str, noise_shape: tuple[int, int]) -> Callable[[np.ndarray], np.ndarray]:
    """The full (H, A) ticket of an array searched in `subspace`."""
    return functools.partial(Subspace.parse(subspace, noise_shape).expand, noise_shape=noise_shape)


def optimizer(cfg: SearchConfig, noise_shape: tuple[int, int], keys: list[int]) -> Optimizer:
    """The run's optimizer over its sub-space, fresh from its seed, on the search seed `keys`;
    OptionError if the budget cannot score even the first ticket it asks for."""
    searched = Subspace.parse(cfg.subspace, noise_shape).shape(noise_shape)
    built = OPTIMIZERS[cfg.method](searched, keys, np.random.default_rng(cfg.seed), cfg.settings())
    needed = len(copy.deepcopy(built).ask()[0].seeds)
    if cfg.budget < needed:
        raise OptionError(f"budget {cfg.budget} is too small: {cfg.method} needs {needed} episodes to score "
                          "one ticket", "budget")
    return built


def baselines(evaluator: Evaluator, tasks: list[str], base: NoiseSource, zero: NoiseSource,
              heldout: list[int]) -> None:
    """Base and zero ticket on every task's held-out seeds (recorded; the verdict reads them back)."""
    with evaluator.progress(2 * len(heldout) * len(tasks), "held-out: base and zero ticket"):
        for name in tasks:
            evaluator.run([("base", base, heldout), ("zero", zero, heldout)], name)


def search(cfg: SearchConfig, evaluator: Evaluator, optimizer: Optimizer, evaluate: Callable,
           n_tasks: int) -> SearchResult:
    """The search itself, within the budget; the bar ends at the episodes spent and says why."""
    several = f", {n_tasks} tasks" if n_tasks > 1 else ""
    with evaluator.progress(cfg.budget, f"search ({cfg.method}{several})") as bar:
        result = run_search(optimizer, evaluate, budget=cfg.budget, stop_after_perfect=cfg.stop_after_perfect,
                            max_tickets=cfg.max_tickets)
        if result.episodes_used < cfg.budget:
            bar.set_postfix_str(f"{result.episodes_used} of {cfg.budget} spent: {result.stopped_because}")
    return result


def top_candidates(result: SearchResult, cfg: SearchConfig, seeds: int) -> list:
    """The best search candidates: top_k, or 3 x top_k to choose from on validation seeds."""
    k = cfg.top_k * (3 if cfg.validation() else 1)
    return result.top(k, min_episodes=seeds) or result.top(k)


@dataclass(frozen=True)
class Validated:
    """Validation's outcome: every ticket that ran there, with its score, and the chosen top_k."""

    scored: list[Ticket]
    chosen: list[Ticket]

    def of(self, ticket: Ticket) -> Ticket:
        """`ticket` with its validation score."""
        return next(t for t in self.scored if t.id == ticket.id)


def validate(cfg: SearchConfig, evaluator: Evaluator, tickets: list[Ticket], seeds: list[int],
             tasks: list[str]) -> Validated:
    """The top_k of `tickets` by mean return on the validation `seeds` of every task (ties: search
    rank): a selection on states neither the search nor the held-out verdict uses."""
    with evaluator.progress(len(seeds) * len(tickets) * len(tasks), "validation: search's best tickets"):
        runs = [evaluator.run([(t.id, Constant(t.noise), seeds) for t in tickets], task) for task in tasks]
    scores = [float(np.mean([np.mean([r.ret for r in per_task[i]]) for per_task in runs]))
              for i in range(len(tickets))]
    scored = [t.with_record(validation_score=score, validation_seeds=(seeds[0], seeds[-1]))
              for t, score in zip(tickets, scores, strict=True)]
    ranked = sorted(range(len(tickets)), key=lambda i: -scores[i])  # stable: ties keep search rank
    return Validated(scored, [scored[i] for i in ranked[: cfg.top_k]])


def with_zero(tickets: list[Ticket], zero: Ticket) -> list[Ticket]:
    """The tickets the verdict judges after validation: `tickets`, and the zero ticket after them if
    it is not among them. It is a constant noise like any ticket, so the job delivers it wherever it
    is best on the held-out seeds."""
    return tickets if any(t.id == zero.id for t in tickets) else [*tickets, zero]


def verdict(evaluator: Evaluator, tickets: list[Ticket], zero: NoiseSource, base: NoiseSource,
            heldout: list[int], tasks: list[str]) -> dict[str, dict[str, Judged]]:
    """Base, zero ticket and `tickets` judged on the held-out seeds of each task."""
    sources = {"zero": zero} | {t.id: Constant(t.noise) for t in tickets}
    with evaluator.progress(judge_size(sources, len(heldout)) * len(tasks), "held-out: top tickets"):
        return {name: judge(evaluator, sources, heldout, base, name) for name in tasks}


def front(cfg: SearchConfig, names: Names, evaluator: Evaluator, result: SearchResult, seeds: tuple,
          baselines: tuple, expand: Callable, max_steps: int, out: Path) -> tuple[ParetoFront, dict]:
    """The Pareto front of the search's tickets for (objective, front objective), judged on the
    held-out seeds; its tickets saved, front.json and front.png written. Returns the front and each
    front ticket's front record by id."""
    search_seeds, heldout = seeds
    scored = {}
    for candidate in result.candidates:
        if candidate.n >= len(search_seeds):
            noise = expand(candidate.ticket)
            scored[ticket_id(noise, names.fingerprint)] = (Constant(noise), candidate)
    fronts = {}

    def save(candidate, front_record: dict) -> str:
        ticket = searched(cfg, names, result, candidate, search_seeds, expand, [names.task])
        fronts[ticket.id] = front_record
        return str(ticket.with_record(front=front_record).save(out / "tickets" / f"{ticket.id}.safetensors"))

    with evaluator.progress(None, "Pareto front"):  # its size is known only once found
        study = pareto_study(evaluator, scored, (cfg.objective, cfg.front_objective), max_steps=max_steps,
                             heldout=heldout, base=baselines[0], zero=baselines[1], save=save, out=out)
    write_atomic(out / "front.json", json.dumps(study.to_dict(), indent=2) + "\n")
    return study, fronts
