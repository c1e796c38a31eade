"""Train the LeRobot diffusion policy of `lerobot_reach.py` with LeRobot's own tools, and copy its
pretrained folder to `examples/lerobot_reach_policy/`. In the LeRobot venv (README, "LeRobot"):

    python examples/lerobot_train.py [--work runs/lerobot-train]

1. Demonstrations: Meta-World's scripted reach expert on goldenticket's training seeds, made
   imperfect as the bundled reach policies' were (each demonstrator aims at the goal shifted by
   U(+-4 cm), Gaussian action noise of std 0.15, only successful episodes kept).
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
from lerobot_reach import MAX_STEPS, LeRobotReach, split

POLICY_DIR = Path(__file__).with_name("lerobot_reach_policy")
DEMOS, STYLE = 20, DemoStyle(action_noise=0.15, goal_offset=0.04)
STEPS, SAVE_EVERY = 2_000, 500
POLICY = {  # DiffusionConfig fields that differ from LeRobot's defaults
    "noise_scheduler_type": "DDIM", "num_inference_steps": 10, "down_dims": "[32,64]",
    "diffusion_step_embed_dim": 32, "optimizer_lr": "5e-4", "scheduler_warmup_steps": 200,
    "device": "cpu", "push_to_hub": "false",
}
# One torch thread (two ran 6x slower on this 2-core machine shared with other jobs); no hub.
ENVIRONMENT = {"OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}


def make_dataset(root: Path) -> None:
    """The demonstrations as a LeRobotDataset at `root` (a new folder)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    space = LeRobotReach.observation_space
    features = {
        "observation.state": {"dtype": "float32", "shape": space["agent_pos"].shape, "names": None},
        "observation.environment_state": {"dtype": "float32", "shape": space["environment_state"].shape,
                                          "names": None},
        "action": {"dtype": "float32", "shape": (4,), "names": None},
    }
    dataset = LeRobotDataset.create("local/metaworld-reach", fps=LeRobotReach.metadata["render_fps"],
                                    features=features, root=root, use_videos=False)
    demos = collect_demos(MetaWorldTask("metaworld/reach-v3", max_steps=MAX_STEPS), DEMOS, STYLE)
    for observations, actions in zip(demos.obs, demos.actions, strict=True):
        for obs, action in zip(observations, actions, strict=True):
            parts = split(obs)
            dataset.add_frame({"observation.state": parts["agent_pos"],
                               "observation.environment_state": parts["environment_state"],
                               "action": action.astype(np.float32), "task": "reach the goal"})
        dataset.save_episode()
    dataset.finalize()
    print(f"{DEMOS} demonstrations ({demos.attempts} attempts), {dataset.num_frames} frames -> {root}")


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


def train(dataset: Path, out: Path) -> Path:
    """lerobot-train on `dataset` into `out` (resumed from its last checkpoint); its pretrained folder."""
    return lerobot_train(out, ["--dataset.repo_id=local/metaworld-reach", f"--dataset.root={dataset}",
                               "--policy.type=diffusion", *(f"--policy.{k}={v}" for k, v in POLICY.items()),
                               f"--steps={STEPS}", "--batch_size=64", f"--save_freq={SAVE_EVERY}",
                               "--log_freq=500"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/lerobot-train"),
                        help="folder of the dataset and of lerobot-train's output (default: %(default)s)")
    work = parser.parse_args().work
    if not (work / "dataset" / "meta" / "info.json").is_file():
        shutil.rmtree(work / "dataset", ignore_errors=True)
        make_dataset(work / "dataset")
    pretrained = train(work / "dataset", work / "train")
    shutil.rmtree(POLICY_DIR, ignore_errors=True)
    shutil.copytree(pretrained, POLICY_DIR)
    print(f"{pretrained} -> {POLICY_DIR}")


if __name__ == "__main__":
    main()
