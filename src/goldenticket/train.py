"""Demonstrations from scripted experts (Meta-World's, robomimic's Lift, Can, Square and Transport,
LIBERO-Object's), and deterministic policy training."""

from __future__ import annotations

import glob
import hashlib
import io
import json
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional
from tqdm import tqdm

from goldenticket.config import EngineOptions, TrainConfig
from goldenticket.errors import OptionError, UserError
from goldenticket.files import new_folder_beside, write_atomic
from goldenticket.policies import mlp
from goldenticket.policies.mlp import Denoiser, MLPPolicy, PolicyConfig, ddim_alpha_bar
from goldenticket.seeds import seeds_in
from goldenticket.stats import Rate
from goldenticket.store import RunStore
from goldenticket.tasks import MetaWorldTask, get_task, libero_experts, robomimic_experts
from goldenticket.tasks.base import stack
from goldenticket.tasks.lerobot_envs import LeRobotEnvTask
from goldenticket.tasks.metaworld import STATE_DIM
from goldenticket.tasks.pixels import SIZE as PIXELS
from goldenticket.tasks.pixels import PixelsTask
from goldenticket.tasks.robomimic import RobomimicTask

ExpertTask = MetaWorldTask | RobomimicTask | LeRobotEnvTask  # the tasks with scripted experts


@dataclass(frozen=True)
class DemoStyle:
    """How imperfect the demonstrators are.

    Each demonstration comes from an expert with its own habit: it sees the object (and the
    goal) shifted by constant offsets drawn per episode from U(-offset, offset) in x and y, so
    it grasps or aims off-centre in its own way; on top, Gaussian action noise. Only
    successful demos are kept.
    """

    grasp_offset: float = 0.0
    action_noise: float = 0.0
    goal_offset: float = 0.0

    def habit(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One demonstrator's constant (grasp, goal) shifts in x and y."""
        grasp = rng.uniform(-self.grasp_offset, self.grasp_offset, 2)
        goal = rng.uniform(-self.goal_offset, self.goal_offset, 2) if self.goal_offset else np.zeros(2)
        return grasp, goal

    def describe(self) -> str:
        aims = [f"the object shifted by U(+-{self.grasp_offset}) m"] if self.grasp_offset else []
        aims += [f"the goal shifted by U(+-{self.goal_offset}) m"] if self.goal_offset else []
        habit = f"aims at {' and '.join(aims)} in x and y (drawn per episode), plus " if aims else ""
        return f"each demonstrator {habit}Gaussian action noise (std {self.action_noise})"


@dataclass
class Demos:
    obs: list[np.ndarray]  # per episode [T, obs_dim], or [T, obs_dim + tasks] with a task one-hot
    actions: list[np.ndarray]  # per episode [T, action_dim]
    attempts: int
    seconds: float = 0.0  # the wall time their collection took

    @classmethod
    def of_tasks(cls, per_task: list[Demos]) -> Demos:
        """One multi-task dataset: each episode's observations followed by its task's one-hot."""
        merged = cls([], [], sum(d.attempts for d in per_task), sum(d.seconds for d in per_task))
        for index, demos in enumerate(per_task):
            for obs, actions in zip(demos.obs, demos.actions, strict=True):
                one_hot = np.zeros((len(obs), len(per_task)), np.float32)
                one_hot[:, index] = 1
                merged.obs.append(np.concatenate([obs, one_hot], axis=1))
                merged.actions.append(actions)
        return merged

    def to_bytes(self) -> bytes:
        """The demonstrations as an .npz file's bytes (`from_file` reads them back)."""
        arrays = {"attempts": np.array(self.attempts), "seconds": np.array(self.seconds)}
        for i, (obs, actions) in enumerate(zip(self.obs, self.actions, strict=True)):
            arrays |= {f"actions/{i}": actions} | dict(_flat(obs, f"obs/{i}"))
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        return buffer.getvalue()

    @classmethod
    def from_file(cls, path: Path) -> Demos:
        with np.load(path, allow_pickle=False) as arrays:
            tree: dict = {}
            for name in arrays.files:
                *parents, leaf = name.split("/")
                node = tree
                for key in parents:
                    node = node.setdefault(key, {})
                node[leaf] = arrays[name]
        episodes = range(len(tree["actions"]))
        return cls([tree["obs"][str(i)] for i in episodes], [tree["actions"][str(i)] for i in episodes],
                   int(tree["attempts"]), float(tree["seconds"]))


def _flat(obs, prefix: str) -> Iterator[tuple[str, np.ndarray]]:
    """(path, array) for an observation array or a nested dict of them."""
    if not isinstance(obs, dict):
        yield prefix, obs
        return
    for key, value in obs.items():
        yield from _flat(value, f"{prefix}/{key}")


def kept_demos(out: Path, task: ExpertTask, n: int, style: DemoStyle, seed: int) -> Demos:
    """`collect_demos`, kept in a hidden file beside `out` named by the recipe: a killed build, run
    again, trains on the same demonstrations instead of collecting them again (a Transport recipe's
    take most of an hour). `forget_kept_demos` removes the file once the policy is written; the name
    knows the recipe, not the expert's code: delete the file to collect afresh after changing it."""
    recipe = json.dumps([task.name, n, asdict(style), seed]).encode()
    path = kept_beside(out, hashlib.sha256(recipe).hexdigest(), "demos.npz")
    if path.is_file():
        return Demos.from_file(path)
    demos = collect_demos(task, n, style, seed)
    write_atomic(path, demos.to_bytes())
    return demos


def forget_kept_demos(out: Path) -> None:
    """Remove the demonstrations `kept_demos` kept beside `out`, once its policy is written."""
    pattern = kept_beside(out.with_name(glob.escape(out.name)), "?" * 16, "demos.npz").name
    for kept in out.parent.glob(pattern):  # any recipe's digest, and no other folder's files
        kept.unlink(missing_ok=True)


def kept_beside(out: Path, digest: str, kind: str) -> Path:
    """The hidden file beside `out` that keeps a build's `kind` of work ("demos.npz",
    "episodes.sqlite") under `digest` until the policy is written."""
    return out.with_name(f".{out.name}.{digest[:16]}.{kind}")


def collect_demos(task: ExpertTask, n: int, style: DemoStyle, seed: int = 0) -> Demos:
    """`n` successful scripted-expert demonstrations on training seeds."""
    env = task.make_env()
    experts = _experts(task, env)
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    demos = Demos([], [], 0)
    bar = tqdm(total=n, desc="demonstrations", unit="demo")
    for episode_seed in seeds_in("train", 100 * n):
        if len(demos.obs) == n:
            break
        expert = experts(*style.habit(rng))
        obs_seq, act_seq, success = _expert_episode(expert, env, task, episode_seed, style.action_noise, rng)
        demos.attempts += 1
        if success:
            demos.obs.append(obs_seq)
            demos.actions.append(act_seq)
            bar.update()
    bar.close()
    demos.seconds = time.perf_counter() - start
    if len(demos.obs) < n:
        raise UserError(f"only {len(demos.obs)} of {n} expert demos succeeded in {demos.attempts} "
                        "attempts; lower --grasp-offset, --goal-offset or --action-noise")
    return demos


Expert = Callable[[np.ndarray], np.ndarray]  # one episode's expert: observation -> action


def _experts(task: ExpertTask, env) -> Callable[[np.ndarray, np.ndarray], Expert]:
    """The task's scripted expert for a demonstrator's (grasp, goal) shifts. Meta-World's experts
    read the env's full state, whatever the policy will see, with the shifts added to the object's
    and the goal's x and y."""
    experts = {RobomimicTask: robomimic_experts, LeRobotEnvTask: libero_experts}.get(type(task))
    if experts:
        experts.check(task.name)
        return lambda grasp, goal: experts.expert(task.name, env, grasp, goal).act
    from metaworld.policies import ENV_POLICY_MAP

    if task.env_name not in ENV_POLICY_MAP:
        raise UserError(f"no scripted expert for {task.name}")
    scripted = ENV_POLICY_MAP[task.env_name]()

    def expert(grasp: np.ndarray, goal: np.ndarray) -> Expert:
        offset = np.zeros(STATE_DIM)
        offset[4:6], offset[-3:-1] = grasp, goal
        return lambda obs: scripted.get_action(env.state.astype(np.float64) + offset)

    return expert


def _expert_episode(expert: Expert, env, task, seed, noise, rng):
    """One episode of the expert, with Gaussian action noise."""
    obs, obs_seq, act_seq, success = env.reset(seed), [], [], False
    for _ in range(task.max_steps):
        action = np.clip(expert(obs) + noise * rng.standard_normal(task.action_dim), -1, 1)
        obs_seq.append(obs)
        act_seq.append(action.astype(np.float32))
        obs, success, _ = env.step(action)
        if success:
            break
    return stack(obs_seq), np.array(act_seq), success


def chunk_dataset(demos: Demos, horizon: int) -> tuple[np.ndarray | dict[str, np.ndarray], np.ndarray]:
    """(obs_t, actions t..t+H-1) pairs; past the end, the last action repeats."""
    chunks = []
    for a in demos.actions:
        padded = np.concatenate([a, np.repeat(a[-1:], horizon - 1, axis=0)])
        chunks.append(np.stack([padded[t : t + horizon] for t in range(len(a))]))
    return stack(demos.obs, np.concatenate), np.concatenate(chunks)


def train_policy(cfg: PolicyConfig, demos: Demos, *, steps: int = 20_000, batch: int = 256,
                 lr: float = 1e-3, seed: int = 0) -> tuple[MLPPolicy, list[float]]:
    """Train a denoiser on demo chunks; deterministic for a seed. Returns policy and loss curve.

    Runs on one thread: the thread count changes floating-point reduction order, so it is part
    of what makes training reproducible.
    """
    torch.set_num_threads(1)
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    obs_np, act_np = chunk_dataset(demos, cfg.horizon)
    model = Denoiser(cfg)
    state = obs_np["agent_pos"] if cfg.image_size else obs_np[:, : cfg.obs_dim]  # a task one-hot: as is
    model.obs_mean.copy_(torch.as_tensor(state.mean(0)))
    model.obs_std.copy_(torch.as_tensor(state.std(0) + 1e-3))
    inputs = _network_inputs(model, obs_np)
    act = model.normalise_actions(torch.as_tensor(act_np))
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    losses, running = [], []
    for step in tqdm(range(steps), desc=f"training {cfg.name}", unit="step", mininterval=1):
        idx = torch.randint(len(act), (batch,), generator=gen)
        loss = _denoising_loss(model, cfg, inputs(idx, gen), act[idx], gen)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        running.append(loss.item())
        if len(running) == 1000 or step == steps - 1:  # mean per 1k steps; the last may be shorter
            losses.append(sum(running) / len(running))
            running = []
    return MLPPolicy(cfg, model), losses


SHIFT = 4  # training frames move by up to this many pixels each way (random-shift augmentation)


def _network_inputs(model: Denoiser, obs_np) -> Callable[[torch.Tensor, torch.Generator], torch.Tensor]:
    """The network's inputs for a batch of row indices: observations standardised once, or frames
    encoded batch by batch (the encoder learns), each shifted by up to SHIFT pixels."""
    if not isinstance(obs_np, dict):
        obs = model.normalise_obs(torch.as_tensor(obs_np, dtype=torch.float32))  # robosuite's are float64
        return lambda idx, gen: obs[idx]
    pixels, agent_pos = torch.as_tensor(obs_np["pixels"]), torch.as_tensor(obs_np["agent_pos"])

    def encoded(idx: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        return model.normalise_obs({"pixels": shifted(pixels[idx], gen), "agent_pos": agent_pos[idx]})

    return encoded


def shifted(frames: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Frames [B, S, S, 3], each moved by its own random offset of up to SHIFT pixels per axis
    (edges repeated), as float."""
    size = frames.shape[1]
    padded = functional.pad(frames.permute(0, 3, 1, 2).float(), (SHIFT,) * 4, mode="replicate")
    rows, cols = torch.randint(2 * SHIFT + 1, (2, len(frames)), generator=gen).tolist()
    crops = [p[:, r : r + size, c : c + size] for p, r, c in zip(padded, rows, cols, strict=True)]
    return torch.stack(crops).permute(0, 2, 3, 1)


def _denoising_loss(model, cfg, obs, x0, gen):
    noise = torch.randn(x0.shape, generator=gen)
    if cfg.kind == "flow":  # x_t = t * noise + (1 - t) * x0, velocity = noise - x0
        t = torch.rand(len(x0), generator=gen)
        xt = t[:, None, None] * noise + (1 - t[:, None, None]) * x0
        return torch.mean((model(obs, xt, t) - (noise - x0)) ** 2)
    k = torch.randint(cfg.train_timesteps, (len(x0),), generator=gen)
    t = k.float() / (cfg.train_timesteps - 1)
    a = ddim_alpha_bar(t)[:, None, None]
    xt = a.sqrt() * x0 + (1 - a).sqrt() * noise
    return torch.mean((model(obs, xt, t) - noise) ** 2)


def build_policy(cfg: TrainConfig, out: Path) -> dict:
    """Collect demos, train, measure base and zero-ticket success, write the policy folder `out`.
    A `metaworld-pixels/` task gives a policy that sees its camera's frames and `agent_pos`.

    Everything is written to a hidden folder beside `out` that becomes `out` only when complete,
    so a failed or interrupted run leaves no half-written policy."""
    cfg.check()
    seeds_in("heldout", cfg.heldout)  # a UserError now, not after training
    task = get_task(cfg.task)
    if not isinstance(task, MetaWorldTask | RobomimicTask):
        raise OptionError("train needs a built-in task with scripted experts (Meta-World's, "
                          f"{', '.join(robomimic_experts.EXPERTS)}), got {cfg.task!r}", "task")
    name = f"{cfg.task}/{cfg.kind}"
    style = DemoStyle(cfg.grasp_offset, cfg.action_noise, cfg.goal_offset)
    policy_cfg = PolicyConfig(name, cfg.kind, task.obs_dim, task.action_dim, cfg.horizon, cfg.n_exec,
                              steps=cfg.denoise_steps,
                              image_size=PIXELS if isinstance(task, PixelsTask) else None)

    def fill(folder: Path) -> dict:
        demos = kept_demos(out, task, cfg.demos, style, cfg.seed)
        start = time.perf_counter()
        policy, losses = train_policy(policy_cfg, demos, steps=cfg.steps, batch=cfg.batch, seed=cfg.seed)
        trained = time.perf_counter() - start
        policy.save(folder)
        with measurement_store(out, folder) as store:
            measured = measure(folder, task, cfg.heldout, cfg.workers, store=store)
            cost = build_cost(demos.seconds, trained, store)
        return {"policy": name, "demos": cfg.demos, "demo_attempts": demos.attempts,
                "style": asdict(style), "train_steps": cfg.steps, "batch": cfg.batch, "seed": cfg.seed,
                "loss_per_1k_steps": [round(x, 5) for x in losses]} | measured | cost

    return _into_new_folder(out, fill, policy_cfg)


def build_multitask_policy(name: str, recipes: dict[str, tuple[int, DemoStyle]], kind: str, out: Path, *,
                           steps: int, denoise_steps: int, hidden: int = 256, horizon: int = 8,
                           n_exec: int = 4, seed: int = 0, heldout: int = 200, workers: int = 1) -> dict:
    """One network for several Meta-World tasks, told which by a one-hot: trained on each task's
    (n_demos, style) demonstrations, measured per task; written like `build_policy`."""
    tasks = [get_task(t) for t in recipes]
    if not all(isinstance(t, MetaWorldTask) for t in tasks):
        raise UserError("a multi-task policy needs built-in Meta-World tasks (scripted experts)")
    cfg = PolicyConfig(name, kind, tasks[0].obs_dim, tasks[0].action_dim, horizon, n_exec, hidden=hidden,
                       steps=denoise_steps, tasks=list(recipes))

    def fill(folder: Path) -> dict:
        per_task = [kept_demos(out, t, n, style, seed) for t, (n, style) in zip(tasks, recipes.values(),
                                                                              strict=True)]
        start = time.perf_counter()
        policy, losses = train_policy(cfg, Demos.of_tasks(per_task), steps=steps, seed=seed)
        trained = time.perf_counter() - start
        policy.save(folder)
        card = {"policy": name, "demos": sum(len(d.obs) for d in per_task), "train_steps": steps,
                "seed": seed, "loss_per_1k_steps": [round(x, 5) for x in losses], "tasks": {}}
        with measurement_store(out, folder) as store:
            for task, demos, (n, style) in zip(tasks, per_task, recipes.values(), strict=True):
                card["tasks"][task.name] = {"demos": n, "demo_attempts": demos.attempts,
                                            "style": asdict(style)} | measure(folder, task, heldout, workers,
                                                                              store=store)
            card |= build_cost(sum(d.seconds for d in per_task), trained, store)
        for arm in ("base", "zero"):  # over all tasks' episodes: the task average
            rates = [entry[arm] for entry in card["tasks"].values()]
            card[arm] = Rate.counted(sum(round(r["success_rate"] * r["n"]) for r in rates),
                                     sum(r["n"] for r in rates)).to_dict()
        return card

    return _into_new_folder(out, fill, cfg)


def _into_new_folder(out: Path, fill: Callable[[Path], dict], cfg: PolicyConfig) -> dict:
    """`fill` a hidden folder beside `out` (it returns the card), write the card, then rename the
    folder to `out`: a failed or interrupted build leaves no half-written policy."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f"--out {out} already exists; choose a new folder")
    partial = new_folder_beside(out)  # an OSError now if `out` cannot be written
    try:
        write_card(partial, fill(partial), cfg)
        if out.exists():
            out.rmdir()
        partial.rename(out)
        forget_kept_demos(out)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return json.loads((out / "card.json").read_text())


@contextmanager
def measurement_store(out: Path, folder: Path) -> Iterator[RunStore]:
    """A run store for measuring the policy just saved in `folder`, beside `out` and named by the
    policy's files: a killed build, run again, trains the same policy and runs only the episodes
    its measurement had not recorded. Removed once the measurement is complete."""
    digest = hashlib.sha256()
    for file in sorted(f for f in folder.iterdir() if f.is_file()):
        digest.update(file.name.encode() + file.read_bytes())
    path = kept_beside(out, digest.hexdigest(), "episodes.sqlite")
    with RunStore(path) as store:
        yield store
    for file in path.parent.glob(f"{glob.escape(path.name)}*"):  # the store and what SQLite keeps beside it
        file.unlink()


def build_cost(demos_seconds: float, train_seconds: float, store: RunStore) -> dict:
    """What a build took: collecting its demonstrations and training (wall time, one core), and
    its measurement's episodes' own times (`episodes_seconds`)."""
    return {"wall_s": {"demos": round(demos_seconds, 1), "train": round(train_seconds, 1),
                       "measure_episodes": episodes_seconds(store)}}


def episodes_seconds(store: RunStore) -> float:
    """The episodes' own wall times in `store`, summed (one core each): over every part of a
    measurement stopped and resumed, where a wall clock counts only the last."""
    return round(sum(row.wall_time for row in store.episodes()), 1)


def measure(policy_dir: Path, task, heldout: int, workers: int = 1, *,
            noise_shape: tuple[int, ...] | None = None, store: RunStore | None = None) -> dict:
    """Base and zero-ticket success of a saved policy on the first `heldout` held-out seeds; its
    zero ticket has `noise_shape` (default: the goldenticket policy's); episodes go to `store`."""
    from goldenticket.evaluation import BASE, ZERO, Evaluator, judge
    from goldenticket.noise import Constant

    shape = noise_shape or MLPPolicy.load(policy_dir).noise_shape
    with Evaluator.open(str(policy_dir), task, EngineOptions(workers=workers), store=store) as evaluator:
        zero = Constant(np.zeros(shape, np.float32))
        with evaluator.progress(2 * heldout, "held-out: base and zero ticket"):
            rows = judge(evaluator, {ZERO: zero}, seeds_in("heldout", heldout)).rows
    return {arm.key: rows[arm].to_dict() for arm in (BASE, ZERO)}


def write_card(directory: Path, card: dict, cfg: PolicyConfig) -> None:
    """card.json (the measured numbers) and MODEL_CARD.md (the same, for people)."""
    write_atomic(directory / "card.json", json.dumps(card, indent=2) + "\n")
    write_atomic(directory / "MODEL_CARD.md", model_card(card, cfg))


TARGET_BAND = (0.2, 0.85)  # base success where a golden ticket has room to help


def band_note(base_rate: float) -> str:
    low, high = TARGET_BAND
    if low <= base_rate <= high:
        return ""
    return (f"\n- **Outside the target band**: base success is outside the suite's {low:.0%}-{high:.0%}"
            " band with this recipe; shipped anyway.")


def _rate(r: dict) -> str:
    return f"{r['success_rate']:.1%} (95% Wilson [{r['ci_low']:.1%}, {r['ci_high']:.1%}], n={r['n']})"


def model_card(card: dict, cfg: PolicyConfig) -> str:
    """A short human-readable model card from the measured numbers."""
    if "tasks" in card:
        return multitask_card(card, cfg)
    style = DemoStyle(**card["style"])
    return f"""# {card['policy']}

{_model_lines(card, cfg)}
- **Data**: {card['demos']} successful scripted-expert demonstrations (of {card['demo_attempts']}
  attempts) on training seeds, disjoint from search and held-out seeds.
- **Why it is imperfect**: few, noisy, multimodal demonstrations: {style.describe()}. The
  policy learns that spread of habits; fresh noise at each replan mixes them within one episode.
{_training_line(card, cfg)}
- **Held-out success** (first {card['base']['n']} held-out seeds):
  - base policy (fresh Gaussian noise at every call): {_rate(card['base'])}
  - zero ticket (w = 0): {_rate(card['zero'])}{band_note(card['base']['success_rate'])}

Rebuild: `goldenticket train --task {card['policy'].rsplit('/', 1)[0]} --kind {cfg.kind} \\
--demos {card['demos']} --grasp-offset {card['style']['grasp_offset']} \\
--goal-offset {style.goal_offset} --action-noise {style.action_noise} \\
--steps {card['train_steps']}{_batch_flag(card)} --seed {card['seed']} \\
--horizon {cfg.horizon} --n-exec {cfg.n_exec} --denoise-steps {cfg.steps} --out DIR`
{REBUILD_NOTE}{FRAMES_NOTE if cfg.image_size else ""}"""


def multitask_card(card: dict, cfg: PolicyConfig) -> str:
    """The model card of a multi-task policy: demonstrations and held-out success per task."""
    rows = "\n".join(f"| {task} | {t['demos']} of {t['demo_attempts']}: {DemoStyle(**t['style']).describe()} "
                      f"| {_rate(t['base'])} | {_rate(t['zero'])} |" for task, t in card["tasks"].items())
    return f"""# {card['policy']}

{_model_lines(card, cfg)}
- **Task conditioning**: one network for {len(cfg.tasks)} tasks; it sees the observation followed by
  a one-hot over its tasks (in the order below). Tickets, search and evaluation name the task.
- **Data**: {card['demos']} successful scripted-expert demonstrations on training seeds (disjoint
  from search and held-out seeds), with each task's single-task recipe: few, noisy, multimodal.
{_training_line(card, cfg)}
- **Held-out success** per task (first {card['base']['n'] // len(cfg.tasks)} held-out seeds each); over all
  tasks: base {_rate(card['base'])}, zero ticket {_rate(card['zero'])}.

| task | demonstrations (kept of attempts): why imperfect | base policy | zero ticket |
|---|---|---|---|
{rows}

Rebuild: `python benchmarks/build_zoo.py --multitask --only {cfg.kind}` (seed {card['seed']},
{card['train_steps']} steps).
{REBUILD_NOTE}"""


def _model_lines(card: dict, cfg: PolicyConfig) -> str:
    return f"""- **Model**: {cfg.kind} MLP denoiser, {cfg.layers} x {cfg.hidden} GELU; predicts {cfg.horizon}
  actions, executes {cfg.n_exec} then replans; {cfg.steps} {'Euler' if cfg.kind == 'flow' else 'DDIM'} steps
  (another count at load time: `{card['policy']}@N`).{_encoder_line(cfg)}"""


def _encoder_line(cfg: PolicyConfig) -> str:
    if not cfg.image_size:
        return ""
    return f"""
- **Sees**: a {cfg.image_size} x {cfg.image_size} RGB frame (`pixels`), encoded by three 3 x 3 stride-2
  convolutions ({', '.join(map(str, mlp.ConvEncoder.CHANNELS[1:]))} channels, GELU) and a linear layer to
  {mlp.FEATURES} features, beside `agent_pos` (hand x, y, z and gripper); the goal and objects are only
  in the frame."""


def _batch_flag(card: dict) -> str:
    return f" --batch {card['batch']}" if card.get("batch", 256) != 256 else ""


def _training_line(card: dict, cfg: PolicyConfig) -> str:
    losses, steps = card["loss_per_1k_steps"], card["train_steps"]
    rate = "cosine learning rate" + (f", frames shifted by up to {SHIFT} px" if cfg.image_size else "")
    return f"""- **Training**: {steps} AdamW steps, batch {card.get('batch', 256)}, {rate}, seed
  {card['seed']}; mean loss over the first / last (up to) 1k steps: {losses[0]:.4f} / {losses[-1]:.4f}.""" + \
        _cost_line(card)


def _cost_line(card: dict) -> str:
    """What the build took, where its card records it (cards of earlier builds do not)."""
    if "wall_s" not in card:
        return ""
    minutes = {key: f"{seconds / 60:.1f} min" for key, seconds in card["wall_s"].items()}
    return f"""
- **Build time**: demonstrations {minutes['demos']}, training {minutes['train']}, measurement
  {minutes['measure_episodes']} of episodes (one core each, summed over every part of a resumed build)."""


REBUILD_NOTE = """\
(training runs in float32: bit for bit on the same kind of CPU; on another CPU the weights, and so
the fingerprint and the numbers, differ. Rollouts of these weights give the same episodes on any
x86-64 CPU with AVX2 and FMA.)
"""

FRAMES_NOTE = """\
The frames come from Mesa's software rasterizer (llvmpipe) through EGL: the same episodes need the
same frames, so the same Mesa release as well (a resumed run stops with one line when a seed's
initial frame differs from the one it recorded).
"""
