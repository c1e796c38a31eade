"""Every option of a search, an evaluation, a training run, a transfer and a real-robot session,
and every search method's settings, once: typed fields with their defaults and help. Pure data and
checks: it imports nothing of goldenticket's but errors, factories, seeds and objectives.

The command line's flags are generated from these fields (`cli.py`: field `search_seeds` is
`--search-seeds`), a run can be given as a TOML file whose keys are the fields, and every search's
output folder keeps the resolved config it ran with (`config.toml`), so it can be run again from
that folder alone: `goldenticket search --config runs/x/config.toml`.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import tomllib
import typing
from collections.abc import Callable, Sequence
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from types import UnionType

from goldenticket.errors import OptionError, UserError
from goldenticket.factories import import_name
from goldenticket.objectives import FRONT_OBJECTIVES, OBJECTIVES
from goldenticket.seeds import SEED_SETS

MAX_NONFINITE = 0.1  # default: stop once base and zero ticket both pass this fraction of non-finite episodes
SINKS = {"tensorboard": "tensorboard", "wandb": "wandb"}  # a `log` sink (tracking.py) -> the package it needs
SEEDS_END = max(block.stop for block in SEED_SETS.values())  # every seed set lies in 0:SEEDS_END
DEFAULT_CONFIRM = {"sequential": 70, "fixed": 50}  # a session's confirm episodes per stopping rule (never
# more episodes under sequential stopping than under fixed)


def option(default=MISSING, help: str = "", **cli) -> field:
    """A config field (one without a default must be given); `cli` holds how the command line spells
    it beyond the generated flag (choices, action, its own flag)."""
    return field(default=default, metadata={"help": help, "cli": cli})


POLICY_HELP = ("bundled policy name (see `goldenticket policies`) or a folder written by `train` (append "
               "@N to run N denoising steps), or package.module:factory returning a NoisePolicy")
TASK_HELP = ("task name, e.g. metaworld/pick-place-v3, robomimic/lift, libero/object/0 or pusht (the docs' "
             "task list), or package.module:factory returning a gymnasium.Env")
SUCCESS_HELP = ("Gymnasium tasks: package.module:function(obs, info) -> bool deciding success "
                "(default: info['success'] or info['is_success'])")


METHODS: dict[str, type] = {}  # a search method's name -> the dataclass of its settings
SELF_RACING = ("cem-racing", "cem-bounds")  # methods that race their own tickets: no race, no halving
HALVING_UP_TO = 1100  # search episodes up to which halving is the default (the budget curve's rule)


def method(name: str):
    """Register the decorated settings dataclass as search method `name`'s (the LeRobot
    `register_subclass` pattern): `--method name` and `optimizer = {...}` in a config file."""
    def register(cls):
        METHODS[name] = cls
        return cls
    return register


def method_settings(name: str, values: dict):
    """Method `name`'s settings with `values` changed; OptionError for an unknown method, setting or
    a value of the wrong type."""
    if name not in METHODS:
        raise OptionError(f"unknown method {name!r}; choose from {list(METHODS)}", "method")
    cls = METHODS[name]
    if unknown := sorted(set(values) - {f.name for f in fields(cls)}):
        raise OptionError(f"unknown optimizer setting {', '.join(unknown)} for {name}; its settings: "
                          f"{', '.join(f.name for f in fields(cls))}", "optimizer")
    check_types(cls, values)
    return cls(**values)


@method("rs")
@dataclass(frozen=True)
class RandomSearchSettings:
    """Random search (the paper's Alg. 1): i.i.d. N(0, I) tickets, each on every search seed."""

    batch_size: int = option(50, "tickets per ask")
    num_tickets: int | None = option(None, "tickets in all (default: until the budget is spent)")


@method("cem")
@dataclass(frozen=True)
class CEMSettings:
    """The cross-entropy method (Alg. 2) over a diagonal Gaussian: sample `population`, keep the top
    `elite_frac`, refit with smoothing `alpha`; sigma floored at `sigma_min`, then inflated by
    `sigma_extra`."""

    population: int = option(50, "tickets per iteration")
    elite_frac: float = option(0.2, "fraction of the population refit on")
    alpha: float = option(1.0, "smoothing of the refit (1: the elites' statistics alone)")
    sigma_init: float = option(1.0, "initial standard deviation")
    sigma_min: float = option(0.01, "floor of the standard deviation")
    sigma_extra: float = option(0.0, "noise added to the standard deviation after each refit")
    iterations: int | None = option(None, "iterations (default: until the budget is spent)")


@method("zos")
@dataclass(frozen=True)
class ZerothOrderSettings:
    """Zeroth-order search (Alg. 3): a random walk on a sphere of `radius` around a pivot."""

    candidates: int = option(10, "tickets per iteration")
    radius: float = option(0.5, "L2 radius of the steps")
    iterations: int | None = option(None, "iterations after the pivot (default: until the budget)")


@method("cem-racing")
@dataclass(frozen=True)
class CEMRacingSettings(CEMSettings):
    """CEM whose population is raced by sequential halving over `tiers` blocks of search seeds."""

    tiers: int = option(5, "blocks of search seeds; the top half survives each")


@method("cem-bounds")
@dataclass(frozen=True)
class CEMBoundsSettings(CEMSettings):
    """CEM whose population is raced with Hoeffding confidence bounds, `block` seeds at a time."""

    block: int = option(4, "search seeds per block")
    delta: float = option(0.1, "level of each confidence bound")
    value_range: float = option(1.0, "range of an episode's return")


@method("cma-es")
@dataclass(frozen=True)
class CMAESSettings:
    """CMA-ES (the `cma` package) over the flattened ticket."""

    population: int = option(20, "tickets per generation")
    sigma_init: float = option(1.0, "initial step size")
    mean: tuple[tuple[float, ...], ...] | None = option(None, "start ticket, rows of the searched shape "
                                                        "(default: w = 0)")
    iterations: int | None = option(None, "generations (default: until the budget is spent)")


@method("tiled-then-full")
@dataclass(frozen=True)
class TiledThenFullSettings:
    """CMA-ES over a tiled ticket, then CMA-ES over the full ticket from the tiled stage's best (run
    with the full sub-space)."""

    population: int = option(20, "tickets per generation, in both stages")
    sigma_init: float = option(1.0, "the tiled stage's initial step size")
    tiled_generations: int = option(2, "generations of the tiled stage")
    sigma_full: float = option(0.5, "the full stage's initial step size")


@dataclass(frozen=True)
class ModelBasedSettings:
    """Model-based search through an Optuna sampler, each searched number in [-bound, bound] and seen
    by the sampler as its N(0, 1) quantile."""

    batch_size: int = option(4, "tickets per ask (the sampler treats the unscored ones as pending)")
    startup: int = option(10, "random tickets before the model proposes")
    bound: float = option(3.0, "each searched number lies in [-bound, bound]")
    start_at_zero: bool = option(True, "score w = 0 first")
    num_tickets: int | None = option(None, "tickets in all (default: until the budget is spent)")


@method("tpe")
@dataclass(frozen=True)
class TPESettings(ModelBasedSettings):
    """The tree-structured Parzen estimator (Optuna's multivariate TPESampler, constant liar)."""


@method("gp")
@dataclass(frozen=True)
class GPSettings(ModelBasedSettings):
    """Bayesian optimisation with a Gaussian process (Optuna's GPSampler: a Matern-5/2 kernel with
    learned noise, log expected improvement)."""


@dataclass(frozen=True, kw_only=True)
class EngineOptions:
    """Where episodes run; results do not depend on it."""

    workers: int = option(2, "worker processes (results do not depend on it)")
    backend: str = option("local", "where episodes run: local processes, or Ray actors (results do not "
                          "depend on it)", choices=("local", "ray"))
    address: str | None = option(None, "Ray cluster address, e.g. ray://head:10001 (default: start a "
                                 "local Ray instance)")
    max_nonfinite: float = option(MAX_NONFINITE, "an episode whose policy call returns NaN or infinite "
                                  "actions ends as a failure of its arm; stop (the policy or its adapter "
                                  "broken) only when more than this fraction of the held-out episodes of "
                                  "both the base and the zero ticket end so")
    device: str = option("cpu", "where a LeRobot checkpoint's model runs: cpu, or cuda / cuda:N (there the "
                         "numbers hold for the same GPU model, driver and versions; workers share one model)")

    def check(self) -> None:  # workers: the engine knows this machine's limit (rollout.Engine)
        check_max_nonfinite(self.max_nonfinite)
        check_device(self.device)


def check_device(device: str) -> None:
    """`cpu`, `cuda` or `cuda:N`; a GPU one only where torch sees a GPU."""
    kind, _, index = device.partition(":")
    if not (device == "cpu" or (kind == "cuda" and (not index or index.isdigit()))):
        raise OptionError(f"device must be cpu, cuda or cuda:N, got {device!r}", "device")
    if kind == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise OptionError(f"device {device}: torch sees no CUDA GPU here (torch.cuda.is_available() is "
                              "False); run on the CPU (device cpu, the default)", "device")


def check_max_nonfinite(fraction: float) -> None:
    if not 0 <= fraction <= 1:
        raise OptionError(f"max_nonfinite must be a fraction in [0, 1], got {fraction}", "max_nonfinite")


@dataclass(frozen=True)
class SearchConfig(EngineOptions):
    """One search run; the same config and seed always give the same numbers. `task` may be
    several task names (a tuple): one ticket for a multi-task policy, judged per task."""

    policy: str | object = option(help=POLICY_HELP)  # or a NoisePolicy object
    task: str | Callable | tuple[str, ...] = option(
        help=TASK_HELP + "; repeat for one ticket over several tasks of a multi-task policy (task-averaged "
        "success, judged per task) (default in search: the task a bundled single-task policy was trained on)",
        action="append")
    method: str = option("cma-es", "random search, CEM, zeroth-order search, CEM raced by halving "
                         "(cem-racing) or by confidence bounds (cem-bounds), CMA-ES",
                         choices=tuple(METHODS))
    budget: int = option(1100, "search episodes to spend at most (per task for transfer); with the "
                         "default halving and validation, at most 1250 episodes before the verdict")
    seed: int = option(0, "seed of every random draw")
    search_seeds: int = option(20, "initial states to search on (per task)")
    heldout: int = option(200, "held-out initial states (per task) to judge base, zero ticket and tickets on")
    top_k: int = option(3, "best search tickets judged on held-out states (after validation, the zero "
                        "ticket beside them)")
    objective: str = option("success", "episode return the search maximises; speed: short successful "
                            "episodes; success-progress: success, ties broken by how far failed episodes "
                            "got (Meta-World's shaped reward at their end)", choices=tuple(OBJECTIVES))
    stop_after_perfect: int | None = option(3, "stop once this many tickets succeed on every search seed "
                                            "(0 or None: never)")
    max_tickets: int | None = option(None, "stop after this many distinct tickets (default: no cap)")
    race: float | None = option(None, "race every ticket against the best so far on blocks of 5 search "
                                "seeds: it stops where a one-sided sign test on the seeds both ran says it "
                                "is worse at p < RACE, e.g. 0.1 (not with cem-racing or cem-bounds, which "
                                "race their own way; default: every ticket runs on every search seed)")
    halving: bool | None = option(None, "spend episodes by sequential halving: each generation's tickets on "
                                  "the first 5 search seeds, the better half on the next 5, and so on, the "
                                  "last ones on every search seed; and the tickets to validate on the first "
                                  "10 validation seeds, the better half on the next 10, while that half is "
                                  "more than top_k (default: on where the budget is at most 1100 and no "
                                  "race, cem-racing or cem-bounds races the tickets; --no-halving: every "
                                  "ticket on every seed)",
                                  action=argparse.BooleanOptionalAction)
    max_steps: int | None = option(None, "episode step limit (default: the task's, 150 for Meta-World)")
    success: str | Callable | None = option(None, SUCCESS_HELP)
    subspace: str = option("tiled", "what the search varies: tiled (one action-sized vector repeated over "
                           "the horizon), full (every entry), channels:I,J (those action channels; the "
                           "others 0)")
    front_objective: str | None = option(None, "a second objective: also find the Pareto front between "
                                         "the two (front.json, front.png)", choices=tuple(OBJECTIVES))
    validation_seeds: int | None = option(None, "run the 3 x top_k best search tickets on this many "
                                          "validation states, with the zero ticket and any ticket given, "
                                          "and judge the top_k of those on held-out states (default: 40 "
                                          "for one task, 0 for several; 0: judge the search's top_k)")
    no_regression: bool = option(False, "several tasks: never pick a ticket significantly worse than the "
                                 "base on a task", action="store_true")
    tickets: tuple[str | Path, ...] | str | Path = option(
        (), "a ticket file or bundled ticket id to validate beside the search's best and the zero ticket "
        "(e.g. from another task or an earlier run); repeat for several", action="append", flag="--ticket",
        metavar="TICKET")
    log: tuple[str, ...] | str = option(
        (), "also log the search to tensorboard (in --out/tensorboard) or wandb (offline, in --out/wandb); "
        "repeat or comma-separate for both. --out/log.csv is always written", action="append", metavar="SINK")
    optimizer: dict | None = option(None, "a setting of the method changed from its default, e.g. "
                                    "population=40 or sigma_init=0.5 (each method's settings: the "
                                    "concepts page); repeat for several; in a config file, optimizer = "
                                    "{population = 40}", key_values=True, metavar="KEY=VALUE")

    def __post_init__(self):
        object.__setattr__(self, "tickets", ticket_refs(self.tickets))
        object.__setattr__(self, "log", sink_names(self.log))
        if isinstance(self.task, list):
            object.__setattr__(self, "task", self.task[0] if len(self.task) == 1 else tuple(self.task))
        if self.stop_after_perfect == 0:
            object.__setattr__(self, "stop_after_perfect", None)

    def halves(self) -> bool:
        """Whether the run spends its episodes by sequential halving: `halving`, or by default where
        the budget is at most HALVING_UP_TO and its tickets are not raced (`race`, or a method that
        races its own)."""
        if self.halving is not None:
            return self.halving
        return self.budget <= HALVING_UP_TO and self.race is None and self.method not in SELF_RACING

    @property
    def tasks(self) -> tuple:
        """The run's tasks: one, or several for a multi-task run."""
        return self.task if isinstance(self.task, tuple) else (self.task,)

    def check(self) -> None:
        """Every option, before any episode runs."""
        super().check()
        if self.stop_after_perfect is not None and self.stop_after_perfect < 0:
            raise OptionError(f"stop_after_perfect must be >= 0 (0: never), got {self.stop_after_perfect}",
                              "stop_after_perfect")
        for name in ("seed", "validation_seeds"):
            if getattr(self, name) is not None and getattr(self, name) < 0:
                raise OptionError(f"{name} must be >= 0, got {getattr(self, name)}", name)
        for name in ("budget", "search_seeds", "heldout", "top_k", "max_tickets", "max_steps"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise OptionError(f"{name} must be > 0, got {getattr(self, name)}", name)
        for name, allowed in (("objective", OBJECTIVES), ("front_objective", (*OBJECTIVES, None))):
            if getattr(self, name) not in allowed:
                raise OptionError(f"unknown {name} {getattr(self, name)!r}; choose from "
                                  f"{list(OBJECTIVES)}", name)
        self.settings()
        self._check_method()
        if self.tickets and not self.validation():
            raise OptionError("tickets: a given ticket runs on the validation seeds beside the search's "
                              "best, so it needs validation_seeds > 0", "tickets", "validation_seeds")
        self._check_tasks()
        self._check_front()
        check_sinks(self.log)

    def _check_method(self) -> None:
        if self.method == "tiled-then-full" and self.subspace != "full":
            raise OptionError("tiled-then-full searches the full ticket in its second stage: run it with "
                              "subspace full", "method", "subspace")
        self._check_race()

    def _check_race(self) -> None:
        if self.race is not None and not 0 < self.race < 1:
            raise OptionError(f"race must be a level in (0, 1), e.g. 0.1, got {self.race}", "race")
        if self.race is not None and self.halving:
            raise OptionError("race and halving cannot both be set; choose one", "race", "halving")
        raced = "race" if self.race is not None else "halving" if self.halving else None
        if raced and self.method in SELF_RACING:
            raise OptionError(f"{self.method} races its own populations; {raced} is for the other methods",
                              raced, "method")

    def _check_tasks(self) -> None:
        if len(self.tasks) > 1:
            for name in ("success", "front_objective"):
                if getattr(self, name):
                    raise OptionError(f"{name} is for single-task runs; not with several task", name, "task")
        elif self.no_regression:
            raise OptionError("no_regression needs several task (it guards every task's success)",
                              "no_regression", "task")

    def _check_front(self) -> None:
        if not self.front_objective:
            return
        if self.front_objective == self.objective:
            raise OptionError(f"objective {self.objective} twice: a Pareto front needs two different "
                              "objectives", "objective")
        if not {self.objective, self.front_objective} <= set(FRONT_OBJECTIVES):
            raise OptionError(f"a Pareto front's objectives must be among {list(FRONT_OBJECTIVES)}",
                              "objective", "front_objective")

    def validation(self) -> int:
        """Validation seeds this run uses."""
        if self.validation_seeds is None:
            return 0 if len(self.tasks) > 1 else 40
        return self.validation_seeds

    def settings(self):
        """The method's settings: its registered dataclass with `optimizer` applied."""
        return method_settings(self.method, self.optimizer or {})


@dataclass(frozen=True)
class EvaluateConfig(EngineOptions):
    """Base, zero ticket and tickets judged on held-out seeds."""

    policy: str | object = option(help=POLICY_HELP)
    task: str | Callable | None = option(None, TASK_HELP + " (default: the task the tickets were found on, "
                                         "if it is a built-in task; a ticket never names code to run)")
    tickets: tuple[str | Path, ...] | str | Path = option(
        (), "ticket file or bundled ticket id; repeat for several; without it, only the base and the zero "
        "ticket run", action="append", flag="--ticket", metavar="TICKET")
    seeds: Sequence[int] = option(range(1_000_000, 1_000_200), "held-out seed range A:B, A included, B "
                                  "not (seeds 1000000:2000000 name held-out states)", seed_range=True)
    seed: int = option(0, "seed of the base policy's Gaussian noise")
    max_steps: int | None = option(None, "episode step limit (default: the tickets' own, else the task's)")
    success: str | Callable | None = option(None, SUCCESS_HELP.replace("(default: ", "(default: the "
                                                                       "tickets' own, else "))
    allow_transfer: bool = option(False, "run tickets found for another policy or task, or under another "
                                  "max_steps or success (transfer studies)", action="store_true")
    mixture: bool = option(False, "add an arm that draws one of the tickets at every policy call, and "
                           "report each arm's diversity (spread of executed actions from one initial "
                           "state)", action="store_true")
    epsilon: float = option(0.0, "with mixture: fresh Gaussian noise instead of a ticket with this "
                            "probability")

    def __post_init__(self):
        object.__setattr__(self, "tickets", ticket_refs(self.tickets))

    def check(self) -> None:
        super().check()
        if self.seed < 0:
            raise OptionError(f"seed must be >= 0, got {self.seed}", "seed")
        check_seeds(self.seeds)
        if not 0 <= self.epsilon <= 1 or (self.epsilon and not self.mixture):
            raise OptionError(f"epsilon must be in [0, 1] and comes with mixture, got {self.epsilon}",
                              "epsilon", "mixture")


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """A policy trained on imperfect scripted-expert demonstrations, and its model card."""

    task: str = option(help="built-in Meta-World task, e.g. metaworld/reach-v3 (metaworld-pixels/...: a "
                       "policy that sees camera frames), or robomimic/lift or robomimic/can")
    kind: str = option("flow", "flow matching (Euler steps) or DDIM (eta = 0)", choices=("flow", "ddim"))
    demos: int = option(20, "successful demonstrations to train on")
    grasp_offset: float = option(0.0, "each demonstrator aims at the object shifted by U(+-this) m in x "
                                 "and y")
    goal_offset: float = option(0.0, "each demonstrator aims at the goal shifted by U(+-this) m in x and y")
    action_noise: float = option(0.0, "std of Gaussian noise added to the demonstrators' actions")
    steps: int = option(20_000, "gradient steps")
    batch: int = option(256, "demonstration chunks per gradient step")
    denoise_steps: int = option(10, "Euler / DDIM steps at inference")
    horizon: int = option(8, "actions predicted per call (H)")
    n_exec: int = option(4, "actions executed before replanning")
    heldout: int = option(200, "held-out initial states the model card's base and zero-ticket success use")
    seed: int = option(0, "seed of demonstrations and training")
    workers: int = option(1, "worker processes measuring the model card's success")

    def check(self) -> None:
        """Every option, before any demonstration is collected."""
        for name in ("demos", "steps", "batch", "denoise_steps", "horizon", "n_exec", "heldout", "workers"):
            if getattr(self, name) <= 0:
                raise OptionError(f"{name} must be > 0, got {getattr(self, name)}", name)
        if self.n_exec > self.horizon:
            raise OptionError(f"n_exec {self.n_exec} cannot exceed horizon {self.horizon}", "n_exec",
                              "horizon")
        for name in ("seed", "grasp_offset", "goal_offset", "action_noise"):
            if getattr(self, name) < 0:
                raise OptionError(f"{name} must be >= 0, got {getattr(self, name)}", name)
        if self.kind not in ("flow", "ddim"):
            raise OptionError(f"unknown kind {self.kind!r}; choose from ['flow', 'ddim']", "kind")


@dataclass(frozen=True, kw_only=True)
class TransferOptions:
    """`transfer`'s own options, beside a search's: the tickets to judge instead of searching one per
    task, or each task's search budget (no default: one or the other)."""

    budget: int | None = option(None, "search episodes per task; needed unless --ticket is given")
    tickets: tuple[str | Path, ...] | str | Path = option((), "take these tickets (files or bundled ids) "
                                                          "instead of searching one per task",
                                                          action="append", flag="--ticket", metavar="TICKET")

    def __post_init__(self):
        object.__setattr__(self, "tickets", ticket_refs(self.tickets))

    def check(self) -> None:
        if self.budget is None and not self.tickets:
            raise OptionError("transfer needs budget (search episodes per task) or tickets", "budget",
                              "tickets")


STOPPING_HELP = (
    "sequential (default): a race runs the tickets in rounds and drops each one that clearly trails the "
    "leader, until one is left or N x K search episodes are spent; then it and the base run in pairs until "
    "a sequential test decides (at most --confirm pairs). In simulation, 6 x 25 with one ticket 20 to 40 "
    "points better than the base: 31-63% fewer operator episodes than fixed, at equal or higher power; false "
    "golden below --alpha (benchmarks/results/session_sequential.md). fixed: the paper's protocol, N x K "
    "episodes, then the top 2 and the base on M each")


@dataclass(frozen=True, kw_only=True)
class SessionConfig:
    """A real-robot session's plan (`session new`): N random tickets raced, or K episodes each, then the
    finalists and the base; `session.Plan` checks the numbers."""

    policy: str = option(help="the policy the robot runs (name, folder or import string)")
    tickets: int = option(6, "candidate tickets (N, at least 2)")
    episodes_per_ticket: int = option(25, "search episodes per ticket (K); sequential: the race spends at "
                                      "most N x K in all")
    stopping: str = option("sequential", STOPPING_HELP, choices=tuple(DEFAULT_CONFIRM))
    alpha: float = option(0.05, "type-I error: the chance of calling a ticket golden when it is no better")
    confirm: int | None = option(
        None, f"confirm episodes per arm (M): fixed, each finalist and the base run M (default "
        f"{DEFAULT_CONFIRM['fixed']}); sequential, at most M pairs of the finalist and the base (default "
        f"{DEFAULT_CONFIRM['sequential']}, so never more episodes than fixed); N x K + 3 x M (fixed) or "
        "+ 2 x M is at most 100000")
    seed: int = option(0, "seed of the tickets, the order and the base noise")

    def check(self) -> None:
        if self.seed < 0:
            raise OptionError(f"seed must be >= 0, got {self.seed}", "seed")
        if self.stopping not in DEFAULT_CONFIRM:
            raise OptionError(f"stopping must be one of {', '.join(DEFAULT_CONFIRM)}, got {self.stopping!r}",
                              "stopping")

    def confirm_episodes(self) -> int:
        """M: as given, else the stopping rule's default."""
        return DEFAULT_CONFIRM[self.stopping] if self.confirm is None else self.confirm


@dataclass(frozen=True, kw_only=True)
class ServeConfig:
    """Where `session serve` listens for the operator page and the robot."""

    host: str = option("127.0.0.1", "interface; other than local needs --token")
    port: int = option(8765, "TCP port of the operator page and the robot's HTTP API")
    token: str | None = option(None, "required from every client when set")


def ticket_refs(tickets) -> tuple[str, ...]:
    """Ticket files or ids as strings: one given alone (a str or a Path), or several."""
    return (str(tickets),) if isinstance(tickets, str | Path) else tuple(map(str, tickets))


def sink_names(value) -> tuple[str, ...]:
    """`log` as a tuple of sink names, from one name, a comma-separated list or several of them."""
    items = [value] if isinstance(value, str) else value
    return tuple(dict.fromkeys(name.strip() for item in items for name in item.split(",") if name.strip()))


def check_sinks(sinks: Sequence[str]) -> None:
    """OptionError unless every sink is known and its package imports (before any work is done)."""
    for name in sinks:
        if name not in SINKS:
            raise OptionError(f"unknown log {name!r}; choose from {', '.join(SINKS)}", "log")
        try:
            importlib.import_module(SINKS[name])
        except ImportError:
            raise OptionError(f"log {name} needs the {SINKS[name]} package: pip install {SINKS[name]}",
                              "log") from None


def make(cls, values: dict):
    """`cls(**values)`, or one line naming the options `cls` does not have."""
    names = {f.name for f in fields(cls)}
    if unknown := sorted(set(values) - names):
        raise UserError(f"unknown option {', '.join(unknown)}; options are: {', '.join(sorted(names))}")
    missing = [f.name for f in fields(cls) if f.default is MISSING and f.name not in values]
    if missing:
        raise OptionError(f"{', '.join(missing)} must be given", *missing)
    check_types(cls, values)
    return cls(**values)


@functools.cache
def field_types(cls) -> dict:
    """Each field's annotation of `cls`, evaluated (the module postpones them: `f.type` is a string)."""
    return typing.get_type_hints(cls)


def check_types(cls, values: dict) -> None:
    """OptionError naming the first value that is not of its field's annotated type."""
    for f in fields(cls):
        if f.name in values and not conforms(value := values[f.name], field_types(cls)[f.name]):
            raise OptionError(f"{f.name} must be of type {f.type}, got {value!r} ({type(value).__name__})",
                              f.name)


def conforms(value, hint) -> bool:
    """Whether `value` is of type `hint`: a bool is no int, an int is a float, a list is a tuple, and a
    range is a Sequence[int]."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (UnionType, typing.Union):
        return any(conforms(value, arg) for arg in args)
    if origin in (tuple, Sequence):
        if isinstance(value, range):
            return origin is Sequence and args[0] is int
        return isinstance(value, tuple | list) and all(conforms(v, args[0]) for v in value)
    if hint in (int, float):
        return isinstance(value, int | hint) and not isinstance(value, bool)
    return isinstance(value, hint)


def read_toml(path: Path) -> dict:
    """A config file's values (keys are the fields), as the fields' types take them."""
    try:
        values = tomllib.loads(path.read_text())
    except OSError as exc:
        raise UserError(f"cannot read config {path}: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a TOML file ({exc})") from None
    if isinstance(values.get("seeds"), str):
        values["seeds"] = seed_range(values["seeds"])
    return values


def seed_range(text: str) -> range:
    """Seeds "A:B": A included, B not, as Python's range(A, B)."""
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise OptionError(f"seeds: expected A:B (integers), got {text!r}", "seeds") from None
    if not 0 <= a < b:
        raise OptionError(f"seed range {text!r} must satisfy 0 <= A < B", "seeds")
    check_seeds(range(a, b))
    return range(a, b)


def check_seeds(seeds: Sequence[int]) -> None:
    """OptionError unless there are seeds and all lie in the seed sets (a range's ends only: it may be
    too long to count)."""
    if not seeds:
        raise OptionError("seeds: none given", "seeds")
    ends = (seeds[0], seeds[-1]) if isinstance(seeds, range) else seeds
    low, high = min(ends), max(ends)
    if low < 0 or high >= SEEDS_END:
        raise OptionError(f"seeds {low}:{high + 1} lie beyond the seed sets (0:{SEEDS_END})", "seeds")


def to_toml(config) -> str:
    """The config as a TOML file `read_toml` gives back (None fields left out; a policy object or a
    function as its import string)."""
    lines = []
    for f in cli_fields(type(config)):
        value = getattr(config, f.name)
        if value is None:
            continue
        if isinstance(value, range):
            value = f"{value.start}:{value.stop}"
        elif not isinstance(value, str | int | float | bool | tuple | list | dict):
            value = named(value)
        lines.append(f"{f.name} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def _toml_value(value) -> str:
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return json.dumps(value)  # a TOML basic string, integer or float


def named(obj) -> str | None:
    """A user's object as files record it: a string as it is, else its import string."""
    return obj if obj is None or isinstance(obj, str) else import_name(obj)


def spelled_flags(*classes) -> dict[str, str]:
    """The fields of `classes` whose flag is not the generated one (`tickets` -> `--ticket`)."""
    return {f.name: f.metadata["cli"]["flag"] for cls in classes for f in fields(cls)
            if "flag" in f.metadata["cli"]}


def cli_fields(cls, skip: Sequence[str] = ()) -> list:
    """The fields as the command line lists them: the run's own, then where episodes run."""
    engine = {f.name for f in fields(EngineOptions)}
    chosen = [f for f in fields(cls) if f.name not in skip]
    return sorted(chosen, key=lambda f: f.name in engine)
