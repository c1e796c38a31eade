"""Train a small SmolVLA on five LIBERO-Object tasks with LeRobot's own tools, and copy its pretrained
folder, with its offline backbone inside and a model card written from this run, to
`examples/smolvla_libero_policy/`. In the LeRobot venv (README, "LeRobot"):

    python examples/smolvla_libero_train.py [--work runs/smolvla-libero-train]

1. A SmolVLM backbone of the "small" size in `smolvla_backbone.py` (config, tokenizer and
   processor, written offline; SmolVLA's own random weights, all of them trained).
2. Demonstrations: the LIBERO-Object scripted expert (`goldenticket.tasks.libero_experts`) on
   goldenticket's training seeds of `libero/object/0` to `4`, made imperfect (each demonstrator
   aims at the object and the basket shifted by U(+-2 cm), Gaussian action noise), seen as
   LeRobot's LIBERO eval shows them: both cameras at 64 x 64 (the task's env options
   observation_height and observation_width), the 8-number state and the task's instruction.
3. They are written as one LeRobotDataset with LeRobot's LIBERO keys (`observation.images.image`,
   `observation.images.image2`, `observation.state`) in a local folder; nothing goes to a hub.
4. `lerobot-train` trains the SmolVLA on the CPU without wandb; rerunning resumes from its last
   checkpoint. The recipe's checkpoint ships, with the backbone folder inside the policy folder.

The policy runs on the frame size it was trained on: `--env-option observation_height=64
--env-option observation_width=64` (goldenticket), `--env.observation_height=64
--env.observation_width=64` (lerobot-eval).
"""

import json
import sys
import textwrap
from importlib.metadata import version
from pathlib import Path

from safetensors.torch import load_file

from goldenticket.train import DemoStyle

sys.path.insert(0, str(Path(__file__).parent))
from smolvla_backbone import SIZES
from smolvla_recipe import BATCH, CARD, SMALL_SMOLVLA, Recipe, build, work_folder

SIZE = 64  # camera frames, height and width
RECIPE = Recipe(
    name="libero-object-smolvla",
    tasks=tuple(f"libero/object/{i}" for i in range(5)),
    task_options={"observation_height": SIZE, "observation_width": SIZE},
    observations={"observation.images.image": ("pixels", "image"),
                  "observation.images.image2": ("pixels", "image2"), "observation.state": ("agent_pos",)},
    fps=20,  # LeRobot's LiberoEnv: robosuite's control rate
    demos=15, style=DemoStyle(grasp_offset=0.02, action_noise=0.1, goal_offset=0.02),
    # LIBERO-Object's instructions run to 56 characters, and the backbone's tokenizer has one a character
    policy=SMALL_SMOLVLA | {"tokenizer_max_length": 64},
    steps=3_000, save_every=500, shipped_step=3_000,
    policy_dir=Path(__file__).with_name("smolvla_libero_policy"), work=Path("runs/smolvla-libero-train"),
)


def parameters(folder: Path) -> int:
    return sum(weights.numel() for weights in load_file(folder / "model.safetensors").values())


def shown(path: Path) -> str:
    """`path` relative to the current folder where it lies inside it."""
    return str(path.relative_to(Path.cwd())) if path.is_relative_to(Path.cwd()) else str(path)


def options(recipe: Recipe, prefix: str) -> str:
    """The tasks' env options on a command line: `--env-option ` (goldenticket), `--env.` (lerobot-eval)."""
    return " ".join(f"{prefix}{key}={value}" for key, value in recipe.task_options.items())


def model_text(recipe: Recipe, config: dict) -> str:
    text, vision, side = SIZES["small"]["text"], SIZES["small"]["vision"], SIZES["small"]["image_size"]
    chunk, width, used = config["chunk_size"], config["max_action_dim"], config["output_features"]["action"]
    return (
        f"**Model**: LeRobot {version('lerobot')}'s SmolVLA (`\"type\": \"smolvla\"`), "
        f"{parameters(recipe.policy_dir) / 1e6:.2f}M parameters, on the \"small\" SmolVLM backbone of "
        f"`examples/smolvla_backbone.py` ({text['num_hidden_layers']} text layers of width "
        f"{text['hidden_size']}, a {vision['num_hidden_layers']}-layer vision tower on {side} x {side} "
        f"frames in {vision['patch_size']} px patches), written offline and carried in `backbone/` (config, "
        "a character-level tokenizer, the processor; no weights there: every weight is SmolVLA's own, all "
        f"of them trained). A chunk of {chunk} actions from {config['num_steps']} flow-matching steps, "
        f"{config['n_action_steps']} executed per call. Its noise, and so a ticket, is `({chunk}, {width})`: "
        f"`max_action_dim` {width}, of which the robot uses {used['shape'][0]}.")


def seen_text(recipe: Recipe, config: dict) -> str:
    inputs = ", ".join(f"`{key}` {feature['shape']}" for key, feature in config["input_features"].items())
    return (
        f"**Sees**: both cameras of `libero/object/<id>` (agent view and wrist) at "
        f"{recipe.task_options['observation_height']} x {recipe.task_options['observation_width']}, the "
        "robot's state (end-effector position, axis-angle, gripper) and the task's instruction, as LeRobot's "
        f"LIBERO eval gives them: {inputs}. It runs on frames of that size: "
        f"`{options(recipe, '--env-option ')}` in goldenticket, `{options(recipe, '--env.')}` in "
        "`lerobot-eval --env.type=libero`.")


def data_texts(recipe: Recipe, work: Path) -> list[str]:
    demos = json.loads((work / "demos.json").read_text())
    info = json.loads((work / "dataset" / "meta" / "info.json").read_text())
    attempts, seconds = sum(d["attempts"] for d in demos.values()), sum(d["seconds"] for d in demos.values())
    per_task = ", ".join(str(d["attempts"]) for d in demos.values())
    return [
        "**Tasks and instructions**: " + ", ".join(f"`{name}` (\"{d['instruction']}\")"
                                                   for name, d in demos.items()) + ".",
        f"**Data**: {recipe.demos} successful scripted-expert demonstrations per task on goldenticket's "
        f"training seeds ({info['total_episodes']} episodes, {info['total_frames']} frames at {info['fps']} "
        f"fps), {recipe.style.describe()}; {attempts} attempts ({per_task} per task) in "
        f"{seconds / 60:.0f} min ({seconds / attempts:.1f} s an attempt, LIBERO's resets included): a "
        "LeRobotDataset in a local folder."]


def training_text(recipe: Recipe, work: Path, config: dict) -> str:
    seconds = json.loads((work / "training.json").read_text())["seconds"]
    return (
        f"**Training**: `lerobot-train`, batch {BATCH}, AdamW at {config['optimizer_lr']:g} with "
        f"{config['scheduler_warmup_steps']} warm-up steps and cosine decay over {recipe.steps} steps, on "
        f"one CPU thread ({seconds / 60:.0f} min, {seconds / recipe.steps:.2f} s a step, beside the "
        f"machine's other work). This folder is the {recipe.shipped_step}-step checkpoint.")


def card(recipe: Recipe, work: Path) -> str:
    """The model card: what this run's recipe, demonstrations, dataset and training measured."""
    config = json.loads((recipe.policy_dir / "config.json").read_text())
    evaluate = (f"`lerobot-venv/bin/goldenticket evaluate --policy {shown(recipe.policy_dir)} --task "
                f"{recipe.tasks[0]} {options(recipe, '--env-option ')} --seeds 1000000:1000032`")
    items = [model_text(recipe, config), seen_text(recipe, config), *data_texts(recipe, work),
             training_text(recipe, work, config),
             f"**Held-out success**: not measured by the script that wrote this card; per task, {evaluate}."]
    bullets = [textwrap.fill(item, 100, initial_indent="- ", subsequent_indent="  ", break_long_words=False,
                             break_on_hyphens=False) for item in items]
    rebuild = textwrap.fill("Rebuild, in LeRobot's venv: `python examples/smolvla_libero_train.py` (training "
                            "runs in float32, so on another kind of CPU the weights differ).", 100)
    title = f"# SmolVLA on {len(recipe.tasks)} LIBERO-Object tasks"
    return "\n".join([title, "", *bullets, "", rebuild]) + "\n"


if __name__ == "__main__":
    work = work_folder(RECIPE, __doc__.splitlines()[0])
    build(RECIPE, work)
    (RECIPE.policy_dir / CARD).write_text(card(RECIPE, work.resolve()))
