"""The golden-ticket job: baselines, search, held-out verdict, ticket files, summary.json."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from goldenticket.errors import UserError
from goldenticket.evaluation import Evaluator, Judged, judge
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import load_policy
from goldenticket.rollout import Engine
from goldenticket.search import EpisodeOutcome, SearchResult, make_optimizer, run_search
from goldenticket.stats import holm_adjust
from goldenticket.store import RunStore
from goldenticket.tasks import OBJECTIVES, SEED_SETS, get_task, seeds_in
from goldenticket.tasks.base import require_unseen
from goldenticket.tickets import Ticket, zero_ticket


@dataclass(frozen=True)
class SearchConfig:
    """One search run; the same config and seed always give the same numbers."""

    policy: str
    task: str
    method: str = "cem-racing"
    budget: int = 1500  # search episodes
    seed: int = 0
    search_seeds: int = 20
    heldout: int = 200
    top_k: int = 5
    objective: str = "success"
    stop_after_perfect: int | None = 3
    max_tickets: int | None = None
    workers: int = 2

    def check(self) -> None:
        for name in ("budget", "search_seeds", "heldout", "top_k", "workers", "max_tickets"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise UserError(f"--{name.replace('_', '-')} must be > 0, got {getattr(self, name)}")
        if self.objective not in OBJECTIVES:
            raise UserError(f"unknown objective {self.objective!r}; choose from {list(OBJECTIVES)}")


def find_golden_tickets(cfg: SearchConfig, out: Path) -> dict:
    """Run the whole job into `out`; resumes from `out/run.sqlite` if it holds the same config."""
    cfg.check()
    policy, task = load_policy(cfg.policy), get_task(cfg.task)
    heldout, search_seeds = seeds_in("heldout", cfg.heldout), seeds_in("search", cfg.search_seeds)
    optimizer = make_optimizer(cfg.method, policy.noise_shape, search_seeds,
                               np.random.default_rng(cfg.seed))
    out.mkdir(parents=True, exist_ok=True)
    store = _open_store(out, cfg)
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    with Engine(cfg.policy, task, objective=cfg.objective, workers=cfg.workers) as engine:
        evaluator = Evaluator(engine, store)
        with _progress(evaluator, 2 * cfg.heldout, "held-out: base and zero ticket"):
            evaluator.run([("base", base, heldout), ("zero", zero, heldout)])
        with _progress(evaluator, cfg.budget, f"search ({cfg.method})") as bar:
            result = run_search(optimizer, query_evaluator(evaluator), budget=cfg.budget,
                                stop_after_perfect=cfg.stop_after_perfect,
                                max_tickets=cfg.max_tickets)
            bar.total = result.episodes_used
        top = result.top(cfg.top_k, min_episodes=len(optimizer.seeds)) or result.top(cfg.top_k)
        if not top:
            raise UserError(f"--budget {cfg.budget} is too small to evaluate a single ticket")
        weights = policy.weights_hash()
        tickets = [_ticket(cfg, weights, result, c, search_seeds) for c in top]
        with _progress(evaluator, cfg.heldout * len(tickets), "held-out: top tickets"):
            judged = judge(evaluator, {"zero": zero} | {t.id: Constant(t.noise) for t in tickets},
                           heldout, base)
    store.close()
    _adjust_for_multiplicity(judged, [t.id for t in tickets])
    span = [heldout[0], heldout[-1]]
    summary = _summary(cfg, judged, _save_ranked(tickets, judged, out, span), result, span)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _open_store(out: Path, cfg: SearchConfig) -> RunStore:
    store = RunStore(out / "run.sqlite")
    stored, wanted = store.get_config(), asdict(cfg) | {"workers": None}
    if stored is None:
        store.set_config(wanted)
    elif stored != wanted:
        store.close()
        raise UserError(f"{out} holds a different run; choose another --out or the same options")
    return store


def _progress(evaluator: Evaluator, total: int, desc: str) -> tqdm:
    bar = tqdm(total=total, desc=desc, unit="ep", dynamic_ncols=True)
    evaluator.on_done = bar.update
    return bar


def query_evaluator(evaluator: Evaluator):
    def evaluate(queries):
        jobs = [(Ticket(q.ticket).id, Constant(q.ticket), q.seeds) for q in queries]
        return [EpisodeOutcome(np.array([r.ret for r in rs]), np.array([r.success for r in rs]))
                for rs in evaluator.run(jobs)]
    return evaluate


def _ticket(cfg: SearchConfig, weights_hash: str, result: SearchResult, candidate,
            search_seeds: list[int]) -> Ticket:
    return Ticket(candidate.ticket, {
        "policy": cfg.policy, "policy_weights_hash": weights_hash,
        "noise_shape": list(candidate.ticket.shape), "task": cfg.task, "method": cfg.method,
        "budget": cfg.budget, "episodes_used": result.episodes_used, "seed": cfg.seed,
        "objective": cfg.objective, "search_seeds": [search_seeds[0], search_seeds[-1]],
        "search_score": candidate.mean_return, "search_episodes": candidate.n,
    })


def _adjust_for_multiplicity(judged: dict[str, Judged], ticket_ids: list[str]) -> None:
    """Testing k tickets on the same seeds: Holm-adjust their p-values so 'golden' stays honest."""
    for attr in ("p_value", "p_vs_zero"):
        adjusted = holm_adjust([getattr(judged[t], attr) for t in ticket_ids])
        for ticket_id, p in zip(ticket_ids, adjusted, strict=True):
            setattr(judged[ticket_id], attr, p)


def _save_ranked(tickets: list[Ticket], judged: dict[str, Judged], out: Path,
                 span: list[int]) -> list[dict]:
    """Save each ticket with its held-out result; entries best first (success, then p)."""
    ranked = sorted(tickets, key=lambda t: (-judged[t.id].rate.success_rate, judged[t.id].p_value))
    entries = []
    for t in ranked:
        t.metadata["heldout"] = judged[t.id].to_dict() | {"seeds": span}
        path = t.save(out / "tickets" / f"{t.id}.safetensors")
        entries.append(judged[t.id].to_dict() | {"ticket_id": t.id, "ticket_path": str(path),
                                                 "search_score": t.metadata["search_score"]})
    return entries


def _summary(cfg: SearchConfig, judged: dict[str, Judged], entries: list[dict],
             result: SearchResult, span: list[int]) -> dict:
    return {
        "task": cfg.task, "policy": cfg.policy, "method": cfg.method, "seed": cfg.seed,
        "search_episodes": result.episodes_used, "stopped_because": result.stopped_because,
        "heldout_seeds": span,
        "base": judged["base"].to_dict(), "zero": judged["zero"].to_dict(),
        "golden": entries[0], "tickets": entries,
        "p_value_note": "p-values: one-sided exact McNemar (sign) test on the paired held-out "
                        "seeds, ticket better than base (p vs base) or than the zero ticket "
                        f"(p vs zero), Holm-adjusted over the {len(entries)} tickets tested. "
                        "'golden' means p vs base < 0.05.",
    }


def evaluate_tickets(policy_name: str, task_name: str, ticket_paths: list[Path],
                     seeds: list[int], seed: int = 0, workers: int = 2) -> dict[str, dict]:
    """Base, zero ticket and each ticket on `seeds`; p-values vs base (one-sided, paired)."""
    policy, task = load_policy(policy_name), get_task(task_name)
    tickets = [Ticket.load(p, expected_shape=policy.noise_shape) for p in ticket_paths]
    require_unseen(seeds, SEED_SETS["train"], "training-demonstration seeds")
    for path, ticket in zip(ticket_paths, tickets, strict=True):
        low, high = ticket.metadata.get("search_seeds", (-1, -1))
        if low >= 0:
            require_unseen(seeds, range(low, high + 1), f"search seeds of {path}")
    sources = {"zero": Constant(zero_ticket(policy.noise_shape).noise)}
    sources |= {t.id: Constant(t.noise) for t in tickets}
    with Engine(policy_name, task, workers=workers) as engine:
        evaluator = Evaluator(engine)
        with _progress(evaluator, len(seeds) * (len(sources) + 1), "evaluating"):
            judged = judge(evaluator, sources, seeds, Gaussian(seed))
    return {label: j.to_dict() for label, j in judged.items()}
