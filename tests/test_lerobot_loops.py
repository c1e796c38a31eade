"""`with_ticket` (goldenticket.policies.lerobot.loops) on stand-ins for LeRobot's two kinds of policy:
one whose `select_action` takes `noise` (diffusion, SmolVLA) and one whose `select_action` calls
`predict_action_chunk` without it (pi0, pi0.5). LeRobot's own policies in its own loops:
tests/test_lerobot.py and tests/test_lerobot_vla.py."""

from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from goldenticket.errors import UserError
from goldenticket.policies.lerobot import with_ticket
from goldenticket.tickets import Ticket

CHUNK, DIM, ACTIONS = 4, 3, 2  # chunk_size, max_action_dim, n_action_steps


class Pi0Like:
    """select_action queues the first ACTIONS actions of predict_action_chunk(batch), whose noise is
    drawn inside unless passed; the action is the noise itself, so the test sees it."""

    config = SimpleNamespace(type="pi0", chunk_size=CHUNK, max_action_dim=DIM)

    def __init__(self):
        self.weights = torch.ones(1)
        self.reset()

    def reset(self):
        self._queue = deque()

    def select_action(self, batch: dict) -> torch.Tensor:
        if not self._queue:
            self._queue.extend(self.predict_action_chunk(batch)[:, :ACTIONS].transpose(0, 1))
        return self._queue.popleft()

    def predict_action_chunk(self, batch: dict, **kwargs) -> torch.Tensor:
        return self.sample_actions(len(batch["observation.state"]), **kwargs)

    def sample_actions(self, rows: int, noise=None) -> torch.Tensor:
        return torch.randn(rows, CHUNK, DIM) if noise is None else noise.clone()


class SmolVLALike(Pi0Like):
    """select_action takes the noise and hands it on."""

    config = SimpleNamespace(type="smolvla", chunk_size=CHUNK, max_action_dim=DIM)

    def select_action(self, batch: dict, noise=None) -> torch.Tensor:
        if not self._queue:
            chunk = self.sample_actions(len(batch["observation.state"]), noise)
            self._queue.extend(chunk[:, :ACTIONS].transpose(0, 1))
        return self._queue.popleft()


def ticket() -> np.ndarray:
    return np.arange(CHUNK * DIM, dtype=np.float32).reshape(CHUNK, DIM)


@pytest.mark.parametrize("kind", [Pi0Like, SmolVLALike])
def test_every_chunk_starts_from_the_ticket_on_every_row(kind):
    policy = with_ticket(kind(), Ticket(ticket()))
    batch = {"observation.state": torch.zeros(3, 5), "task": ["reach"] * 3}
    expected = np.broadcast_to(ticket()[[*range(ACTIONS), 0]], (3, ACTIONS + 1, DIM))  # 2 chunks' first rows
    for _ in range(2):  # episodes: reset() drops what the last one left queued
        policy.reset()
        actions = torch.stack([policy.select_action(batch) for _ in range(ACTIONS + 1)], dim=1)
        np.testing.assert_array_equal(actions.numpy(), expected)
    chunk = policy.predict_action_chunk(batch)  # as real-time chunking calls it
    np.testing.assert_array_equal(chunk.numpy(), np.broadcast_to(ticket(), (3, CHUNK, DIM)))


def test_the_policy_it_wraps_and_that_policys_class_are_left_as_they_were():
    policy = Pi0Like()
    ticketed = with_ticket(policy, ticket())
    assert isinstance(ticketed, Pi0Like) and ticketed.weights is policy.weights
    assert Pi0Like.predict_action_chunk is Pi0Like.__dict__["predict_action_chunk"]
    batch = {"observation.state": torch.zeros(1, 5)}
    ticketed.select_action(batch)
    assert not policy._queue and len(ticketed._queue) == ACTIONS - 1  # queues of its own
    torch.manual_seed(0)
    assert not torch.equal(policy.select_action(batch), torch.from_numpy(ticket()[0]))


@pytest.mark.parametrize(("config", "says"), [
    (SimpleNamespace(type="act"), "not this act policy"),
    (SimpleNamespace(type="diffusion", noise_scheduler_type="DDPM"), "diffusion under DDIM"),
    (Pi0Like.config, r"has shape \(4, 2\); this pi0 policy draws \(4, 3\)"),
])
def test_a_policy_or_ticket_that_does_not_fit_is_refused(config, says):
    policy = SimpleNamespace(config=config)
    with pytest.raises(UserError, match=says):
        with_ticket(policy, np.zeros((CHUNK, 2), np.float32))
