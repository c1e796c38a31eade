"""Train the LeRobot diffusion policy of `lerobot_reach.py` (or of `lerobot_button.py`) with LeRobot's
own tools, and copy its pretrained folder to `examples/lerobot_<task>_policy/`. In the LeRobot venv
(README, "LeRobot"):

    python examples/lerobot_train.py [--task reach|button] [--work runs/lerobot-train[-button]]

1. Demonstrations: Meta-World's scripted expert on goldenticket's training seeds, made imperfect
   as the bundled policies of the task were (reach: 20 demonstrators, each aiming at the goal
   shifted by U(+-4 cm), Gaussian action noise of std 0.15; button-press-topdown: 10, each seeing
   the button shifted by U(+-4 cm), noise of std 0.3; only successful episodes kept).
2. They are written as a LeRobotDataset (LeRobot's `LeRobotDataset.create`, `add_frame`,
   `save_episode`) in a local folder; nothing goes to a hub.
3. `lerobot-train` trains a state-only DiffusionPolicy on the CPU (DDIM, small U-Net), without
   wandb and without pushing to a hub; rerunning the script resumes from its last checkpoint.
"""

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from goldenticket.tasks import MetaWorldTask
from goldenticket.train import DemoStyle, collect_demos

sys.path.insert(0, str(Path(__file__).parent))
from lerobot_reach import MAX_STEPS, LeRobotMetaWorld, split

# name -> (Meta-World task, demonstrations, their style, the instruction in the dataset)
TASKS = {"reach": ("reach-v3", 20, DemoStyle(action_noise=0.15, goal_offset=0.04), "reach the goal"),
         "button": ("button-press-topdown-v3", 10, DemoStyle(action_noise=0.3, grasp_offset=0.04),
                    "press the button from the top")}
STEPS, SAVE_EVERY = 2_000, 500
POLICY = {  # DiffusionConfig fields that differ from LeRobot's defaults
    "noise_scheduler_type": "DDIM", "num_inference_steps": 10, "down_dims": "[32,64]",
    "diffusion_step_embed_dim": 32, "optimizer_lr": "5e-4", "scheduler_warmup_steps": 200,
    "device": "cpu", "push_to_hub": "false",
}
# One torch thread (two ran 6x slower on this 2-core machine shared with other jobs); no hub.
ENVIRONMENT = {"OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}


def make_dataset(task: str, root: Path) -> None:
    """`task`'s demonstrations as a LeRobotDataset at `root` (a new folder)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    metaworld_task, demos, style, instruction = TASKS[task]
    space = LeRobotMetaWorld.observation_space
    features = {
        "observation.state": {"dtype": "float32", "shape": space["agent_pos"].shape, "names": None},
        "observation.environment_state": {"dtype": "float32", "shape": space["environment_state"].shape,
                                          "names": None},
        "action": {"dtype": "float32", "shape": (4,), "names": None},
    }
    dataset = LeRobotDataset.create(f"local/metaworld-{task}", fps=LeRobotMetaWorld.metadata["render_fps"],
                                    features=features, root=root, use_videos=False)
    made = collect_demos(MetaWorldTask(f"metaworld/{metaworld_task}", max_steps=MAX_STEPS), demos, style)
    for observations, actions in zip(made.obs, made.actions, strict=True):
        for obs, action in zip(observations, actions, strict=True):
            parts = split(obs)
            dataset.add_frame({"observation.state": parts["agent_pos"],
                               "observation.environment_state": parts["environment_state"],
                               "action": action.astype(np.float32), "task": instruction})
        dataset.save_episode()
    dataset.finalize()
    print(f"{demos} demonstrations ({made.attempts} attempts), {dataset.num_frames} frames -> {root}")


def lerobot_train(out: Path, flags: list[str]) -> Path:
    """`lerobot-train` with `flags` into `out`, or resumed from its last checkpoint there, on one
    torch thread without a hub; the last checkpoint's pretrained folder."""
    last = out / "checkpoints" / "last"
    if (last / "pretrained_model").is_dir():
        flags = [f"--config_path={last / 'pretrained_model' / 'train_config.json'}", "--resume=true"]
    else:
        flags = [*flags, f"--output_dir={out}", "--num_workers=0", "--seed=0", "--wandb.enable=false"]
    print(" ".join(["lerobot-train", *flags]))
    subprocess.run([str(Path(sys.executable).with_name("lerobot-train")), *flags], check=True,
                   env=os.environ | ENVIRONMENT)
    return last / "pretrained_model"


def train(task: str, dataset: Path, out: Path) -> Path:
    """lerobot-train on `task`'s `dataset` into `out` (resumed from its last checkpoint); its
    pretrained folder."""
    return lerobot_train(out, [f"--dataset.repo_id=local/metaworld-{task}", f"--dataset.root={dataset}",
                               "--policy.type=diffusion", *(f"--policy.{k}={v}" for k, v in POLICY.items()),
                               f"--steps={STEPS}", "--batch_size=64", f"--save_freq={SAVE_EVERY}",
                               "--log_freq=500"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=list(TASKS), default="reach",
                        help="the Meta-World task (default: %(default)s)")
    parser.add_argument("--work", type=Path,
                        help="folder of the dataset and of lerobot-train's output (default: "
                             "runs/lerobot-train for reach, runs/lerobot-train-<task> for another)")
    args = parser.parse_args()
    work = args.work or Path("runs/lerobot-train" + ("" if args.task == "reach" else f"-{args.task}"))
    if not (work / "dataset" / "meta" / "info.json").is_file():
        shutil.rmtree(work / "dataset", ignore_errors=True)
        make_dataset(args.task, work / "dataset")
    pretrained = train(args.task, work / "dataset", work / "train")
    policy_dir = Path(__file__).with_name(f"lerobot_{args.task}_policy")
    shutil.rmtree(policy_dir, ignore_errors=True)
    shutil.copytree(pretrained, policy_dir)
    print(f"{pretrained} -> {policy_dir}")


if __name__ == "__main__":
    main()
