"""DPPO checkpoints (Ren et al., "Diffusion Policy Policy Optimization", arXiv:2409.00588) as policies.

The folders are built here in DPPO's own format: tensors named as DPPO's DiffusionMLP names them
(model/diffusion/mlp_diffusion.py, model/common/mlp.py), saved as its agents save them, beside configs
shaped as its robomimic configs and its normalization.npz. Actions are checked against a float64
numpy re-implementation of DPPO's network and DDIM sampling written from DPPO's code.
"""

import copy
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from goldenticket.cli import main
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import dppo, load_policy
from goldenticket.policies.registry import bundled_task
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task

OBS, ACT, H, T = 5, 2, 4, 20
RNG_SEED = 0

PRETRAIN = """\
defaults:
  - _self_
hydra:
  run:
    dir: ${logdir}
_target_: agent.pretrain.train_diffusion_agent.TrainDiffusionAgent

name: ${env}_pre_diffusion_mlp_ta${horizon_steps}_td${denoising_steps}
logdir: ${oc.env:DPPO_LOG_DIR}/robomimic-pretrain/${name}/${now:%Y-%m-%d}_${now:%H-%M-%S}_${seed}
train_dataset_path: ${oc.env:DPPO_DATA_DIR}/robomimic/${env}/train.npz

seed: 42
device: cuda:0
env: can
obs_dim: 5
action_dim: 2
denoising_steps: 20
horizon_steps: 4
cond_steps: 1

train:
  n_epochs: 3000
  batch_size: 256
  learning_rate: 1e-4

model:
  _target_: model.diffusion.diffusion.DiffusionModel
  predict_epsilon: True
  denoised_clip_value: 1.0
  network:
    _target_: model.diffusion.mlp_diffusion.DiffusionMLP
    time_dim: 16
    mlp_dims: [32, 32, 32]
    residual_style: True
    cond_dim: ${eval:'${obs_dim} * ${cond_steps}'}
    horizon_steps: ${horizon_steps}
    action_dim: ${action_dim}
  horizon_steps: ${horizon_steps}
  obs_dim: ${obs_dim}
  action_dim: ${action_dim}
  denoising_steps: ${denoising_steps}
  device: ${device}

ema:
  decay: 0.995
"""

EVAL = """\
_target_: agent.eval.eval_diffusion_agent.EvalDiffusionAgent
normalization_path: ${oc.env:DPPO_DATA_DIR}/robomimic/${env_name}/normalization.npz
env_name: can
obs_dim: 5
action_dim: 2
denoising_steps: 20
cond_steps: 1
horizon_steps: 4
act_steps: 3
ft_denoising_steps: 0
use_ddim: False

model:
  _target_: model.diffusion.diffusion_eval_ft.DiffusionEval
  ft_denoising_steps: ${ft_denoising_steps}
  predict_epsilon: True
  denoised_clip_value: 1.0
  randn_clip_value: 3
  use_ddim: ${use_ddim}
  network_path: ${base_policy_path}
  network:
    _target_: model.diffusion.mlp_diffusion.DiffusionMLP
    time_dim: 16
    mlp_dims: [32, 32, 32]
    residual_style: True
    cond_dim: ${eval:'${obs_dim} * ${cond_steps}'}
    horizon_steps: ${horizon_steps}
    action_dim: ${action_dim}
  horizon_steps: ${horizon_steps}
  obs_dim: ${obs_dim}
  action_dim: ${action_dim}
  denoising_steps: ${denoising_steps}
"""

FINETUNE = """\
_target_: agent.finetune.train_ppo_diffusion_agent.TrainPPODiffusionAgent
obs_dim: 5
action_dim: 2
denoising_steps: 20
ft_denoising_steps: 10
cond_steps: 1
horizon_steps: 4
act_steps: 4

model:
  _target_: model.diffusion.diffusion_ppo.PPODiffusion
  gamma_denoising: 0.99
  randn_clip_value: 3
  min_sampling_denoising_std: 0.1
  actor:
    _target_: model.diffusion.mlp_diffusion.DiffusionMLP
    time_dim: 16
    mlp_dims: [32, 32, 32]
    residual_style: True
    cond_dim: ${eval:'${obs_dim} * ${cond_steps}'}
    horizon_steps: ${horizon_steps}
    action_dim: ${action_dim}
  critic:
    _target_: model.common.critic.CriticObs
    mlp_dims: [16, 16, 16]
    cond_dim: ${eval:'${obs_dim} * ${cond_steps}'}
  ft_denoising_steps: ${ft_denoising_steps}
  horizon_steps: ${horizon_steps}
  obs_dim: ${obs_dim}
  action_dim: ${action_dim}
  denoising_steps: ${denoising_steps}
"""

# The furniture configs' architecture: no residual blocks, layer norms, an observation encoder.
PLAIN = (PRETRAIN.replace("    mlp_dims: [32, 32, 32]\n    residual_style: True\n",
                          "    mlp_dims: [24, 24]\n    cond_mlp_dims: [12, 6]\n    use_layernorm: True\n"
                          "    activation_type: ReLU\n    out_activation_type: Tanh\n    time_dim: 8\n")
         .replace("    time_dim: 16\n", "", 1))
NET_RESIDUAL = {"mlp_dims": [32, 32, 32], "residual": True}
NET_PLAIN = {"mlp_dims": [24, 24], "residual": False, "time_dim": 8, "cond_mlp_dims": [12, 6],
             "layernorm": True, "activation": "ReLU", "out_activation": "Tanh"}
NORMALIZATION = {"obs_min": np.linspace(-2, 0, OBS, dtype=np.float32),
                 "obs_max": np.linspace(1, 3, OBS, dtype=np.float32),
                 "action_min": np.array([-0.5, -2.0], np.float32),
                 "action_max": np.array([1.5, 0.0], np.float32)}


def dppo_shapes(mlp_dims, residual, time_dim=16, cond_mlp_dims=None, layernorm=False, cond_dim=OBS,
                **_) -> dict[str, tuple]:
    """DiffusionMLP's tensors by DPPO's names: time_embedding (a Sequential: embedding, Linear, Mish,
    Linear), cond_mlp and, for mlp_mean, MLP's moduleList.{i}.linear_1 / norm_1 or ResidualMLP's layers
    (Linear, TwoLayerPreActivationResNetLinear blocks l1, l2, norm1, norm2, Linear)."""
    td, out = time_dim, H * ACT
    shapes = {"time_embedding.1.weight": (2 * td, td), "time_embedding.1.bias": (2 * td,),
              "time_embedding.3.weight": (td, 2 * td), "time_embedding.3.bias": (td,)}
    cond_out = cond_dim
    if cond_mlp_dims:
        dims = [cond_dim, *cond_mlp_dims]
        for i in range(len(dims) - 1):
            shapes |= {f"cond_mlp.moduleList.{i}.linear_1.weight": (dims[i + 1], dims[i]),
                       f"cond_mlp.moduleList.{i}.linear_1.bias": (dims[i + 1],)}
        cond_out = cond_mlp_dims[-1]
    dims = [out + td + cond_out, *mlp_dims, out]
    if residual:
        w, blocks = mlp_dims[0], (len(mlp_dims) - 1) // 2
        shapes |= {"mlp_mean.layers.0.weight": (w, dims[0]), "mlp_mean.layers.0.bias": (w,)}
        for k in range(1, blocks + 1):
            block = f"mlp_mean.layers.{k}"
            for part in ("l1", "l2"):
                shapes |= {f"{block}.{part}.weight": (w, w), f"{block}.{part}.bias": (w,)}
            for part in ("norm1", "norm2") if layernorm else ():
                shapes |= {f"{block}.{part}.weight": (w,), f"{block}.{part}.bias": (w,)}
        last = f"mlp_mean.layers.{blocks + 1}"
        shapes |= {f"{last}.weight": (out, w), f"{last}.bias": (out,)}
    else:
        for i in range(len(dims) - 1):
            shapes |= {f"mlp_mean.moduleList.{i}.linear_1.weight": (dims[i + 1], dims[i]),
                       f"mlp_mean.moduleList.{i}.linear_1.bias": (dims[i + 1],)}
            if layernorm and i < len(dims) - 2:
                shapes |= {f"mlp_mean.moduleList.{i}.norm_1.weight": (dims[i + 1],),
                           f"mlp_mean.moduleList.{i}.norm_1.bias": (dims[i + 1],)}
    return shapes


def dppo_network(seed: int, net=NET_RESIDUAL, **overrides) -> dict[str, torch.Tensor]:
    """A DiffusionMLP state dict with random weights from `seed` (norm weights near 1). A residual one
    passes its input chunk through to its output as well, so that epsilon is near x_t, as a trained
    network's is, and DDIM's clip of x0 binds only now and then."""
    rng = np.random.default_rng(seed)
    state = {}
    for name, shape in dppo_shapes(**net, **overrides).items():
        base = 1.0 if "norm" in name and name.endswith("weight") else 0.0
        scale = 0.3 / math.sqrt(shape[-1]) if len(shape) == 2 else 0.03
        state[name] = torch.tensor(base + scale * rng.standard_normal(shape), dtype=torch.float32)
    if net["residual"]:
        last = (len(net["mlp_dims"]) - 1) // 2 + 1
        state["mlp_mean.layers.0.weight"][: H * ACT, : H * ACT] += torch.eye(H * ACT)
        state[f"mlp_mean.layers.{last}.weight"][:, : H * ACT] += torch.eye(H * ACT)
    return state


def prefixed(prefix: str, state: dict) -> dict:
    return {prefix + k: v for k, v in state.items()}


def pretrained(model: dict, ema: dict | None = None) -> dict:
    """What DPPO's pre-training saves: DiffusionModel's state dicts, the network's tensors under network."""
    return {"epoch": 3000, "model": prefixed("network.", model), "ema": prefixed("network.", ema or model)}


def dppo_folder(path: Path, config: str = PRETRAIN, checkpoint: dict | None = None,
                normalization=NORMALIZATION) -> Path:
    path.mkdir()
    torch.save(checkpoint or pretrained(dppo_network(RNG_SEED)), path / "state_3000.pt")
    (path / "config.yaml").write_text(config)
    np.savez_compressed(path / "normalization.npz", **normalization)
    return path


# -- DPPO's sampler, re-implemented in float64 numpy from model/diffusion/{diffusion,sampling,modules}.py --


def dppo_alphas_cumprod(steps: int) -> np.ndarray:
    """DPPO's cosine_beta_schedule (numpy, cast to float32), then its torch cumprod of 1 - betas."""
    x = np.linspace(0, steps + 1, steps + 1)
    ac = np.cos(((x / (steps + 1)) + 0.008) / (1 + 0.008) * np.pi * 0.5) ** 2
    ac = ac / ac[0]
    betas = torch.tensor(np.clip(1 - (ac[1:] / ac[:-1]), 0, 0.999), dtype=torch.float32)
    return torch.cumprod(1.0 - betas, dim=0).numpy().astype(np.float64)


ACTIVATIONS = {"Mish": lambda h: h * np.tanh(np.logaddexp(0, h)), "ReLU": lambda h: np.maximum(h, 0),
               "Tanh": np.tanh, "Identity": lambda h: h}


def reference_eps(sd, x, t, cond, mlp_dims, residual, time_dim=16, cond_mlp_dims=None, layernorm=False,
                  activation="Mish", out_activation="Identity"):
    """DiffusionMLP.forward: [chunk, time embedding, (encoded) state] through mlp_mean."""
    w = {k: v.double().numpy() for k, v in sd.items()}
    act, out_act = ACTIVATIONS[activation], ACTIVATIONS[out_activation]

    def linear(h, name):
        return h @ w[name + ".weight"].T + w[name + ".bias"]

    def norm(h, name, eps):
        mean, var = h.mean(-1, keepdims=True), h.var(-1, keepdims=True)
        return (h - mean) / np.sqrt(var + eps) * w[name + ".weight"] + w[name + ".bias"]

    half = time_dim // 2
    angles = t * np.exp(np.arange(half) * -(math.log(10000) / (half - 1)))
    emb = np.broadcast_to(np.concatenate([np.sin(angles), np.cos(angles)]), (len(x), time_dim))
    emb = linear(ACTIVATIONS["Mish"](linear(emb, "time_embedding.1")), "time_embedding.3")
    state = cond
    for i in range(len(cond_mlp_dims or ())):
        state = linear(state, f"cond_mlp.moduleList.{i}.linear_1")
        state = act(state) if i < len(cond_mlp_dims) - 1 else state
    h = np.concatenate([x.reshape(len(x), -1), emb, state], axis=1)
    if residual:
        blocks = (len(mlp_dims) - 1) // 2
        h = linear(h, "mlp_mean.layers.0")
        for k in range(1, blocks + 1):
            r = norm(h, f"mlp_mean.layers.{k}.norm1", 1e-6) if layernorm else h
            r = linear(act(r), f"mlp_mean.layers.{k}.l1")
            r = norm(r, f"mlp_mean.layers.{k}.norm2", 1e-6) if layernorm else r
            h = h + linear(act(r), f"mlp_mean.layers.{k}.l2")
        h = out_act(linear(h, f"mlp_mean.layers.{blocks + 1}"))
    else:
        last = len(mlp_dims)
        for i in range(last + 1):
            h = linear(h, f"mlp_mean.moduleList.{i}.linear_1")
            if layernorm and i < last:
                h = norm(h, f"mlp_mean.moduleList.{i}.norm_1", 1e-5)
            h = out_act(h) if i == last else act(h)
    return h.reshape(x.shape)


def reference_actions(sd, obs, noise, ddim_steps, net=NET_RESIDUAL, act_steps=H, normalization=NORMALIZATION,
                      ft_sd=None, ft_below=0, clip=1.0):
    """DiffusionModel with use_ddim: DDIM's timesteps arange(N) * (T // N), alphas at them and at the step
    before (1 after the last), flipped; x0 clipped and epsilon recomputed from it; the env wrapper's
    normalisation of observations and unnormalisation of actions."""
    n = normalization
    cond = 2 * ((obs - n["obs_min"]) / (n["obs_max"] - n["obs_min"] + 1e-6) - 0.5)
    cond = cond.reshape(len(obs), -1)
    ac = dppo_alphas_cumprod(T)
    ddim_t = np.arange(ddim_steps) * (T // ddim_steps)
    alphas, prev = ac[ddim_t], np.concatenate([[1.0], ac[ddim_t[:-1]]])
    x = noise.astype(np.float64)
    for t, a, a_prev in zip(ddim_t[::-1], alphas[::-1], prev[::-1], strict=True):
        eps = reference_eps(ft_sd if t < ft_below else sd, x, float(t), cond, **net)
        x0 = np.clip((x - np.sqrt(1 - a) * eps) / np.sqrt(a), -clip, clip)
        eps = (x - np.sqrt(a) * x0) / np.sqrt(1 - a)
        x = np.sqrt(a_prev) * x0 + np.sqrt(1 - a_prev) * eps
    chunk = x[:, :act_steps]
    return (chunk + 1) / 2 * (n["action_max"] - n["action_min"]) + n["action_min"]


def inputs(rows: int, seed: int = 1, cond_steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    shape = (rows, OBS) if cond_steps == 1 else (rows, cond_steps, OBS)
    return rng.uniform(-2, 3, shape), rng.standard_normal((rows, H, ACT)).astype(np.float32)


def close(actions, reference) -> bool:
    return actions.shape == reference.shape and np.abs(actions - reference).max() < 2e-6


# -- tests --


def test_the_schedule_is_dppos():
    for steps in (20, 100):
        assert np.array_equal(dppo.alphas_cumprod(steps).numpy(),
                              dppo_alphas_cumprod(steps).astype(np.float32))


def test_a_pretraining_folder_loads_as_a_policy(tmp_path):
    folder = dppo_folder(tmp_path / "can")
    policy = load_policy(str(folder))
    assert (policy.noise_shape, policy.n_exec, policy.n_obs_steps) == ((H, ACT), H, 1)
    assert policy.fingerprint().startswith("dppo-") and policy.fingerprint().endswith("@20")
    fewer = load_policy(f"{folder}@8")
    assert fewer.fingerprint().endswith("@8") and fewer.fingerprint()[:-3] != policy.fingerprint()[:-4]
    assert load_policy(str(folder / "state_3000.pt")).fingerprint() == policy.fingerprint()
    assert bundled_task(str(folder)) is None and bundled_task(f"{folder}@8") is None
    obs, noise = inputs(3)
    assert policy.act(obs, noise).shape == (3, H, ACT) and policy.act(obs, noise).dtype == np.float32


@pytest.mark.parametrize(("config", "net"), [(PRETRAIN, NET_RESIDUAL), (PLAIN, NET_PLAIN)])
def test_the_network_is_dppos_diffusion_mlp(tmp_path, config, net):
    sd = dppo_network(RNG_SEED, net)
    policy = load_policy(str(dppo_folder(tmp_path / "can", config, pretrained(sd))))
    network = copy.deepcopy(policy.networks["base"]).double()
    rng = np.random.default_rng(3)
    x, cond = rng.standard_normal((6, H, ACT)), rng.uniform(-1, 1, (6, OBS))
    for t in (0, 7, 19):
        eps = network(torch.tensor(x), torch.full((6,), float(t), dtype=torch.float64), torch.tensor(cond))
        assert np.abs(eps.detach().numpy() - reference_eps(sd, x, float(t), cond, **net)).max() < 1e-12


@pytest.mark.parametrize("steps", [None, 8, 3, 1])
@pytest.mark.parametrize(("config", "net"), [(PRETRAIN, NET_RESIDUAL), (PLAIN, NET_PLAIN)])
def test_actions_are_dppos_ddim(tmp_path, config, net, steps):
    sd = dppo_network(RNG_SEED, net)
    folder = dppo_folder(tmp_path / "can", config, pretrained(sd))
    policy = load_policy(str(folder) + (f"@{steps}" if steps else ""))
    obs, noise = inputs(20)
    assert close(policy.act(obs, noise), reference_actions(sd, obs, noise, steps or T, net))


def test_a_network_of_known_output_gives_ddims_closed_form(tmp_path):
    """epsilon = c everywhere (the last layer zero but its bias): one DDIM step from x_T at t = 0 is
    x0 = clip((x_T - sqrt(1 - a0) c) / sqrt(a0)); two steps (t = 10, then 0) compose two of them."""
    sd = dppo_network(RNG_SEED)
    c = np.linspace(-0.3, 0.3, H * ACT)
    sd["mlp_mean.layers.2.weight"].zero_()
    sd["mlp_mean.layers.2.bias"] = torch.tensor(c, dtype=torch.float32)
    c = sd["mlp_mean.layers.2.bias"].double().numpy().reshape(H, ACT)
    folder = dppo_folder(tmp_path / "can", checkpoint=pretrained(sd))
    obs, noise = inputs(5)
    noise *= 0.2  # inside the clip
    a = dppo_alphas_cumprod(T)
    lo, span = NORMALIZATION["action_min"], NORMALIZATION["action_max"] - NORMALIZATION["action_min"]

    def unnormalised(x):
        return (x + 1) / 2 * span + lo

    one = (noise - np.sqrt(1 - a[0]) * c) / np.sqrt(a[0])
    assert np.abs(one).max() < 1 and close(load_policy(f"{folder}@1").act(obs, noise), unnormalised(one))
    x0 = (noise - np.sqrt(1 - a[10]) * c) / np.sqrt(a[10])
    x = np.sqrt(a[0]) * x0 + np.sqrt(1 - a[0]) * c
    two = (x - np.sqrt(1 - a[0]) * c) / np.sqrt(a[0])
    assert np.abs(two).max() < 1 and close(load_policy(f"{folder}@2").act(obs, noise), unnormalised(two))


def test_ddpm_run_with_n_steps_is_dppos_ddim_config_with_n_steps(tmp_path):
    ddpm = load_policy(f"{dppo_folder(tmp_path / 'ddpm')}@5")
    ddim = PRETRAIN.replace("  denoised_clip_value: 1.0\n", "  denoised_clip_value: 1.0\n  use_ddim: True\n"
                            "  ddim_steps: 5\n")
    ddim = load_policy(str(dppo_folder(tmp_path / "ddim", ddim)))
    obs, noise = inputs(4)
    assert np.array_equal(ddpm.act(obs, noise), ddim.act(obs, noise))
    assert ddpm.fingerprint().endswith("@5") and ddim.fingerprint().endswith("@5")


def test_actions_are_deterministic_row_independent_and_follow_the_ticket(tmp_path):
    policy = load_policy(str(dppo_folder(tmp_path / "can")))
    obs, noise = inputs(37)  # three blocks of 16 rows, the last padded
    actions = policy.act(obs, noise)
    assert np.array_equal(actions, policy.act(obs.copy(), noise.copy()))
    order = np.random.default_rng(2).permutation(37)
    assert np.array_equal(policy.act(obs[order], noise[order]), actions[order])
    for i in (0, 17, 36):
        assert np.array_equal(policy.act(obs[i : i + 1], noise[i : i + 1]), actions[i : i + 1])
    ticket = np.broadcast_to(noise[:1], noise.shape)
    other = np.broadcast_to(noise[1:2], noise.shape)
    assert not np.array_equal(policy.act(obs, ticket), policy.act(obs, other))


def test_pretraining_runs_the_ema_weights_and_dppos_eval_config_the_model_weights(tmp_path):
    model, ema = dppo_network(1), dppo_network(2)
    obs, noise = inputs(6)
    expected = {name: reference_actions(sd, obs, noise, T) for name, sd in (("model", model), ("ema", ema))}
    assert np.abs(expected["model"] - expected["ema"]).max() > 1e-2
    both = pretrained(model, ema)
    assert close(load_policy(str(dppo_folder(tmp_path / "pre", PRETRAIN, both))).act(obs, noise),
                 expected["ema"])
    evaluated = load_policy(str(dppo_folder(tmp_path / "eval", EVAL, both))).act(obs, noise)
    assert close(evaluated, expected["model"][:, :3])  # act_steps: 3
    model_only = {"epoch": 10, "model": prefixed("network.", model)}
    assert close(load_policy(str(dppo_folder(tmp_path / "model", PRETRAIN, model_only))).act(obs, noise),
                 expected["model"])


def test_a_dsrl_config_runs_dppos_eval_with_ddim(tmp_path):
    """DSRL's robomimic configs: DPPO's DiffusionEval on a pre-trained checkpoint, use_ddim with 8 steps."""
    dsrl = EVAL.replace("use_ddim: False", "use_ddim: True").replace(
        "  use_ddim: ${use_ddim}\n", "  use_ddim: ${use_ddim}\n  ddim_steps: 8\n  controllable_noise: True\n")
    model, ema = dppo_network(1), dppo_network(2)
    policy = load_policy(str(dppo_folder(tmp_path / "dsrl", dsrl, pretrained(model, ema))))
    obs, noise = inputs(6)
    assert policy.fingerprint().endswith("@8")
    assert close(policy.act(obs, noise), reference_actions(model, obs, noise, 8, act_steps=3))


def test_a_fine_tuned_checkpoint_runs_actor_ft_at_the_fine_tuned_steps(tmp_path):
    """DPPO's fine-tuning saves network. and actor. (the frozen base, one module), actor_ft. and critic.;
    the fine-tuned network acts at timesteps t < ft_denoising_steps."""
    base, tuned = dppo_network(1), dppo_network(2)
    saved = {"itr": 150, "model": prefixed("network.", base) | prefixed("actor.", base)
             | prefixed("actor_ft.", tuned) | {"critic.mlp.weight": torch.zeros(3, 5)}}
    obs, noise = inputs(6)
    policy = load_policy(str(dppo_folder(tmp_path / "ft", FINETUNE, saved)))
    assert close(policy.act(obs, noise), reference_actions(base, obs, noise, T, ft_sd=tuned, ft_below=10))
    fewer = load_policy(str(tmp_path / "ft") + "@4")  # timesteps 15, 10, 5, 0: the last two fine-tuned
    assert close(fewer.act(obs, noise), reference_actions(base, obs, noise, 4, ft_sd=tuned, ft_below=10))
    untuned = load_policy(str(dppo_folder(tmp_path / "eval", EVAL, saved)))  # eval: ft_denoising_steps 0
    assert close(untuned.act(obs, noise), reference_actions(base, obs, noise, T)[:, :3])
    assert policy.fingerprint() != untuned.fingerprint()


def test_an_observation_history_is_flattened_oldest_first(tmp_path):
    config = PRETRAIN.replace("cond_steps: 1", "cond_steps: 2")
    sd = dppo_network(RNG_SEED, cond_dim=2 * OBS)
    policy = load_policy(str(dppo_folder(tmp_path / "can", config, pretrained(sd))))
    assert policy.n_obs_steps == 2
    obs, noise = inputs(5, cond_steps=2)
    assert close(policy.act(obs, noise), reference_actions(sd, obs, noise, T))
    with pytest.raises(dppo.UserError, match=r"low-dim state \[B, 2, 5\], got \[5, 5\]$"):
        policy.act(obs[:, 0], noise)


class Drift(gym.Env):
    """Observes 5 numbers, the first two moved by the actions; ends after 6 steps."""

    observation_space = gym.spaces.Box(-10, 10, (OBS,), dtype=np.float64)
    action_space = gym.spaces.Box(-5, 5, (ACT,), dtype=np.float64)

    def reset(self, seed=None, options=None):
        self.state, self.t = np.random.default_rng(seed).uniform(-1, 1, OBS), 0
        return self.state.copy(), {}

    def step(self, action):
        self.t += 1
        self.state[:ACT] += 0.1 * np.asarray(action)
        return self.state.copy(), 0.0, self.t >= 6, False, {"success": False}


@pytest.mark.parametrize("cond_steps", [1, 2])
def test_rollout_runs_a_dppo_policy_with_its_observation_history(tmp_path, cond_steps):
    config = PRETRAIN.replace("cond_steps: 1", f"cond_steps: {cond_steps}")
    sd = dppo_network(RNG_SEED, cond_dim=cond_steps * OBS)
    policy = load_policy(f"{dppo_folder(tmp_path / 'can', config, pretrained(sd))}@4")
    ticket = Constant(np.full(policy.noise_shape, 0.5, np.float32))
    episodes = [Episode(Gaussian(0), 1_000_000), Episode(ticket, 1_000_001), Episode(ticket, 1_000_000)]
    results = rollout(policy, get_task(Drift), episodes)
    assert [r.length for r in results] == [6, 6, 6]


def test_the_writer_saves_what_dppo_saves(tmp_path):
    spec = dppo.NetworkSpec(action_dim=ACT, horizon_steps=H, cond_dim=OBS, mlp_dims=(32,) * 3,
                            residual_style=True)
    network = dppo.DiffusionMLP(spec)
    network.load_state_dict(dppo_network(RNG_SEED))
    path = dppo.save_checkpoint(tmp_path / "out", network, NORMALIZATION, denoising_steps=T, epoch=7)
    saved = torch.load(path, weights_only=True)
    assert path.name == "state_7.pt" and sorted(saved) == ["ema", "epoch", "model"] and saved["epoch"] == 7
    shapes = {k: tuple(v.shape) for k, v in saved["ema"].items()}
    assert shapes == prefixed("network.", dppo_shapes(**NET_RESIDUAL))
    obs, noise = inputs(4)
    sd = {k.removeprefix("network."): v for k, v in saved["ema"].items()}
    assert close(load_policy(str(tmp_path / "out")).act(obs, noise), reference_actions(sd, obs, noise, T))


def refusal(capsys, policy: Path | str) -> str:
    """The one line `goldenticket evaluate` prints for `policy`, once it exited with code 2."""
    assert main(["evaluate", "--policy", str(policy), "--task", "metaworld/reach-v3",
                 "--seeds", "1000000:1000002"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    return lines[0]


def _edit(old: str, new: str):
    def edit(folder: Path) -> None:
        text = (folder / "config.yaml").read_text()
        assert old in text
        (folder / "config.yaml").write_text(text.replace(old, new, 1))
    return edit


def _normalization_without_action_max(folder: Path) -> None:
    np.savez(folder / "normalization.npz", **{k: v for k, v in NORMALIZATION.items() if k != "action_max"})


BAD = {
    "vision": (_edit("mlp_diffusion.DiffusionMLP", "mlp_diffusion.VisionDiffusionMLP"),
               "model.network._target_ is 'model.diffusion.mlp_diffusion.VisionDiffusionMLP'"),
    "unet": (_edit("mlp_diffusion.DiffusionMLP", "unet.Unet1D"), "not its image or UNet networks"),
    "sampler": (_edit("diffusion.diffusion.DiffusionModel", "diffusion.diffusion_idql.IDQLDiffusion"),
                "model._target_ is 'model.diffusion.diffusion_idql.IDQLDiffusion'"),
    "shape": (_edit("mlp_dims: [32, 32, 32]", "mlp_dims: [48, 48, 48]"),
              "tensor network.mlp_mean.layers.0.bias has shape [32]; the config's DiffusionMLP needs [48]"),
    "layers": (_edit("mlp_dims: [32, 32, 32]", "mlp_dims: [32, 32, 32, 32, 32]"),
               "tensor network.mlp_mean.layers.2.bias [8] has no place in the config's DiffusionMLP"),
    "normalization": (lambda folder: (folder / "normalization.npz").unlink(), "no normalization.npz"),
    "normalization key": (_normalization_without_action_max, "no 'action_max'"),
    "config": (lambda folder: (folder / "config.yaml").unlink(), "needs its run's config beside it"),
    "key": (_edit("  obs_dim: ${obs_dim}\n", ""), "no model.obs_dim (DPPO's configs set it)"),
    "reference": (_edit("horizon_steps: 4\n", ""),
                  "model.network.horizon_steps refers to ${horizon_steps}, which the config does not set"),
    "resolver": (_edit("horizon_steps: 4", "horizon_steps: ${oc.env:H}"), "goldenticket does not resolve"),
    "code": (_edit("${obs_dim} * ${cond_steps}", "__import__('os').getpid()"), "only arithmetic"),
    "cond_dim": (_edit("${eval:'${obs_dim} * ${cond_steps}'}", "7"),
                 "model.network.cond_dim is 7, not obs_dim * cond_steps = 5 * 1"),
    "history": (_edit("cond_steps: 1", "cond_steps: 2"), "tensor network.mlp_mean.layers.0.weight has shape "
                "[32, 29]; the config's DiffusionMLP needs [32, 34]"),
    "x0": (_edit("predict_epsilon: True", "predict_epsilon: False"), "predicts epsilon"),
    "steps": (lambda folder: None, "21 DDIM steps, more than the 20 trained timesteps"),
    "two": (lambda folder: (folder / "state_10.pt").write_bytes((folder / "state_3000.pt").read_bytes()),
            "holds 2 checkpoints (state_10.pt, state_3000.pt)"),
    "torch": (lambda folder: (folder / "state_3000.pt").write_text("text"),
              "state_3000.pt: torch.load(weights_only=True) cannot read it"),
}


@pytest.mark.parametrize("case", BAD)
def test_a_bad_dppo_checkpoint_is_one_line(tmp_path, capsys, case):
    spoil, says = BAD[case]
    folder = dppo_folder(tmp_path / "can")
    spoil(folder)
    policy = f"{folder}@21" if case == "steps" else folder
    assert says in refusal(capsys, policy)
