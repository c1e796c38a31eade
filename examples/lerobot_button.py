"""Meta-World button-press-topdown-v3 in LeRobot's observation format (`lerobot_reach.py`'s env on
this task: `environment_state` is the button's xyz and the goal's), for the LeRobot diffusion policy
in `lerobot_button_policy/` (trained by `lerobot_train.py --task button`). From the repository root,
in the LeRobot venv:

    goldenticket search --policy examples/lerobot_button_policy --task examples.lerobot_button:make_env \
        --out runs/lerobot-button
"""

import gymnasium as gym

from examples.lerobot_reach import make_env as make_metaworld_env


def make_env() -> gym.Env:
    return make_metaworld_env("button-press-topdown-v3")
