"""Policies by name: a bundled policy (`zoo`), a folder (goldenticket's own, LeRobot's or DPPO's),
a Hugging Face Hub repo id (its snapshot), an import string or a NoisePolicy object; tickets fitted to
them and deployed."""

from __future__ import annotations

import dataclasses
import hashlib
import math
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.factories import build, call_users, import_name, is_import_string
from goldenticket.policies import dppo, lerobot
from goldenticket.policies.base import NoisePolicy, TicketedPolicy
from goldenticket.policies.mlp import MLPPolicy
from goldenticket.tickets import MAX_VALUES, Ticket
from goldenticket.zoo import (  # noqa: F401  (re-exported: the package's names)
    BUNDLED_DIR,
    bundled,
    bundled_task,
    bundled_tickets,
    find_ticket,
    hub_snapshot,
    is_hub_id,
    policy_names,
    split_steps,
)


def load_policy(name: str | NoisePolicy, device: str = "cpu", rename_map: dict | None = None,
                overrides: dict | None = None) -> NoisePolicy:
    """A bundled policy by name, a policy directory (config.json + model.safetensors), a LeRobot
    checkpoint folder or the Hugging Face Hub repo id of one (`lerobot/smolvla_libero`), or a DPPO
    checkpoint (a folder with a `.pt`, or the `.pt`), where an `@N` suffix sets the number of
    denoising steps, any NoisePolicy built by an import string `package.module:factory`, or a
    NoisePolicy object itself (checked). `device` places a LeRobot checkpoint's model, `rename_map`
    renames its env's observation keys and `overrides` change settings of its config, as
    `lerobot-eval` takes them; every other policy runs where it runs (the bundled ones on the CPU,
    where their numbers are the same on every machine)."""
    base, steps = split_steps(name) if isinstance(name, str) else (None, None)
    path = policy_folder(base) if isinstance(name, str) and not is_import_string(name) else None
    if path is not None and lerobot.is_checkpoint(path):
        return lerobot.load(path, steps, name, device, rename_map, overrides)
    if rename_map or overrides:
        raise UserError(f"rename_map and policy_override are for LeRobot checkpoints; policy "
                        f"{policy_label(name)!r} is not one")
    if device != "cpu":
        raise UserError(f"device {device}: only LeRobot checkpoints run on a chosen device; policy "
                        f"{policy_label(name)!r} runs where it runs (bundled policies: on the CPU)")
    if not isinstance(name, str):
        return _checked(name, policy_label(name))
    if is_import_string(name):
        return _checked(build(name, "policy"), name)
    if dppo.is_checkpoint(path):
        return dppo.load(path, steps, name)
    if not (path / "config.json").is_file():
        path = bundled(base)
    policy = MLPPolicy.load(path)
    if steps is None:
        return policy
    return MLPPolicy(dataclasses.replace(policy.cfg, name=name, steps=steps), policy.model)


def policy_folder(base: str) -> Path:
    """What a policy name (without `@N`) names on disk: a path here, else a Hub repo's snapshot, else
    the name as a path (a bundled policy's name)."""
    return hub_snapshot(base) if is_hub_id(base) else Path(base)


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
