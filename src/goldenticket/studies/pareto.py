"""Pareto fronts: tickets that trade one objective against another (e.g. success against speed).

Every ticket the search scored on all its search seeds gets a score per objective; the front is
the tickets no other ticket beats on both. The front is then re-judged on held-out seeds beside
the base and the zero ticket, its tickets saved, and `front.json` / `front.png` written. A
deployed `TicketedPolicy` switches between front tickets with `use()`, keeping the model loaded.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from goldenticket.evaluation import ZERO, Arm, Evaluator, judge
from goldenticket.noise import NoiseSource
from goldenticket.objectives import OBJECTIVES
from goldenticket.plots import front_png
from goldenticket.results import FrontArm, ParetoFront
from goldenticket.rollout import EpisodeResult
from goldenticket.ticket_search import Candidate


def _scores(objectives: Sequence[str], results: Sequence[EpisodeResult], max_steps: int) -> dict:
    return {o: ticket_score(o, results, max_steps) for o in objectives}


def ticket_score(objective: str, results: Sequence[EpisodeResult], max_steps: int) -> float:
    """A ticket's score on its episodes; higher is better. `speed` is the mean of
    1 - length / max_steps over the successful episodes only (0 if none succeeded), so that it
    measures how fast a ticket succeeds, not how often; every other objective is its mean return."""
    if objective == "speed":
        won = [1 - r.length / max_steps for r in results if r.success]
        return float(np.mean(won)) if won else 0.0
    return float(np.mean([OBJECTIVES[objective](r.success, r.length, max_steps, 0.0) for r in results]))


def non_dominated(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point matches or beats on both coordinates while beating
    on one (both maximised); equal points are all kept."""
    return [i for i, (x, y) in enumerate(points)
            if not any(a >= x and b >= y and (a > x or b > y) for a, b in points)]


def pareto_study(evaluator: Evaluator, scored: dict[str, tuple[NoiseSource, Candidate]],
                 objectives: tuple[str, str], *, max_steps: int, heldout: Sequence[int],
                 base: NoiseSource, zero: NoiseSource, save: Callable[[Candidate, dict], str],
                 out: Path) -> ParetoFront:
    """The front among the `scored` tickets (ticket id -> its noise source and search candidate),
    judged on `heldout` beside base and zero; `save(candidate, front_metadata)` writes a front
    ticket and returns its path. Writes `front.png` into `out`."""
    labels = list(scored)
    searched = evaluator.run([(label, source, c.seeds) for label, (source, c) in scored.items()])
    points = [_scores(objectives, runs, max_steps) for runs in searched]
    front = [labels[i] for i in non_dominated([tuple(p.values()) for p in points])]
    verdict = judge(evaluator, {ZERO: zero} | {Arm.ticket(label): scored[label][0] for label in front},
                    heldout, base)
    rows = {arm: FrontArm(row, _scores(objectives, verdict.arms[arm].results, max_steps))
            for arm, row in verdict.rows.items()}
    for label in front:
        arm = Arm.ticket(label)
        metadata = {"objectives": list(objectives), "heldout": rows[arm].to_dict()}
        rows[arm] = replace(rows[arm], ticket_path=save(scored[label][1], metadata))
    search = tuple((label, p, label in front) for label, p in zip(labels, points, strict=True))
    study = ParetoFront(objectives, (heldout[0], heldout[-1]), search, rows)
    front_png(study, out / "front.png")
    return study
