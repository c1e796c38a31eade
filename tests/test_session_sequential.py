"""Sequential real-robot sessions: the race, the sequential sign test and when it stops, the
robot's client against a live server, the CLI options."""

import itertools
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from scipy.integrate import quad
from test_session import _client, _free_port, _plan, _server

from goldenticket import stats
from goldenticket.errors import UserError
from goldenticket.session import Client, Plan, ScoreConflict, Session

POLICY = "metaworld/pick-place-v3/flow"


def _sequential(**kw) -> Plan:
    return _plan(**{"stopping": "sequential", "tickets": 6, "episodes_per_ticket": 4, "confirm": 20} | kw)


def _play(session: Session, success) -> list:
    """Score every due episode with success(NextEpisode, status); the stages seen, in order."""
    stages = []
    while (due := session.next()) is not None:
        status = session.status()
        stages.append(status["stage"])
        session.score(due.episode, success(due, status))
    return stages


def test_the_mixture_e_value_is_its_integral_and_the_test_keeps_alpha_exactly():
    for w, n in ((0, 0), (3, 4), (7, 9), (1, 10), (20, 32)):
        integral = quad(lambda q, w=w, n=n: 2 * q ** w * (1 - q) ** (n - w) / 0.5 ** n, 0.5, 1)[0]
        assert stats.mixture_log_e(w, n - w) == pytest.approx(np.log(integral), rel=1e-9)
    cap, alpha = 12, 0.05
    threshold = stats.sequential_threshold(cap, alpha)
    golden = sum(stats.sequential_sign_test(signs, [not s for s in signs], cap, alpha).decision == "golden"
                 for signs in itertools.product([True, False], repeat=cap))  # every discordant path
    assert golden / 2 ** cap == pytest.approx(stats.sequential_level(threshold, cap))
    assert golden / 2 ** cap < alpha
    below = max(v for row in stats._log_e_table(cap) for v in row if v < threshold)
    assert stats.sequential_level(below, cap) >= alpha  # the threshold is the smallest that keeps alpha
    concordant = stats.sequential_sign_test([True] * cap, [True] * cap, cap, alpha)  # no discordant pair
    assert (concordant.decision, concordant.reason) == ("not golden", "out of reach")
    assert concordant.pairs < cap
    with pytest.raises(ValueError, match="exceed the cap"):
        stats.sequential_sign_test([True] * 5, [False] * 5, 4)


def test_the_race_halves_the_candidates_and_spends_the_search_budget():
    assert Plan("p", "fp", (2, 2), 6, 25, 75, 0).rounds == [(6, 8, 3), (3, 16, 2), (2, 25, 1)]
    assert Plan("p", "fp", (2, 2), 2, 25, 75, 0).rounds == [(2, 25, 1)]
    assert Plan("p", "fp", (2, 2), 6, 25, 50, 0, "fixed").rounds == [(6, 25, 2)]
    plan = Plan("p", "fp", (2, 2), 6, 25, 75, 0)
    assert plan.starts == [0, 48, 96, 146, 296] and plan.episodes == 296 <= 6 * 25 + 3 * 50


def test_weak_tickets_are_dropped_and_the_finalist_runs_in_blind_pairs(tmp_path):
    session = Session.new(tmp_path, _sequential())
    best = session.scores()[0]["arm"]
    stages = _play(session, lambda due, status: due.ticket_id == best or (due.ticket_id == "base"
                                                                          and due.episode % 3 != 0))
    scores = session.scores()
    runs = {arm: sum(r["phase"] == "search" and r["arm"] == arm for r in scores)
            for arm in {r["arm"] for r in scores}}
    rounds = session.plan.rounds
    assert sorted(runs.values()) == sorted([rounds[0][1]] * 3 + [rounds[0][1] + rounds[1][1]]
                                           + [sum(each for _, each, _ in rounds)] * 2 + [0])
    assert runs[best] == max(runs.values())  # the best ticket runs in every round
    confirm = [r for r in scores if r["phase"] == "confirm"]
    assert {r["arm"] for r in confirm} == {best, "base"}
    pairs = [tuple(r["arm"] for r in confirm[i:i + 2]) for i in range(0, len(confirm), 2)]
    assert all(set(p) == {best, "base"} for p in pairs) and len(set(pairs)) == 2  # both orders occur
    assert "search phase, round 2 of 3" in stages
    assert "confirm phase, pair 2 of at most 20, run 2 of 2: the same scene as run 1" in stages
    assert not any(best in s or "base" in s for s in stages)


def test_a_clearly_better_ticket_stops_the_session_early(tmp_path):
    session = Session.new(tmp_path, _sequential())
    _play(session, lambda due, status: due.ticket_id != "base")
    status = session.status()
    verdict, stopping = status["verdict"], status["verdict"]["stopping"]
    finalist = next(a for a in verdict["arms"] if a != "base")
    assert verdict["arms"][finalist]["verdict"] == "golden" and verdict["arms"][finalist]["p_value"] < 0.05
    threshold = stats.sequential_threshold(20, 0.05)
    needed = next(k for k in range(1, 21) if stats.mixture_log_e(k, 0) >= threshold)
    assert stopping["reason"] == "decided early" and stopping["pairs"] == needed < 20
    assert stopping["ticket_only"] == needed and stopping["episodes"] == session.plan.starts[-2] + 2 * needed
    assert status["due"] is None and status["scored"] == stopping["episodes"] < status["total"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["verdict"] == verdict and summary["plan"]["stopping"] == "sequential"
    assert summary["verdict"]["stopping"]["test"].startswith("sequential sign test")
    each = [e for _, e, _ in session.plan.rounds]  # 1, 2 and 4 episodes per candidate per round
    assert sorted(summary["search_episodes"].values()) == [each[0]] * 3 + [sum(each[:2])] + [sum(each)] * 2
    with pytest.raises(ScoreConflict, match="the session is complete"):
        session.score(stopping["episodes"], True)
    session.undo(status["last_scored"])  # the decision is undone with its last score
    assert session.status()["due"] == status["last_scored"] and not (tmp_path / "summary.json").exists()


def test_equal_arms_reach_the_cap_or_lose_hope_and_are_not_golden(tmp_path):
    coin = np.random.default_rng(7)
    session = Session.new(tmp_path, _sequential())
    _play(session, lambda due, status: bool(coin.random() < 0.5))
    verdict = session.verdict()
    (finalist,), stopping = set(verdict["arms"]) - {"base"}, verdict["stopping"]
    assert verdict["arms"][finalist]["verdict"] == "not golden"
    assert stopping["e_value"] < stopping["threshold"]
    assert stopping["reason"] in ("decided early", "cap reached")


def test_scene_ids_on_both_runs_of_a_pair_make_the_test_paired(tmp_path):
    session = Session.new(tmp_path, _sequential())
    confirm = session.plan.starts[-2]
    while (due := session.next()) is not None:
        pair = (due.episode - confirm) // 2
        session.score(due.episode, due.ticket_id != "base", scene=f"layout {pair}" if pair >= 0 else None)
    assert session.verdict()["stopping"]["test"] == "sequential sign test, pairs matched by scene id"


def test_the_plan_is_a_function_of_the_seed_and_the_scores(tmp_path):
    outcomes = {}

    def success(due, status):
        return outcomes.setdefault(due.episode, (due.episode * 7) % 5 < 2)

    first, second = Session.new(tmp_path / "a", _sequential()), Session.new(tmp_path / "b", _sequential())
    _play(first, success)
    end_of_round = first.plan.starts[1] - 1
    for episode in range(first.plan.starts[1]):  # the second session: round 1, undo, rescore
        second.score(episode, outcomes[episode])
    planned = second.status()["planned"]
    second.undo(end_of_round)  # drops round 2, planned from the score undone
    assert second.status()["planned"] == first.plan.starts[1] < planned
    second.score(end_of_round, outcomes[end_of_round])
    second = Session(tmp_path / "b")  # another process goes on
    while (due := second.next()) is not None:
        second.score(due.episode, outcomes[due.episode])
    strip = [{k: r[k] for k in ("episode", "phase", "arm", "success")} for r in first.scores()]
    assert strip == [{k: r[k] for k in ("episode", "phase", "arm", "success")} for r in second.scores()]


def test_plans_without_a_stopping_rule_open_as_fixed_and_bad_plans_are_refused(tmp_path):
    import sqlite3

    Session.new(tmp_path, _plan())
    con = sqlite3.connect(tmp_path / "session.sqlite")
    plan = json.loads(con.execute("SELECT value FROM plan").fetchone()[0])
    del plan["stopping"], plan["alpha"]  # as stored before sequential stopping existed
    con.execute("UPDATE plan SET value = ?", (json.dumps(plan),))
    con.commit()
    assert Session(tmp_path).plan.stopping == "fixed" and Session(tmp_path).status()["total"] == 15
    for bad in ({"alpha": 1.5}, {"stopping": "whenever"}, {"confirm": 4}, {"confirm": 1001}):
        with pytest.raises(UserError, match="--alpha|--stopping|--confirm"):
            _sequential(**bad)


def test_session_new_takes_the_stopping_rule_and_alpha(tmp_path, capsys):
    from goldenticket.cli import main

    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "seq")]) == 0
    plan = Session(tmp_path / "seq").plan
    assert (plan.stopping, plan.alpha, plan.confirm, plan.episodes) == ("sequential", 0.05, 75, 296)
    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "fixed"),
                 "--stopping", "fixed", "--alpha", "0.1"]) == 0
    plan = Session(tmp_path / "fixed").plan
    assert (plan.stopping, plan.alpha, plan.confirm, plan.episodes) == ("fixed", 0.1, 50, 300)
    assert "at most 296 episodes in all (sequential stopping)" in capsys.readouterr().out
    for flags in (["--alpha", "0"], ["--confirm", "3"]):
        assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "bad"), *flags]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 2 and all(line.startswith("goldenticket: error: ") for line in errors)
    assert "--alpha" in errors[0] and "--confirm" in errors[1] and not (tmp_path / "bad").exists()


def test_the_http_api_says_what_is_due_and_why_the_session_stopped(tmp_path):
    Session.new(tmp_path, _sequential(tickets=2, episodes_per_ticket=1, confirm=6))
    client = _client(tmp_path)
    due = client.get("/api/next").json()
    assert due["noise_shape"] == [8, 4] and client.get("/api/status").json()["stopping"] == "sequential"
    while not (due := client.get("/api/next").json()).get("done"):
        assert client.post("/api/score", json={"episode": due["episode"],
                                               "success": due["ticket_id"] != "base"}).status_code == 200
    status = client.get("/api/status").json()
    assert status["stage"] == "complete" and "decided early after" in status["verdict"]["stopping"]["why"]


_ROBOT = """
import sys, time
from goldenticket.session import Client

robot = Client(sys.argv[1], patience=30)
while (due := robot.next()) is not None:
    noise = due.noise_source()
    assert noise().shape == (8, 4)
    time.sleep(0.05)  # the episode runs
    robot.score(due.episode, due.ticket_id != "base" and due.episode % 4 != 1)
"""


def test_a_robot_client_resumes_after_the_robot_and_the_server_are_killed(tmp_path):
    """The robot process and then the server are killed with SIGKILL mid-way; the robot restarts
    and goes on with the due episode, riding out the server's restart; the session stops early."""
    Session.new(tmp_path / "s", _sequential())
    port = _free_port()
    server = _server(tmp_path / "s", port)
    (tmp_path / "robot.py").write_text(textwrap.dedent(_ROBOT))
    url = f"http://127.0.0.1:{port}"
    robot = subprocess.Popen([sys.executable, str(tmp_path / "robot.py"), url])

    def scored() -> int:
        return Client(url).status()["scored"]

    try:
        for kill_at, restart in ((8, "robot"), (16, "server")):
            while scored() < kill_at:
                time.sleep(0.02)
            if restart == "robot":
                os.kill(robot.pid, signal.SIGKILL)
                robot.wait()
                robot = subprocess.Popen([sys.executable, str(tmp_path / "robot.py"), url])
            else:
                os.kill(server.pid, signal.SIGKILL)
                server.wait()
                time.sleep(0.5)  # the robot's requests fail meanwhile; it retries
                server = _server(tmp_path / "s", port)
        assert robot.wait(timeout=120) == 0
        status = Client(url).status()
    finally:
        robot.kill()
        server.kill()
    assert status["due"] is None and status["verdict"]["stopping"]["reason"] == "decided early"
    scores = Session(tmp_path / "s").scores()
    done = [r for r in scores if r["success"] is not None]
    assert [r["episode"] for r in done] == list(range(len(done))) == sorted(r["entry"] - 1 for r in done)


def test_the_client_reports_refusals_and_a_missing_server_in_one_line(tmp_path):
    Session.new(tmp_path, _sequential())
    port = _free_port()
    server = _server(tmp_path, port)
    try:
        client = Client(f"http://127.0.0.1:{port}")
        with pytest.raises(ScoreConflict, match="not due") as conflict:
            client.score(3, True)
        assert conflict.value.details == {"due": 0}
        with pytest.raises(UserError, match="not in the plan"):
            client.score(10**6, True)
    finally:
        server.kill()
        server.wait()
    with pytest.raises(UserError, match="no session server answers"):
        Client(f"http://127.0.0.1:{port}", patience=0.5).next()


def test_the_terminal_says_why_a_sequential_session_stopped(tmp_path, capsys):
    from goldenticket.session.terminal import score_in_terminal

    session = Session.new(tmp_path, _sequential(tickets=2, episodes_per_ticket=1, confirm=6))
    answers = iter(["s", "f", *["s", "f"] * 6])
    arms = []

    def read(prompt):
        arms.append(prompt)
        return next(answers)

    assert score_in_terminal(session, read) == 0
    out = capsys.readouterr().out
    assert "Stopped: " in out and "pairs" in out and "/at most " in arms[0]
    assert "(confirm phase, pair 1 of at most 6, run 1 of 2: set up a new scene)" in arms[2]
