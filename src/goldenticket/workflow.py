"""The golden-ticket job: baselines, search, held-out verdict, ticket files, summary.json."""

from __future__ import annotations

import copy
import functools
import json
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from tqdm import tqdm

from goldenticket.errors import UserError
from goldenticket.evaluation import (
    MAX_NONFINITE,
    Evaluator,
    Judged,
    adjust_for_multiplicity,
    check_max_nonfinite,
    judge,
    p_value_note,
)
from goldenticket.factories import import_name
from goldenticket.files import write_atomic
from goldenticket.noise import Constant, Gaussian, TopK
from goldenticket.plots import arms_png, search_png
from goldenticket.policies import NoisePolicy, identity, load_policy, policy_label
from goldenticket.rollout import Engine
from goldenticket.store import RunStore
from goldenticket.studies.diversity import action_spread
from goldenticket.studies.pareto import pareto_study
from goldenticket.tasks import OBJECTIVES, get_task, seeds_in
from goldenticket.tasks.base import FRONT_OBJECTIVES, require_heldout, require_unseen
from goldenticket.ticket_search import EpisodeOutcome, SearchResult, make_optimizer, run_search
from goldenticket.ticket_search.subspace import Subspace
from goldenticket.tickets import Ticket, zero_ticket


@dataclass(frozen=True)
class SearchConfig:
    """One search run; the same config and seed always give the same numbers."""

    policy: str | NoisePolicy  # a name or import string (see policies.load_policy), or the object
    task: str | Callable | tuple[str, ...]  # a task name, a gymnasium.Env factory or its import
    # string, or several task names (multi-task: `multitask.find_multitask_tickets`, `transfer`)
    method: str = "cma-es"
    budget: int = 2000  # search episodes
    seed: int = 0
    search_seeds: int = 20
    heldout: int = 200
    top_k: int = 3
    objective: str = "success"
    stop_after_perfect: int | None = 3
    max_tickets: int | None = None
    workers: int = 2
    max_steps: int | None = None  # None: the task's own limit
    success: str | Callable | None = None  # Gymnasium tasks: predicate (obs, info) -> bool
    backend: str = "local"  # or "ray": episodes on Ray actors
    address: str | None = None  # the Ray cluster (None: a local Ray instance)
    subspace: str = "full"  # or "tiled", "channels:I,J" (ticket_search.subspace)
    front_objective: str | None = None  # a second objective: also find the Pareto front (studies.pareto)
    validation_seeds: int | None = None  # > 0: pick the top_k among 3 x top_k search tickets on these
    # seeds; None: 100 for one task, 0 for several
    no_regression: bool = False  # multi-task: never call best a ticket significantly worse on a task
    max_nonfinite: float = MAX_NONFINITE  # stop once more of an arm's held-out episodes end in NaN actions

    def check(self) -> None:
        """Every option, before any episode runs."""
        check_max_nonfinite(self.max_nonfinite)
        if self.stop_after_perfect is not None and self.stop_after_perfect < 1:
            raise UserError(f"--stop-after-perfect must be >= 1 (0 on the command line: never), "
                            f"got {self.stop_after_perfect}")
        if self.seed < 0:
            raise UserError(f"--seed must be >= 0, got {self.seed}")
        if self.validation_seeds is not None and self.validation_seeds < 0:
            raise UserError(f"--validation-seeds must be >= 0, got {self.validation_seeds}")
        for name in ("budget", "search_seeds", "heldout", "top_k", "workers", "max_tickets", "max_steps"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise UserError(f"--{name.replace('_', '-')} must be > 0, got {getattr(self, name)}")
        for objective in filter(None, (self.objective, self.front_objective)):
            if objective not in OBJECTIVES:
                raise UserError(f"unknown objective {objective!r}; choose from {list(OBJECTIVES)}")
        if isinstance(self.task, tuple):
            for option, value in (("--validation-seeds", self.validation_seeds), ("--success", self.success),
                                  ("--objective (a second)", self.front_objective)):
                if value:
                    raise UserError(f"{option} is for single-task runs; not with several --task")
        elif self.no_regression:
            raise UserError("--no-regression needs several --task (it guards every task's success)")
        if self.front_objective and not {self.objective, self.front_objective} <= set(FRONT_OBJECTIVES):
            raise UserError(f"a Pareto front's objectives must be among {list(FRONT_OBJECTIVES)}")
        if self.front_objective == self.objective:
            raise UserError(f"--objective {self.objective} twice: a Pareto front needs two different "
                            "objectives")

    def validation(self) -> int:
        """Validation seeds this run uses."""
        if self.validation_seeds is None:
            return 0 if isinstance(self.task, tuple) else 100
        return self.validation_seeds

    def optimizer(self, noise_shape: tuple[int, int], search_seeds: list[int]):
        """This run's optimizer over its sub-space, fresh from its seed; UserError if the budget
        cannot score even the first ticket it asks for."""
        searched = Subspace.parse(self.subspace, noise_shape).shape(noise_shape)
        optimizer = make_optimizer(self.method, searched, search_seeds, np.random.default_rng(self.seed))
        needed = len(copy.deepcopy(optimizer).ask()[0].seeds)
        if self.budget < needed:
            raise UserError(f"--budget {self.budget} is too small: {self.method} needs {needed} "
                            "episodes to score one ticket")
        return optimizer


def find_golden_tickets(cfg: SearchConfig, out: Path) -> dict:
    """Run the whole job into `out`; resumes from `out/run.sqlite` if it holds the same config."""
    cfg.check()
    policy, task = load_policy(cfg.policy), get_task(cfg.task, cfg.max_steps, cfg.success)
    heldout, search_seeds = seeds_in("heldout", cfg.heldout), seeds_in("search", cfg.search_seeds)
    validation = seeds_in("validation", cfg.validation())
    optimizer = cfg.optimizer(policy.noise_shape, search_seeds)
    names = Names.of(cfg.policy, policy, task.name, task.max_steps, cfg.success)
    expand = functools.partial(Subspace.parse(cfg.subspace, policy.noise_shape).expand,
                               noise_shape=policy.noise_shape)
    task.check()
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    with Engine(cfg.policy, task, objective=cfg.objective, workers=cfg.workers, backend=cfg.backend,
                address=cfg.address, loaded=policy) as engine, \
            _open_store(out, cfg, names) as store:
        evaluator = Evaluator(engine, store, max_nonfinite=cfg.max_nonfinite)
        with progress_bar(evaluator, 2 * cfg.heldout, "held-out: base and zero ticket"):
            evaluator.run([("base", base, heldout), ("zero", zero, heldout)])
        with progress_bar(evaluator, cfg.budget, f"search ({cfg.method})") as bar:
            result = run_search(optimizer, query_evaluator(evaluator, names.fingerprint, expand),
                                budget=cfg.budget, stop_after_perfect=cfg.stop_after_perfect,
                                max_tickets=cfg.max_tickets)
            bar.total = result.episodes_used
        top = _top(result, cfg, len(optimizer.seeds))
        candidates = [_ticket(cfg, names, result, c, search_seeds, expand) for c in top]
        tickets = _select(cfg, evaluator, candidates, validation)
        with progress_bar(evaluator, cfg.heldout * (len(tickets) + 2), "held-out: top tickets"):
            judged = judge(evaluator, {"zero": zero} | {t.id: Constant(t.noise) for t in tickets},
                           heldout, base)
        front, fronts = _front(cfg, names, evaluator, result, (search_seeds, heldout), (base, zero), expand,
                               task.max_steps, out) if cfg.front_objective else (None, {})
    adjust_for_multiplicity(judged, [t.id for t in tickets])
    span = [heldout[0], heldout[-1]]
    summary = _summary(cfg, names, judged, _save_ranked(tickets, judged, out, span, fronts), result, span)
    if front:
        summary["front"] = [label for label in front["heldout"] if label not in ("base", "zero")]
    write_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    title = f"{names.policy} on {names.task}"
    arms_png(arm_rows(summary["base"], summary["zero"], summary["tickets"]), out / "verdict.png", title,
             best=f"ticket {summary['best']['ticket_id']}")
    order = {id(c): i for i, c in enumerate(result.candidates)}  # a ticket's place in the search
    place = {ticket.id: order[id(c)] for ticket, c in zip(candidates, top, strict=True)}
    search_png([c.mean_return for c in result.candidates], [c.n for c in result.candidates],
               out / "search.png", f"{cfg.method} search: {title}",
               validated=list(place.values()) if validation else [],
               judged=[place[t["ticket_id"]] for t in summary["tickets"]],
               base=(float(np.mean([r.ret for r in judged["base"].results])),
                     f"held-out seeds {span[0]}..{span[1]}"))
    return summary


def _top(result: SearchResult, cfg: SearchConfig, seeds: int) -> list:
    """The best search candidates: top_k, or 3 x top_k to choose from on validation seeds."""
    k = cfg.top_k * (3 if cfg.validation() else 1)
    return result.top(k, min_episodes=seeds) or result.top(k)


def _select(cfg: SearchConfig, evaluator: Evaluator, tickets: list[Ticket], seeds: list[int]) -> list[Ticket]:
    """`tickets` as ranked by search, or, with validation `seeds`, the top_k of them by mean return
    on those seeds (ties: search rank): a selection on states neither the search nor the
    held-out verdict uses."""
    if not seeds:
        return tickets
    with progress_bar(evaluator, len(seeds) * len(tickets), "validation: search's best tickets"):
        runs = evaluator.run([(t.id, Constant(t.noise), seeds) for t in tickets])
    scores = [float(np.mean([r.ret for r in rs])) for rs in runs]
    for ticket, score in zip(tickets, scores, strict=True):
        ticket.metadata |= {"validation_score": score, "validation_seeds": [seeds[0], seeds[-1]]}
    ranked = sorted(range(len(tickets)), key=lambda i: -scores[i])  # stable: ties keep search rank
    return [tickets[i] for i in ranked[: cfg.top_k]]


def _front(cfg: SearchConfig, names: Names, evaluator: Evaluator, result: SearchResult, seeds: tuple,
           baselines: tuple, expand: Callable, max_steps: int, out: Path) -> tuple[dict, dict[str, dict]]:
    """The Pareto front of the search's tickets for (objective, front objective), judged on the
    held-out seeds; its tickets saved, front.json and front.png written. Returns the study and each
    front ticket's front metadata by id."""
    search_seeds, heldout = seeds
    scored = {}
    for candidate in result.candidates:
        if candidate.n >= len(search_seeds):
            noise = expand(candidate.ticket)
            scored[Ticket(noise, {"policy_fingerprint": names.fingerprint}).id] = (Constant(noise), candidate)

    fronts = {}

    def save(candidate, front_metadata: dict) -> str:
        ticket = _ticket(cfg, names, result, candidate, search_seeds, expand)
        ticket.metadata["front"] = fronts[ticket.id] = front_metadata
        return str(ticket.save(out / "tickets" / f"{ticket.id}.safetensors"))

    with progress_bar(evaluator, None, "Pareto front"):  # its size is known only once found
        study = pareto_study(evaluator, scored, (cfg.objective, cfg.front_objective), max_steps=max_steps,
                             heldout=heldout, base=baselines[0], zero=baselines[1], save=save, out=out)
    write_atomic(out / "front.json", json.dumps(study, indent=2) + "\n")
    return study, fronts


def arm_rows(base: dict, zero: dict, tickets: list[dict]) -> dict[str, dict]:
    """Verdict rows as people read them: base, zero ticket, then each ticket by its id."""
    return {"base": base, "zero ticket": zero} | {f"ticket {t['ticket_id']}": t for t in tickets}


@dataclass(frozen=True)
class Names:
    """How the run's files name its policy and task, what its tickets are found for (the policy's
    identity) and the episode settings they are found under (None: not one value)."""

    policy: str
    task: str
    fingerprint: str
    max_steps: int | None = None
    success: str | None = None

    @classmethod
    def of(cls, policy_ref: str | NoisePolicy, policy: NoisePolicy, task_name: str,
           max_steps: int | None = None, success: str | Callable | None = None) -> Names:
        """Names of `policy`, built from `policy_ref`, on the task named `task_name`."""
        return cls(policy_label(policy_ref), task_name, identity(policy), max_steps, _named(success))


def _named(obj: str | Callable | None) -> str | None:
    """A user's function as files record it: its import string."""
    return obj if obj is None or isinstance(obj, str) else import_name(obj)


def _open_store(out: Path, cfg: SearchConfig, names: Names) -> RunStore:
    """The run store in `out`, holding this config (the policy's fingerprint included: a policy
    retrained in place is another run)."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is a file; name a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create --out {out}: {exc.strerror}") from None
    store = RunStore(out / "run.sqlite")
    config = {f.name: getattr(cfg, f.name) for f in fields(cfg) if f.name != "max_nonfinite"} | {
        "policy": names.policy, "task": names.task, "success": _named(cfg.success),
        "policy_fingerprint": names.fingerprint,
        "workers": None, "backend": None, "address": None}  # where episodes run does not change them
    if not store.claim_config(config):
        store.close()
        raise UserError(f"{out} holds a different run; choose another --out or the same options")
    return store


def progress_bar(evaluator: Evaluator, total: int | None, desc: str) -> tqdm:
    """A tqdm bar that the evaluator advances as episodes finish (or are read back)."""
    bar = tqdm(total=total, desc=desc, unit="ep", dynamic_ncols=True)
    evaluator.on_done = bar.update
    return bar


def query_evaluator(evaluator: Evaluator, fingerprint: str, expand: Callable = lambda searched: searched,
                    where: Callable[[int], tuple[str | None, int]] = lambda key: (None, key)):
    """The search driver's evaluate(): each query's episodes, labelled by the ticket's id;
    `expand` turns a searched array into the full ticket, `where` a query's seed into the (task,
    seed) it runs on (multi-task search; default: the engine's task, the seed itself)."""
    def evaluate(queries):
        tickets = [expand(q.ticket) for q in queries]
        ids = [Ticket(t, {"policy_fingerprint": fingerprint}).id for t in tickets]
        returns = [np.zeros(len(q.seeds)) for q in queries]
        successes = [np.zeros(len(q.seeds), dtype=bool) for q in queries]
        by_task: dict = {}  # task -> query index -> [(position in query, seed)]
        for i, q in enumerate(queries):
            for position, key in enumerate(q.seeds):
                task, seed = where(key)
                by_task.setdefault(task, {}).setdefault(i, []).append((position, seed))
        for task, slots in by_task.items():
            jobs = [(ids[i], Constant(tickets[i]), [seed for _, seed in pairs]) for i, pairs in slots.items()]
            for (i, pairs), results in zip(slots.items(), evaluator.run(jobs, task), strict=True):
                for (position, _), r in zip(pairs, results, strict=True):
                    returns[i][position], successes[i][position] = r.ret, r.success
        return [EpisodeOutcome(r, s) for r, s in zip(returns, successes, strict=True)]
    return evaluate


def _ticket(cfg: SearchConfig, names: Names, result: SearchResult, candidate,
            search_seeds: list[int], expand: Callable) -> Ticket:
    noise = expand(candidate.ticket)
    limit = {} if names.max_steps is None else {"max_steps": names.max_steps}
    return Ticket(noise, limit | {"success": names.success} | {
        "policy": names.policy, "policy_fingerprint": names.fingerprint,
        "noise_shape": list(noise.shape), "task": names.task, "method": cfg.method,
        "subspace": cfg.subspace, "searched_shape": list(candidate.ticket.shape),
        "budget": cfg.budget, "episodes_used": result.episodes_used, "seed": cfg.seed,
        "objective": cfg.objective, "search_seeds": [search_seeds[0], search_seeds[-1]],
        "search_score": candidate.mean_return, "search_episodes": candidate.n,
    })


def _save_ranked(tickets: list[Ticket], judged: dict[str, Judged], out: Path, span: list[int],
                 fronts: dict[str, dict]) -> list[dict]:
    """Save each ticket with its held-out result (and its place on the Pareto front, `fronts` by
    ticket id, if it has one); entries best first (success, then p)."""
    ranked = sorted(tickets, key=lambda t: (-judged[t.id].rate.success_rate, judged[t.id].p_value))
    entries = []
    for t in ranked:
        t.metadata["heldout"] = judged[t.id].to_dict() | {"seeds": span}
        if t.id in fronts:
            t.metadata["front"] = fronts[t.id]
        path = t.save(out / "tickets" / f"{t.id}.safetensors")
        validation = {k: t.metadata[k] for k in ("validation_score",) if k in t.metadata}
        entries.append(judged[t.id].to_dict() | validation | {"ticket_id": t.id, "ticket_path": str(path),
                                                              "search_score": t.metadata["search_score"]})
    return entries


def _summary(cfg: SearchConfig, names: Names, judged: dict[str, Judged], entries: list[dict],
             result: SearchResult, span: list[int]) -> dict:
    return {
        "task": names.task, "policy": names.policy, "method": cfg.method, "seed": cfg.seed,
        "search_episodes": result.episodes_used, "stopped_because": result.stopped_because,
        "heldout_seeds": span,
        "base": judged["base"].to_dict(), "zero": judged["zero"].to_dict(),
        "best": entries[0], "tickets": entries,
        "p_value_note": p_value_note(len(entries)),
    }


def evaluate_tickets(policy_ref: str | NoisePolicy, task_ref: str | Callable | None, ticket_paths: list[Path],
                     seeds: list[int], seed: int = 0, workers: int = 2, allow_transfer: bool = False,
                     max_steps: int | None = None, success: str | Callable | None = None,
                     backend: str = "local", address: str | None = None, mixture: bool = False,
                     epsilon: float = 0.0, max_nonfinite: float = MAX_NONFINITE) -> dict[str, dict]:
    """Base, zero ticket and each ticket on held-out `seeds`: one-sided paired p-values vs base
    and vs zero, Holm-adjusted over the tickets. The task, `max_steps` and `success` default to
    those the tickets were found under; a ticket found for another policy or task, or a setting
    that contradicts its own, is refused unless `allow_transfer`. `mixture` adds an arm that draws
    one of the tickets at every policy call (Gaussian noise with probability `epsilon`), and gives
    every arm its `diversity` (`studies.diversity.action_spread` on the first 10 seeds)."""
    require_heldout(seeds)
    if seed < 0:
        raise UserError(f"--seed must be >= 0, got {seed}")
    if not 0 <= epsilon <= 1 or (epsilon and not mixture):
        raise UserError(f"--epsilon must be in [0, 1] and comes with --mixture, got {epsilon}")
    check_max_nonfinite(max_nonfinite)
    policy = load_policy(policy_ref)
    loaded = {path: Ticket.load(path, expected_shape=policy.noise_shape) for path in ticket_paths}
    given = {"task": task_ref, "max_steps": max_steps, "success": success}
    settings = found_under(list(loaded.values()), given, allow_transfer)
    task = get_task(settings["task"], settings["max_steps"], settings["success"])
    names = Names.of(policy_ref, policy, task.name)
    for path, ticket in loaded.items():
        if not allow_transfer:
            ticket.check_fits(names.fingerprint, names.task, str(path))
        if (searched := ticket.search_seeds()) is not None:
            require_unseen(seeds, searched, f"search seeds of {path}")
    tickets = list({t.id: t for t in loaded.values()}.values())  # a ticket named twice is judged once
    if mixture and len(tickets) < 2:
        raise UserError("--mixture needs at least 2 different tickets (--ticket A --ticket B)")
    task.check()
    zero = Constant(zero_ticket(policy.noise_shape).noise)
    reseeded = {"base": lambda r: Gaussian(seed + r), "zero": lambda r: zero}
    reseeded |= {t.id: lambda r, t=t: Constant(t.noise) for t in tickets}
    if mixture:
        stacked = np.stack([t.noise for t in tickets])
        reseeded["mixture"] = lambda r: TopK(stacked, seed + r, epsilon)
    sources = {label: source(0) for label, source in reseeded.items() if label != "base"}
    with Engine(policy_ref, task, workers=workers, backend=backend, address=address, loaded=policy) as engine:
        evaluator = Evaluator(engine, max_nonfinite=max_nonfinite)
        with progress_bar(evaluator, len(seeds) * (len(sources) + 1), "evaluating"):
            judged = judge(evaluator, sources, seeds, Gaussian(seed))
    adjust_for_multiplicity(judged, [label for label in sources if label != "zero"])
    rows = {label: j.to_dict() for label, j in judged.items()}
    if mixture:
        for label, source in tqdm(reseeded.items(), desc="diversity", unit="arm"):
            rows[label]["diversity"] = action_spread(policy, task, source, seeds[:10])
    return rows


SETTING_FLAGS = {"task": "--task", "max_steps": "--max-steps", "success": "--success"}


def found_under(tickets: list[Ticket], given: dict, allow_transfer: bool = False) -> dict:
    """The task, max_steps and success to judge `tickets` under: each as `given` where given (not
    None), else as the tickets record they were found and judged under (None where they record
    nothing). UserError when the tickets disagree on an unset one, when no task is known, or when
    a given one contradicts a ticket's, unless `allow_transfer`."""
    settings = {}
    for key, value in given.items():
        recorded = {}  # value -> the first ticket recording it
        for ticket in tickets:
            if key in ticket.metadata and not (key == "task" and "tasks" in ticket.metadata):
                recorded.setdefault(ticket.metadata[key], ticket.id)
        flag, named = SETTING_FLAGS[key], _named(value) if key != "max_steps" else value
        if value is None and len(recorded) > 1:
            found = ", ".join(map(str, recorded))
            raise UserError(f"the tickets were found under different {flag} ({found}); give {flag}")
        clash = [(v, t) for v, t in recorded.items() if value is not None and v != named]
        if clash and not allow_transfer and key != "task":  # a task mismatch: check_fits says it
            raise UserError(f"{flag} {named} contradicts ticket {clash[0][1]}, found and judged with "
                            f"{flag} {clash[0][0]}; leave {flag} out to use the ticket's, or "
                            "--allow-transfer to run it anyway")
        settings[key] = value if value is not None else next(iter(recorded), None)
    if settings["task"] is None:
        raise UserError("no task given and no ticket names one; give --task")
    return settings
