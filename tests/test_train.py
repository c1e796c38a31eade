import json

import numpy as np
import pytest

from goldenticket.config import TrainConfig
from goldenticket.policies import PolicyConfig, TicketedPolicy
from goldenticket.seeds import seeds_in
from goldenticket.tasks import get_task
from goldenticket.train import Demos, DemoStyle, chunk_dataset, collect_demos, train_policy


@pytest.mark.slow
def test_demos_and_training_are_deterministic_for_a_seed():
    task = get_task("metaworld/pick-place-v3")
    style = DemoStyle(grasp_offset=0.02, action_noise=0.1)
    demos = [collect_demos(task, 2, style, seed=0) for _ in range(2)]
    assert all(np.array_equal(a, b) for a, b in zip(demos[0].actions, demos[1].actions, strict=True))
    obs, chunks = chunk_dataset(demos[0], horizon=8)
    assert chunks.shape == (len(obs), 8, 4)
    cfg = PolicyConfig("test/flow", "flow", 39, 4, hidden=32, layers=2, steps=3)
    (a, loss_a), (b, loss_b) = (train_policy(cfg, demos[0], steps=100, seed=1) for _ in range(2))
    assert a.weights_hash() == b.weights_hash() and loss_a == loss_b
    c, _ = train_policy(cfg, demos[0], steps=100, seed=2)
    assert c.weights_hash() != a.weights_hash()
    deployed = TicketedPolicy(a, np.zeros(a.noise_shape, np.float32))
    assert deployed.act(obs[:3]).shape == (3, cfg.n_exec, 4)


@pytest.mark.slow
def test_train_with_few_steps_writes_a_complete_policy(tmp_path, capsys):
    from goldenticket.cli import main

    out = tmp_path / "p"
    assert main(["train", "--task", "metaworld/reach-v3", "--steps", "300", "--demos", "2",
                 "--heldout", "4", "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"config.json", "model.safetensors", "card.json",
                                               "MODEL_CARD.md"}
    card = json.loads((out / "card.json").read_text())
    assert len(card["loss_per_1k_steps"]) == 1 and card["base"]["n"] == 4
    progress = capsys.readouterr().err
    assert all(stage in progress for stage in ("demonstrations", "training", "held-out"))
    assert main(["train", "--task", "metaworld/reach-v3", "--steps", "300", "--out", str(out)]) == 2


def test_a_failed_train_leaves_no_policy(tmp_path, monkeypatch):
    from goldenticket import train

    def broken(*args, **kwargs):
        raise RuntimeError("measurement failed")

    monkeypatch.setattr(train, "measure", broken)
    with pytest.raises(RuntimeError):
        train.build_policy(TrainConfig(task="metaworld/reach-v3", demos=1, steps=10, heldout=2),
                           tmp_path / "p")
    # no policy: only its demonstrations and episodes, hidden
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".npz", ".sqlite"]


def test_a_build_killed_while_measuring_resumes_its_measurement(tmp_path, monkeypatch):
    """Run again, a killed build trains the same policy and runs only the episodes it had not recorded;
    the record goes once the card is written."""
    from goldenticket import store, train

    measure, recorded = train.measure, []

    def killed(folder, task, heldout, workers, **options):
        measure(folder, task, 1, workers, **options)  # the first seed's episodes, then killed
        raise KeyboardInterrupt

    def record(self, rows):
        recorded.extend(rows := list(rows))
        plain_record(self, rows)

    cfg = TrainConfig(task="metaworld/reach-v3", demos=1, steps=10, heldout=2)
    plain_record = store.RunStore.record
    monkeypatch.setattr(store.RunStore, "record", record)
    monkeypatch.setattr(train, "measure", killed)
    with pytest.raises(KeyboardInterrupt):
        train.build_policy(cfg, tmp_path / "p")
    [kept] = [p for p in tmp_path.iterdir() if not p.name.endswith(".demos.npz")]
    assert kept.name.startswith(".p.") and kept.name.endswith(".episodes.sqlite")
    first, recorded[:] = list(recorded), []
    monkeypatch.setattr(train, "measure", measure)
    card = train.build_policy(cfg, tmp_path / "p")
    _, second = seeds_in("heldout", 2)
    assert card["base"]["n"] == card["zero"]["n"] == 2
    assert sorted((r.ticket_id, r.seed) for r in recorded) == [("base", second), ("zero", second)]
    both = sum(r.wall_time for r in first + recorded)  # the measurement's cost counts both parts
    assert card["wall_s"]["measure_episodes"] == pytest.approx(both, abs=0.051) and len(first) == 2
    assert "- **Build time**: demonstrations" in (tmp_path / "p" / "MODEL_CARD.md").read_text()
    assert list(tmp_path.iterdir()) == [tmp_path / "p"]


def test_a_killed_build_trains_again_on_the_demonstrations_it_collected(tmp_path, monkeypatch):
    """The demonstrations are kept beside the policy's folder until it is written: run again, a killed
    build collects none (an unchanged recipe), and nothing of them is left once the policy is written."""
    from goldenticket import train

    collect, collected = train.collect_demos, []

    def counted(*args):
        collected.append(args[1])
        return collect(*args)

    def killed(*args, **options):
        raise KeyboardInterrupt

    cfg = TrainConfig(task="metaworld/reach-v3", demos=2, steps=10, heldout=1)
    monkeypatch.setattr(train, "collect_demos", counted)
    monkeypatch.setattr(train, "measure", killed)
    with pytest.raises(KeyboardInterrupt):
        train.build_policy(cfg, tmp_path / "p")
    [kept] = [p for p in tmp_path.iterdir() if p.name.endswith(".demos.npz")]
    demos = train.Demos.from_file(kept)
    assert len(demos.obs) == 2 and demos.attempts >= 2 and demos.obs[0].shape[0] == demos.actions[0].shape[0]
    monkeypatch.undo()
    monkeypatch.setattr(train, "collect_demos", counted)
    card = train.build_policy(cfg, tmp_path / "p")
    assert collected == [2] and card["demo_attempts"] == demos.attempts
    assert list(tmp_path.iterdir()) == [tmp_path / "p"]


def test_a_written_policy_forgets_its_own_kept_demonstrations_and_no_other_folders(tmp_path):
    from goldenticket import train

    mine = train.kept_beside(tmp_path / "lift", "0" * 64, "demos.npz")
    others = [train.kept_beside(tmp_path / name, "1" * 64, "demos.npz") for name in ("lift.v2", "lif")]
    for path in (mine, *others):
        path.write_bytes(b"")
    train.forget_kept_demos(tmp_path / "lift")
    assert sorted(tmp_path.iterdir()) == sorted(others)


def test_demonstrations_of_frames_survive_the_file(tmp_path):
    obs = [{"pixels": np.zeros((3, 4, 4, 3), np.uint8), "agent_pos": np.ones((3, 2))}]
    demos = Demos(obs, [np.ones((3, 4), np.float32)], 5, 61.5)
    (tmp_path / "d.npz").write_bytes(demos.to_bytes())
    back = Demos.from_file(tmp_path / "d.npz")
    assert (back.attempts, back.seconds) == (5, 61.5)
    assert np.array_equal(back.obs[0]["pixels"], obs[0]["pixels"])
    assert back.obs[0]["agent_pos"].dtype == np.float64 and np.array_equal(back.actions[0], demos.actions[0])
