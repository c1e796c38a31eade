import json
from pathlib import Path

import numpy as np
import pytest
import torch

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.evaluation import Arm, Verdict, VerdictRow, judged_arms
from goldenticket.evaluation import multitask_verdict as verdict
from goldenticket.multitask import greedy_cover
from goldenticket.policies import MLPPolicy, PolicyConfig
from goldenticket.results import TransferCell
from goldenticket.rollout import EpisodeResult
from goldenticket.seeds import SEED_SETS
from goldenticket.stats import Rate
from goldenticket.store import RunStore
from goldenticket.tickets import Ticket

TASKS = ["metaworld/reach-v3", "metaworld/drawer-close-v3"]
SMALL = ["--budget", "24", "--search-seeds", "4", "--heldout", "4", "--max-steps", "40", "--method", "rs",
         "--workers", "1"]


@pytest.fixture(scope="module")
def mt_policy(tmp_path_factory) -> str:
    """An untrained two-task flow policy (fixed weights from a seed)."""
    torch.manual_seed(0)
    cfg = PolicyConfig("test/mt2/flow", "flow", 39, 4, hidden=32, layers=2, steps=3, tasks=TASKS)
    path = tmp_path_factory.mktemp("mt_policy")
    MLPPolicy(cfg).save(path)
    return str(path)


def _tasks_args(tasks=TASKS):
    return [arg for task in tasks for arg in ("--task", task)]


def test_the_one_hot_conditions_the_actions(mt_policy):
    policy = MLPPolicy.load(Path(mt_policy))
    obs, noise = np.ones((3, 39), np.float32), np.zeros((3, 8, 4), np.float32)
    reach, drawer = (policy.conditioned(t).act(obs, noise) for t in TASKS)
    assert not np.array_equal(reach, drawer)
    with pytest.raises(UserError, match="multi-task"):
        policy.act(obs, noise)
    with pytest.raises(UserError, match="not trained for task 'metaworld/push-v3'"):
        policy.conditioned("metaworld/push-v3")


@pytest.mark.slow
def test_multitask_search_judges_each_task_on_unsearched_seeds(mt_policy, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["search", "--policy", mt_policy, *_tasks_args(), *SMALL, "--top-k", "2",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["tasks"]) == set(TASKS) and summary["average"]["base"]["n"] == 8
    with RunStore(out / "run.sqlite") as store:
        for task in TASKS:
            rows = store.episodes(task=task)
            searched = {r.seed for r in rows if r.seed_set == "search"}
            heldout = {r.seed for r in rows if r.seed_set == "heldout"}
            assert searched and heldout and not searched & heldout
            assert all(r.seed in SEED_SETS[r.seed_set] for r in rows)
            judged = {r.ticket_id for r in rows if r.seed_set == "heldout"}
            assert judged >= {"base", "zero", *summary["tickets"]}
    ticket_path = next((out / "tickets").iterdir())
    ticket = Ticket.load(ticket_path)
    assert ticket.metadata["tasks"] == TASKS and set(ticket.metadata["heldout"]["per_task"]) == set(TASKS)
    assert "average" in capsys.readouterr().out
    assert (out / "verdict.png").stat().st_size > 0
    # a multi-task ticket runs on each of its tasks without --allow-transfer
    assert main(["evaluate", "--policy", mt_policy, "--task", TASKS[1], "--ticket", str(ticket_path),
                 "--seeds", "1000000:1000002", "--workers", "1",
                 "--plot", str(tmp_path / "e.png")]) == 0


def _arms(**outcomes: list[bool]) -> Verdict:
    return judged_arms({Arm.of(key): [EpisodeResult(seed, s, float(s), 1, 0.0) for seed, s in enumerate(arm)]
                        for key, arm in outcomes.items()})


def test_no_regression_passes_over_a_ticket_worse_on_one_task():
    # ticket A: best on average, but 10 of 10 base successes lost on task y; ticket B: no loss.
    per_task = {
        "x": _arms(base=[False] * 20, zero=[False] * 20, A=[True] * 20, B=[True] * 4 + [False] * 16),
        "y": _arms(base=[True] * 10 + [False] * 10, zero=[False] * 20, A=[False] * 20,
                   B=[True] * 10 + [False] * 10),
    }
    a, b = Arm.ticket("A"), Arm.ticket("B")
    assert verdict(per_task, no_regression=False).best == a
    guarded = verdict(per_task, no_regression=True)
    assert guarded.best == b and guarded.regressions == {a: ["y"], b: []}
    only_a = _arms(base=[True] * 10 + [False] * 10, zero=[False] * 20, A=[False] * 20)
    assert verdict({"y": only_a}, no_regression=True).best is None
    assert guarded.to_dict()["regressions"] == {"A": ["y"], "B": []} and guarded.to_dict()["best"] == "B"


def test_judging_several_tasks_twice_gives_the_same_p_values():
    per_task = {"x": _arms(base=[False] * 20, zero=[False] * 20, A=[True] * 8 + [False] * 12,
                           B=[True] * 6 + [False] * 14),
                "y": _arms(base=[False] * 20, zero=[False] * 20, A=[True] * 5 + [False] * 15,
                           B=[False] * 20)}
    first = verdict(per_task, no_regression=False)
    assert verdict(per_task, no_regression=False) == first  # nothing adjusted in place, so never twice
    assert first.average[Arm.ticket("A")].p_vs_base == 2 * 0.5 ** 13  # 13 wins of 13, Holm over 2


def test_greedy_cover_picks_the_fewest_tickets_and_falls_back_to_the_best():
    def cell(gain, significant):
        return TransferCell(0.5 + gain, gain, 0.01 if significant else 0.5, significant)

    gains = {"A": (0.2, 0.1, -0.1, -0.2, 0.0), "B": (0.3, 0.0, 0.2, -0.1, 0.0),
             "C": (0.0, 0.0, 0.3, -0.3, 0.1)}
    significant = {"A": {"t1", "t2"}, "B": {"t1", "t3"}, "C": {"t3"}}
    cells = {t: {f"t{i + 1}": cell(g, f"t{i + 1}" in significant[t]) for i, g in enumerate(gains[t])}
             for t in gains}
    bases = {t: VerdictRow(Rate.counted(50, 100)) for t in ("t1", "t2", "t3", "t4", "t5")}
    cover = greedy_cover(cells, bases)
    # A and B each cover two tasks, B with the larger gain; then A covers t2; t4: no ticket beats
    # the base; t5: C beats it, not significantly
    assert cover.tickets == ("B", "A") and cover.fallbacks == ("C",)
    uses = {t: use.key for t, (use, _) in cover.table.items()}
    assert uses == {"t1": "B", "t2": "A", "t3": "B", "t4": "base", "t5": "C"}


@pytest.mark.slow
def test_transfer_writes_the_matrix_heatmap_and_cover(mt_policy, tmp_path, capsys):
    out = tmp_path / "transfer"
    assert main(["transfer", "--policy", mt_policy, *_tasks_args(), *SMALL, "--out", str(out)]) == 0
    study = json.loads((out / "transfer.json").read_text())
    # each task's search found one ticket; two tasks may find the same one (same seed, same pool)
    found = sorted(t for tasks in study["tickets"].values() for t in tasks)
    assert study["tasks"] == TASKS and found == sorted(TASKS)
    assert all(set(row) == set(TASKS) for row in study["cells"].values())
    assert set(study["cover"]["table"]) == set(TASKS)
    assert len((out / "transfer.csv").read_text().splitlines()) == 1 + 2 * len(study["tickets"])
    assert (out / "transfer.png").stat().st_size > 0 and "switching table" in capsys.readouterr().out
    searched = {json.loads(p.read_text())["best"]["ticket_id"]
                for p in (out / "search").glob("*/summary.json")}
    assert searched == set(study["tickets"])
    # the same tickets given by file, no search: the same matrix
    paths = [str(p) for p in (out / "search").glob("*/tickets/*.safetensors")]
    given = [arg for path in paths for arg in ("--ticket", path)]
    unbudgeted = ["transfer", "--policy", mt_policy, *_tasks_args(), *SMALL[2:]]
    assert main([*unbudgeted, *given, "--out", str(tmp_path / "given")]) == 0
    assert json.loads((tmp_path / "given" / "transfer.json").read_text())["cells"] == study["cells"]
    capsys.readouterr()
    assert main([*unbudgeted, "--out", str(tmp_path / "none")]) == 2
    assert "needs --budget" in capsys.readouterr().err


@pytest.mark.slow
def test_several_tasks_validate_on_every_task_when_asked(mt_policy, tmp_path):
    out = tmp_path / "validated"
    assert main(["search", "--policy", mt_policy, *_tasks_args(), *SMALL, "--top-k", "1",
                 "--validation-seeds", "3", "--out", str(out)]) == 0
    with RunStore(out / "run.sqlite") as store:
        rows = store.episodes(seed_set="validation")
    for task in TASKS:
        assert {(r.ticket_id, r.seed) for r in rows if r.task == task} == {
            (t, s) for t in {r.ticket_id for r in rows} for s in range(3_000_000, 3_000_003)}
    best = json.loads((out / "summary.json").read_text())["best"]
    scores = {t: np.mean([np.mean([r.ret for r in rows if r.task == task and r.ticket_id == t])
                          for task in TASKS]) for t in {r.ticket_id for r in rows}}
    assert scores[best] == max(scores.values())
    assert Ticket.load(out / "tickets" / f"{best}.safetensors").metadata["validation_score"] == scores[best]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["validation_scores"] == {t: scores[t] for t in summary["tickets"]}  # as one task's rows


@pytest.mark.parametrize("args, message", [
    (["transfer", "--task", TASKS[0]], "at least two --task"),
    (["search", "--task", TASKS[0], "--no-regression"], "--no-regression needs several --task"),
    (["search", *_tasks_args([*TASKS, "metaworld/push-v3"])], "not trained for task 'metaworld/push-v3'"),
    (["search", *_tasks_args([TASKS[0], TASKS[0]])], "given twice"),
    (["search", *_tasks_args(), "--success", "byo_example:reached"], "single-task"),
])
def test_bad_multitask_input_exits_2_with_one_line(mt_policy, tmp_path, capsys, args, message):
    assert main([*args, "--policy", mt_policy, *SMALL, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
