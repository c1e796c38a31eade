"""The `evaluate` command: tickets against the base and the zero ticket on held-out seeds, under
the settings they were found with."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
from tqdm import tqdm

from goldenticket import checks
from goldenticket.config import RECORDED_SETTINGS, EvaluateConfig, named
from goldenticket.errors import OptionError, UserError
from goldenticket.evaluation import BASE, MIXTURE, ZERO, Arm, Evaluator, VerdictRow, judge
from goldenticket.factories import is_import_string
from goldenticket.job.plan import Names
from goldenticket.noise import Constant, Gaussian, TopK
from goldenticket.policies import find_ticket, load_policy
from goldenticket.seeds import require_heldout, require_unseen
from goldenticket.store import RunStore
from goldenticket.studies.diversity import action_spread
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket, zero_ticket


def evaluate_tickets(cfg: EvaluateConfig, store: RunStore | None = None) -> dict[Arm, VerdictRow]:
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
    cfg = with_recorded_settings(cfg)
    policy = load_policy(cfg.policy, cfg.device, **cfg.policy_settings())
    loaded = {path: Ticket.load(path, expected_shape=policy.noise_shape)
              for path in map(find_ticket, cfg.tickets)}
    given = {"task": cfg.task, "max_steps": cfg.max_steps, "success": cfg.success}
    settings = found_under(list(loaded.values()), given, cfg.allow_transfer)
    task = get_task(settings["task"], settings["max_steps"], settings["success"], cfg.env_option)
    names = Names.of(cfg.policy, policy, task.name)
    for path, ticket in loaded.items():
        if not cfg.allow_transfer:
            ticket.check_fits(names.fingerprint, names.task, str(path))
        if (searched := ticket.search_seeds()) is not None:
            require_unseen(seeds, searched, f"search seeds of {path}")
    tickets = list({t.id: t for t in loaded.values()}.values())  # a ticket named twice is judged once
    if cfg.mixture and len(tickets) < 2:
        raise OptionError("mixture needs at least 2 different tickets (tickets A and B)", "mixture")
    checks.require(task, policy, acting=False)  # the policy reads the task's observations, then the task's
    zero = Constant(zero_ticket(policy.noise_shape).noise)
    reseeded = {BASE: lambda r: Gaussian(cfg.seed + r), ZERO: lambda r: zero}
    reseeded |= {Arm.ticket(t.id): lambda r, t=t: Constant(t.noise) for t in tickets}
    if cfg.mixture:
        stacked = np.stack([t.noise for t in tickets])
        reseeded[MIXTURE] = lambda r: TopK(stacked, cfg.seed + r, cfg.epsilon)
    sources = {arm: source(0) for arm, source in reseeded.items() if arm != BASE}
    with Evaluator.open(cfg.policy, task, cfg, store, loaded=policy) as evaluator, \
            evaluator.progress(len(seeds) * (len(sources) + 1), "evaluating"):
        rows = dict(judge(evaluator, sources, seeds, Gaussian(cfg.seed)).rows)
    if cfg.mixture:
        for arm, source in tqdm(reseeded.items(), desc="diversity", unit="arm"):
            rows[arm] = replace(rows[arm], diversity=action_spread(policy, task, source, seeds[:10]))
    return rows


def with_recorded_settings(cfg: EvaluateConfig) -> EvaluateConfig:
    """`cfg` with the rename_map, policy_override and env_option its tickets were found under, where
    it gives none; OptionError where the tickets record different ones."""
    tickets = {ref: Ticket.load(find_ticket(ref)) for ref in cfg.tickets}
    recorded = {}
    for key in RECORDED_SETTINGS:
        values = {ref: ticket.metadata[key] for ref, ticket in tickets.items() if key in ticket.metadata}
        if getattr(cfg, key) is not None or not values:
            continue
        if not all(isinstance(value, dict) for value in values.values()):
            raise UserError(f"{next(iter(values))}: ticket metadata {key} must be an object")
        if len({json.dumps(value, sort_keys=True) for value in values.values()}) > 1:
            raise OptionError(f"the tickets were found under different {key}; give {key}", key)
        recorded[key] = next(iter(values.values()))
    return replace(cfg, **recorded)


def found_under(tickets: list[Ticket], given: dict, allow_transfer: bool = False) -> dict:
    """The task, max_steps and success to judge `tickets` under: each as `given` where given (not
    None), else as the tickets record they were found and judged under (None where they record
    nothing). UserError when the tickets disagree on an unset one, when no task is known, when a
    given one contradicts a ticket's, unless `allow_transfer`, and when an unset one would be code
    a ticket names (a factory or predicate): a shared file never runs code."""
    settings = {}
    for key, value in given.items():
        recorded = {}  # value -> the first ticket recording it
        for ticket in tickets:
            meta = ticket.metadata  # as its file has it: a recorded null counts
            if key in meta and not (key == "task" and "tasks" in meta):
                recorded.setdefault(meta[key], ticket.id)
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
        if value is None and isinstance(settings[key], str) and is_import_string(settings[key]):
            ticket = recorded[settings[key]]
            raise OptionError(f"ticket {ticket} names {settings[key]!r}, code of its own, as its {key}; a "
                              f"ticket does not run code: give {key} to run it", key)
    if settings["task"] is None:
        raise OptionError("no task given and no ticket names one; give task", "task")
    return settings

