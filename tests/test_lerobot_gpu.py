"""The GPU contract of a LeRobot policy, with nothing but LeRobot and one CUDA GPU: no simulator, so
that it runs wherever a GPU and LeRobot are; and the GPU benchmark's whole path, on the CPU."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goldenticket.policies import load_policy

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT))  # examples.*
sys.path.insert(0, str(Path(__file__).parent))
from lerobot_models import tiny_smolvla  # noqa: E402

pytestmark = [pytest.mark.lerobot, pytest.mark.slow, pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None, reason="LeRobot is not installed (its own venv: README)")]
CAMERAS, SIZE, ROWS = ("image", "image1"), 32, 4


def observations(rng: np.random.Generator) -> dict:
    """`ROWS` observations of a state, an environment state and two camera frames."""
    return {"agent_pos": rng.standard_normal((ROWS, 4)).astype(np.float32),
            "environment_state": rng.standard_normal((ROWS, 6)).astype(np.float32),
            "pixels": {c: rng.integers(0, 256, (ROWS, SIZE, SIZE, 3), dtype=np.uint8) for c in CAMERAS}}


@pytest.mark.gpu
def test_on_a_gpu_a_smolvla_gives_the_same_actions_every_time(tmp_path):
    """One machine, one GPU, the same noise: the same actions, call after call and load after load,
    and close to the CPU's."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature

    from examples.smolvla_backbone import write_backbone

    if not torch.cuda.is_available():
        pytest.skip("no CUDA GPU here")
    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (4,)),
              "observation.environment_state": PolicyFeature(FeatureType.ENV, (6,))}
    inputs |= {f"observation.images.{c}": PolicyFeature(FeatureType.VISUAL, (3, SIZE, SIZE)) for c in CAMERAS}
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (4,))}
    folder = str(tiny_smolvla(tmp_path / "policy", write_backbone(tmp_path / "backbone", "tiny"), inputs,
                              outputs))
    rng = np.random.default_rng(3)
    obs, noise = observations(rng), rng.standard_normal((ROWS, 10, 32)).astype(np.float32)
    instruction = "Reach a goal position"
    on_gpu = [load_policy(folder, "cuda").instructed(instruction).act(obs, noise) for _ in range(2)]
    np.testing.assert_array_equal(*on_gpu)
    assert on_gpu[0].shape == (ROWS, 5, 4)
    on_cpu = load_policy(folder).instructed(instruction).act(obs, noise)
    np.testing.assert_allclose(on_gpu[0], on_cpu, atol=1e-3)


def test_the_gpu_benchmark_runs_lerobots_loop_and_the_engine_on_both_paths_in_its_smoke_mode(tmp_path):
    """`benchmarks/gpu_throughput.py --smoke`: a tiny SmolVLA on the CPU through the GPU run's whole path.
    LeRobot's eval loop and the engine run the same episodes, and their ratio is recorded; the fast path
    is measured at every batch of the exact one, and its actions differ from the exact ones, a little."""
    run = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gpu_throughput.py"), "--smoke",
                          "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr[-3000:]
    result = json.loads((tmp_path / "gpu_throughput.json").read_text())
    assert result["finished"] and result["device"] == "cpu (--smoke)"
    rows = result["rows"]
    [lerobot] = [row for row in rows if row.get("loop") == "lerobot eval_policy"]
    engine = {(row["path"], row["env_workers"]): row for row in rows
              if row.get("loop") == "goldenticket engine"}
    assert set(engine) == {("exact", 1), ("fast", 1), ("exact", 4)}
    assert all(row["episodes"] == lerobot["episodes"] for row in engine.values())
    for path in ("exact", "fast"):
        ratio = engine[path, 1]["episodes_per_s"] / lerobot["episodes_per_s"]
        assert result["vs_lerobot"]["smolvla"][path] == engine[path, 1]["vs_lerobot"] == pytest.approx(ratio)
    calls = {path: [row for row in rows if row.get("path") == path and "batch" in row]
             for path in ("exact", "fast")}
    assert [row["batch"] for row in calls["fast"]] == [row["batch"] for row in calls["exact"]] == [1, 2, 4]
    assert all(0 < row["max_abs_action_diff"] < 0.1 * row["max_abs_action"] for row in calls["fast"])
    assert "x the episodes/s of LeRobot's eval_policy on the same 8 episodes" in run.stdout
