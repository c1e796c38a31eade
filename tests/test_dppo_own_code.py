"""DPPO checkpoints written and sampled by DPPO's own code (Ren et al., arXiv:2409.00588; commit cc7234a,
in ../shared/dppo beside the repository: model/diffusion/ and model/common/, unmodified).

DPPO's classes build the networks and models, its agents' `torch.save` calls write the checkpoints, and
the runs' configs are written as Hydra writes `.hydra/config.yaml` (OmegaConf.to_yaml of the composed
config: interpolations kept, `hydra` and `defaults` dropped). goldenticket loads the folder a user puts
together from them; its actions are compared with DPPO's own sampling (`model(cond, deterministic=True)`,
the call of DPPO's eval and fine-tuning agents) from the same initial noise: DPPO draws x_T with the first
`torch.randn` of its forward pass, so DPPO samples right after `torch.manual_seed(s)` and the ticket is
the first `torch.randn` after the same seed. DPPO runs float32, goldenticket float64 rounded to 2^-20:
actions agree to TOLERANCE, and to CLOSE with DPPO's code run in float64. Marked `robomimic`: the last
test steps robomimic's Lift in its venv (with einops, the `robomimic` extra, for DPPO's code).
"""

import contextlib
import copy
import importlib.metadata
import importlib.util
import shutil
import sys
from collections import deque
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml

from goldenticket.cli import main
from goldenticket.noise import Constant
from goldenticket.policies import load_policy
from goldenticket.rollout import Episode, rollout

DPPO = Path(__file__).resolve().parents[2] / "shared" / "dppo"
OBS, ACT, H, ACT_STEPS, COND, T = 19, 7, 4, 3, 2, 20  # robomimic Lift's sizes, two observations per call
TOLERANCE = 2e-4  # on unnormalised actions in [-1, 1]: DPPO as it runs (float32) against goldenticket
CLOSE = 1e-5  # DPPO run in float64
NETWORKS = {  # DiffusionMLP's arguments: DPPO's robomimic layout, its furniture layout, a plain MLP
    "robomimic": {"time_dim": 16, "mlp_dims": [32, 32, 32], "residual_style": True},
    "furniture": {"time_dim": 8, "mlp_dims": [32, 32, 32], "cond_mlp_dims": [16, 8], "use_layernorm": True,
                  "residual_style": True},
    "plain": {"time_dim": 8, "mlp_dims": [24, 24], "activation_type": "ReLU", "use_layernorm": True},
}
SAMPLERS = {  # sampling settings in a config's model section
    "ddpm": {},  # DPPO's robomimic configs: DDPM over denoising_steps
    "ddim": {"use_ddim": True, "ddim_steps": 5},  # DPPO's furniture configs run DDIM
    "ddim, uneven": {"use_ddim": True, "ddim_steps": 6},  # 20 // 6: timesteps 15, 12, ..., 0
    "ddim, clipped": {"use_ddim": True, "ddim_steps": 5, "eps_clip_value": 0.3,
                      "final_action_clip_value": 0.5},
}
RNG = np.random.default_rng(0)
NORMALIZATION = {  # as DPPO's process_robomimic_dataset.py saves it: float64 minima and maxima
    "obs_min": RNG.uniform(-1.5, -0.5, OBS), "obs_max": RNG.uniform(0.5, 1.5, OBS),
    "action_min": RNG.uniform(-1.0, -0.8, ACT), "action_max": RNG.uniform(0.8, 1.0, ACT)}


def robosuite_version() -> str | None:
    return importlib.metadata.version("robosuite") if importlib.util.find_spec("robosuite") else None


pytestmark = [pytest.mark.robomimic, pytest.mark.skipif(
    not (DPPO / "model" / "diffusion" / "diffusion.py").is_file(),
    reason=f"DPPO's own model code is not at {DPPO} (DPPO commit cc7234a: model/diffusion, model/common)")]
needs_robosuite = pytest.mark.skipif(robosuite_version() != "1.5.2",
                                     reason="robosuite 1.5.2 is not installed (its own venv: README)")


@pytest.fixture(scope="module")
def dppo():
    """DPPO's model classes, imported from its own code (a top-level package named `model`)."""
    pytest.importorskip("einops", reason="DPPO's model code imports einops (pip install einops)")
    sys.path.insert(0, str(DPPO))
    try:
        from model.common.mlp import MLP
        from model.diffusion.diffusion import DiffusionModel
        from model.diffusion.diffusion_eval import DiffusionEval
        from model.diffusion.diffusion_ppo import PPODiffusion
        from model.diffusion.mlp_diffusion import DiffusionMLP

        yield SimpleNamespace(MLP=MLP, DiffusionModel=DiffusionModel, DiffusionEval=DiffusionEval,
                              PPODiffusion=PPODiffusion, DiffusionMLP=DiffusionMLP)
    finally:
        sys.path.remove(str(DPPO))
        for name in [m for m in sys.modules if m == "model" or m.startswith("model.")]:
            del sys.modules[name]


# ---- DPPO's runs: models built by its classes, checkpoints saved as its agents save them ----------------

def common(sampler: dict) -> dict:
    """The keyword arguments every DPPO model here takes (as its configs pass them)."""
    return {"horizon_steps": H, "obs_dim": OBS, "action_dim": ACT, "denoising_steps": T, "device": "cpu",
            "denoised_clip_value": 1.0, "randn_clip_value": 3, **sampler}


def network(dppo, net: str):
    return dppo.DiffusionMLP(action_dim=ACT, horizon_steps=H, cond_dim=OBS * COND, **NETWORKS[net])


def moved(module: torch.nn.Module, seed: int, scale: float = 0.1) -> torch.nn.Module:
    """`module` with every parameter moved by seeded Gaussian steps (what training would change)."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in module.parameters():
            parameter.add_(scale * torch.randn(parameter.shape, generator=generator))
    return module


def pretraining_run(dppo, run: Path, net: str, epoch: int = 3000) -> Path:
    """A pre-training run as DPPO's TrainDiffusionAgent leaves it: checkpoint/state_<epoch>.pt ({"epoch",
    "model", "ema"}, agent/pretrain/train_agent.py's save_model) and .hydra/config.yaml."""
    torch.manual_seed(0)
    model = dppo.DiffusionModel(network=network(dppo, net), **common({}))
    ema_model = moved(copy.deepcopy(model), seed=1)  # its EMA differs from the trained weights
    checkpoint = run / "checkpoint" / f"state_{epoch}.pt"
    checkpoint.parent.mkdir(parents=True)
    torch.save({"epoch": epoch, "model": model.state_dict(), "ema": ema_model.state_dict()}, checkpoint)
    hydra_config(run, pretraining_config(net))
    return checkpoint


def fine_tuning_run(dppo, run: Path, base: Path, net: str, sampler: dict, ft_steps: int, itr: int = 150):
    """A PPO fine-tuning run from the pre-trained checkpoint `base`, as DPPO's TrainPPODiffusionAgent leaves
    it: checkpoint/state_<itr>.pt ({"itr", "model"}, agent/finetune/train_agent.py's save_model; "model"
    holds network., actor. (the same frozen module), actor_ft., critic. and, where the model has one,
    eta.) and .hydra/config.yaml. Returns DPPO's model and the checkpoint."""
    model = ppo_model(dppo, base, net, sampler, ft_steps)
    moved(model.actor_ft, seed=2)  # what PPO's updates change
    checkpoint = run / "checkpoint" / f"state_{itr}.pt"
    checkpoint.parent.mkdir(parents=True)
    torch.save({"itr": itr, "model": model.state_dict()}, checkpoint)
    hydra_config(run, fine_tuning_config(net, sampler, ft_steps))
    return model, checkpoint


class Eta(torch.nn.Module):
    """Stands in for DPPO's EtaFixed (model/diffusion/eta.py, not among the files here): parameters under
    eta. in a DDIM fine-tuning checkpoint, unused by deterministic sampling."""

    def __init__(self):
        super().__init__()
        self.eta_logit = torch.nn.Parameter(torch.zeros(1))


def ppo_model(dppo, checkpoint: Path, net: str, sampler: dict, ft_steps: int):
    """DPPO's PPODiffusion as its fine-tuning builds it from a pre-training checkpoint: network_path loads
    its "ema"; actor_ft starts as a copy of the base, actor."""
    eta = {"eta": Eta()} if sampler.get("use_ddim") else {}
    return dppo.PPODiffusion(actor=network(dppo, net), critic=dppo.MLP([OBS * COND, 16, 1]),
                             ft_denoising_steps=ft_steps, network_path=str(checkpoint), gamma_denoising=0.99,
                             clip_ploss_coef=0.01, min_sampling_denoising_std=0.1, **eta, **common(sampler))


def eval_model(dppo, checkpoint: Path, net: str, sampler: dict, ft_steps: int):
    """DPPO's DiffusionEval (its eval configs' model): "model" weights, actor_ft at the fine-tuned steps."""
    return dppo.DiffusionEval(network_path=str(checkpoint), ft_denoising_steps=ft_steps,
                              network=network(dppo, net), **common(sampler))


# ---- the configs, as Hydra writes them -------------------------------------------------------------------

def hydra_config(run: Path, config: dict) -> Path:
    """`.hydra/config.yaml` as Hydra writes it: OmegaConf.to_yaml (yaml.dump, block style, keys in order,
    interpolations as written) of the composed config, without its `hydra` and `defaults` keys."""
    path = run / ".hydra" / "config.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(yaml.dump(config, default_flow_style=False, allow_unicode=True, sort_keys=False))
    return path


def diffusion_mlp(net: str) -> dict:
    return {"_target_": "model.diffusion.mlp_diffusion.DiffusionMLP", **NETWORKS[net],
            "cond_dim": "${eval:'${obs_dim} * ${cond_steps}'}", "horizon_steps": "${horizon_steps}",
            "action_dim": "${action_dim}"}


def sizes(**more) -> dict:
    return {"seed": 42, "device": "cuda:0", "env_name": "lift", "obs_dim": OBS, "action_dim": ACT,
            "denoising_steps": T, **more, "cond_steps": COND, "horizon_steps": H}


RUN_TIME = "${now:%Y-%m-%d}_${now:%H-%M-%S}_${seed}"
MODEL_SIZES = {"horizon_steps": "${horizon_steps}", "obs_dim": "${obs_dim}", "action_dim": "${action_dim}",
               "denoising_steps": "${denoising_steps}", "device": "${device}"}
ENV = {"n_envs": 50, "name": "${env_name}", "max_episode_steps": 300, "wrappers": {
    "robomimic_lowdim": {"normalization_path": "${normalization_path}",
                         "low_dim_keys": ["robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos",
                                          "object"]},
    "multi_step": {"n_obs_steps": "${cond_steps}", "n_action_steps": "${act_steps}",
                   "max_episode_steps": "${env.max_episode_steps}", "reset_within_step": True}}}


def pretraining_config(net: str) -> dict:
    """cfg/robomimic/pretrain/<task>/pre_diffusion_mlp.yaml, composed."""
    return {"_target_": "agent.pretrain.train_diffusion_agent.TrainDiffusionAgent",
            "name": "${env_name}_pre_diffusion_mlp_ta${horizon_steps}_td${denoising_steps}",
            "logdir": "${oc.env:DPPO_LOG_DIR}/robomimic-pretrain/${name}/" + RUN_TIME,
            "train_dataset_path": "${oc.env:DPPO_DATA_DIR}/robomimic/${env_name}/train.npz", **sizes(),
            "train": {"n_epochs": 3000, "batch_size": 256, "learning_rate": 0.0001, "save_model_freq": 500},
            "model": {"_target_": "model.diffusion.diffusion.DiffusionModel", "predict_epsilon": True,
                      "denoised_clip_value": 1.0, "network": diffusion_mlp(net), **MODEL_SIZES},
            "ema": {"decay": 0.995},
            "train_dataset": {"_target_": "agent.dataset.sequence.StitchedSequenceDataset",
                              "dataset_path": "${train_dataset_path}", "horizon_steps": "${horizon_steps}",
                              "cond_steps": "${cond_steps}", "device": "${device}"}}


def fine_tuning_config(net: str, sampler: dict, ft_steps: int) -> dict:
    """cfg/robomimic/finetune/<task>/ft_ppo_diffusion_mlp.yaml, composed, with `sampler` in its model."""
    eta = {"learn_eta": False, "eta": {"base_eta": 1, "input_dim": "${obs_dim}", "mlp_dims": [16, 16],
                                       "action_dim": "${action_dim}", "min_eta": 0.1, "max_eta": 1.0,
                                       "_target_": "model.diffusion.eta.EtaFixed"}} if sampler else {}
    return {"_target_": "agent.finetune.train_ppo_diffusion_agent.TrainPPODiffusionAgent",
            "name": "${env_name}_ft_diffusion_mlp_ta${horizon_steps}_td${denoising_steps}"
                    "_tdf${ft_denoising_steps}",
            "logdir": "${oc.env:DPPO_LOG_DIR}/robomimic-finetune/${name}/" + RUN_TIME,
            "base_policy_path": "${oc.env:DPPO_LOG_DIR}/robomimic-pretrain/lift/checkpoint/state_3000.pt",
            "normalization_path": "${oc.env:DPPO_DATA_DIR}/robomimic/${env_name}/normalization.npz",
            **sizes(ft_denoising_steps=ft_steps, act_steps=ACT_STEPS), "env": ENV,
            "model": {"_target_": "model.diffusion.diffusion_ppo.PPODiffusion", "gamma_denoising": 0.99,
                      "clip_ploss_coef": 0.01, "randn_clip_value": 3, "min_sampling_denoising_std": 0.1,
                      **sampler, **eta, "network_path": "${base_policy_path}", "actor": diffusion_mlp(net),
                      "critic": {"_target_": "model.common.critic.CriticObs", "mlp_dims": [16],
                                 "cond_dim": "${eval:'${obs_dim} * ${cond_steps}'}"},
                      "ft_denoising_steps": "${ft_denoising_steps}", **MODEL_SIZES}}


def eval_config(net: str, sampler: dict, ft_steps: int) -> dict:
    """cfg/robomimic/eval/<task>/eval_diffusion_mlp.yaml, composed, with `sampler` in its model."""
    return {"_target_": "agent.eval.eval_diffusion_agent.EvalDiffusionAgent",
            "name": "${env_name}_eval_diffusion_mlp_ta${horizon_steps}_td${denoising_steps}",
            "logdir": "${oc.env:DPPO_LOG_DIR}/robomimic-eval/${name}/" + RUN_TIME,
            "base_policy_path": None,
            "normalization_path": "${oc.env:DPPO_DATA_DIR}/robomimic/${env_name}/normalization.npz",
            **sizes(act_steps=ACT_STEPS, ft_denoising_steps=ft_steps), "n_steps": 300, "env": ENV,
            "model": {"_target_": "model.diffusion.diffusion_eval_ft.DiffusionEval",
                      "ft_denoising_steps": "${ft_denoising_steps}", "predict_epsilon": True,
                      "denoised_clip_value": 1.0, "randn_clip_value": 3, **sampler,
                      "network_path": "${base_policy_path}", "network": diffusion_mlp(net), **MODEL_SIZES}}


def policy_folder(folder: Path, checkpoint: Path, config: Path) -> Path:
    """What a user puts together for goldenticket: the checkpoint, the run's config, normalization.npz."""
    folder.mkdir()
    shutil.copy(checkpoint, folder)
    shutil.copy(config, folder / "config.yaml")
    np.savez_compressed(folder / "normalization.npz", **NORMALIZATION)
    return folder


# ---- DPPO's sampling, and its env wrappers' normalisation -----------------------------------------------

def normalized(obs: np.ndarray) -> np.ndarray:
    """RobomimicLowdimWrapper.normalize_obs (env/gym_utils/wrapper/robomimic_lowdim.py)."""
    n = NORMALIZATION
    return 2 * ((obs - n["obs_min"]) / (n["obs_max"] - n["obs_min"] + 1e-6) - 0.5)


def unnormalized(action: np.ndarray) -> np.ndarray:
    """RobomimicLowdimWrapper.unnormalize_action."""
    n = NORMALIZATION
    return (action + 1) / 2 * (n["action_max"] - n["action_min"]) + n["action_min"]


@contextlib.contextmanager
def default_dtype(dtype: torch.dtype):
    before = torch.get_default_dtype()
    torch.set_default_dtype(dtype)
    try:
        yield
    finally:
        torch.set_default_dtype(before)


def ticket(seed: int, rows: int, dtype: torch.dtype = torch.float32) -> np.ndarray:
    """x_T as DPPO draws it after torch.manual_seed(seed): the first torch.randn((B, H, A))."""
    with default_dtype(dtype):
        torch.manual_seed(seed)
        return torch.randn((rows, H, ACT)).numpy()


def dppo_actions(model, states: np.ndarray, seed: int, act_steps: int = ACT_STEPS,
                 dtype: torch.dtype = torch.float32) -> np.ndarray:
    """The actions DPPO's eval agent executes (agent/eval/eval_diffusion_agent.py): normalised
    observations [B, cond_steps, obs_dim] as float32, model(cond, deterministic=True), the first
    act_steps of the chunk, unnormalised by the wrapper. With dtype float64, DPPO's code runs as it is on
    its weights in float64, torch's default dtype float64 (its noise schedule stays float32, as DPPO
    computes it)."""
    model = copy.deepcopy(model).to(dtype)
    with default_dtype(dtype), torch.no_grad():
        cond = {"state": torch.from_numpy(states).to(dtype)}
        torch.manual_seed(seed)
        chunk = model(cond=cond, deterministic=True).trajectories.numpy()
    return unnormalized(chunk[:, :act_steps])


def observations(rows: int, seed: int = 3) -> np.ndarray:
    """Raw observations [B, cond_steps, obs_dim], partly outside the normalization's range."""
    rng = np.random.default_rng(seed)
    n = NORMALIZATION
    return n["obs_min"] + rng.uniform(-0.2, 1.2, (rows, COND, OBS)) * (n["obs_max"] - n["obs_min"])


def difference(policy, model, dtype: torch.dtype = torch.float32, rows: int = 24, seed: int = 7) -> float:
    """Max abs difference between goldenticket's actions and DPPO's, on the same observations and x_T."""
    obs = observations(rows)
    ours = policy.act(obs, ticket(seed, rows, dtype))
    assert ours.shape == (rows, policy.n_exec, ACT)
    return float(np.abs(ours - dppo_actions(model, normalized(obs), seed, policy.n_exec, dtype)).max())


def assert_same_actions(policy, model) -> None:
    """DPPO's actions within TOLERANCE as it runs (float32), within CLOSE when it runs float64."""
    assert difference(policy, model) < TOLERANCE
    assert difference(policy, model, torch.float64) < CLOSE


def dppo_episode(model, env, seed: int, noise_seed: int, steps: int) -> np.ndarray:
    """The actions DPPO's eval loop executes in `env`: observations normalised as they come
    (RobomimicLowdimWrapper), the last cond_steps stacked oldest first, the first repeated while there are
    fewer (MultiStep's stack_last_n_obs, env/gym_utils/wrapper/multi_step.py), act_steps actions a call."""
    recent = deque([normalized(env.reset(seed))], maxlen=COND)
    executed = []
    while len(executed) < steps:
        states = np.stack([recent[0]] * (COND - len(recent)) + list(recent))[None]
        for action in dppo_actions(model, states, noise_seed)[0]:
            recent.append(normalized(env.step(action)[0]))
            executed.append(action)
    return np.array(executed[:steps])


# ---- the tests ---------------------------------------------------------------------------------------------

DDIM_OVER_T = {"use_ddim": True, "ddim_steps": T}  # what a DDPM config runs as here


def loaded(folder: Path, checkpoint: Path, config: Path, steps: str = ""):
    return load_policy(f"{policy_folder(folder, checkpoint, config)}{steps}")


@pytest.mark.parametrize("net", NETWORKS)
def test_a_pretraining_run_acts_as_dppos_fine_tuning_starts_from_it(dppo, tmp_path, net):
    """Its config (DiffusionModel, DDPM) runs DDIM over the 20 timesteps, `@N` N steps, with the "ema"
    weights: DPPO's PPODiffusion loading the checkpoint (ft_denoising_steps 0) with use_ddim and ddim_steps
    20 or N. Its eval config (DiffusionEval, DDPM) runs the "model" weights, as DPPO's."""
    checkpoint = pretraining_run(dppo, tmp_path / "run", net)
    config = tmp_path / "run" / ".hydra" / "config.yaml"
    for steps in (T, 5):
        policy = loaded(tmp_path / f"policy{steps}", checkpoint, config, f"@{steps}" if steps != T else "")
        sampler = {"use_ddim": True, "ddim_steps": steps}
        assert policy.n_obs_steps == COND and policy.n_exec == H  # no act_steps in the config: the chunk
        assert_same_actions(policy, ppo_model(dppo, checkpoint, net, sampler, 0))
        assert difference(policy, eval_model(dppo, checkpoint, net, sampler, 0)) > 100 * TOLERANCE
    config = hydra_config(tmp_path / "eval run", eval_config(net, {}, 0))
    evaluated = loaded(tmp_path / "eval", checkpoint, config)
    assert evaluated.n_exec == ACT_STEPS
    assert_same_actions(evaluated, eval_model(dppo, checkpoint, net, DDIM_OVER_T, 0))


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_dppos_eval_config_on_a_pretraining_checkpoint(dppo, tmp_path, sampler):
    settings = SAMPLERS[sampler]
    checkpoint = pretraining_run(dppo, tmp_path / "run", "robomimic")
    config = hydra_config(tmp_path / "eval run", eval_config("robomimic", settings, 0))
    policy = loaded(tmp_path / "policy", checkpoint, config)
    assert_same_actions(policy, eval_model(dppo, checkpoint, "robomimic", settings or DDIM_OVER_T, 0))


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_a_fine_tuning_run_acts_as_dppos_fine_tuned_policy(dppo, tmp_path, sampler):
    """Its config (PPODiffusion) runs the frozen base (actor.) and, at the last ft_denoising_steps, actor_ft:
    as the PPODiffusion DPPO saved (a DDIM run) or DPPO's DiffusionEval with use_ddim and ddim_steps 20 (a
    DDPM run, whose own sampling adds fresh noise at every step). DPPO's eval config runs the same with the
    run's ft_denoising_steps, and the base alone with 0."""
    settings, net = SAMPLERS[sampler], "furniture"
    ft_steps = 2 if settings else 10  # of 5 or 6 DDIM steps; of 20 DDPM steps, as DPPO's robomimic runs
    base = pretraining_run(dppo, tmp_path / "pre", net)
    model, checkpoint = fine_tuning_run(dppo, tmp_path / "ft", base, net, settings, ft_steps)
    dppo_sampler = settings or DDIM_OVER_T
    tuned = model if settings else eval_model(dppo, checkpoint, net, dppo_sampler, ft_steps)
    config = tmp_path / "ft" / ".hydra" / "config.yaml"
    assert_same_actions(loaded(tmp_path / "policy", checkpoint, config), tuned)
    for steps in (ft_steps, 0):
        config = hydra_config(tmp_path / f"eval run {steps}", eval_config(net, settings, steps))
        evaluated = loaded(tmp_path / f"eval {steps}", checkpoint, config)
        assert_same_actions(evaluated, eval_model(dppo, checkpoint, net, dppo_sampler, steps))
    assert difference(evaluated, tuned) > 100 * TOLERANCE  # the base alone acts otherwise


@needs_robosuite
def test_an_episode_of_lift_executes_dppos_actions(dppo, tmp_path, capsys):
    """DPPO's robomimic fine-tuning layout (DDPM, 20 timesteps, 10 fine-tuned) in Lift: goldenticket's
    rollout with the ticket executes the actions DPPO's eval loop executes from the same x_T; the folder
    runs through `goldenticket evaluate`."""
    from goldenticket.tasks.robomimic import RobomimicTask

    base = pretraining_run(dppo, tmp_path / "pre", "robomimic")
    _, checkpoint = fine_tuning_run(dppo, tmp_path / "ft", base, "robomimic", {}, 10)
    folder = policy_folder(tmp_path / "policy", checkpoint, tmp_path / "ft" / ".hydra" / "config.yaml")
    seed, noise_seed, steps = 1_000_000, 11, 4 * ACT_STEPS
    task = RobomimicTask("robomimic/lift", max_steps=steps)
    episode = Episode(Constant(ticket(noise_seed, 1)[0]), seed)
    ours = rollout(load_policy(str(folder)), task, [episode], record_actions=True)[0].actions
    reference = eval_model(dppo, checkpoint, "robomimic", DDIM_OVER_T, 10)
    theirs = dppo_episode(reference, task.make_env(), seed, noise_seed, steps)
    assert ours.shape == theirs.shape == (steps, ACT)
    assert np.abs(ours - theirs).max() < TOLERANCE
    assert main(["evaluate", "--policy", str(folder), "--task", "robomimic/lift",
                 "--seeds", "1000000:1000002", "--max-steps", "6"]) == 0
    assert "zero ticket     0.0%" in capsys.readouterr().out
