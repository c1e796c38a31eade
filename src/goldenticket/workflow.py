"""The golden-ticket job: baselines, search, held-out verdict, ticket files, summary.json."""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from goldenticket.config import EvaluateConfig, SearchConfig, named, to_toml
from goldenticket.errors import OptionError, UserError
from goldenticket.evaluation import (
    Evaluator,
    Judged,
    VerdictRow,
    adjust_for_multiplicity,
    judge,
    judge_size,
    multitask_verdict,
    to_dicts,
)
from goldenticket.files import write_atomic
from goldenticket.noise import Constant, Gaussian, TopK
from goldenticket.plots import arms_png, search_png, tasks_png
from goldenticket.policies import NoisePolicy, find_ticket, for_task, identity, load_policy, policy_label
from goldenticket.results import ZERO_SOURCE, FoundTicket, MultitaskSummary, ParetoFront, SearchRun, Summary
from goldenticket.store import RunStore
from goldenticket.studies.diversity import action_spread
from goldenticket.studies.pareto import pareto_study
from goldenticket.tasks import get_task, seeds_in
from goldenticket.tasks.base import require_heldout, require_unseen
from goldenticket.ticket_search import EpisodeOutcome, SearchResult, run_search
from goldenticket.ticket_search.subspace import Subspace
from goldenticket.tickets import Ticket, zero_ticket
from goldenticket.tracking import Tracker


def find_golden_tickets(cfg: SearchConfig, out: Path) -> Summary | MultitaskSummary:
    """Run the whole job into `out`; resumes from `out/run.sqlite` if it holds the same config.
    On several tasks (a multi-task policy's), one ticket for the task-averaged objective, judged
    per task and on average. Search episodes go to the tasks in turn: seed key k runs task
    k mod T on search seed k div T, so every prefix the optimizer uses (a racing tier, say) spreads
    evenly over the tasks; one task is the case T = 1."""
    cfg.check()
    policy = load_policy(cfg.policy)
    tasks = checked_tasks(policy, cfg)
    task_names = [t.name for t in tasks]
    heldout, search_seeds = seeds_in("heldout", cfg.heldout), seeds_in("search", cfg.search_seeds)
    validation = seeds_in("validation", cfg.validation())
    keys = list(range(len(tasks) * len(search_seeds)))
    optimizer = cfg.optimizer(policy.noise_shape, keys)
    names = Names.of(cfg.policy, policy, " + ".join(task_names), shared(t.max_steps for t in tasks),
                     cfg.success)
    expand = functools.partial(Subspace.parse(cfg.subspace, policy.noise_shape).expand,
                               noise_shape=policy.noise_shape)
    base, zero = Gaussian(cfg.seed), Constant(zero_ticket(policy.noise_shape).noise)
    others = _other_candidates(cfg, names, policy.noise_shape, task_names)

    def where(key: int) -> tuple[str, int]:
        return task_names[key % len(tasks)], search_seeds[key // len(tasks)]

    with Evaluator.open(cfg.policy, tasks, cfg, objective=cfg.objective, loaded=policy) as evaluator, \
            open_store(out, cfg, names) as store, Tracker(cfg, out, search_title(cfg, names)) as tracker:
        evaluator.store = store  # the engine starts first: options it refuses leave no run folder
        with evaluator.progress(2 * cfg.heldout * len(tasks), "held-out: base and zero ticket"):
            for name in task_names:
                evaluator.run([("base", base, heldout), ("zero", zero, heldout)], name)
        tasks_said = f", {len(tasks)} tasks" if len(tasks) > 1 else ""
        with evaluator.progress(cfg.budget, f"search ({cfg.method}{tasks_said})") as bar:
            evaluate = query_evaluator(evaluator, names.fingerprint, expand, where)
            result = run_search(optimizer, tracker.watch(evaluate, expand, names.fingerprint),
                                budget=cfg.budget, stop_after_perfect=cfg.stop_after_perfect,
                                max_tickets=cfg.max_tickets)
            bar.total = result.episodes_used
        top = _top(result, cfg, len(keys))
        candidates = [_ticket(cfg, names, result, c, search_seeds, expand, task_names) for c in top]
        chosen = _select(cfg, evaluator, candidates + (others if validation else []), validation, task_names)
        tickets = _with_zero(chosen, others[0]) if validation else chosen
        tracker.validated(candidates + others)
        sources = {"zero": zero} | {t.id: Constant(t.noise) for t in tickets}
        with evaluator.progress(judge_size(sources, cfg.heldout) * len(tasks), "held-out: top tickets"):
            per_task = {name: judge(evaluator, sources, heldout, base, name) for name in task_names}
        front, fronts = _front(cfg, names, evaluator, result, (search_seeds, heldout), (base, zero), expand,
                               tasks[0].max_steps, out) if cfg.front_objective else (None, {})
    run = SearchRun(names.policy, cfg.method, cfg.seed, result.episodes_used, result.stopped_because,
                    (heldout[0], heldout[-1]))
    if len(tasks) > 1:
        summary = _multitask_summary(cfg, per_task, tickets, run, out)
    else:
        summary = _summary(names, per_task[task_names[0]], tickets, run, out, fronts, front)
    record = summary.to_dict()
    write_atomic(out / "summary.json", json.dumps(record, indent=2) + "\n")
    tracker.finish(record)
    order = {id(c): i for i, c in enumerate(result.candidates)}  # a search ticket's place in the search
    place = {ticket.id: order[id(c)] for ticket, c in zip(candidates, top, strict=True)}
    base_return = float(np.mean([r.ret for judged in per_task.values() for r in judged["base"].results]))
    _pictures(cfg, names, summary, result, place, bool(validation), base_return, out)
    return summary


def checked_tasks(policy: NoisePolicy, cfg: SearchConfig) -> list:
    """The run's tasks, each one the policy can act on and whose reset(seed) fixes the initial
    state (UserError now, not mid-run)."""
    tasks = [get_task(name, cfg.max_steps, cfg.success) for name in cfg.tasks]
    if len({t.name for t in tasks}) < len(tasks):
        raise OptionError("a task is given twice", "task")
    for task in tasks:
        for_task(policy, task.name)
        task.check()
    return tasks


def shared(values) -> int | None:
    """The one value all of `values` share, else None."""
    distinct = set(values)
    return distinct.pop() if len(distinct) == 1 else None


def _pictures(cfg: SearchConfig, names: Names, summary: Summary | MultitaskSummary, result: SearchResult,
              place: dict[str, int], validated: bool, base_return: float, out: Path) -> None:
    """verdict.png (per arm, or per task and on average) and search.png, with the tickets the
    job validated and judged marked (`place`: ticket id -> its place in the search)."""
    title = f"{names.policy} on {names.task}"
    if isinstance(summary, MultitaskSummary):
        tasks_png(summary.verdict, out / "verdict.png",
                  f"{names.policy}: one ticket for {len(summary.verdict.tasks)} tasks")
        judged, best = summary.verdict.tickets, summary.verdict.best
    else:
        arms_png(to_dicts(summary.rows()), out / "verdict.png", title, best=f"ticket {summary.best.label}")
        judged, best = [t.id for t in summary.tickets], summary.best.id
    span = summary.run.heldout_seeds
    search_png([c.mean_return for c in result.candidates], [c.n for c in result.candidates],
               out / "search.png", search_title(cfg, names),
               validated=list(place.values()) if validated else [],
               judged=[place[t] for t in judged if t in place], chosen=place.get(best),
               base=(base_return, f"held-out seeds {span[0]}:{span[1] + 1}"))


def search_title(cfg: SearchConfig, names: Names) -> str:
    return f"{cfg.method} search: {names.policy} on {names.task}"


def _top(result: SearchResult, cfg: SearchConfig, seeds: int) -> list:
    """The best search candidates: top_k, or 3 x top_k to choose from on validation seeds."""
    k = cfg.top_k * (3 if cfg.validation() else 1)
    return result.top(k, min_episodes=seeds) or result.top(k)


def _select(cfg: SearchConfig, evaluator: Evaluator, tickets: list[Ticket], seeds: list[int],
            tasks: list[str]) -> list[Ticket]:
    """`tickets` as ranked by search, or, with validation `seeds`, the top_k of them by mean return
    on those seeds of every task (ties: search rank): a selection on states neither the search nor
    the held-out verdict uses."""
    if not seeds:
        return tickets
    with evaluator.progress(len(seeds) * len(tickets) * len(tasks), "validation: search's best tickets"):
        runs = [evaluator.run([(t.id, Constant(t.noise), seeds) for t in tickets], task) for task in tasks]
    scores = [float(np.mean([np.mean([r.ret for r in per_task[i]]) for per_task in runs]))
              for i in range(len(tickets))]
    for ticket, score in zip(tickets, scores, strict=True):
        ticket.metadata |= {"validation_score": score, "validation_seeds": [seeds[0], seeds[-1]]}
    ranked = sorted(range(len(tickets)), key=lambda i: -scores[i])  # stable: ties keep search rank
    return [tickets[i] for i in ranked[: cfg.top_k]]


def _with_zero(tickets: list[Ticket], zero: Ticket) -> list[Ticket]:
    """The tickets the verdict judges after validation: `tickets`, and the zero ticket after them if
    it is not among them. It is a constant noise like any ticket, so the job delivers it wherever it
    is best on the held-out seeds."""
    return tickets if any(t.id == zero.id for t in tickets) else [*tickets, zero]


def _front(cfg: SearchConfig, names: Names, evaluator: Evaluator, result: SearchResult, seeds: tuple,
           baselines: tuple, expand: Callable, max_steps: int, out: Path) -> tuple[ParetoFront, dict]:
    """The Pareto front of the search's tickets for (objective, front objective), judged on the
    held-out seeds; its tickets saved, front.json and front.png written. Returns the front and each
    front ticket's front metadata by id."""
    search_seeds, heldout = seeds
    scored = {}
    for candidate in result.candidates:
        if candidate.n >= len(search_seeds):
            noise = expand(candidate.ticket)
            scored[Ticket(noise, {"policy_fingerprint": names.fingerprint}).id] = (Constant(noise), candidate)

    fronts = {}

    def save(candidate, front_metadata: dict) -> str:
        ticket = _ticket(cfg, names, result, candidate, search_seeds, expand, [names.task])
        ticket.metadata["front"] = fronts[ticket.id] = front_metadata
        return str(ticket.save(out / "tickets" / f"{ticket.id}.safetensors"))

    with evaluator.progress(None, "Pareto front"):  # its size is known only once found
        study = pareto_study(evaluator, scored, (cfg.objective, cfg.front_objective), max_steps=max_steps,
                             heldout=heldout, base=baselines[0], zero=baselines[1], save=save, out=out)
    write_atomic(out / "front.json", json.dumps(study.to_dict(), indent=2) + "\n")
    return study, fronts


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
        return cls(policy_label(policy_ref), task_name, identity(policy), max_steps, named(success))


def open_store(out: Path, cfg: SearchConfig, names: Names) -> RunStore:
    """The run store in `out`, holding this config (the policy's fingerprint included: a policy
    retrained in place is another run)."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is a file; name a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create --out {out}: {exc.strerror}") from None
    store = RunStore(out / "run.sqlite")
    config = {f.name: getattr(cfg, f.name) for f in fields(cfg) if f.name not in ("max_nonfinite", "log")} | {
        "policy": names.policy, "task": names.task, "success": named(cfg.success),
        "policy_fingerprint": names.fingerprint,
        "workers": None, "backend": None, "address": None}  # where episodes run does not change them
    if not store.claim_config(config):
        store.close()
        raise UserError(f"{out} holds a different run; choose another --out or the same options")
    write_atomic(out / "config.toml", to_toml(cfg))
    return store


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


def _other_candidates(cfg: SearchConfig, names: Names, shape: tuple[int, int],
                      tasks: list[str]) -> list[Ticket]:
    """Tickets that enter validation beside the search's best: the zero ticket (first) and the
    tickets `cfg.tickets` names (files or bundled ids; any policy's or task's, if the shape fits)."""
    sources = {ZERO_SOURCE: zero_ticket(shape).noise} | {
        f"given: {ref}": Ticket.load(find_ticket(ref), expected_shape=shape).noise for ref in cfg.tickets}
    tickets = [Ticket(noise, _provenance(names, shape, tasks, {"source": source, "search_score": None}))
               for source, noise in sources.items()]
    return list({t.id: t for t in tickets}.values())  # a given ticket may be the zero ticket


def _ticket(cfg: SearchConfig, names: Names, result: SearchResult, candidate,
            search_seeds: list[int], expand: Callable, tasks: list[str]) -> Ticket:
    noise = expand(candidate.ticket)
    return Ticket(noise, _provenance(names, noise.shape, tasks, {
        "method": cfg.method, "subspace": cfg.subspace, "searched_shape": list(candidate.ticket.shape),
        "budget": cfg.budget, "episodes_used": result.episodes_used, "seed": cfg.seed,
        "objective": cfg.objective, "search_seeds": [search_seeds[0], search_seeds[-1]],
        "search_score": candidate.mean_return, "search_episodes": candidate.n}))


def _provenance(names: Names, shape: tuple[int, int], tasks: list[str], how: dict) -> dict:
    """A candidate ticket's metadata: what it is for and under which settings, then `how` it came."""
    limit = {} if names.max_steps is None else {"max_steps": names.max_steps}
    several = {"tasks": tasks} if len(tasks) > 1 else {}
    return limit | {"success": names.success, "policy": names.policy, "policy_fingerprint": names.fingerprint,
                    "noise_shape": list(shape), "task": names.task} | how | several


def _save_ranked(tickets: list[Ticket], judged: dict[str, Judged], out: Path, span: tuple[int, int],
                 fronts: dict[str, dict]) -> tuple[FoundTicket, ...]:
    """Save each ticket with its held-out result (and its place on the Pareto front, `fronts` by
    ticket id, if it has one); best first: by success, the zero ticket before any ticket it ties
    (it needs no search, so a tie is no evidence for the other), then by p."""
    ranked = sorted(tickets, key=lambda t: (-judged[t.id].rate.success_rate,
                                            t.metadata.get("source") != ZERO_SOURCE, judged[t.id].p_vs_base))
    found = []
    for t in ranked:
        row = judged[t.id].row()
        t.metadata["heldout"] = row.to_dict() | {"seeds": list(span)}
        if t.id in fronts:
            t.metadata["front"] = fronts[t.id]
        path = t.save(out / "tickets" / f"{t.id}.safetensors")
        found.append(FoundTicket(t.id, str(path), t.metadata["search_score"], row,
                                 t.metadata.get("validation_score"), t.metadata.get("source"), t))
    return tuple(found)


def _summary(names: Names, judged: dict[str, Judged], tickets: list[Ticket], run: SearchRun, out: Path,
             fronts: dict[str, dict], front: ParetoFront | None) -> Summary:
    """One task's verdict: p-values Holm-adjusted over the tickets, each ticket saved with its
    held-out result, the best first."""
    adjust_for_multiplicity(judged, [t.id for t in tickets])
    found = _save_ranked(tickets, judged, out, run.heldout_seeds, fronts)
    return Summary(names.task, run, judged["base"].row(), judged["zero"].row(), found, front)


def _multitask_summary(cfg: SearchConfig, per_task: dict[str, dict[str, Judged]], tickets: list[Ticket],
                       run: SearchRun, out: Path) -> MultitaskSummary:
    """Several tasks' verdict (`evaluation.multitask_verdict`), each ticket saved with its
    task-averaged and per-task held-out results."""
    verdict = multitask_verdict(per_task, [t.id for t in tickets], cfg.no_regression)
    for ticket in tickets:
        per_task_rows = {task: verdict.tasks[task][ticket.id].to_dict() for task in per_task}
        ticket.metadata["heldout"] = verdict.average[ticket.id].to_dict() | {
            "seeds": list(run.heldout_seeds), "per_task": per_task_rows}
        ticket.save(out / "tickets" / f"{ticket.id}.safetensors")
    return MultitaskSummary(verdict, run)


def evaluate_tickets(cfg: EvaluateConfig, store: RunStore | None = None) -> dict[str, VerdictRow]:
    """Base, zero ticket and each ticket on the held-out `cfg.seeds`: one-sided paired p-values vs
    base and vs zero, Holm-adjusted over the tickets; episodes kept in `store` if given. The task,
    `max_steps` and `success` default to those the tickets were found under; a ticket found for
    another policy or task, or a setting that contradicts its own, is refused unless
    `allow_transfer`. `mixture` adds an arm that draws one of the tickets at every policy call
    (Gaussian noise with probability `epsilon`), and gives every arm its `diversity`
    (`studies.diversity.action_spread` on the first 10 seeds)."""
    cfg.check()
    seeds = list(cfg.seeds)
    require_heldout(seeds)
    policy = load_policy(cfg.policy)
    loaded = {path: Ticket.load(path, expected_shape=policy.noise_shape)
              for path in map(find_ticket, cfg.tickets)}
    given = {"task": cfg.task, "max_steps": cfg.max_steps, "success": cfg.success}
    settings = found_under(list(loaded.values()), given, cfg.allow_transfer)
    task = get_task(settings["task"], settings["max_steps"], settings["success"])
    names = Names.of(cfg.policy, policy, task.name)
    for path, ticket in loaded.items():
        if not cfg.allow_transfer:
            ticket.check_fits(names.fingerprint, names.task, str(path))
        if (searched := ticket.search_seeds()) is not None:
            require_unseen(seeds, searched, f"search seeds of {path}")
    tickets = list({t.id: t for t in loaded.values()}.values())  # a ticket named twice is judged once
    if cfg.mixture and len(tickets) < 2:
        raise OptionError("mixture needs at least 2 different tickets (tickets A and B)", "mixture")
    task.check()
    zero = Constant(zero_ticket(policy.noise_shape).noise)
    reseeded = {"base": lambda r: Gaussian(cfg.seed + r), "zero": lambda r: zero}
    reseeded |= {t.id: lambda r, t=t: Constant(t.noise) for t in tickets}
    if cfg.mixture:
        stacked = np.stack([t.noise for t in tickets])
        reseeded["mixture"] = lambda r: TopK(stacked, cfg.seed + r, cfg.epsilon)
    sources = {label: source(0) for label, source in reseeded.items() if label != "base"}
    with Evaluator.open(cfg.policy, task, cfg, store, loaded=policy) as evaluator, \
            evaluator.progress(len(seeds) * (len(sources) + 1), "evaluating"):
        judged = judge(evaluator, sources, seeds, Gaussian(cfg.seed))
    adjust_for_multiplicity(judged, [label for label in sources if label != "zero"])
    rows = {label: j.row() for label, j in judged.items()}
    if cfg.mixture:
        for label, source in tqdm(reseeded.items(), desc="diversity", unit="arm"):
            rows[label] = replace(rows[label], diversity=action_spread(policy, task, source, seeds[:10]))
    return rows


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
        given_value = named(value) if key != "max_steps" else value
        if value is None and len(recorded) > 1:
            found = ", ".join(map(str, recorded))
            raise OptionError(f"the tickets were found under different {key} ({found}); give {key}", key)
        clash = [(v, t) for v, t in recorded.items() if value is not None and v != given_value]
        if clash and not allow_transfer and key != "task":  # a task mismatch: check_fits says it
            raise OptionError(f"{key} {given_value} contradicts ticket {clash[0][1]}, found and judged with "
                              f"{key} {clash[0][0]}; leave {key} out to use the ticket's, or "
                              "allow_transfer to run it anyway", key, "allow_transfer")
        settings[key] = value if value is not None else next(iter(recorded), None)
    if settings["task"] is None:
        raise OptionError("no task given and no ticket names one; give task", "task")
    return settings
