"""A small SmolVLA trained with LeRobot's own tools from a recipe (`smolvla_train.py` for Meta-World,
`smolvla_libero_train.py` for LIBERO-Object), in the LeRobot venv:

1. A SmolVLM backbone of the "small" size in `smolvla_backbone.py`, written offline.
2. The recipe's demonstrations (`goldenticket.train.collect_demos`), kept per task as they land,
   written as one LeRobotDataset (`LeRobotDataset.create`, `add_frame`, `save_episode`, the task's
   instruction as each frame's "task") in a local folder, with what collecting them took in
   `demos.json` beside it.
3. `lerobot-train` on the CPU without wandb; rerunning resumes from its last checkpoint, and
   `training.json` adds up the seconds it ran.
4. The recipe's checkpoint ships, with the backbone folder inside the policy folder, where
   goldenticket finds it; a model card already in the policy folder stays.
"""

import argparse
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from functools import reduce
from pathlib import Path

import numpy as np

from goldenticket.tasks import get_task
from goldenticket.train import DemoStyle, collect_demos

sys.path.insert(0, str(Path(__file__).parent))
from lerobot_train import lerobot_train
from smolvla_backbone import write_backbone

BACKBONE = "backbone"  # the folder inside the policy folder that holds the SmolVLM backbone
CARD = "MODEL_CARD.md"
BATCH = 32
SMALL_SMOLVLA = {  # SmolVLAConfig fields that differ from LeRobot's defaults, on the "small" backbone
    "load_vlm_weights": "false", "freeze_vision_encoder": "false", "train_expert_only": "false",
    "resize_imgs_with_padding": "[64,64]", "chunk_size": 8, "n_action_steps": 4, "num_steps": 10,
    "optimizer_lr": "5e-4", "scheduler_warmup_steps": 200,
}


@dataclass(frozen=True)
class Recipe:
    """What one SmolVLA learns from, how long it trains and where it ships."""

    name: str  # the dataset's repo id is local/<name>
    tasks: tuple[str, ...]
    observations: dict[str, tuple[str, ...]]  # dataset feature -> its keys in a task's observation
    fps: int  # the dataset's: the tasks' control rate
    demos: int  # per task
    style: DemoStyle
    policy: dict  # SmolVLAConfig fields that differ from LeRobot's defaults
    steps: int
    save_every: int
    shipped_step: int
    policy_dir: Path
    work: Path  # the default folder of the backbone, the dataset and lerobot-train's output
    task_options: dict = field(default_factory=dict)  # env options of every task (`get_task`)


def at(observations: dict, keys: tuple[str, ...]) -> np.ndarray:
    return reduce(dict.__getitem__, keys, observations)


def feature(array: np.ndarray) -> dict:
    """A LeRobotDataset feature for an episode's array: frames (uint8) are images, the rest float32."""
    if array.dtype == np.uint8:
        return {"dtype": "image", "shape": array.shape[1:], "names": ["height", "width", "channels"]}
    return {"dtype": "float32", "shape": array.shape[1:], "names": None}


def frames(episode: dict[str, np.ndarray], instruction: str):
    """One episode's frames (its dataset features' arrays) as `LeRobotDataset.add_frame` takes them."""
    for t in range(len(episode["action"])):
        frame = {key: value[t] if value.dtype == np.uint8 else value[t].astype(np.float32)
                 for key, value in episode.items()}
        yield frame | {"task": instruction}


def task_demos(recipe: Recipe, name: str, folder: Path) -> tuple[list[dict[str, np.ndarray]], dict]:
    """One task's demonstrations (each episode's dataset features' arrays) and its record: instruction,
    attempts, collection seconds. Kept in `folder` as each task lands, so a stopped run collects only
    the tasks still missing."""
    arrays, record = folder / f"{name.replace('/', '-')}.npz", folder / f"{name.replace('/', '-')}.json"
    if not record.is_file():
        task = get_task(name, env_options=recipe.task_options)
        start = time.perf_counter()
        demos = collect_demos(task, recipe.demos, recipe.style)
        seconds = time.perf_counter() - start
        features = recipe.observations.items()
        episodes = [{key: at(observations, keys) for key, keys in features} | {"action": actions}
                    for observations, actions in zip(demos.obs, demos.actions, strict=True)]
        folder.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(arrays, **{f"{i}|{key}": value for i, episode in enumerate(episodes)
                                       for key, value in episode.items()})
        record.write_text(json.dumps({"instruction": task.instruction, "demos": recipe.demos,
                                      "attempts": demos.attempts, "seconds": round(seconds, 1)}) + "\n")
        print(f"{name}: {recipe.demos} demonstrations ({demos.attempts} attempts): {task.instruction!r}")
    with np.load(arrays) as saved:
        episodes = [{} for _ in range(recipe.demos)]
        for key in saved.files:
            index, feature_key = key.split("|")
            episodes[int(index)][feature_key] = saved[key]
    return episodes, json.loads(record.read_text())


def make_dataset(recipe: Recipe, work: Path) -> None:
    """The demonstrations of every task (collected into `work`/demos) as one LeRobotDataset in
    `work`/dataset (a new folder), and `demos.json` beside it when it is whole: each task's record."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = work / "dataset"
    shutil.rmtree(root, ignore_errors=True)
    collected = {name: task_demos(recipe, name, work / "demos") for name in recipe.tasks}
    first = next(iter(collected.values()))[0][0]
    dataset = LeRobotDataset.create(f"local/{recipe.name}", fps=recipe.fps, root=root, use_videos=False,
                                    features={key: feature(value) for key, value in first.items()})
    for episodes, record in collected.values():
        for episode in episodes:
            for frame in frames(episode, record["instruction"]):
                dataset.add_frame(frame)
            dataset.save_episode()
    dataset.finalize()
    (work / "demos.json").write_text(json.dumps({name: record for name, (_, record) in collected.items()},
                                                indent=1) + "\n")
    print(f"{dataset.num_episodes} episodes, {dataset.num_frames} frames -> {root}")


def train(recipe: Recipe, dataset: Path, backbone: Path, out: Path) -> Path:
    """lerobot-train on `dataset` into `out` (resumed from its last checkpoint); the shipped step's
    pretrained folder."""
    policy = recipe.policy | {"scheduler_decay_steps": recipe.steps, "device": "cpu", "push_to_hub": "false"}
    lerobot_train(out, [f"--dataset.repo_id=local/{recipe.name}", f"--dataset.root={dataset}",
                        "--policy.type=smolvla", f"--policy.vlm_model_name={backbone}",
                        *(f"--policy.{k}={v}" for k, v in policy.items()), f"--steps={recipe.steps}",
                        f"--batch_size={BATCH}", f"--save_freq={recipe.save_every}", "--log_freq=100"])
    return out / "checkpoints" / f"{recipe.shipped_step:06d}" / "pretrained_model"


def ship(recipe: Recipe, pretrained: Path, backbone: Path) -> None:
    """The pretrained folder, with the backbone inside it and named relative to it; a model card
    already in the policy folder stays."""
    target = recipe.policy_dir
    card = (target / CARD).read_text() if (target / CARD).is_file() else None
    shutil.rmtree(target, ignore_errors=True)
    shutil.copytree(pretrained, target, ignore=shutil.ignore_patterns("train_config.json"))
    shutil.copytree(backbone, target / BACKBONE)
    for name in ("config.json", "policy_preprocessor.json"):
        path = target / name
        path.write_text(path.read_text().replace(json.dumps(str(backbone)), json.dumps(BACKBONE)))
    if card is not None:
        (target / CARD).write_text(card)
    print(f"{pretrained} -> {target}")


def build(recipe: Recipe, work: Path) -> None:
    """Backbone, dataset and training in `work` (each step skipped where its output is there, training
    resumed), then the recipe's checkpoint shipped; `training.json` in `work` adds up the seconds
    lerobot-train ran, over all calls."""
    work = work.resolve()
    backbone = work / BACKBONE
    if not (backbone / "config.json").is_file():
        write_backbone(backbone, "small")
    if not (work / "demos.json").is_file():
        make_dataset(recipe, work)
    start = time.perf_counter()
    pretrained = train(recipe, work / "dataset", backbone, work / "train")
    timing = work / "training.json"
    seconds = json.loads(timing.read_text())["seconds"] if timing.is_file() else 0.0
    timing.write_text(json.dumps({"seconds": round(seconds + time.perf_counter() - start, 1)}) + "\n")
    ship(recipe, pretrained, backbone)


def work_folder(recipe: Recipe, description: str) -> Path:
    """The --work folder from the command line."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--work", type=Path, default=recipe.work,
                        help="folder of the backbone, the dataset and lerobot-train's output "
                        "(default: %(default)s)")
    return parser.parse_args().work
