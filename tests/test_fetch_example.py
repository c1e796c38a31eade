"""The second environment family: FetchPush (gymnasium-robotics, float64 dict observations) with
the example DDIM policy on the diffusers adapter, searched from the CLI at a tiny budget, and
its training script at a tiny size."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from goldenticket.cli import main

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT / "examples"))


@pytest.mark.slow
def test_fetch_push_is_searched_from_the_cli(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))  # as when run from the repository's root
    out = tmp_path / "run"
    argv = ["search", "--policy", "examples.fetch_push:make_policy",
            "--task", "examples.fetch_push:make_env", "--method", "cem-racing", "--budget", "40",
            "--search-seeds", "5", "--validation-seeds", "4", "--heldout", "8", "--top-k", "2",
            "--workers", "1", "--out", str(out)]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["task"] == "examples.fetch_push:make_env"
    assert summary["policy"] == "examples.fetch_push:make_policy"
    searched = [t for t in summary["tickets"] if t.get("source") != "zero ticket"]
    assert summary["base"]["n"] == 8 and len(searched) == 2 and len(summary["tickets"]) <= 3  # and w = 0
    assert summary["base"]["success_rate"] > 0  # the trained policy pushes some blocks home


def test_the_expert_and_the_training_script_run():
    import train_fetch_push
    from fetch_push import HORIZON, N_EXEC, scheduler

    from goldenticket.policies.diffusers import SchedulerPolicy

    obs, chunks = train_fetch_push.demonstrations(2, np.random.default_rng(0))
    assert chunks.shape[1:] == (HORIZON, 4) and len(obs["observation"]) == len(chunks)
    network = train_fetch_push.train(obs, chunks, steps=3, batch=8)
    policy = SchedulerPolicy(network, scheduler(), noise_shape=(HORIZON, 4), n_exec=N_EXEC, steps=2)
    one = {k: v[:3].numpy().astype(np.float64) for k, v in obs.items()}
    assert policy.act(one, np.zeros((3, HORIZON, 4), np.float32)).shape == (3, 4, 4)
