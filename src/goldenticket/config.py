"""Every option of a search, an evaluation, a comparison, a training run, a transfer, a real-robot
session and a check, once: typed fields with their defaults and help (`options.option`); each search
method's settings are its own, in `ticket_search.methods`. Pure data and checks: it imports nothing
of goldenticket's but errors, options, factories, seeds, objectives and those settings.

The command line's flags are generated from these fields (`cli.py`: field `search_seeds` is
`--search-seeds`), a run can be given as a TOML file whose keys are the fields, and every search's
output folder keeps the resolved config it ran with (`config.toml`), so it can be run again from
that folder alone: `goldenticket search --config runs/x/config.toml`.
"""

from __future__ import annotations

import argparse
import importlib
import json
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

from goldenticket.errors import OptionError, UserError
from goldenticket.factories import import_name
from goldenticket.objectives import FRONT_OBJECTIVES, OBJECTIVES
from goldenticket.options import check_types, option
from goldenticket.seeds import SEED_SETS, require_heldout
from goldenticket.ticket_search.methods import METHODS, OWN_TILING, SELF_RACING, method_settings

MAX_NONFINITE = 0.1  # default: stop once base and zero ticket both pass this fraction of non-finite episodes
STEP_TIMEOUT = 600.0  # default seconds an env step or a policy call may take: hangs end, slow simulators run
SINKS = {"tensorboard": "tensorboard", "wandb": "wandb"}  # a `log` sink (tracking.py) -> the package it needs
SEEDS_END = max(block.stop for block in SEED_SETS.values())  # every seed set lies in 0:SEEDS_END
DEFAULT_CONFIRM = {"sequential": 70, "fixed": 50}  # a session's confirm episodes per stopping rule (never
# more episodes under sequential stopping than under fixed)


POLICY_HELP = ("bundled policy name (see `goldenticket policies`) or a folder written by `train` (append "
               "@N to run N denoising steps), or package.module:factory returning a NoisePolicy")
TASK_HELP = ("task name, e.g. metaworld/pick-place-v3, robomimic/lift, libero/object/0 or pusht (the docs' "
             "task list), or package.module:factory returning a gymnasium.Env")
SUCCESS_HELP = ("Gymnasium tasks: package.module:function(obs, info) -> bool deciding success "
                "(default: info['success'] or info['is_success'])")

HALVING_UP_TO = 1100  # search episodes up to which halving is the default (the budget curve's rule)


RECORDED_SETTINGS = ("rename_map", "policy_override", "env_option")  # PolicySettings', as tickets record them


@dataclass(frozen=True, kw_only=True)
class PolicySettings:
    """How a LeRobot checkpoint runs on a task, as `lerobot-eval` takes it (its --rename_map,
    --policy.KEY=VALUE and --env.KEY=VALUE); tickets record them."""

    rename_map: dict | None = option(
        None, "LeRobot checkpoints: an env's observation key renamed to the policy's, as lerobot-eval's "
        "--rename_map, e.g. observation.images.image=observation.images.camera1; repeat for several",
        key_values=True, metavar="KEY=VALUE")
    policy_override: dict | None = option(
        None, "LeRobot checkpoints: a setting of its config.json changed for this run, as lerobot-eval's "
        "--policy.KEY=VALUE: n_action_steps=N (actions executed per call)", key_values=True,
        metavar="KEY=VALUE")
    env_option: dict | None = option(
        None, "LeRobot's LIBERO tasks: a setting of the env's LeRobot config, as lerobot-eval's "
        "--env.KEY=VALUE: control_mode=relative|absolute, observation_height=N, observation_width=N (the "
        "cameras' size, 360 by default); repeat for several", key_values=True, metavar="KEY=VALUE")

    def policy_settings(self) -> dict:
        """The given ones, as `load_policy` takes them (rename_map, overrides)."""
        given = {"rename_map": self.rename_map, "overrides": self.policy_override}
        return {key: value for key, value in given.items() if value}


@dataclass(frozen=True, kw_only=True)
class EngineOptions(PolicySettings):
    """Where and how episodes run, and how a LeRobot checkpoint runs (PolicySettings). An option that
    changes no result is declared so (`changes_results=False`): a run's store does not hold it, so a
    rerun may change it and resume."""

    workers: int = option(2, "worker processes (results do not depend on it)", changes_results=False)
    backend: str = option("local", "where episodes run: local processes, or Ray actors (results do not "
                          "depend on it)", changes_results=False, choices=("local", "ray"))
    address: str | None = option(None, "Ray cluster address, e.g. ray://head:10001 (default: start a "
                                 "local Ray instance)", changes_results=False)
    max_nonfinite: float = option(MAX_NONFINITE, "an episode whose policy call returns NaN or infinite "
                                  "actions ends as a failure of its arm; stop (the policy or its adapter "
                                  "broken) only when more than this fraction of the held-out episodes of "
                                  "both the base and the zero ticket end so", changes_results=False)
    device: str = option("cpu", "where a LeRobot checkpoint's model runs: cpu, or cuda / cuda:N (there the "
                         "numbers hold for the same GPU model, driver and versions; workers share one model)")
    step_timeout: float = option(STEP_TIMEOUT, "seconds one env reset or step, or one policy call, may run "
                                 "before the run stops in one line naming it (finished episodes are kept: a "
                                 "rerun resumes); 0: no limit", changes_results=False, metavar="SECONDS")

    def check(self) -> None:  # workers: the engine knows this machine's limit (rollout.Engine)
        check_max_nonfinite(self.max_nonfinite)
        check_device(self.device)
        if not 0 <= self.step_timeout < float("inf"):
            raise OptionError(f"step_timeout must be a number of seconds >= 0 (0: no limit), got "
                              f"{self.step_timeout}", "step_timeout")


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
    method: str = option("portfolio", "random search, CEM, zeroth-order search, CEM raced by halving "
                         "(cem-racing) or by confidence bounds (cem-bounds), CMA-ES, CMA-ES over a tiled "
                         "then the full ticket (tiled-then-full), or a tiled and a full CMA-ES sharing "
                         "the budget by which finds the better tickets (portfolio)",
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
    subspace: str | None = option(None, "what the search varies: tiled (one action-sized vector repeated "
                                  "over the horizon), full (every entry), channels:I,J (those action "
                                  "channels; the others 0) (default: full for portfolio and "
                                  "tiled-then-full, which tile tickets themselves; tiled for the others)")
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
        "repeat or comma-separate for both. --out/log.csv is always written", changes_results=False,
        action="append", metavar="SINK")
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
        if self.subspace is None:
            object.__setattr__(self, "subspace", "full" if self.method in OWN_TILING else "tiled")

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
        if self.method in OWN_TILING and self.subspace != "full":
            raise OptionError(f"{self.method} searches tiled and full tickets itself: run it with subspace "
                              "full", "method", "subspace")
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
        check_judged_seeds(self.seed, self.seeds)
        if not 0 <= self.epsilon <= 1 or (self.epsilon and not self.mixture):
            raise OptionError(f"epsilon must be in [0, 1] and comes with mixture, got {self.epsilon}",
                              "epsilon", "mixture")


@dataclass(frozen=True)
class CompareConfig(EngineOptions):
    """Policy A against policy B (another policy, or the same one with or without a ticket) on the
    same held-out seeds: a paired A/B test."""

    policy: str | object = option(help="policy A: " + POLICY_HELP)
    against: str | object = option(help="policy B, run on the same held-out seeds as policy A (a bundled "
                                   "name, folder or import string, as for policy; the same one to compare "
                                   "it with and without a ticket)")
    task: str | Callable | None = option(None, TASK_HELP + " (default: the task the tickets were found on, "
                                         "else the one the bundled policies were trained on, where they "
                                         "name one)")
    ticket: str | Path | None = option(None, "a ticket file or bundled ticket id policy A runs with "
                                       "(default: none, fresh Gaussian noise)")
    against_ticket: str | Path | None = option(None, "a ticket file or bundled ticket id policy B runs "
                                               "with (default: none, fresh Gaussian noise)")
    seeds: Sequence[int] = option(range(1_000_000, 1_000_200), "held-out seed range A:B, A included, B "
                                  "not: each seed is one initial state both policies start from",
                                  seed_range=True)
    seed: int = option(0, "seed of the Gaussian noise of an arm without a ticket (the same noise for A "
                       "and B)")
    max_steps: int | None = option(None, "episode step limit (default: the tickets' own, else the task's)")
    success: str | Callable | None = option(None, SUCCESS_HELP.replace("(default: ", "(default: the "
                                                                       "tickets' own, else "))
    allow_transfer: bool = option(False, "run a ticket found for another policy or task, or under another "
                                  "max_steps or success", action="store_true")

    def __post_init__(self):
        for name in ("ticket", "against_ticket"):
            if isinstance(getattr(self, name), Path):
                object.__setattr__(self, name, str(getattr(self, name)))

    def check(self) -> None:
        super().check()
        check_judged_seeds(self.seed, self.seeds)


def check_judged_seeds(seed: int, seeds: Sequence[int]) -> None:
    """An evaluation's noise seed (>= 0) and its seeds (held-out ones, in the seed sets)."""
    if seed < 0:
        raise OptionError(f"seed must be >= 0, got {seed}", "seed")
    check_seeds(seeds)
    require_heldout(seeds)


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """A policy trained on imperfect scripted-expert demonstrations, and its model card."""

    task: str = option(help="built-in Meta-World task, e.g. metaworld/reach-v3 (metaworld-pixels/...: a "
                       "policy that sees camera frames), or a robomimic task (robomimic/lift, can, "
                       "square, transport)")
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
class CheckConfig(PolicySettings):
    """A policy and a task looked at before any search (`goldenticket check`): the checks the job runs
    (`goldenticket.checks`), each printed with what it saw."""

    policy: str | object = option(help=POLICY_HELP)
    task: str | Callable = option(help=TASK_HELP + " (default: the task a bundled single-task policy was "
                                  "trained on)")
    success: str | Callable | None = option(None, SUCCESS_HELP)
    device: str = option("cpu", "where a LeRobot checkpoint's model runs: cpu, or cuda / cuda:N")

    def check(self) -> None:
        check_device(self.device)


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
