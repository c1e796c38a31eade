"""DSRL-NA (DSRL with noise aliasing) as a subclass of stable-baselines3's SAC, no fork.

SAC's actor still chooses the noise w for each observation s, but its critic Q^W(s, w) learns no
TD backup. A second critic Q^A(s, a) learns by TD over the action chunks a the frozen policy
executed, and Q^W is distilled from it, Q^W(s, w) ~ min Q^A(s, pi(s, w)), on noises w drawn from
the policy's own N(0, I) (clipped to the actor's range). Noises that the policy maps to the same
chunk (aliases) thus share whatever any of them taught Q^A. From Wagenmaker et al., "Steering
Your Diffusion Policy with Latent Space Reinforcement Learning" (arXiv 2506.15799).

The environment's `info["chunk"]` holds the chunk each step's noise made (flattened; its actions
run until the episode ends); `chunk_of(obs, actions)` maps the actor's actions (noise over its
magnitude, in [-1, 1]) to the policy's chunks.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F


class ChunkReplayBuffer(ReplayBuffer):
    """SB3's replay buffer that also keeps each transition's executed chunk (`info["chunk"]`);
    `sample` returns (SB3's samples, their chunks). One environment only."""

    def __init__(self, *args, chunk_dim: int, **kwargs):
        super().__init__(*args, **kwargs)
        if self.n_envs != 1:
            raise ValueError(f"ChunkReplayBuffer holds one environment's transitions, got {self.n_envs}")
        self.chunks = np.zeros((self.buffer_size, chunk_dim), np.float32)

    def add(self, obs, next_obs, action, reward, done, infos) -> None:
        self.chunks[self.pos] = infos[0]["chunk"]
        super().add(obs, next_obs, action, reward, done, infos)

    def _get_samples(self, batch_inds: np.ndarray, env=None):
        return super()._get_samples(batch_inds, env), self.to_torch(self.chunks[batch_inds])


class NoiseAliasingSAC(SAC):
    """DSRL-NA: SAC in the noise space whose critic is distilled from an action-space critic.

    Per gradient step: the entropy coefficient, Q^A's TD step, every `distill_every`-th step one
    distillation step of Q^W, then the actor against Q^W. `noise_magnitude` scales the actor's
    [-1, 1] to the noise the policy receives; `chunk_dim` is the flattened chunk's size.
    """

    def __init__(self, policy, env, *, chunk_of: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                 chunk_dim: int = 0, noise_magnitude: float = 1.5, distill_every: int = 2, **kwargs):
        self.chunk_of, self.chunk_dim = chunk_of, chunk_dim
        self.noise_magnitude, self.distill_every = noise_magnitude, distill_every
        super().__init__(policy, env, replay_buffer_class=ChunkReplayBuffer,
                         replay_buffer_kwargs={"chunk_dim": chunk_dim}, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        chunks = spaces.Box(-np.inf, np.inf, (self.chunk_dim,), np.float32)
        kwargs = self.policy.critic_kwargs | {"action_space": chunks}
        self.action_critic, self.action_critic_target = (
            ContinuousCritic(**self.policy._update_features_extractor(kwargs)).to(self.device)
            for _ in range(2))
        self.action_critic_target.load_state_dict(self.action_critic.state_dict())
        self.action_critic_target.set_training_mode(False)
        self.action_critic.optimizer = self.policy.optimizer_class(
            self.action_critic.parameters(), lr=self.lr_schedule(1), **self.policy.optimizer_kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "chunk_of", "action_critic", "action_critic_target"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "action_critic", "action_critic_target", "action_critic.optimizer"], variables

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self.policy.set_training_mode(True)
        self.action_critic.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer, self.action_critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        self._update_learning_rate(optimizers)
        for step in range(gradient_steps):
            data, chunks = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            noise, log_prob = self.actor.action_log_prob(data.observations)
            ent_coef = self._tune_entropy(log_prob.reshape(-1, 1))
            self._step(self.action_critic, self._action_critic_loss(data, chunks, ent_coef))
            if step % self.distill_every == 0:
                self._step(self.critic, self._distillation_loss(data.observations))
            q = _min_q(self.critic, data.observations, noise)
            self._step(self.actor, (ent_coef * log_prob.reshape(-1, 1) - q).mean())
            polyak_update(self.action_critic.parameters(), self.action_critic_target.parameters(), self.tau)
        self._n_updates += gradient_steps

    @staticmethod
    def _step(net, loss: th.Tensor) -> None:
        net.optimizer.zero_grad()
        loss.backward()
        net.optimizer.step()

    def _tune_entropy(self, log_prob: th.Tensor) -> th.Tensor:
        """The entropy coefficient for this step, after one step of its own tuning (as SAC's)."""
        if self.ent_coef_optimizer is None:
            return self.ent_coef_tensor
        ent_coef = th.exp(self.log_ent_coef.detach())
        loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
        self.ent_coef_optimizer.zero_grad()
        loss.backward()
        self.ent_coef_optimizer.step()
        return ent_coef

    def _chunks(self, obs: th.Tensor, noise: th.Tensor) -> th.Tensor:
        return th.as_tensor(self.chunk_of(obs.cpu().numpy(), noise.cpu().numpy()), device=self.device)

    def _action_critic_loss(self, data, chunks: th.Tensor, ent_coef: th.Tensor) -> th.Tensor:
        """Q^A's soft TD loss on the executed chunks; the next chunk is the policy's from the actor's
        noise."""
        with th.no_grad():
            next_obs = data.next_observations
            noise, log_prob = self.actor.action_log_prob(next_obs)
            q = _min_q(self.action_critic_target, next_obs, self._chunks(next_obs, noise))
            target = data.rewards + (1 - data.dones) * self.gamma * (q - ent_coef * log_prob.reshape(-1, 1))
        return 0.5 * sum(F.mse_loss(q, target) for q in self.action_critic(data.observations, chunks))

    def _distillation_loss(self, obs: th.Tensor) -> th.Tensor:
        """Q^W's loss against min Q^A of the chunks the policy makes from N(0, I) noises."""
        with th.no_grad():
            shape = (len(obs), *self.action_space.shape)
            noise = (th.randn(shape, device=self.device) / self.noise_magnitude).clamp(-1, 1)
            target = _min_q(self.action_critic, obs, self._chunks(obs, noise))
        return 0.5 * sum(F.mse_loss(q, target) for q in self.critic(obs, noise))


def _min_q(critic: ContinuousCritic, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """The smallest of the critic's Q-values, [B, 1]."""
    return th.cat(critic(obs, actions), dim=1).min(dim=1, keepdim=True).values
