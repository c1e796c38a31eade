"""Bundled policies, named like `metaworld/pick-place-v3/flow`, shipped inside the package.

A policy name may end in `@N` to run with N denoising steps instead of the trained default,
e.g. `metaworld/pick-place-v3/ddim@2`; the weights are the same, only inference changes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.factories import build, call_users, import_name, is_import_string
from goldenticket.policies import dppo, lerobot
from goldenticket.policies.base import NoisePolicy, TicketedPolicy
from goldenticket.policies.mlp import MLPPolicy
from goldenticket.tickets import MAX_VALUES, Ticket

BUNDLED_DIR = Path(__file__).parent / "bundled"


def policy_names() -> list[str]:
    """The bundled policies' names; a hidden folder (a policy being built) is none."""
    names = (cfg.parent.relative_to(BUNDLED_DIR) for cfg in BUNDLED_DIR.rglob("config.json"))
    return sorted(str(name) for name in names if not any(part.startswith(".") for part in name.parts))


def bundled_tickets() -> list[Path]:
    """Golden tickets shipped beside the bundled policies (`<policy>/tickets/<id>.safetensors`)."""
    return sorted(BUNDLED_DIR.rglob("tickets/*.safetensors"))


def find_ticket(ref: str) -> Path:
    """A ticket file path, or the id of a bundled ticket (as `goldenticket tickets list` shows)."""
    path = Path(ref)
    if path.is_file():
        return path
    matches = [p for p in bundled_tickets() if p.stem == ref]
    if not matches:
        raise UserError(f"{ref}: no such ticket file or bundled ticket id (see `goldenticket tickets list`)")
    if len(matches) > 1:
        raise UserError(f"ticket id {ref} is ambiguous; name one file: "
                        + ", ".join(str(p) for p in matches))
    return matches[0]


def split_steps(name: str) -> tuple[str, int | None]:
    """`"a/b/ddim@2"` -> `("a/b/ddim", 2)`; a name without `@N` -> `(name, None)`."""
    base, at, steps = name.rpartition("@")
    if not at:
        return name, None
    if not steps.isdigit() or int(steps) < 1:
        raise UserError(f"policy {name!r}: the part after '@' must be a step count >= 1")
    return base, int(steps)


def load_policy(name: str | NoisePolicy, device: str = "cpu") -> NoisePolicy:
    """A bundled policy by name, a policy directory (config.json + model.safetensors), a LeRobot
    checkpoint folder or a DPPO checkpoint (a folder with a `.pt`, or the `.pt`), where an `@N` suffix
    sets the number of denoising steps, any NoisePolicy
    built by an import string `package.module:factory`, or a NoisePolicy object itself (checked).
    `device` places a LeRobot checkpoint's model; every other policy runs where it runs (the
    bundled ones on the CPU, where their numbers are the same on every machine)."""
    base, steps = split_steps(name) if isinstance(name, str) else (None, None)
    if isinstance(name, str) and not is_import_string(name) and lerobot.is_checkpoint(Path(base)):
        return lerobot.load(Path(base), steps, name, device)
    if device != "cpu":
        raise UserError(f"device {device}: only LeRobot checkpoints run on a chosen device; policy "
                        f"{policy_label(name)!r} runs where it runs (bundled policies: on the CPU)")
    if not isinstance(name, str):
        return _checked(name, policy_label(name))
    if is_import_string(name):
        return _checked(build(name, "policy"), name)
    path = Path(base)
    if dppo.is_checkpoint(path):
        return dppo.load(path, steps, name)
    if not (path / "config.json").is_file():
        path = _bundled(base)
    policy = MLPPolicy.load(path)
    if steps is None:
        return policy
    return MLPPolicy(dataclasses.replace(policy.cfg, name=name, steps=steps), policy.model)


def bundled_task(name: str) -> str | None:
    """The task a bundled single-task policy was trained on, the folder its name lies in
    (`metaworld/pick-place-v3/flow@2` -> `metaworld/pick-place-v3`); None for a multi-task one and for
    any other policy (an import string, a folder, a LeRobot or DPPO checkpoint); UserError for an unknown
    name."""
    if is_import_string(name):
        return None
    base, _ = split_steps(name)
    path = Path(base)
    if lerobot.is_checkpoint(path) or dppo.is_checkpoint(path) or (path / "config.json").is_file():
        return None
    if json.loads((_bundled(base) / "config.json").read_text()).get("tasks"):
        return None
    return base.rpartition("/")[0]


def _bundled(base: str) -> Path:
    """A bundled policy's folder; UserError naming an unknown one."""
    if base not in policy_names():
        raise UserError(f"unknown policy {base!r}; run `goldenticket policies` to list them")
    return BUNDLED_DIR / base


def for_task(policy: NoisePolicy, task) -> NoisePolicy:
    """The policy acting on `task` (a Task, or a task name): a language policy (one with
    `instructed(text)`) given the task's `instruction`, a multi-task policy (one with `tasks` and
    `conditioned(name)`) conditioned on its name; any other policy as it is."""
    name = task if isinstance(task, str) else task.name
    if callable(getattr(policy, "instructed", None)):
        instruction = getattr(task, "instruction", None)
        if not instruction:
            raise UserError(f"policy {policy_label(policy)!r} reads a language instruction, and task "
                            f"{name!r} gives none (a task's instruction: docs/contracts.md)")
        return policy.instructed(instruction)
    if not (getattr(policy, "tasks", None) and callable(getattr(policy, "conditioned", None))):
        return policy
    return policy.conditioned(name)


def _checked(policy, name: str) -> NoisePolicy:
    """The object if it looks like a NoisePolicy, else a one-line UserError saying what is off."""
    shape = getattr(policy, "noise_shape", None)
    if not (isinstance(shape, tuple | list) and len(shape) == 2
            and all(isinstance(d, int) and not isinstance(d, bool) and d >= 1 for d in shape)):
        raise UserError(f"policy {name!r}: noise_shape must be (H, A) with H, A >= 1, got {shape!r}")
    if math.prod(shape) > MAX_VALUES:
        raise UserError(f"policy {name!r}: noise_shape {tuple(shape)} holds more than the {MAX_VALUES} "
                        "values a ticket may have")
    if not (isinstance(getattr(policy, "n_exec", None), int) and policy.n_exec >= 1):
        raise UserError(f"policy {name!r}: n_exec must be an integer >= 1")
    if not callable(getattr(policy, "act", None)):
        raise UserError(f"policy {name!r}: needs act(obs, noise[B, H, A]) -> actions[B, n_exec, A]")
    return policy


def policy_label(policy: str | NoisePolicy) -> str:
    """How runs, tickets and tables name a policy: its name string, or an object's `name`
    attribute, else the import name of its class."""
    if isinstance(policy, str):
        return policy
    return getattr(policy, "name", None) or import_name(policy)


def fingerprint(policy: NoisePolicy, label: str) -> str:
    """What a ticket is found for: the policy's own `fingerprint()` (bundled policies: weights hash
    and step count) or, for a policy that has none, a hash of its label."""
    if not callable(getattr(policy, "fingerprint", None)):
        return "name-" + hashlib.sha256(label.encode()).hexdigest()[:16]
    value = call_users(policy.fingerprint, f"policy {label!r}: fingerprint()")
    if not isinstance(value, str):
        raise UserError(f"policy {label!r}: fingerprint() must return a string, got {type(value).__name__}")
    return value


def identity(policy: NoisePolicy) -> str:
    """What a ticket is found for, the same however the policy object was reached (a bundled
    name, a folder, an import string or the object itself): its `fingerprint()` where it has
    one, else a hash of its `name`, else of its class's import name `module:Class`."""
    return fingerprint(policy, policy_label(policy))


def deploy(policy: str | NoisePolicy, ticket: str | Path, task: str | None = None) -> TicketedPolicy:
    """`policy` (a name, folder, import string or object) acting with `ticket` (a file or a
    bundled ticket id), once the ticket is checked to have the policy's noise shape and to
    have been found for this policy (and for `task`, when given); one-line UserError if not."""
    policy = load_policy(policy)
    loaded = Ticket.load(find_ticket(str(ticket)), expected_shape=tuple(policy.noise_shape))
    loaded.check_fits(identity(policy), task, str(ticket))
    return TicketedPolicy(policy, loaded.noise)
