"""Studies: mixture arms and their diversity, ..."""

import json

import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.tickets import Ticket

POLICY, TASK = "metaworld/reach-v3/flow", "metaworld/reach-v3"


def _tickets(tmp_path, n: int) -> list[str]:
    rng = np.random.default_rng(0)
    return [str(Ticket(rng.standard_normal((8, 4), dtype=np.float32)).save(tmp_path / f"t{i}.safetensors"))
            for i in range(n)]


@pytest.mark.slow
def test_a_mixture_arm_is_judged_and_spreads_between_tickets_and_base(tmp_path, capsys):
    args = ["evaluate", "--policy", POLICY, "--task", TASK, "--seeds", "1000000:1000006", "--max-steps", "40",
            "--workers", "1", "--plot", str(tmp_path / "e.png"), "--mixture", "--epsilon", "0.2", "--json"]
    for ticket in _tickets(tmp_path, 2):
        args += ["--ticket", ticket]
    assert main(args) == 0
    rows = json.loads(capsys.readouterr().out)
    assert set(rows) == {"base", "zero", "mixture", *(Ticket.load(t).id for t in _tickets(tmp_path, 2))}
    assert rows["mixture"]["n"] == 6 and "p_vs_base" in rows["mixture"]
    tickets = [r["diversity"] for label, r in rows.items() if label not in ("base", "mixture")]
    assert tickets == [0.0, 0.0, 0.0]  # constant noise, deterministic policy and env
    assert rows["base"]["diversity"] > rows["mixture"]["diversity"] > 0


def test_mixture_options_are_checked(tmp_path, capsys):
    one, two = _tickets(tmp_path, 1), _tickets(tmp_path, 2)
    base = ["evaluate", "--policy", POLICY, "--task", TASK, "--seeds", "1000000:1000004",
            "--plot", str(tmp_path / "e.png")]
    assert main([*base, "--ticket", one[0], "--ticket", one[0], "--mixture"]) == 2
    assert main([*base, "--ticket", two[0], "--ticket", two[1], "--epsilon", "0.1"]) == 2
    assert main([*base, "--ticket", two[0], "--ticket", two[1], "--mixture", "--epsilon", "1.5"]) == 2
    errors = capsys.readouterr().err.splitlines()
    assert len(errors) == 3 and "at least 2 different tickets" in errors[0] and "--epsilon" in errors[1]


def _search(tmp_path, subspace: str) -> int:
    return main(["search", "--policy", POLICY, "--task", TASK, "--method", "rs", "--budget", "12",
                 "--search-seeds", "3", "--heldout", "4", "--top-k", "1", "--max-steps", "30",
                 "--validation-seeds", "0", "--workers", "1", "--subspace", subspace,
                 "--out", str(tmp_path / subspace.replace(":", "-"))])


@pytest.mark.slow
def test_subspace_search_saves_full_tickets_that_record_their_subspace(tmp_path):
    assert _search(tmp_path, "tiled") == 0 and _search(tmp_path, "channels:3") == 0
    tiled = Ticket.load(next((tmp_path / "tiled" / "tickets").glob("*.safetensors")))
    assert tiled.noise.shape == (8, 4) and (tiled.noise == tiled.noise[0]).all()
    assert tiled.metadata["subspace"] == "tiled" and tiled.metadata["searched_shape"] == [1, 4]
    gripper = Ticket.load(next((tmp_path / "channels-3" / "tickets").glob("*.safetensors")))
    assert (gripper.noise[:, :3] == 0).all() and (gripper.noise[:, 3] != 0).all()
    assert gripper.metadata["searched_shape"] == [8, 1]


def test_bad_subspaces_exit_2_with_one_line(tmp_path, capsys):
    for bad in ("channels:9", "channels:x", "channels:1,1", "diagonal"):
        assert _search(tmp_path, bad) == 2
    errors = capsys.readouterr().err.splitlines()
    assert len(errors) == 4 and all(e.startswith("goldenticket: error: --subspace") for e in errors)


def test_non_dominated_keeps_the_front_and_ties():
    from goldenticket.studies.pareto import non_dominated

    points = [(0.5, 0.6), (0.7, 0.5), (0.5, 0.6), (0.4, 0.4), (0.7, 0.4), (0.2, 0.9)]
    assert non_dominated(points) == [0, 1, 2, 5]


@pytest.mark.slow
def test_a_two_objective_search_writes_the_front_and_a_policy_switches_along_it(tmp_path, capsys):
    from goldenticket.policies import TicketedPolicy, load_policy

    out = tmp_path / "front"
    assert main(["search", "--policy", POLICY, "--task", TASK, "--method", "rs", "--budget", "24",
                 "--search-seeds", "3", "--heldout", "6", "--top-k", "1", "--max-steps", "40",
                 "--validation-seeds", "0", "--workers", "1", "--objective", "success",
                 "--front-objective", "speed",
                 "--out", str(out)]) == 0
    assert "Pareto front (success vs speed)" in capsys.readouterr().out
    study = json.loads((out / "front.json").read_text())
    front = [e["ticket_id"] for e in study["search"] if e["front"]]
    assert len(study["search"]) == 8 and front and set(study["heldout"]) == {"base", "zero", *front}
    assert json.loads((out / "summary.json").read_text())["front"] == front
    assert (out / "front.png").stat().st_size > 0
    deployed = TicketedPolicy(load_policy(POLICY), np.zeros((8, 4), np.float32))
    obs = np.zeros((1, 39), np.float32)
    for ticket_id in front:
        ticket = Ticket.load(out / "tickets" / f"{ticket_id}.safetensors")
        assert ticket.metadata["front"]["objectives"] == ["success", "speed"]
        deployed.use(ticket.noise)
        assert np.array_equal(deployed.act(obs), deployed.policy.act(obs, ticket.noise[None]))


def test_objective_combinations_are_checked(tmp_path, capsys):
    base = ["search", "--policy", POLICY, "--task", TASK, "--budget", "10", "--out", str(tmp_path / "x")]
    assert main([*base, "--objective", "success", "--front-objective", "success"]) == 2
    errors = capsys.readouterr().err.splitlines()
    assert len(errors) == 1 and "two different" in errors[0] and "--objective" in errors[0], errors
    with pytest.raises(SystemExit) as exit_:
        main([*base, "--objective", "success", "--objective", "speed"])
    assert exit_.value.code == 2 and "--objective given twice" in capsys.readouterr().err


@pytest.mark.slow
def test_validation_seeds_choose_among_the_searchs_best_on_states_of_their_own(tmp_path):
    from goldenticket.store import RunStore

    out = tmp_path / "validated"
    assert main(["search", "--policy", POLICY, "--task", TASK, "--method", "rs", "--budget", "24",
                 "--search-seeds", "3", "--heldout", "6", "--top-k", "1", "--max-steps", "40",
                 "--workers", "1", "--validation-seeds", "4", "--out", str(out)]) == 0
    with RunStore(out / "run.sqlite") as store:
        rows = store.episodes(seed_set="validation")
    by_ticket: dict[str, list[bool]] = {}
    for row in rows:
        by_ticket.setdefault(row.ticket_id, []).append(row.success)
    assert len(by_ticket) == 3 + 1 and all(len(v) == 4 for v in by_ticket.values())  # and the zero ticket
    assert {r.seed for r in rows} == set(range(3_000_000, 3_000_004))
    best = json.loads((out / "summary.json").read_text())["best"]
    assert best["validation_score"] == max(float(np.mean(v)) for v in by_ticket.values())
    assert best["validation_score"] == float(np.mean(by_ticket[best["ticket_id"]]))


def test_one_task_validates_on_40_seeds_unless_told_and_several_tasks_do_not():
    from goldenticket.config import SearchConfig

    assert SearchConfig(POLICY, TASK).validation() == 40
    assert SearchConfig(POLICY, TASK, validation_seeds=0).validation() == 0
    assert SearchConfig(POLICY, (TASK, "metaworld/push-v3")).validation() == 0
