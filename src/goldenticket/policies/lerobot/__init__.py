"""LeRobot checkpoints as NoisePolicies: the folder `lerobot-train` writes under
`checkpoints/*/pretrained_model` (config.json, model.safetensors, policy_preprocessor*.json,
policy_postprocessor*.json and their state files), for LeRobot 0.6.1's diffusion (DDIM), SmolVLA,
pi0 and pi0.5 policies.

Observations go to the model as in LeRobot's own eval (`lerobot-eval`): its
`preprocess_observation`, the task's instruction as "task", then the saved preprocessor pipeline;
actions come back through the saved postprocessor. A ticket is the model's initial noise
(`diffusion.py`, `vla.py`); each call executes `n_action_steps` actions. On the CPU the model runs
as LeRobot runs it, in float32, on fixed blocks of BLOCK rows on one torch thread: each row's
actions are bitwise those LeRobot's own call gives for it in a batch of BLOCK envs, and do not
depend on the other rows. `with_ticket` (`loops.py`) runs a ticket inside LeRobot's own loops.
LeRobot is imported only when such a folder is loaded.
"""

from __future__ import annotations

from pathlib import Path

from goldenticket.policies.lerobot.checkpoint import LeRobotPolicy, checked_config, is_checkpoint
from goldenticket.policies.lerobot.diffusion import DiffusionPolicyAdapter
from goldenticket.policies.lerobot.loops import with_ticket
from goldenticket.policies.lerobot.vla import VLAPolicy

__all__ = ["LeRobotPolicy", "checked_config", "is_checkpoint", "load", "with_ticket"]


def load(path: str | Path, steps: int | None = None, name: str | None = None, device: str = "cpu",
         rename_map: dict | None = None, overrides: dict | None = None) -> LeRobotPolicy:
    """The adapter for the folder's policy type, loaded on `device` with `rename_map` and config
    `overrides` (LeRobotPolicy); one-line UserError for a folder no ticket can steer."""
    kind = checked_config(Path(path))["type"]
    adapter = DiffusionPolicyAdapter if kind == "diffusion" else VLAPolicy
    return adapter(path, steps, name, device, rename_map, overrides)
