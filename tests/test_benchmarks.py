import existence
import numpy as np
import pytest
import search_methods


def _rate(p, n=200):
    return {"success_rate": p, "ci_low": p - 0.05, "ci_high": p + 0.05, "n": n}


def _row(base, zero, best, p_base, p_zero):
    fresh = _rate(best) | {"p_vs_base": p_base, "p_vs_zero": p_zero, "base": _rate(base), "zero": _rate(zero),
                           "inside_recorded_interval": True}
    return {"task": "t", "policy": "flow", "base": _rate(base), "zero": _rate(zero), "best": _rate(best),
            "p_vs_base": p_base, "p_vs_zero": p_zero, "golden": p_base < 0.05, "fresh": fresh,
            "search": "cma-es, 2000 episodes"}


def test_existence_summary_counts_gains_sign_test_and_targets():
    rows = [_row(0.5, 0.6, 0.7, 0.001, 0.04), _row(0.5, 0.5, 0.5, 1.0, 1.0),
            _row(0.6, 0.7, 0.55, 0.9, 0.99), _row(0.3, 0.3, 0.4, 0.01, 0.2)]
    s = existence.summary_rows(rows)
    assert s["vs_base"] | {"win_rate_ci": None} == {
        "significant": 2, "wins": 2, "losses": 1, "ties": 1, "sign_test_p": 0.5,
        "win_rate_ci": None, "mean_gain": pytest.approx(0.0625)}
    assert s["vs_zero"]["significant"] == 1 and s["vs_zero"]["losses"] == 1
    table = existence.markdown(rows, s, 60.0)
    assert table.count("\n| t | flow |") == 4 and "**golden**" in table and "2 of 4 pairs" in table
    expected = {"vs_base": 0.5, "vs_zero": 0.25,
                "failure_reduction": pytest.approx(np.mean([0.2 / 0.5, 0, -0.05 / 0.4, 0.1 / 0.7])),
                "mean_gain": pytest.approx(np.mean([0.2, 0, -0.05, 0.1]))}
    assert s["targets"] == {"pairs": 4, "judged": expected, "fresh": expected}
    strong = existence.summary_rows([*rows, _row(0.9, 0.9, 1.0, 0.001, 0.001)])["targets"]
    assert strong["pairs"] == 4 and strong["judged"] == expected  # a base above 85% is not a target pair


def test_base_floor_is_the_lowest_base_above_which_nine_in_ten_pairs_reach_the_bar():
    rows = [_row(b, b, best, 0.01, 0.5) for b, best in
            [(0.95, 1.0), (0.9, 0.97), (0.8, 0.95), (0.7, 0.92), (0.6, 0.5), (0.5, 0.95)]]
    assert existence.base_floor(rows, 0.9) == {"bar": 0.9, "floor": 0.7, "n": 4, "k": 4}
    assert existence.base_floor(rows, 0.97) == {"bar": 0.97, "floor": 0.9, "n": 2, "k": 2}
    assert existence.base_floor(rows, 1.01) is None
    table = existence.markdown(rows, existence.summary_rows(rows), 60.0)
    assert "**Base floor** for the bar 90% (the paper's T*): 70.0%. Of the 4 pairs" in table


def test_existence_pairs_cover_flow_and_both_ddim_step_counts():
    task = "metaworld/reach-v3"
    assert existence.pairs(("reach-v3",)) == [(task, f"{task}/flow"), (task, f"{task}/ddim@8"),
                                              (task, f"{task}/ddim@2")]


def test_search_method_winner_per_budget():
    n = len(search_methods.CHECKPOINTS)

    def curve(rates):
        return [{"budget": b, "search": 1.0, "heldout": r}
                for b, r in zip(search_methods.CHECKPOINTS, rates, strict=True)]

    results = {"p": {"base": 0.5} | {m: curve([0.5] * n) for m in search_methods.METHODS}}
    results["p"]["zos"] = curve([0.6] * n)
    results["p"]["cem"] = curve([0.4] + [0.7] * (n - 1))
    assert search_methods.winners(results) == [("zos", 0.6)] + [("cem", 0.7)] * (n - 1)
    held = [p["heldout"] for m in search_methods.METHODS for p in results["p"][m]]
    assert search_methods.shrinkage(results) == pytest.approx(1 - np.mean(held))


@pytest.mark.slow
def test_dsrl_steers_the_frozen_policy_through_the_noise_space():
    import dsrl
    from stable_baselines3 import SAC

    from goldenticket.policies import load_policy
    from goldenticket.tasks import get_task, seeds_in

    policy, task = load_policy("metaworld/reach-v3/flow"), get_task("metaworld/reach-v3", max_steps=12)
    env = dsrl.NoiseSpaceEnv(policy, task, seeds_in("search", 3))
    obs, _ = env.reset()
    obs, reward, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
    assert env.observation_space.contains(obs) and env.env_steps == policy.n_exec and reward in (0.0, 1.0)
    quick = dsrl.SAC | {"learning_starts": 10, "gradient_steps": 2}
    model = SAC("MlpPolicy", env, seed=0, device="cpu", **quick)
    model.learn(30)
    steered = dsrl.ActorNoise(policy, model)
    actions = steered.act(np.stack([obs, obs]), np.zeros((2, *policy.noise_shape), np.float32))
    assert actions.shape == (2, policy.n_exec, 4) and np.array_equal(actions[0], actions[1])
