import numpy as np

from goldenticket.policies import PolicyConfig, TicketedPolicy
from goldenticket.tasks import get_task
from goldenticket.train import DemoStyle, chunk_dataset, collect_demos, train_policy


def test_demos_and_training_are_deterministic_for_a_seed():
    task = get_task("metaworld/pick-place-v3")
    style = DemoStyle(grasp_offset=0.02, action_noise=0.1)
    demos = [collect_demos(task, 2, style, seed=0) for _ in range(2)]
    assert all(np.array_equal(a, b) for a, b in zip(demos[0].actions, demos[1].actions, strict=True))
    obs, chunks = chunk_dataset(demos[0], horizon=8)
    assert chunks.shape == (len(obs), 8, 4)
    cfg = PolicyConfig("test/flow", "flow", 39, 4, hidden=32, layers=2, steps=3)
    (a, loss_a), (b, loss_b) = (train_policy(cfg, demos[0], steps=1000, seed=1) for _ in range(2))
    assert a.weights_hash() == b.weights_hash() and loss_a == loss_b
    c, _ = train_policy(cfg, demos[0], steps=1000, seed=2)
    assert c.weights_hash() != a.weights_hash()
    deployed = TicketedPolicy(a, np.zeros(a.noise_shape, np.float32))
    assert deployed.act(obs[:3]).shape == (3, cfg.n_exec, 4)
