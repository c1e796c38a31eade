import numpy as np
import pytest

from goldenticket.errors import UserError
from goldenticket.policies import MLPPolicy, load_policy


@pytest.mark.parametrize("kind", ["flow", "ddim"])
def test_deterministic_given_noise_and_batch_independent(tiny_policies, rng, kind):
    policy = tiny_policies[kind]
    obs = rng.standard_normal((6, 39)).astype(np.float32)
    noise = rng.standard_normal((6, *policy.noise_shape)).astype(np.float32)
    actions = policy.act(obs, noise)
    assert actions.shape == (6, policy.n_exec, 4)
    assert np.array_equal(actions, policy.act(obs, noise))
    other = policy.act(obs, noise + 1.0)
    assert not np.allclose(actions, other)  # the noise really steers the output
    assert np.all(np.abs(actions) <= 1.0)


@pytest.mark.parametrize("name", ["metaworld/pick-place-v3/flow", "metaworld/pick-place-v3/ddim"])
def test_each_row_is_bitwise_independent_of_its_batch(rng, name):
    """CPU matmul kernels change with the row count; a row's actions must not."""
    policy = load_policy(name)
    obs = rng.standard_normal((20, 39)).astype(np.float32)
    noise = rng.standard_normal((20, *policy.noise_shape)).astype(np.float32)
    full = policy.act(obs, noise)
    for size in range(1, 20):
        rows = rng.permutation(20)[:size]
        assert np.array_equal(policy.act(obs[rows], noise[rows]), full[rows]), size


@pytest.mark.parametrize("kind", ["flow", "ddim"])
def test_save_load_round_trip(tiny_policies, tmp_path, rng, kind):
    policy = tiny_policies[kind]
    policy.save(tmp_path)
    loaded = load_policy(str(tmp_path))
    obs = rng.standard_normal((3, 39)).astype(np.float32)
    noise = rng.standard_normal((3, *policy.noise_shape)).astype(np.float32)
    assert np.array_equal(policy.act(obs, noise), loaded.act(obs, noise))
    assert loaded.weights_hash() == policy.weights_hash()


def test_bad_policy_inputs(tmp_path):
    with pytest.raises(UserError, match="unknown policy"):
        load_policy("metaworld/nope/flow")
    (tmp_path / "config.json").write_text("{not json")
    with pytest.raises(UserError, match="config.json: not a JSON file"):
        MLPPolicy.load(tmp_path)


def test_a_hub_repo_id_is_told_from_bundled_names_paths_and_import_strings(tmp_path, monkeypatch):
    from goldenticket.zoo import check_name, is_hub_id

    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "policy").mkdir(parents=True)
    assert is_hub_id("lerobot/smolvla_libero") and is_hub_id("someone/my.policy-v2")
    for name in ("metaworld/pick-place-v3/flow", "metaworld/pick-place-v3", "byo_example:make_policy",
                 "runs/policy", "lerobot/a/b", "../x", "a/../b", "nope"):
        assert not is_hub_id(name), name
    with pytest.raises(UserError, match="unknown policy 'metaworld/pick-place-v3'"):
        check_name("metaworld/pick-place-v3")


def test_a_hub_repo_id_is_looked_up_in_the_hub_cache_and_one_not_there_names_the_download(
        tmp_path, monkeypatch, capsys):
    pytest.importorskip("huggingface_hub")
    from huggingface_hub import constants

    from goldenticket.cli import main
    from goldenticket.zoo import check_name

    repo = tmp_path / "hub" / "models--someone--cached"
    (repo / "snapshots" / "abc123").mkdir(parents=True)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text("abc123")
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)
    check_name("someone/cached@4")  # the command line's pre-check: in the cache
    assert main(["evaluate", "--policy", "someone/not-cached", "--task", "metaworld/reach-v3",
                 "--seeds", "1000000:1000002"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "`hf download someone/not-cached`" in lines[0], lines


@pytest.mark.slow
def test_every_bundled_policy_loads_runs_and_has_a_model_card(rng):
    from goldenticket.policies import BUNDLED_DIR, for_task, policy_names

    assert {"metaworld/pick-place-v3/flow", "metaworld/mt10/flow", "metaworld/mt10/ddim"} <= set(
        policy_names())
    for name in policy_names():
        policy = load_policy(name)
        assert policy.name == name and (BUNDLED_DIR / name / "MODEL_CARD.md").is_file()
        noise = rng.standard_normal((2, *policy.noise_shape)).astype(np.float32)
        obs = np.zeros((2, policy.cfg.obs_dim), np.float32)
        if policy.cfg.image_size:  # an image policy sees a frame and agent_pos
            frames = np.zeros((2, policy.cfg.image_size, policy.cfg.image_size, 3), np.uint8)
            obs = {"pixels": frames, "agent_pos": np.zeros((2, 4), np.float32)}
        for task in policy.tasks or [None]:  # a multi-task policy acts on each of its tasks
            acting = policy if task is None else for_task(policy, task)
            assert acting.act(obs, noise).shape == (2, policy.n_exec, policy.cfg.action_dim)


def test_denoising_steps_set_at_load_time(rng):
    eight, two = load_policy("metaworld/pick-place-v3/ddim"), load_policy("metaworld/pick-place-v3/ddim@2")
    assert (eight.cfg.steps, two.cfg.steps) == (8, 2) and two.name.endswith("@2")
    assert two.weights_hash() == eight.weights_hash()
    obs = np.zeros((2, 39), np.float32)
    noise = rng.standard_normal((2, *eight.noise_shape)).astype(np.float32)
    assert not np.array_equal(two.act(obs, noise), eight.act(obs, noise))
    for bad in ("metaworld/pick-place-v3/ddim@0", "metaworld/pick-place-v3/ddim@x"):
        with pytest.raises(UserError, match="step count"):
            load_policy(bad)


def test_zoo_ships_at_least_22_policies_with_measured_cards():
    import json

    from goldenticket.policies import BUNDLED_DIR, policy_names

    assert len(policy_names()) >= 22
    for name in policy_names():
        card = json.loads((BUNDLED_DIR / name / "card.json").read_text())
        per_task = card.get("tasks", {"": card})  # a multi-task card: measured on each task
        assert card["policy"] == name and card["base"]["n"] == card["zero"]["n"] == 200 * len(per_task)
        assert all(t["base"]["n"] == t["zero"]["n"] == 200 for t in per_task.values())


@pytest.mark.slow
def test_a_shipped_ticket_reproduces_its_recorded_heldout_success():
    from goldenticket.noise import Constant
    from goldenticket.policies import bundled_tickets
    from goldenticket.rollout import Episode, rollout
    from goldenticket.tasks import get_task
    from goldenticket.tickets import Ticket

    tickets = [Ticket.load(p) for p in bundled_tickets()]
    assert tickets, "no golden tickets are bundled"
    ticket = min(tickets, key=lambda t: ("reach" not in t.metadata["task"], t.id))  # shortest episodes
    meta = ticket.metadata
    seeds = range(meta["heldout"]["seeds"][0], meta["heldout"]["seeds"][1] + 1)
    results = rollout(load_policy(meta["policy"]), get_task(meta["task"]),
                      [Episode(Constant(ticket.noise), s) for s in seeds])
    assert np.mean([r.success for r in results]) == meta["heldout"]["success_rate"]


@pytest.mark.slow
def test_shipped_tickets_name_their_policy_and_their_id_names_them():
    from goldenticket.policies import bundled_tickets
    from goldenticket.tickets import Ticket

    paths = bundled_tickets()
    tickets = [Ticket.load(p) for p in paths]
    assert len({t.id for t in tickets}) == len(tickets)
    for path, ticket in zip(paths, tickets, strict=True):
        assert path.stem == ticket.id
        assert ticket.metadata["policy_fingerprint"] == load_policy(ticket.metadata["policy"]).fingerprint()


def test_observations_of_another_size_are_refused_in_one_line(rng):
    policy = load_policy("metaworld/reach-v3/flow")
    noise = rng.standard_normal((2, *policy.noise_shape)).astype(np.float32)
    with pytest.raises(UserError, match=r"sees state vectors \[B, 39\], got \[2, 19\]"):
        policy.act(np.zeros((2, 19)), noise)
