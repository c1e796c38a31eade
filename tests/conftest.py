import numpy as np
import pytest
import torch

from goldenticket.policies import MLPPolicy, PolicyConfig

SLOW_TOO = ("browser", "ray", "lerobot", "robomimic")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items) -> None:
    """Browser, Ray, LeRobot and robomimic tests are slow too: `-m "not slow"` is the fast tier."""
    for item in items:
        if any(item.get_closest_marker(name) for name in SLOW_TOO):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def tiny_policies(tmp_path_factory) -> dict[str, MLPPolicy]:
    """Untrained but fixed flow and DDIM policies for pick-place (weights from a seed)."""
    out = {}
    for kind in ("flow", "ddim"):
        torch.manual_seed(0)
        cfg = PolicyConfig(f"test/{kind}", kind, obs_dim=39, action_dim=4, hidden=32, layers=2,
                           steps=3)
        policy = MLPPolicy(cfg)
        policy.save(tmp_path_factory.mktemp(kind))
        out[kind] = policy
    return out


@pytest.fixture(scope="module")
def policy_dir(tiny_policies, tmp_path_factory) -> str:
    """The tiny flow policy saved as a policy folder."""
    path = tmp_path_factory.mktemp("policy")
    tiny_policies["flow"].save(path)
    return str(path)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
