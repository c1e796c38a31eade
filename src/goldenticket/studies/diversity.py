"""How much a noise source varies what the robot does from one initial state.

Each arm runs `repeats` episodes from each of `seeds`, with a different noise stream per repeat
(`reseed(r)`). Spread: the RMS distance of each repeat's executed action sequence from the
repeats' mean sequence (sequences padded with zero actions after they end), averaged over the
initial states. A constant ticket on a deterministic policy and env spreads 0; Gaussian noise
(the base policy) spreads most; a mixture of tickets lies between.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from goldenticket.noise import NoiseSource
from goldenticket.policies import NoisePolicy
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import Task


def action_spread(policy: NoisePolicy, task: Task, reseed: Callable[[int], NoiseSource],
                  seeds: Sequence[int], repeats: int = 5) -> float:
    """Mean over `seeds` of the RMS spread of executed actions across `repeats` noise streams."""
    episodes = [Episode(reseed(r), seed) for seed in seeds for r in range(repeats)]
    results = rollout(policy, task, episodes, record_actions=True)
    spreads = []
    for i in range(len(seeds)):
        runs = [r.actions for r in results[i * repeats:(i + 1) * repeats]]
        padded = np.zeros((repeats, max(len(a) for a in runs), runs[0].shape[1]))
        for r, actions in enumerate(runs):
            padded[r, :len(actions)] = actions
        spreads.append(float(np.sqrt(np.mean(np.sum((padded - padded.mean(axis=0)) ** 2, axis=2)))))
    return float(np.mean(spreads))
