"""The diffusers adapter on real schedulers and a network with random weights built here."""

import sys
from pathlib import Path

import numpy as np
import pytest

import goldenticket

pytest.importorskip("diffusers")
sys.path.insert(0, str(Path(__file__).parent))
import byo_diffusers  # noqa: E402

POLICIES = {f"ddim {p}": lambda p=p: byo_diffusers.make_ddim_policy(p)
            for p in ("epsilon", "sample", "v_prediction")} | {"flow": byo_diffusers.make_flow_policy}


@pytest.mark.parametrize("make", POLICIES.values(), ids=POLICIES.keys())
def test_scheduler_policy_keeps_the_noise_policy_contract(make):
    policy, rng = make(), np.random.default_rng(0)
    obs = {"pos": rng.uniform(-1, 1, (5, 2)), "goal": rng.uniform(-1, 1, (5, 2))}  # float64, a dict
    noise = rng.standard_normal((5, *policy.noise_shape)).astype(np.float32)
    actions = policy.act(obs, noise)
    assert actions.shape == (5, policy.n_exec, 2) and np.isfinite(actions).all()
    assert np.array_equal(actions, policy.act(obs, noise))  # deterministic given the noise
    assert not np.allclose(actions, policy.act(obs, noise + 1))  # the noise steers it
    assert np.allclose(policy.act({k: v[:2] for k, v in obs.items()}, noise[:2]), actions[:2], atol=1e-6)
    assert policy.fingerprint() == make().fingerprint()


@pytest.mark.slow
def test_scheduler_policies_run_through_workers_by_import_string():
    for name in ("byo_diffusers:make_ddim_policy", "byo_diffusers:make_flow_policy"):
        rows = goldenticket.evaluate(name, "byo_example:make_env", seeds=range(1_000_000, 1_000_006),
                                     max_steps=20, workers=2)
        assert rows["base"].rate.n == 6 and {"base", "zero"} == set(rows)
