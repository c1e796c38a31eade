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
from goldenticket.config import DEFAULT_CONFIRM
from goldenticket.errors import OptionError, UserError
from goldenticket.session import Client, Plan, ScoreConflict, Session
from goldenticket.session import race as rules

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
    paths = list(itertools.product([True, False], repeat=cap))  # every discordant path
    golden = sum(stats.sequential_sign_test(signs, [not s for s in signs], cap, alpha).decision == "golden"
                 for signs in paths)
    assert golden / 2 ** cap == pytest.approx(stats.sequential_level(threshold, cap))
    assert golden / 2 ** cap < alpha
    below = max(v for row in stats._log_e_table(cap) for v in row if v < threshold)
    assert stats.sequential_level(below, cap) >= alpha  # the threshold is the smallest that keeps alpha
    loose = 0.2  # a threshold in reach long enough for the futility stop to act
    plain, stopped = ([stats.sequential_sign_test(p, [not s for s in p], cap, loose, futility) for p in paths]
                      for futility in (None, rules.FUTILITY))
    wins = [sum(t.decision == "golden" for t in tests) / 2 ** cap for tests in (stopped, plain)]
    assert wins[0] <= wins[1] < loose  # it only ever stops not golden
    q1, beta = rules.FUTILITY  # Ville: a ticket winning q1 of the discordant pairs is stopped futile
    chance = sum(q1 ** sum(p) * (1 - q1) ** (cap - sum(p))  # with chance at most beta
                 for p, t in zip(paths, stopped, strict=True) if t.reason == "futile")
    assert 0 < chance <= beta
    concordant = stats.sequential_sign_test([True] * cap, [True] * cap, cap, alpha)  # no discordant pair
    assert (concordant.decision, concordant.reason) == ("not golden", "out of reach")
    assert concordant.pairs < cap
    with pytest.raises(ValueError, match="exceed the cap"):
        stats.sequential_sign_test([True] * 5, [False] * 5, 4)


def test_the_futility_stop_ends_a_losing_ticket_early():
    q1, beta = rules.FUTILITY
    losses = next(n for n in range(1, 20) if n * np.log(2 - 2 * q1) <= np.log(beta))
    ticket, base = [False] * losses, [True] * losses
    test = stats.sequential_sign_test(ticket, base, 70, 0.05, rules.FUTILITY)
    assert (test.decision, test.reason, test.pairs) == ("not golden", "futile", losses)
    assert stats.sequential_sign_test(ticket[:-1], base[:-1], 70, 0.05, rules.FUTILITY).decision is None
    assert stats.sequential_sign_test(ticket, base, 70, 0.05).decision is None  # without it: not yet
    with pytest.raises(ValueError, match="futility"):
        stats.futile(1, 1, 0.4, beta)


def test_the_race_drops_candidates_that_trail_the_leader_and_stops_at_one_or_the_budget():
    names = list("abcdef")

    def race(plan, wins_by_round):
        """rules.race over rounds of {candidate: successes, None: not scored yet}."""
        search, each = [], plan.first_round
        for wins in wins_by_round:
            search += [(arm, won and i < won) for arm, won in wins.items() for i in range(each)]
            each = rules.ROUND
        return rules.race(plan, names, search)

    plan, first = Plan("p", "fp", (2, 2), 6, 25, 70, 0), rules.FIRST_ROUND
    assert plan.first_round == first and plan.episodes == 6 * 25 + 2 * 70 <= 6 * 25 + 3 * 50
    clear = race(plan, [dict(zip(names, [0, 0, first, 1, 0, 0], strict=True))])
    assert (clear.ends, clear.alive, clear.next_round) == ([6 * first], ["c"], 0)  # one left: over
    even = race(plan, [dict.fromkeys(names, first // 2)])
    assert (even.alive, even.next_round) == (names, rules.ROUND)  # nobody trails: all go on
    close = race(plan, [dict(zip(names, [first, first - 2, 2, 2, 2, 2], strict=True))])
    assert not rules.trails(first, first - 2, first) and rules.trails(first, 2, first)
    assert close.alive == ["a", "b"] and close.next_round == rules.ROUND
    tied = race(Plan("p", "fp", (2, 2), 6, 12, 70, 0), [{"a": first, "b": first} | dict.fromkeys("cdef", 0)]
                + [{"b": 2, "a": 2}] * 3)  # a and b tie: rounds of 2 x 2 until 6 x 12 is spent
    assert tied.ends == [6 * first + 4 * k for k in range(4)] and tied.ends[-1] + 4 > 6 * 12
    assert (tied.alive, tied.next_round) == (["a", "b"], 0)  # the finalist: the earlier of the tied
    assert race(plan, [dict.fromkeys(names, 1)] + [dict.fromkeys(names, None)]).next_round == 0  # scoring
    fixed = Plan("p", "fp", (2, 2), 6, 25, 50, 0, "fixed")
    fixed = race(fixed, [dict(zip(names, [3, 9, 9, 1, 2, 0], strict=True))])
    assert (fixed.ends, fixed.alive, fixed.next_round) == ([150], ["b", "c"], 0)


def test_weak_tickets_are_dropped_and_the_finalist_runs_in_blind_pairs(tmp_path):
    session = Session.new(tmp_path, _sequential(tickets=3, episodes_per_ticket=20))
    best, rival = session.scores()[0]["arm"], session.scores()[1]["arm"]
    runs: dict[str, int] = {}

    def success(due, status):  # the best always succeeds; the rival fails its every 5th; the rest mostly
        runs[due.ticket_id] = runs.get(due.ticket_id, 0) + 1
        n = runs[due.ticket_id]
        return {best: True, rival: n % 5 != 0, "base": n % 3 == 0}.get(due.ticket_id, n % 4 == 0)

    stages = _play(session, success)
    scores = session.scores()
    search = [r for r in scores if r["phase"] == "search"]
    ran = {arm: sum(r["arm"] == arm for r in search) for arm in {r["arm"] for r in search}}
    weak = (set(ran) - {best, rival}).pop()
    first, each = session.plan.first_round, rules.ROUND
    assert ran[weak] == first < ran[rival] <= ran[best] and (ran[best] - first) % each == 0
    assert len(search) < session.plan.tickets * session.plan.episodes_per_ticket  # the race ended early
    assert {"search phase, round 1, 3 tickets left", "search phase, round 2, 2 tickets left"} <= set(stages)
    confirm = [r for r in scores if r["phase"] == "confirm"]
    assert {r["arm"] for r in confirm} == {best, "base"}
    pairs = [tuple(r["arm"] for r in confirm[i:i + 2]) for i in range(0, len(confirm), 2)]
    assert all(set(p) == {best, "base"} for p in pairs) and len(set(pairs)) == 2  # both orders occur
    assert "confirm phase, pair 2 of at most 20, run 2 of 2: the same scene as run 1" in stages
    assert not any(best in s or "base" in s for s in stages)


def test_a_clearly_better_ticket_stops_the_session_early(tmp_path):
    session = Session.new(tmp_path, _sequential())
    _play(session, lambda due, status: due.ticket_id != "base")
    status = session.status()
    verdict, stopping = status["verdict"], status["verdict"].stopping
    finalist = next(a for a in verdict.arms if a != "base")
    assert verdict.arms[finalist].golden and verdict.arms[finalist].row.p_vs_base < 0.05
    threshold = stats.sequential_threshold(20, 0.05)
    needed = next(k for k in range(1, 21) if stats.mixture_log_e(k, 0) >= threshold)
    assert stopping.reason == "decided early" and stopping.test.pairs == needed < 20
    search = session.plan.tickets * session.plan.episodes_per_ticket  # no ticket trails: the whole budget
    assert stopping.test.ticket_only == needed and stopping.episodes == search + 2 * needed
    assert status["due"] is None and status["scored"] == stopping.episodes < status["total"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["verdict"] == verdict.to_dict() and summary["plan"]["stopping"] == "sequential"
    assert summary["verdict"]["stopping"]["test"].startswith("sequential sign test")
    assert set(summary["search_episodes"].values()) == {session.plan.episodes_per_ticket}
    assert summary["race"] == {"first_round": 4, "round": rules.ROUND, "drop_z": rules.DROP_Z}
    futility = summary["verdict"]["stopping"]["futility"]
    assert futility == dict(zip(("q1", "beta"), rules.FUTILITY, strict=True))
    with pytest.raises(ScoreConflict, match="the session is complete"):
        session.score(stopping.episodes, True)
    session.undo(status["last_scored"])  # the decision is undone with its last score
    assert session.status()["due"] == status["last_scored"] and not (tmp_path / "summary.json").exists()


def test_equal_arms_reach_the_cap_or_lose_hope_and_are_not_golden(tmp_path):
    coin = np.random.default_rng(7)
    session = Session.new(tmp_path, _sequential())
    _play(session, lambda due, status: bool(coin.random() < 0.5))
    verdict = session.verdict()
    (finalist,), stopping = set(verdict.arms) - {"base"}, verdict.stopping
    assert verdict.arms[finalist].decision == "not golden"
    assert stopping.test.e_value < stopping.test.threshold
    assert stopping.reason in ("decided early", "cap reached")


def test_scene_ids_on_both_runs_of_a_pair_make_the_test_paired(tmp_path):
    session, confirm = Session.new(tmp_path, _sequential()), None
    while (due := session.next()) is not None:
        if session.status()["phase"] == "confirm":
            confirm = due.episode if confirm is None else confirm
        scene = None if confirm is None else f"layout {(due.episode - confirm) // 2}"
        session.score(due.episode, due.ticket_id != "base", scene=scene)
    assert session.verdict().stopping.name == "sequential sign test, pairs matched by scene id"


def test_the_plan_is_a_function_of_the_seed_and_the_scores(tmp_path):
    outcomes = {}

    def success(due, status):
        return outcomes.setdefault(due.episode, (due.episode * 7) % 5 < 2)

    plan = _sequential(tickets=3, episodes_per_ticket=20)
    first, second = Session.new(tmp_path / "a", plan), Session.new(tmp_path / "b", plan)
    _play(first, success)
    assert sum(r["phase"] == "search" for r in first.scores()) > 3 * plan.first_round  # more than 1 round
    end_of_round = 3 * plan.first_round - 1
    for episode in range(end_of_round + 1):  # the second session: round 1, undo, rescore
        second.score(episode, outcomes[episode])
    planned = second.status()["planned"]
    second.undo(end_of_round)  # drops round 2, planned from the score undone
    assert second.status()["planned"] == end_of_round + 1 < planned
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
        with pytest.raises(OptionError, match="^(alpha|stopping|under sequential stopping confirm) "):
            _sequential(**bad)


def test_session_new_takes_the_stopping_rule_and_alpha(tmp_path, capsys):
    from goldenticket.cli import main

    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "seq")]) == 0
    plan = Session(tmp_path / "seq").plan
    assert (plan.stopping, plan.alpha, plan.confirm, plan.episodes) == ("sequential", 0.05, 70, 290)
    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "fixed"),
                 "--stopping", "fixed", "--alpha", "0.1"]) == 0
    plan = Session(tmp_path / "fixed").plan
    assert (plan.stopping, plan.alpha, plan.confirm, plan.episodes) == ("fixed", 0.1, 50, 300)
    assert "at most 290 episodes in all (sequential stopping)" in capsys.readouterr().out
    for flags in (["--alpha", "0"], ["--confirm", "3"]):
        assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "bad"), *flags]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 2 and all(line.startswith("goldenticket: error: ") for line in errors)
    assert "--alpha" in errors[0] and "--confirm" in errors[1] and not (tmp_path / "bad").exists()
    with pytest.raises(SystemExit):
        main(["session", "new", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # every placeholder filled, the plan's defaults
    assert "%(" not in text and "%%" not in text and text.count("{") == text.count("{sequential,fixed}")
    assert f"(default {DEFAULT_CONFIRM['sequential']}, so never more episodes than fixed)" in text


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


@pytest.mark.slow
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
