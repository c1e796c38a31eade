"""The `compare` command: policy A against policy B (another policy, or the same one with or without a
ticket) on the same held-out seeds, each seed one initial state both start from: a paired A/B test."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from goldenticket import checks
from goldenticket.config import CompareConfig, named
from goldenticket.errors import OptionError, UserError
from goldenticket.evaluation import BASE, Arm, Evaluator, Job, Judged
from goldenticket.files import open_folder
from goldenticket.job.evaluate import found_under
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import NoisePolicy, find_ticket, identity, load_policy, policy_label
from goldenticket.results import ComparedArm, Comparison
from goldenticket.rollout import EpisodeResult
from goldenticket.seeds import require_unseen
from goldenticket.store import RunStore
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket
from goldenticket.zoo import bundled_task


@dataclass(frozen=True)
class Side:
    """One arm of a comparison: its policy as given (`ref`, what workers rebuild) and as loaded, its
    ticket (None: fresh Gaussian noise), and its arm: the judged policy's own (base, a ticket) for A
    and for B on the same policy, `Arm.other` for B on another policy."""

    ref: str | NoisePolicy
    policy: NoisePolicy
    ticket: Ticket | None
    arm: Arm
    ticket_ref: str | None = None  # the ticket as given: a file or a bundled id

    @property
    def ticket_id(self) -> str | None:
        return None if self.ticket is None else self.ticket.id

    def job(self, seeds: Sequence[int], seed: int) -> Job:
        """Its episodes on `seeds`, under its ticket or under Gaussian noise from `seed`."""
        source = Gaussian(seed) if self.ticket is None else Constant(self.ticket.noise)
        return self.arm.key, source, seeds

    def compared(self, results: Sequence[EpisodeResult]) -> ComparedArm:
        return ComparedArm(policy_label(self.ref), self.ticket_id, self.arm, Judged(tuple(results)))


def compare_policies(cfg: CompareConfig, out: str | Path | None = None) -> Comparison:
    """Policy A (`cfg.policy`, with `cfg.ticket`) and policy B (`cfg.against`, with
    `cfg.against_ticket`) on the held-out `cfg.seeds`: a `Comparison`. Every episode is kept in
    `out`/run.sqlite when `out` is given, and a rerun reads them back. The task, `max_steps` and
    `success` default to those the tickets were found under, the task else to the one the bundled
    policies were trained on; a ticket found for another policy or task is refused unless
    `allow_transfer`. Both policies must act on the task (`checks.policy_and_task_agree`)."""
    cfg.check()
    seeds = list(cfg.seeds)
    sides = _sides(cfg)
    settings = _settings(cfg, [side.ticket for side in sides if side.ticket is not None])
    task = get_task(settings["task"], settings["max_steps"], settings["success"], cfg.env_option)
    for side in sides:
        _check_ticket(cfg, side, task.name, seeds)
    for policy in dict.fromkeys(side.policy for side in sides):  # each acts on the task (A and B need
        checks.policy_and_task_agree(checks.Subject(task, policy))  # not answer their noise)
    checks.require(task)
    results = _run(cfg, sides, task, seeds, out, named(settings["success"]))
    return Comparison(task.name, (seeds[0], seeds[-1]),
                      *(side.compared(ran) for side, ran in zip(sides, results, strict=True)))


def _sides(cfg: CompareConfig) -> tuple[Side, Side]:
    """A and B: their policies loaded (once where they are one), their tickets and their arms."""
    same = cfg.against is cfg.policy or (isinstance(cfg.policy, str) and cfg.against == cfg.policy)
    if same and cfg.ticket == cfg.against_ticket:
        raise OptionError("A and B are the same policy with the same noise, nothing to compare: give ticket "
                          "or against_ticket, or another policy as against", "ticket", "against_ticket",
                          "against")
    policy_a = load_policy(cfg.policy, cfg.device, **cfg.policy_settings())
    policy_b = policy_a if same else load_policy(cfg.against, cfg.device, **cfg.policy_settings())
    return (_side(cfg.policy, policy_a, cfg.ticket),
            _side(cfg.against, policy_b, cfg.against_ticket, None if same else policy_label(cfg.against)))


def _side(ref: str | NoisePolicy, policy: NoisePolicy, ticket_ref: str | None,
          other: str | None = None) -> Side:
    """An arm of `policy` (given as `ref`; `other`: its name, where it is B on another policy than A)
    under the ticket `ticket_ref` names (None: fresh Gaussian noise)."""
    ticket = None if ticket_ref is None else Ticket.load(find_ticket(ticket_ref),
                                                          expected_shape=policy.noise_shape)
    return Side(ref, policy, ticket, arm_of(ticket, other), ticket_ref)


def arm_of(ticket: Ticket | None, other: str | None = None) -> Arm:
    """The arm of a policy under `ticket` (None: fresh Gaussian noise): the judged policy's own (the
    base, a ticket), or another policy's, named `other`."""
    ticket_id = None if ticket is None else ticket.id
    if other is not None:
        return Arm.other(other, ticket_id)
    return BASE if ticket_id is None else Arm.ticket(ticket_id)


def _settings(cfg: CompareConfig, tickets: list[Ticket]) -> dict:
    """The task, `max_steps` and `success`: as given, else as the tickets were found under
    (`job.evaluate.found_under`), the task else as the bundled policies were trained on."""
    given = {"task": cfg.task, "max_steps": cfg.max_steps, "success": cfg.success}
    if cfg.task is None and not any(t.metadata.get("task") or t.metadata.get("tasks") for t in tickets):
        given["task"] = _trained_on(cfg)
    return found_under(tickets, given, cfg.allow_transfer)


def _trained_on(cfg: CompareConfig) -> str | None:
    """The task the bundled ones of policies A and B were trained on (None: neither is a bundled
    single-task policy); OptionError where they name different tasks."""
    tasks = {bundled_task(ref) for ref in (cfg.policy, cfg.against) if isinstance(ref, str)} - {None}
    if len(tasks) > 1:
        raise OptionError(f"policies A and B were trained on different tasks ({', '.join(sorted(tasks))}); "
                          "give task", "task")
    return next(iter(tasks), None)


def _check_ticket(cfg: CompareConfig, side: Side, task: str, seeds: list[int]) -> None:
    """The side's ticket, if any, found for its policy and for `task` (unless `allow_transfer`), on
    search seeds that `seeds` avoid."""
    if side.ticket is None:
        return
    where = f"{side.ticket_ref} for policy {policy_label(side.ref)!r}"
    if not cfg.allow_transfer:
        side.ticket.check_fits(identity(side.policy), task, where)
    if (searched := side.ticket.search_seeds()) is not None:
        require_unseen(seeds, searched, f"search seeds of {where}")


def _run(cfg: CompareConfig, sides: tuple[Side, Side], task, seeds: list[int], out: str | Path | None,
         success: str | None) -> list[list[EpisodeResult]]:
    """Each side's episodes on `seeds`, through one evaluator (its store, its check that every episode
    of a seed begins in one initial state, its progress bar): on one engine where A and B are one
    policy, else on A's engine, then on B's."""
    a, b = sides
    claim = _claim(cfg, sides, task, success)
    with Evaluator.open(a.ref, task, cfg, loaded=a.policy) as evaluator, _store(out, claim) as store, \
            evaluator.progress(2 * len(seeds), "comparing"):
        evaluator.store = store  # the engine starts first: options it refuses leave no run folder
        if b.policy is a.policy:
            return evaluator.run([a.job(seeds, cfg.seed), b.job(seeds, cfg.seed)])
        ran = evaluator.run([a.job(seeds, cfg.seed)])
        evaluator.engine.close()  # A's workers stop before B's start
        with Evaluator.open(b.ref, task, cfg, loaded=b.policy) as other:
            evaluator.engine = other.engine
            return ran + evaluator.run([b.job(seeds, cfg.seed)])


def _claim(cfg: CompareConfig, sides: tuple[Side, Side], task, success: str | None) -> dict:
    """What fixes a comparison's episodes, as its run store holds it: each arm's policy (its name and
    identity) and ticket, the task and its settings, the noise seed, a LeRobot checkpoint's and env's
    settings; not the seeds (a rerun on more seeds reads back those run)."""
    arms = [{"policy": policy_label(side.ref), "policy_fingerprint": identity(side.policy),
             "ticket": side.ticket_id} for side in sides]
    env = {"env_option": cfg.env_option} if cfg.env_option else {}
    return {"compare": arms, "task": task.name, "max_steps": task.max_steps, "success": success,
            "seed": cfg.seed} | cfg.policy_settings() | env


@contextmanager
def _store(out: str | Path | None, config: dict) -> Iterator[RunStore | None]:
    """The run store `out`/run.sqlite holding `config` (None without `out`)."""
    if out is None:
        yield None
        return
    open_folder(out)
    with RunStore(Path(out) / "run.sqlite") as store:
        if not store.claim_config(config):
            raise UserError(f"{out} holds a different run; choose another folder or the same options")
        yield store
