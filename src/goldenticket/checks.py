"""Named checks of a policy and a task, run before any episode counts, as Gymnasium's env checker
(`gymnasium.utils.env_checker`) runs its own: each check is a short function that returns one line
saying what it saw, or raises a one-line UserError saying what is wrong.

Every task kind gets the same checks on the same seeds (`CHECK_SEEDS`: a search seed and a held-out
one), in this process and in a fresh one (the way workers rebuild the task); a policy's checks act
once on those seeds' initial observations. First of all, where the task declares its observations
(`observation_shapes`) and the policy checks them (`check_observations`: LeRobot's), the policy
reads them, building no env: a mismatch answers in seconds. `results` yields each check's `Result`
(the `goldenticket check` command prints them); `require` raises the first failure (the job runs
every check before any episode, `evaluate` the task's and the first).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from goldenticket.errors import UserError
from goldenticket.factories import call_users, in_another_process, picklable
from goldenticket.policies import NoisePolicy, for_task, policy_label
from goldenticket.rollout import checked_actions, observed
from goldenticket.seeds import SEED_SETS
from goldenticket.tasks.base import FIRST_ENV, Env, Episode, Task, episodes, stack, trace

CHECK_SEEDS = (SEED_SETS["search"].start, SEED_SETS["heldout"].start)  # a search seed and a held-out one
CHECK_STEPS = 3  # fixed actions after each check seed's reset
NOISE_DRAWS = 4  # noise arrays the policy acts under, on each check seed's initial observation
ANOTHER_PROCESS = "in another process"
PLACES = "in one env, in another process, and again in the same env and in a new env"  # what repeats


@dataclass(frozen=True)
class Result:
    """One check's outcome: its name, whether it passed, and one line saying what it saw."""

    name: str
    passed: bool
    detail: str
    error: UserError | None = field(default=None, repr=False, compare=False)  # a failure, to re-raise

    def __str__(self) -> str:
        return f"{'pass' if self.passed else 'FAIL'}  {self.name}: {self.detail}"


@dataclass
class Subject:
    """What the checks look at: a task and, for the policy's checks, the policy acting on it; what
    several checks read is computed once."""

    task: Task
    policy: NoisePolicy | None = None

    @cached_property
    def env(self) -> Env:
        """The env the policy acts in and the task's trace starts in (one env fewer to build)."""
        return self.task.make_env()

    @cached_property
    def here(self) -> dict[str, list[Episode]]:
        return trace(self.task, CHECK_SEEDS, CHECK_STEPS, self.env)

    @cached_property
    def there(self) -> list[Episode]:
        return episodes_in_another_process(self.task)

    @cached_property
    def acted(self) -> tuple[np.ndarray, int | None]:
        """The policy's actions [check seeds, NOISE_DRAWS, n_exec, A] on each check seed's initial
        observation under NOISE_DRAWS Gaussian noise arrays, and the task's action size (None where
        it names none)."""
        policy, task, env = for_task(self.policy, self.task), self.task, self.env
        history = getattr(policy, "n_obs_steps", 1)  # as rollout feeds it
        initial = [call_users(env.reset, f"task {task.name!r}: reset()", seed) for seed in CHECK_SEEDS]
        seen = [observed(deque([obs] * history, maxlen=history)) for obs in initial]
        rows = [obs for obs in seen for _ in range(NOISE_DRAWS)]
        noise = np.random.default_rng(0).standard_normal((len(rows), *policy.noise_shape)).astype(np.float32)
        actions = call_users(policy.act, f"policy {policy_label(policy)!r}: act()", stack(rows), noise)
        actions = checked_actions(policy, actions, len(rows))
        return actions.reshape(len(CHECK_SEEDS), NOISE_DRAWS, *actions.shape[1:]), action_size(task, env)


def the_policy_reads_the_task_observations(subject: Subject) -> str:
    """The observations the task declares (`observation_shapes`) are what the policy reads
    (`check_observations`), before any env is built."""
    shapes = subject.task.observation_shapes
    subject.policy.check_observations(shapes)
    return (f"policy {policy_label(subject.policy)!r} reads the observations task {subject.task.name!r} "
            f"declares: {', '.join(shapes)}")


def policy_and_task_agree(subject: Subject) -> str:
    """The policy acts on the task's initial observations (its own checks of their size and keys,
    the job's conditioning on the task) with actions of the contract's shape, as many numbers as
    the task takes."""
    actions, size = subject.acted
    label, task = policy_label(subject.policy), subject.task.name
    if size is not None and actions.shape[-1] != size:
        raise UserError(f"policy {label!r} acts with {actions.shape[-1]} numbers and task {task!r} takes "
                        f"{size}: the policy was made for another task")
    n_exec, width = actions.shape[2:]
    return f"policy {label!r} acts on the observations of task {task!r}: {n_exec} actions of {width} numbers"


def the_policy_answers_its_noise(subject: Subject) -> str:
    """Different noise arrays give different actions for one observation: a policy that ignores its
    noise has no golden tickets (no ticket changes what it does)."""
    actions, _ = subject.acted
    label = policy_label(subject.policy)
    if all(all(np.array_equal(drawn[0], other) for other in drawn[1:]) for drawn in actions):
        raise UserError(f"policy {label!r} ignores its noise: {NOISE_DRAWS} different noise arrays gave the "
                        f"same actions on each initial observation of task {subject.task.name!r} checked, so "
                        "no ticket can change what it does (it has no golden tickets)")
    return f"{NOISE_DRAWS} different noise arrays give different actions on one observation"


def seeds_fix_initial_states(subject: Subject) -> str:
    """reset(seed) gives the same initial observation for the same seed (Gymnasium's
    check_reset_seed_determinism): in one env, in it again after other episodes, in a new env and
    in another process."""
    seed, place, keys = _difference(subject, lambda episode: episode[:1])
    if seed is not None:
        raise UserError(f"task {subject.task.name!r}: reset(seed={seed}) does not fix the initial state (the "
                        f"same seed gave a different observation {place}{keys}); seed every random draw of "
                        "reset from its seed")
    return f"seeds {CHECK_SEEDS[0]} and {CHECK_SEEDS[1]}: the same initial observation {PLACES}"


def same_actions_same_episode(subject: Subject) -> str:
    """The same seed and the same fixed actions give the same observations at every step, wherever
    the episode runs."""
    seed, place, keys = _difference(subject, lambda episode: episode)
    if seed is not None:
        raise UserError(f"task {subject.task.name!r}: the same seed ({seed}) and actions gave different "
                        f"observations {place}{keys}; its episodes are not repeatable on this machine")
    return (f"seeds {CHECK_SEEDS[0]} and {CHECK_SEEDS[1]} through {CHECK_STEPS} fixed actions: the same "
            f"observations {PLACES}")


# by name, in the order they run: the one that builds no env, then the policy's (cheap, and what a
# mistake most often breaks), then the task's
DECLARED_CHECKS: dict[str, Callable[[Subject], str]] = {
    "the policy reads the task's observations": the_policy_reads_the_task_observations,
}
POLICY_CHECKS: dict[str, Callable[[Subject], str]] = {
    "policy and task agree": policy_and_task_agree,
    "the policy answers its noise": the_policy_answers_its_noise,
}
TASK_CHECKS: dict[str, Callable[[Subject], str]] = {
    "seeds fix initial states": seeds_fix_initial_states,
    "same actions, same episode": same_actions_same_episode,
}


def results(task, policy: NoisePolicy | None = None, acting: bool = True) -> Iterator[Result]:
    """Each check's Result as it runs: with a policy, the declared observations' (where the task and
    the policy declare them) and, `acting`, the policy's checks on `task`; then the task's."""
    note = getattr(task, "note", None)  # what this machine changes in a task's numbers, said once
    if callable(note):
        note()
    subject = Subject(task, policy)
    declared = (policy is not None and callable(getattr(policy, "check_observations", None))
                and getattr(type(task), "observation_shapes", None) is not None)
    checks = ((DECLARED_CHECKS if declared else {}) | (POLICY_CHECKS if policy is not None and acting else {})
              | TASK_CHECKS)
    for name, check in checks.items():
        try:
            yield Result(name, True, check(subject))
        except UserError as exc:
            yield Result(name, False, str(exc), exc)


def require(task, policy: NoisePolicy | None = None, acting: bool = True) -> None:
    """The first failing check's UserError, before any episode counts (`results`' arguments)."""
    for result in results(task, policy, acting):
        if result.error is not None:
            raise result.error


def episodes_in_another_process(task) -> list[Episode]:
    """The check seeds' `episodes` in one env of a fresh process, once per task (as pickled) in this
    process: a fresh process starts from nothing, so it sees the same each time (the job on each of
    several tasks, or an evaluation after a search, reuse it)."""
    what = f"task {task.name!r}"
    sent = picklable(task, what)
    if sent not in _elsewhere:
        _elsewhere[sent] = in_another_process(episodes, task, CHECK_SEEDS, CHECK_STEPS, what=what)
    return _elsewhere[sent]


_elsewhere: dict[bytes, list[Episode]] = {}  # the check seeds' episodes in a fresh process, by task pickled


def action_size(task, env) -> int | None:
    """How many numbers an action of the task holds: its `action_dim`, else its env's action space's
    (a flat Box), else None."""
    size = getattr(task, "action_dim", None)
    shape = getattr(getattr(env, "action_space", None), "shape", None)
    return size if size is not None else shape[0] if shape is not None and len(shape) == 1 else None


def _difference(subject: Subject, part: Callable[[Episode], Episode]) -> tuple[int | None, str, str]:
    """The first seed, place and differing keys where `part` of an episode differs from the first
    env's: this process's places first, the other process only where they all agree."""
    reference = subject.here[FIRST_ENV]
    for places in (lambda: subject.here, lambda: {ANOTHER_PROCESS: subject.there}):
        for place, ran in places().items():
            for seed, ours, theirs in zip(CHECK_SEEDS, reference, ran, strict=False):  # ran: a prefix
                if part(ours) != part(theirs):
                    return seed, place, _keys(part(ours), part(theirs))
    return None, "", ""


def _keys(ours: Episode, theirs: Episode) -> str:
    """`: its 'pixels' differ`, naming the observation keys that differ where observations have keys."""
    keys = sorted({key for a, b in zip(ours, theirs, strict=False) for key in a.keys() | b.keys()
                   if key and a.get(key) != b.get(key)})
    return f": its {', '.join(map(repr, keys))} differ" if keys else ""
