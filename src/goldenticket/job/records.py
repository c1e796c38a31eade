"""The record each candidate ticket carries: what it is for, then how it came (a search, the zero
ticket, a ticket given to the job)."""

from __future__ import annotations

import numpy as np

from goldenticket.config import RECORDED_SETTINGS
from goldenticket.job.plan import Plan
from goldenticket.policies import find_ticket
from goldenticket.ticket_search import Candidate, SearchResult
from goldenticket.tickets import GIVEN, ZERO_SOURCE, Ticket, TicketRecord, zero_ticket


def found_for(plan: Plan, **how) -> TicketRecord:
    """A candidate's record: the policy, task(s) and settings it is for (a LeRobot checkpoint's
    rename_map and policy_override, and a LeRobot env's env_option, where given), then `how` it came."""
    names, tasks, cfg = plan.names, plan.task_names, plan.cfg
    settings = {key: getattr(cfg, key) for key in RECORDED_SETTINGS if getattr(cfg, key)}
    return TicketRecord(policy=names.policy, policy_fingerprint=names.fingerprint,
                        noise_shape=tuple(plan.policy.noise_shape), task=names.task,
                        tasks=tuple(tasks) if len(tasks) > 1 else None, max_steps=names.max_steps,
                        success=names.success, extra=settings, **how)


def searched(plan: Plan, result: SearchResult, candidate: Candidate) -> Ticket:
    """A search's candidate as a ticket, with the search's settings and its score there."""
    cfg, seeds = plan.cfg, plan.seeds.search
    return Ticket(plan.expand(candidate.ticket), found_for(
        plan, method=cfg.method, subspace=cfg.subspace, searched_shape=tuple(candidate.ticket.shape),
        budget=cfg.budget, episodes_used=result.episodes_used, seed=cfg.seed, objective=cfg.objective,
        search_seeds=(seeds[0], seeds[-1]), search_score=candidate.mean_return,
        search_episodes=candidate.n))


def other_candidates(plan: Plan) -> list[Ticket]:
    """Tickets that enter validation beside the search's best: the zero ticket (first) and the
    tickets `cfg.tickets` names (files or bundled ids; any policy's or task's, if the shape fits)."""
    shape = plan.policy.noise_shape
    sources: dict[str, np.ndarray] = {ZERO_SOURCE: zero_ticket(shape).noise} | {
        GIVEN + ref: Ticket.load(find_ticket(ref), expected_shape=shape).noise for ref in plan.cfg.tickets}
    tickets = [Ticket(noise, found_for(plan, source=source)) for source, noise in sources.items()]
    return list({t.id: t for t in tickets}.values())  # a given ticket may be the zero ticket
