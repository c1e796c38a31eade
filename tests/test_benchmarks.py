import dataclasses
import json
import sys

import budget_curve
import dsrl
import existence
import multitask
import numpy as np
import pytest
import search_methods
import torch
import untuned_bench

from goldenticket.errors import UserError
from goldenticket.store import EpisodeRow, RunStore
from goldenticket.tickets import Ticket, TicketRecord


def _rate(p, n=200):
    return {"success_rate": p, "ci_low": p - 0.05, "ci_high": p + 0.05, "n": n}


def _row(base, zero, best, p_base, p_zero, below_zero=0.5, spent=1200, zero_ticket=False):
    fresh = _rate(best) | {"p_vs_base": p_base, "p_vs_zero": p_zero, "base": _rate(base), "zero": _rate(zero),
                           "inside_recorded_interval": True, "p_below_base": 0.5, "p_below_zero": below_zero}
    return {"task": "t", "policy": "flow", "base": _rate(base), "zero": _rate(zero), "best": _rate(best),
            "zero_ticket": zero_ticket, "p_vs_base": p_base, "p_vs_zero": p_zero, "golden": p_base < 0.05,
            "fresh": fresh, "fresh_2": fresh, "search": "cma-es, 850 episodes",
            "search_and_validation": spent}


def test_existence_summary_counts_gains_sign_test_and_targets():
    rows = [_row(0.5, 0.6, 0.7, 0.001, 0.04), _row(0.5, 0.5, 0.5, 1.0, 1.0),
            _row(0.6, 0.7, 0.55, 0.9, 0.99, below_zero=0.01, spent=1250), _row(0.3, 0.3, 0.4, 0.01, 0.2)]
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
    on_fresh = expected | {"below_zero": 1, "below_base": 0, "delivered": expected | {"kept_base": 1}}
    assert s["targets"] == {"pairs": 4, "judged": expected, "fresh": on_fresh, "fresh_2": on_fresh}
    assert s["episodes"] == {"mean": 1212.5, "max": 1250}
    assert "significantly below the zero ticket in 1 (target 0)" in table and "at most 1250" in table
    assert "w = 0" not in table and "**The zero ticket**" not in table
    zero = _row(0.3, 0.45, 0.45, 0.01, 1.0, zero_ticket=True)
    table = existence.markdown([*rows, zero], existence.summary_rows([*rows, zero]), 60.0)
    assert "| 45.0% [40%, 50%] (w = 0: the zero ticket) **golden** |" in table
    assert "the best ticket is w = 0 in 1 of 5 pairs (1 of them golden vs base)" in table
    strong = existence.summary_rows([*rows, _row(0.9, 0.9, 1.0, 0.001, 0.001)])["targets"]
    assert strong["pairs"] == 4 and strong["judged"] == expected  # a base above 85% is not a target pair


def test_where_the_best_ticket_is_not_above_the_base_the_job_delivers_the_base():
    behind, ahead = _row(0.5, 0.3, 0.45, 0.9, 0.01), _row(0.5, 0.3, 0.55, 0.2, 0.01)
    assert existence.keeps_base(behind) and not existence.keeps_base(ahead)
    kept = existence.delivered(behind, "fresh")
    assert kept["best"] == _rate(0.5) and not kept["p_vs_base"] < 0.05
    assert existence.delivered(ahead, "fresh")["best"] == ahead["fresh"]
    delivered = existence.target_summary([behind, ahead])["targets"]["fresh"]["delivered"]
    assert delivered == {"vs_base": 0.0, "vs_zero": 0.5, "failure_reduction": pytest.approx(0.05 / 0.5 / 2),
                         "mean_gain": pytest.approx(0.025), "kept_base": 1}


def test_base_floor_is_the_lowest_base_above_which_nine_in_ten_pairs_reach_the_bar():
    rows = [_row(b, b, best, 0.01, 0.5) for b, best in
            [(0.95, 1.0), (0.9, 0.97), (0.8, 0.95), (0.7, 0.92), (0.6, 0.5), (0.5, 0.95)]]
    assert existence.base_floor(rows, 0.9) == {"bar": 0.9, "floor": 0.7, "n": 4, "k": 4}
    assert existence.base_floor(rows, 0.97) == {"bar": 0.97, "floor": 0.9, "n": 2, "k": 2}
    assert existence.base_floor(rows, 1.01) is None
    table = existence.markdown(rows, existence.summary_rows(rows), 60.0)
    assert "**Base floor** for the bar 90% (the paper's T*): 70.0%. Of the 4 pairs" in table


def test_budget_curve_adds_kept_budgets_to_the_existence_tables_point(tmp_path, monkeypatch):
    weak = [_row(0.5, 0.6, 0.7, 0.001, 0.04), _row(0.3, 0.3, 0.4, 0.01, 0.2)]
    rows = [*weak, _row(0.9, 0.9, 1.0, 0.001, 0.001)]
    monkeypatch.setattr(budget_curve, "existence_rows", lambda: rows)
    monkeypatch.setattr(budget_curve, "ROWS", tmp_path)
    assert budget_curve.weak_pairs() == [("metaworld/t", "metaworld/t/flow")] * 2
    (tmp_path / "2000").mkdir()
    (tmp_path / "2000" / "a.json").write_text(json.dumps(_row(0.5, 0.6, 0.9, 0.001, 0.01, spent=2400)))
    kept = [budget for budget, _ in budget_curve.kept_points()]
    assert kept == [1100]  # the defaults' point; of 2000, one of two pairs kept: not a point yet
    (tmp_path / "2000" / "b.json").write_text(json.dumps(_row(0.3, 0.3, 0.8, 0.001, 0.01, spent=2400)))
    points = budget_curve.curve()
    assert [(p["budget"], p["halving"]) for p in points] == [(1100, True), (2000, False)]
    assert points[0]["targets"]["fresh"]["mean_gain"] == pytest.approx(0.15)
    fresh = points[1]["targets"]["fresh"]
    assert fresh | {"failure_reduction": 0, "delivered": None} == {
        "vs_base": 1.0, "vs_zero": 1.0, "failure_reduction": 0, "mean_gain": pytest.approx(0.45),
        "below_zero": 0, "below_base": 0, "delivered": None}
    assert fresh["delivered"]["kept_base"] == 0 and fresh["delivered"]["mean_gain"] == fresh["mean_gain"]
    assert points[1]["episodes"] == {"mean": 2400, "max": 2400}
    table = budget_curve.markdown(points)
    assert "--budgets 2000`" in table
    assert "| 2000 | 20 seeds | 2400 (2400) | fresh seeds | 100% | 100% |" in table


def test_budget_curve_keeps_a_changed_search_apart_from_the_default(tmp_path, monkeypatch):
    weak = [_row(0.5, 0.6, 0.7, 0.001, 0.04), _row(0.3, 0.3, 0.4, 0.01, 0.2)]
    monkeypatch.setattr(budget_curve, "existence_rows", lambda: weak)
    monkeypatch.setattr(budget_curve, "ROWS", tmp_path)
    full = budget_curve.SEARCH | {"search_seeds": 40, "subspace": "full"}
    name = budget_curve.folder_name(850, full)
    assert name == "850-seeds40-full" and budget_curve.point_of(name) == (850, full)
    (tmp_path / name).mkdir()
    row = json.dumps(_row(0.5, 0.6, 0.9, 0.001, 0.01, spent=1250))
    for pair in "ab":
        (tmp_path / name / f"{pair}.json").write_text(row)
    points = budget_curve.curve()
    assert [(p["budget"], p["search_seeds"], p["subspace"], p["halving"]) for p in points] == [
        (1100, 20, "full", True), (850, 40, "full", False)]
    table = budget_curve.markdown(points)
    assert "`python benchmarks/budget_curve.py --budgets 850 --search-seeds 40 --subspace full`" in table
    assert "| 850 | 40 seeds, full | 1250 (1250) | fresh seeds | 100% |" in table


def test_budget_curve_names_a_method_race_and_validation_in_its_folder():
    search = budget_curve.SEARCH | {"method": "tiled-then-full", "subspace": "full", "race": 0.1,
                                    "validation_seeds": 20}
    name = budget_curve.folder_name(300, search)
    assert name == "300-val20-race0.1-full-tiled_then_full"
    assert budget_curve.point_of(name) == (300, search)
    said = "20 seeds, full, tiled-then-full, raced at 0.1, 20 validation seeds"
    assert budget_curve.search_label(search) == said
    flags = "--budgets 300 --subspace full --method tiled-then-full --validation-seeds 20 --race 0.1`"
    assert budget_curve.command(search, [{"budget": 300} | search]).endswith(flags)
    halved = budget_curve.SEARCH | {"halving": True, "validation_seeds": 20}
    assert budget_curve.folder_name(300, halved) == "300-val20-halving"
    assert budget_curve.point_of("300-val20-halving") == (300, halved)
    assert budget_curve.search_label(halved).endswith("20 validation seeds, halved")
    flags = "--validation-seeds 20 --halving`"
    assert budget_curve.command(halved, [{"budget": 300} | halved]).endswith(flags)
    smaller = budget_curve.SEARCH | {"population": 10}
    assert budget_curve.point_of(budget_curve.folder_name(850, smaller)) == (850, smaller)
    own = ("population", "full_population", "full_start")  # the method's settings
    assert budget_curve.settings_of(smaller) == {k: v for k, v in budget_curve.SEARCH.items()
                                                 if k not in own} | {"optimizer": {"population": 10}}
    assert budget_curve.settings_of(search) == {k: v for k, v in search.items() if k not in own}
    started = budget_curve.SEARCH | {"method": "portfolio", "subspace": "full", "full_start": "tiled"}
    name = budget_curve.folder_name(1100, started)
    assert name == "1100-full-portfolio-start_tiled" and budget_curve.point_of(name) == (1100, started)
    said = "portfolio, the full search from the tiled search's best"
    assert budget_curve.search_label(started).endswith(said)
    assert budget_curve.settings_of(started)["optimizer"] == {"full_start": "tiled"}
    assert budget_curve.command(started, [{"budget": 1100} | started]).endswith("--full-start tiled`")
    probed = started | {"full_start": None, "full_population": 10}
    name = budget_curve.folder_name(1100, probed)
    assert name == "1100-fullpop10-full-portfolio" and budget_curve.point_of(name) == (1100, probed)
    assert budget_curve.settings_of(probed)["optimizer"] == {"full_population": 10}
    assert budget_curve.command(probed, [{"budget": 1100} | probed]).endswith("--full-population 10`")


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


QUICK_SAC = {"learning_starts": 10, "gradient_steps": 1, "batch_size": 16, "buffer_size": 1000,
             "policy_kwargs": {"net_arch": [16]}}  # DSRL's SAC, small enough for a test


@pytest.fixture
def one_torch_thread(tmp_path_factory, monkeypatch):
    """A tiny net trains faster on one torch thread than on two busy cores (and SB3's logs go to a test
    folder, not to a new folder in /tmp)."""
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3")))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.slow
def test_dsrl_steers_the_frozen_policy_through_the_noise_space(one_torch_thread):
    from stable_baselines3 import SAC

    from goldenticket.policies import load_policy
    from goldenticket.tasks import get_task, seeds_in


    policy, task = load_policy("metaworld/reach-v3/flow"), get_task("metaworld/reach-v3", max_steps=12)
    env = dsrl.NoiseSpaceEnv(policy, task, seeds_in("search", 3))
    obs, _ = env.reset()
    obs, reward, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
    assert env.observation_space.contains(obs) and env.env_steps == policy.n_exec and reward in (0.0, 1.0)
    model = SAC("MlpPolicy", env, seed=0, device="cpu", **dsrl.SAC | QUICK_SAC)
    model.learn(30)
    steered = dsrl.ActorNoise(policy, model)
    actions = steered.act(np.stack([obs, obs]), np.zeros((2, *policy.noise_shape), np.float32))
    assert actions.shape == (2, policy.n_exec, 4) and np.array_equal(actions[0], actions[1])


@pytest.mark.slow
def test_dsrl_na_learns_from_executed_chunks_and_resumes(one_torch_thread, tmp_path):
    from dsrl_na import NoiseAliasingSAC

    from goldenticket.policies import load_policy
    from goldenticket.tasks import get_task, seeds_in


    policy, task = load_policy("metaworld/reach-v3/flow"), get_task("metaworld/reach-v3", max_steps=12)
    env = dsrl.NoiseSpaceEnv(policy, task, seeds_in("search", 3))
    model = NoiseAliasingSAC("MlpPolicy", env, seed=0, device="cpu", chunk_of=env.chunks,
                             chunk_dim=env.chunk_dim, **dsrl.SAC | QUICK_SAC)
    model.learn(30)
    buffer = model.replay_buffer
    stored = slice(0, buffer.pos)
    # each transition keeps the chunk its noise made, the one Q^A learns from
    made = env.chunks(buffer.observations[stored, 0], buffer.actions[stored, 0])
    assert buffer.pos > 0 and np.allclose(buffer.chunks[stored], made)
    model.save(tmp_path / "na.zip")
    loaded = NoiseAliasingSAC.load(tmp_path / "na.zip", env=env, device="cpu", chunk_of=env.chunks)
    for mine, theirs in zip(model.action_critic.state_dict().values(),
                            loaded.action_critic.state_dict().values(), strict=True):
        assert torch.equal(mine, theirs)
    before = [p.clone() for p in loaded.critic.parameters()]
    model.save_replay_buffer(tmp_path / "replay.pkl")
    loaded.load_replay_buffer(tmp_path / "replay.pkl")
    loaded.learn(5, reset_num_timesteps=False)  # the noise critic moves by distillation alone
    assert any(not torch.equal(a, b) for a, b in zip(before, loaded.critic.parameters(), strict=True))


def _curve(*points, budget=False):
    return [{"seconds": s, "success": p, "env_steps": 10 * s} | ({"budget": 100 * i} if budget else {})
            for i, (s, p) in enumerate(points, 1)]


def test_dsrl_race_times_each_side_to_the_others_best_with_wilson_bounds():
    dsrl_curve = _curve((100, 0.5), (200, 0.6), (300, 0.7))
    to_dsrl, to_search = dsrl.race(dsrl_curve, _curve((5, 0.55), (10, 0.62), (20, 0.64)), n=100)
    # 62% of 100 has an upper bound above 70%, no search point's estimate or lower bound reaches it
    assert to_dsrl == {"target": 0.7, "dsrl_seconds": [300] * 3, "search_seconds": [10, None, None],
                       "speedup": [None, None, 30]}
    # DSRL's 60% reaches 64% by its upper bound, 70% by its estimate, never by its lower bound (60.4%)
    assert to_search == {"target": 0.64, "dsrl_seconds": [200, 300, None], "search_seconds": [20] * 3,
                         "speedup": [10, 15, None]}
    to_dsrl, to_search = dsrl.race(dsrl_curve, _curve((5, 0.55), (10, 0.62), (20, 0.9)), n=100)
    assert to_dsrl["search_seconds"] == [10, 20, 20] and to_dsrl["speedup"] == [15, 15, 30]
    assert to_search["dsrl_seconds"] == [None] * 3 and to_search["speedup"] == [None] * 3
    search = _curve((5, 0.55), (10, 0.62), (20, 0.64), budget=True)
    curves = {"dsrl_sac": dsrl_curve, "dsrl_na": [p | {"success": 0.4} for p in dsrl_curve]}
    for curve in curves.values():
        for p in curve:
            p["sac_steps"] = p["seconds"] // 10
    pair = {"base": 0.5, "plateaued": {"dsrl_sac": False, "dsrl_na": True}} | curves | dict.fromkeys(
        dsrl.SEARCHES, search)
    races = {v: {m: dsrl.race(curve, search, n=100) for m in dsrl.SEARCHES} for v, curve in curves.items()}
    table = dsrl.markdown({"reach-v3": pair | {"race": races}},
                          minutes={"dsrl_sac": 60, "dsrl_na": 90})
    assert "--minutes 60 --na-minutes 90 --pairs reach-v3" in table
    assert "trained per pair: DSRL-SAC 60 min and DSRL-NA 90 min" in table
    assert "| 70% (300 s, 30 steps, 3000) | no | 40% (100 s, 10 steps, 1000) | yes |" in table
    assert "| DSRL-SAC | CMA-ES | DSRL-SAC, 70% | 300 s | not reached (10 s to not reached) | " \
           "not reached (not reached to 30x) |" in table
    assert "| DSRL-NA | CMA-ES | CMA-ES, 64% | not reached | 20 s | not reached |" in table
    sac_only = {k: v for k, v in pair.items() if k != "dsrl_na"} | {
        "plateaued": {"dsrl_sac": False}, "race": {"dsrl_sac": races["dsrl_sac"]}}
    table = dsrl.markdown({"robomimic/can": sac_only}, minutes={"dsrl_sac": 60, "dsrl_na": 0})
    command = "robomimic-venv/bin/python benchmarks/dsrl.py --minutes 60 --na-minutes 0 --pairs robomimic/can"
    assert f"`{command}`" in table and "DSRL-NA" not in table
    assert "on 100 held-out seeds; trained per pair: DSRL-SAC 60 min, judged every 1000 SAC steps" in table
    assert "| robomimic/can | 50% | 70% (300 s, 30 steps, 3000) | no | 100: " in table


def test_dsrl_plateau_means_the_last_third_of_checkpoints_gained_nothing_beyond_noise():
    rising = _curve(*enumerate((0.3, 0.4, 0.5, 0.6, 0.7, 0.8)))
    assert not dsrl.plateaued(rising, n=100)  # its best is in the last third, far above the earlier best
    assert dsrl.plateaued(_curve(*enumerate((0.6, 0.65, 0.62, 0.64, 0.61, 0.66))), n=100)
    assert dsrl.plateaued(_curve(*enumerate((0.5, 0.8, 0.7, 0.6))), n=100)  # declining counts: no gain
    assert not dsrl.plateaued(_curve((1, 0.5), (2, 0.5)), n=100)  # too few checkpoints to say


def test_dsrl_runs_folder_keeps_settings_and_search_points(tmp_path, monkeypatch):
    calls = []
    assert dsrl.cached(tmp_path / "p.json", lambda: calls.append(1) or {"success": 0.5}) == {"success": 0.5}
    assert dsrl.cached(tmp_path / "p.json", lambda: calls.append(1)) == {"success": 0.5} and calls == [1]
    metaworld, robomimic = dsrl.FAMILIES["metaworld"], dsrl.FAMILIES["robomimic"]
    dsrl.check_settings(tmp_path, 1, metaworld)
    dsrl.check_settings(tmp_path, 1, metaworld)
    with pytest.raises(UserError, match="other settings"):
        dsrl.check_settings(tmp_path, 2, metaworld)  # its seconds were measured on one core
    with pytest.raises(UserError, match="other settings"):
        dsrl.check_settings(tmp_path, 1, robomimic)  # judged at other steps
    with pytest.raises(UserError, match="other settings"):
        dsrl.check_settings(tmp_path, 1, dataclasses.replace(metaworld, heldout=metaworld.heldout + 1))


def test_dsrl_pairs_name_their_policy_task_and_family():
    assert dsrl.names("reach-v3") == ("metaworld/reach-v3/flow", "metaworld/reach-v3")
    assert dsrl.names("robomimic/can") == ("robomimic/can/flow", "robomimic/can")
    assert dsrl.family("reach-v3").results == "dsrl"
    assert dsrl.family("robomimic/can").results == "dsrl_robomimic"
    assert dsrl.family("robomimic/lift").halving is None and dsrl.family("reach-v3").halving is False


def test_dsrl_takes_one_simulators_pairs(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["dsrl.py", "--pairs", "reach-v3", "robomimic/lift"])
    with pytest.raises(SystemExit) as exit_:
        dsrl.main()
    assert exit_.value.code == 2 and "give one simulator's" in capsys.readouterr().err


@pytest.mark.slow
def test_dsrl_resumes_from_its_last_checkpoint_and_then_only_reports(tmp_path, monkeypatch, capsys,
                                                                      one_torch_thread):
    from stable_baselines3.common.save_util import load_from_pkl

    small = {"SAC": dsrl.SAC | QUICK_SAC, "SEARCH_SEEDS": 3, "FAMILIES": dsrl.FAMILIES | {
        "metaworld": dsrl.Family(20, 3, (20,), False, "dsrl", "python")}}
    for name, value in small.items():
        monkeypatch.setattr(dsrl, name, value)
    folder = tmp_path / "reach-v3"

    def interrupt(*args):
        raise KeyboardInterrupt

    judge, curves = dsrl.heldout_success, {}
    for variant in dsrl.VARIANTS:
        first = dsrl.dsrl_curve("reach-v3", variant, 1e-9, folder / variant)
        monkeypatch.setattr(dsrl, "heldout_success", interrupt)
        with pytest.raises(KeyboardInterrupt):  # stopped while judging its second checkpoint
            dsrl.dsrl_curve("reach-v3", variant, 1, folder / variant)
        monkeypatch.setattr(dsrl, "heldout_success", judge)
        minutes = first[-1]["seconds"] / 60 * 1.001  # one more checkpoint
        curves[variant] = resumed = dsrl.dsrl_curve("reach-v3", variant, minutes, folder / variant)
        assert resumed[0] == first[0] and resumed[1]["sac_steps"] == 2 * 20
        assert resumed[1]["seconds"] > first[0]["seconds"] and resumed[1]["env_steps"] > first[0]["env_steps"]
        assert resumed[1]["episodes"] > first[0]["episodes"]
        assert sorted(p.name for p in (folder / variant).glob("*-*.*")) == ["replay-40.pkl", "sac-40.zip"]
        assert load_from_pkl(folder / variant / "replay-40.pkl").pos == 2 * 20  # carried over
    minutes = min(curve[-1]["seconds"] for curve in curves.values()) / 60 * 0.999  # both trained longer
    monkeypatch.setattr(dsrl, "ActorNoise", interrupt)  # trained long enough: neither trains nor judges
    monkeypatch.setattr(dsrl, "write_results", interrupt)
    monkeypatch.setattr(sys, "argv", ["dsrl.py", "--minutes", str(minutes), "--na-minutes", str(minutes / 2),
                                      "--pairs", "reach-v3", "--runs", str(tmp_path), "--workers", "1",
                                      "--no-write"])
    dsrl.main()
    for variant, curve in curves.items():
        assert json.loads((folder / variant / "dsrl.json").read_text())["curve"] == curve
    assert {p.name for p in folder.glob("*-20.json")} == {f"{m}-20.json" for m in dsrl.SEARCHES}
    said = capsys.readouterr().out
    assert "| reach-v3 | " in said and f"and DSRL-NA {minutes / 2:g} min" in said


def test_robomimic_pairs_and_the_papers_rows_beside_them(monkeypatch):
    monkeypatch.setattr(existence, "policy_names", lambda: ["robomimic/lift/ddim", "robomimic/lift/flow"])
    assert ("robomimic/lift", "robomimic/lift/ddim@8") in existence.robomimic_pairs()
    assert {task for task, _ in existence.robomimic_pairs()} == {"robomimic/lift"}
    fresh = {"success_rate": 0.9, "base": {"success_rate": 0.5}}
    lines = existence.paper_lines([{"task": "robomimic/lift", "policy": "ddim@8", "fresh": fresh}])
    assert "| lift | 78.4% | 96.2% | 50.0% | 90.0% (ddim@8) |" in lines
    assert "| transport | 10.7% | 18.8% | - | - (no bundled policy) |" in lines
    assert "| can | 42.8% | 80.8% | - | - (no bundled policy) |" in lines
    assert "| lift | 78.4% | 96.2% | - | - (not run yet) |" in existence.paper_lines([])


def test_a_robomimic_run_replaces_its_pairs_rows_and_keeps_the_others(tmp_path, monkeypatch):
    import results_files

    for module in (existence, results_files):
        monkeypatch.setattr(module, "RESULTS", tmp_path)
    monkeypatch.setattr(existence, "keep_best_tickets", lambda summaries, folder: None)
    order = [("robomimic/lift", "robomimic/lift/flow"), ("robomimic/can", "robomimic/can/flow")]
    monkeypatch.setattr(existence, "robomimic_pairs", lambda tasks=None: order)

    def row(task, best):
        return _row(0.5, 0.5, best, 0.01, 0.5) | {"task": task, "wall_time_s": 600, "workers": 2}

    existence.write_robomimic([], [row("robomimic/can", 0.6)], ship_them=False, settings=existence.SETTINGS)
    existence.write_robomimic([], [row("robomimic/lift", 0.7)], ship_them=False, settings=existence.SETTINGS)
    existence.write_robomimic([], [row("robomimic/lift", 0.8)], ship_them=False, settings=existence.SETTINGS)
    record = json.loads((tmp_path / "robomimic_existence.json").read_text())
    assert [(r["task"], r["best"]["success_rate"]) for r in record["pairs"]] == [
        ("robomimic/lift", 0.8), ("robomimic/can", 0.6)]
    assert record["wall_time_s"] == 1200
    table = (tmp_path / "robomimic_existence.md").read_text()
    assert "lift flow 10 min (2 worker(s)), can flow 10 min (2 worker(s))." in table
    assert "Wall time of this run" not in table
    resumed = row("robomimic/can", 0.6) | {"episode_seconds": 7200}
    existence.write_robomimic([], [resumed], ship_them=False, settings=existence.SETTINGS)
    table = (tmp_path / "robomimic_existence.md").read_text()
    assert "can flow 10 min (2 worker(s), 120 min of episodes)." in table


def test_a_pairs_episodes_time_counts_every_part_of_its_run_and_only_its_own_fresh_arms(tmp_path):
    def episode(ticket, seconds):
        return EpisodeRow(ticket, "metaworld/reach-v3", len(ticket), "heldout", True, 1.0, 10, seconds)

    with RunStore(tmp_path / "run.sqlite") as store:  # search, validation, verdict: all its own
        store.record([episode("abc", 100.0), episode("def", 20.0), episode("zero", 2.0)])
    with RunStore(tmp_path / f"{existence.FRESH_RANGES[0]}.sqlite") as store:
        store.record([episode("abc", 10.0), episode("base", 5.0), episode("def", 1000.0)])
    assert existence.pair_episode_seconds(tmp_path, "abc") == 137


def test_existence_runs_only_the_policies_asked_for(monkeypatch):
    ran = []
    monkeypatch.setattr(existence, "run_pair", lambda task, policy, *rest, **kw: ran.append(policy) or {})
    monkeypatch.setattr(existence, "table_row", lambda summary: summary)
    monkeypatch.setattr(existence, "write_robomimic", lambda *args: None)
    monkeypatch.setattr(sys, "argv", ["existence.py", "--robomimic", "can", "--policies", "ddim@2"])
    existence.main()
    assert ran == ["robomimic/can/ddim@2"]


def test_shipping_one_step_count_keeps_the_tickets_of_the_others(tmp_path, monkeypatch):
    tickets = tmp_path / "robomimic" / "can" / "ddim" / "tickets"
    made_for_8 = Ticket(np.zeros((8, 7), np.float32), TicketRecord(policy="robomimic/can/ddim@8"))
    made_for_8.save(tickets / f"{made_for_8.id}.safetensors")
    monkeypatch.setattr(existence, "BUNDLED_DIR", tmp_path)
    not_golden = {"best": {"golden": False}}
    assert existence.ship([not_golden | {"policy": "robomimic/can/ddim@2"}]) == 0
    assert [p.name for p in tickets.iterdir()] == [f"{made_for_8.id}.safetensors"]
    assert existence.ship([not_golden | {"policy": "robomimic/can/ddim@8"}]) == 0
    assert not any(tickets.iterdir())


def test_a_golden_ticket_below_the_zero_ticket_on_fresh_seeds_is_not_shipped(tmp_path, monkeypatch):
    ticket = Ticket(np.full((8, 7), 0.5, np.float32), TicketRecord(policy="robomimic/can/flow"))
    path = tmp_path / "found" / f"{ticket.id}.safetensors"
    ticket.save(path)
    monkeypatch.setattr(existence, "BUNDLED_DIR", tmp_path)
    fresh = {"p_below_base": 0.36, "p_below_zero": 0.9}
    best = {"golden": True, "ticket_path": str(path), "fresh": fresh, "fresh_2": fresh}
    summary = {"policy": "robomimic/can/flow", "best": best}
    assert existence.ship([summary]) == 1
    assert (tmp_path / "robomimic" / "can" / "flow" / "tickets" / path.name).is_file()
    best["fresh"] = fresh | {"p_below_zero": 0.017}
    assert existence.ship([summary]) == 0
    assert not any((tmp_path / "robomimic" / "can" / "flow" / "tickets").iterdir())


def test_untuned_bench_says_what_the_job_delivers_and_sets_the_authors_ticket_beside_each_pair():
    seeds = {"seeds": [1000200, 1000399]}
    ours = _row(0.5, 0.45, 0.9, 1e-6, 1e-7) | {"ticket": "abc", "episode_seconds": 600, "deliver": "ticket"}
    ours["fresh"] = ours["fresh"] | seeds
    del ours["fresh_2"]  # one fresh range judged
    zero = _row(0.5, 0.4, 0.4, 1.0, 1.0, zero_ticket=True) | {"ticket": "def", "episode_seconds": 60,
                                                               "deliver": "base"}
    zero["fresh"], zero["fresh_2"] = zero["fresh"] | seeds, zero["fresh_2"] | seeds
    theirs = {"ticket": "ghi", "fresh": ours["fresh"] | {"success_rate": 0.95}}
    authors = {"authors-ticket": {"franka-1003": theirs}}
    rows = {("franka-1003", "portfolio"): ours, ("franka-1003", "tiled"): zero}
    table = untuned_bench.markdown(rows, authors)
    lines = table.splitlines()[2:]
    base = "tiled: the base (its best, the zero ticket, was not above it)"
    assert [line.split(" | ")[1] for line in lines] == ["portfolio: ticket abc", base, base,
                                                        "the authors' shipped ticket, ghi"]
    assert lines[1].split(" | ")[3] == lines[1].split(" | ")[5] == "50.0% [45%, 55%]"  # the base, delivered
    assert " | - | - | - | - | " in lines[1]
    rates = "| 1000200:1000400 | 50.0% [45%, 55%] | 45.0% [40%, 50%] | 90.0% [85%, 95%] | 1e-06 | 1e-07 |"
    assert rates in lines[0]
    assert "95.0%" in lines[3] and lines[0].endswith("| 1200 | 10 min |")


def test_untuned_bench_keeps_each_rows_ticket_beside_it(tmp_path, monkeypatch):
    ticket = Ticket(np.full((8, 4), 0.5, np.float32), TicketRecord(policy="franka_pick:make_policy_1003"))
    judged = ticket.save(tmp_path / "run" / "tickets" / f"{ticket.id}.safetensors")
    monkeypatch.setattr(untuned_bench, "ROWS", tmp_path / "rows")
    monkeypatch.setattr(untuned_bench, "run_pair",
                        lambda *args, **kw: {"best": {"ticket_path": str(judged)}, "deliver": "ticket"})
    monkeypatch.setattr(untuned_bench, "table_row",
                        lambda summary: {"ticket": ticket.id, "episode_seconds": 7})
    untuned_bench.pair_row("franka-1003", "portfolio", 1250, 1)
    kept = tmp_path / "rows" / "portfolio"
    assert json.loads((kept / "franka-1003.json").read_text()) == {"ticket": ticket.id, "episode_seconds": 7,
                                                                   "deliver": "ticket"}
    assert Ticket.load(kept / "franka-1003.safetensors").id == ticket.id


def test_untuned_bench_draws_each_searchs_budget_curve():
    assert untuned_bench.arm_name("tiled", 1250) == "tiled"
    assert untuned_bench.arm_of(untuned_bench.arm_name("portfolio", 250)) == ("portfolio", 250)
    seeds = {"seeds": [1000200, 1000399]}
    small = _row(0.5, 0.45, 0.7, 1e-3, 1e-3) | {"ticket": "abc", "episode_seconds": 60, "deliver": "ticket"}
    large = _row(0.5, 0.45, 0.9, 1e-6, 1e-7) | {"ticket": "def", "episode_seconds": 600, "deliver": "base"}
    for row in (small, large):
        row["fresh"], row["fresh_2"] = row["fresh"] | seeds, row["fresh_2"] | seeds
    rows = {("fetch-push", "tiled@250"): small, ("fetch-push", "tiled"): large,
            ("franka-1003", "tiled"): large}
    table = untuned_bench.markdown(rows, {})
    assert "| fetch-push | tiled within 250: ticket abc |" in table
    curve = table.split("The budget curve")[1].splitlines()
    assert curve[2] == "| pair | search | 250 | 1250 |"
    assert curve[4] == "| fetch-push | tiled | 70.0% / 70.0% | 50.0% / 50.0% (the base) |"
    assert len(curve) == 5  # franka-1003 has one budget: no curve


def test_a_multitask_study_searches_each_task_and_all_together_and_judges_them_on_fresh_seeds(tmp_path):
    study = dataclasses.replace(multitask.mt10(None), tasks=("metaworld/reach-v3", "metaworld/push-v3"),
                                method="rs", budget=10, heldout=2, fresh=range(1_000_100, 1_000_102))
    results, matrix = multitask.run(study, tmp_path, workers=1)
    assert results["multitask"]["search_episodes"] <= 20 and set(matrix.tasks) == set(study.tasks)
    for task in study.tasks:
        assert [results["fresh"][task][arm]["n"] for arm in multitask.ARMS] == [2] * len(multitask.ARMS)
    again, _ = multitask.run(study, tmp_path, workers=1)  # every episode read back from the run folders
    assert again["fresh"] == results["fresh"] and again["transfer"] == results["transfer"]
    table = multitask.markdown(results, study, workers=1)
    assert "### Fresh held-out seeds 1000100:1000102 (2 per task)" in table
    assert "Search: rs, 10 search episodes per task" in table and "first 2 held-out seeds" in table


def test_the_libero_study_runs_the_shipped_smolvla_on_its_five_tasks_with_the_search_defaults():
    study = multitask.libero_object(None)
    assert study.policy == "examples/smolvla_libero_policy" and len(study.tasks) == 5
    assert study.search() == {"env_option": {"observation_height": 64, "observation_width": 64}}
    assert set(study.fresh).isdisjoint(range(1_000_000, 1_000_000 + study.heldout))
