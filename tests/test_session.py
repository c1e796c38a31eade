"""Real-robot sessions: the protocol, its HTTP API, and a whole session with Meta-World as the robot."""

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

from goldenticket.errors import UserError
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import Engine, Episode, rollout
from goldenticket.session import Plan, ScoreConflict, Session
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket

POLICY, TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"


def _plan(**kw) -> Plan:
    fields = dict(policy="p", policy_fingerprint="fp", noise_shape=(8, 4), tickets=3,
                  episodes_per_ticket=2, confirm=3, seed=0) | kw
    return Plan(**fields)


def test_protocol_scores_once_undoes_and_resumes(tmp_path):
    session = Session.new(tmp_path, _plan())
    assert session.status() == {"scored": 0, "total": 15, "planned": 6, "phase": "search"}
    first = session.next()
    session.score(first.episode, True, "clean grasp")
    with pytest.raises(ScoreConflict, match="scored already"):
        session.score(first.episode, False)
    with pytest.raises(ScoreConflict, match="not in the plan"):
        session.score(99, False)
    assert session.undo() == first.episode and session.next().episode == first.episode
    session.score(first.episode, True)
    assert Session(tmp_path).next().episode == first.episode + 1  # a new process resumes
    with pytest.raises(UserError, match="already planned"):
        Session.new(tmp_path, _plan())
    arms = []
    while (due := session.next()) is not None:
        arms.append(due.ticket_id)
        session.score(due.episode, due.ticket_id != "base" or due.episode % 2 == 0)
    confirm = arms[5:]
    assert len(confirm) == 9 and confirm.count("base") == 3 and len(set(confirm)) == 3
    verdict = session.status()["verdict"]
    assert set(verdict["arms"]) == set(confirm)
    assert all(r.get("test", "").startswith("Fisher") for a, r in verdict["arms"].items() if a != "base")
    saved = {p.stem for p in (tmp_path / "tickets").glob("*.safetensors")}
    assert saved == set(verdict["arms"]) - {"base"}
    assert Ticket.load(tmp_path / "tickets" / f"{saved.pop()}.safetensors").id in verdict["arms"]


def test_base_arm_noise_is_fresh_per_call_from_the_given_seed(tmp_path):
    session = Session.new(tmp_path, _plan(tickets=2, episodes_per_ticket=1, confirm=1, seed=4))
    while (due := session.next()) is not None and due.ticket_id != "base":
        assert due.noise.shape == (8, 4) and due.gaussian_seed is None
        session.score(due.episode, True)
    assert due.noise is None and due.gaussian_seed == [4, due.episode]


def test_scene_ids_pair_the_confirm_episodes(tmp_path):
    session = Session.new(tmp_path, _plan(confirm=4))
    scenes: dict[str, int] = {}
    while (due := session.next()) is not None:
        scene = None
        if session.status()["phase"] == "confirm":
            scenes[due.ticket_id] = scenes.get(due.ticket_id, 0) + 1
            scene = f"layout-{scenes[due.ticket_id]}"
        session.score(due.episode, due.ticket_id != "base", scene=scene)
    tests = {r["test"] for a, r in session.verdict()["arms"].items() if a != "base"}
    assert tests == {"paired exact McNemar (sign) test on scene ids"}


def test_http_api_answers_and_refuses_clearly(tmp_path):
    from starlette.testclient import TestClient

    from goldenticket.session.server import make_app

    Session.new(tmp_path, _plan())
    client = TestClient(make_app(tmp_path))
    due = client.get("/api/next").json()
    assert len(due["noise"]) == 8 and due["gaussian_seed"] is None
    assert client.post("/api/score", json={"episode": due["episode"], "success": True}).status_code == 200
    assert client.post("/api/score", json={"episode": due["episode"], "success": True}).status_code == 409
    for body, message in (({"episode": 1}, "'success'"), ({"episode": "1", "success": True}, "'episode'"),
                          ([1], "JSON object"), ({"episode": 1, "success": True, "note": 3}, "'note'")):
        response = client.post("/api/score", json=body)
        assert response.status_code == 400 and message in response.json()["error"]
    assert client.post("/api/score", content=b"{not json").status_code == 400
    status = client.get("/api/status").json()
    assert status["scored"] == 1 and status["due"] == due["episode"] + 1 and "ticket_id" not in status
    assert "Score the episode" in client.get("/").text
    gated = TestClient(make_app(tmp_path, token="s3cret"))
    assert gated.get("/api/status").status_code == 401
    assert gated.get("/api/status?token=s3cret").status_code == 200
    assert gated.get("/api/status", headers={"Authorization": "Bearer s3cret"}).status_code == 200


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _server(folder, port) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "goldenticket.cli", "session", "serve", str(folder),
                             "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    for _ in range(200):
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status", timeout=1)
            return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"server did not start: {proc.stdout.read().decode()}")


def _call(port, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}", data=data,
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.loads(response.read())


def _source(due: dict, seed: int):
    return Gaussian(seed) if due["noise"] is None else Constant(np.asarray(due["noise"], dtype=np.float32))


def test_a_simulated_robot_and_operator_reach_the_automatic_verdict(tmp_path):
    """Meta-World is the robot: it polls the HTTP API, runs each episode (env seed = episode
    number) and posts the true outcome; the server is killed with SIGKILL mid-way and restarted."""
    from goldenticket.policies import load_policy

    policy, task = load_policy(POLICY), get_task(TASK, max_steps=60)
    plan = _plan(policy=POLICY, noise_shape=policy.noise_shape, tickets=3, episodes_per_ticket=4,
                 confirm=6, seed=3)
    Session.new(tmp_path / "http", plan)
    port = _free_port()
    server = _server(tmp_path / "http", port)
    try:
        for step in range(100):
            if step == 7:  # kill -9 mid-way: nothing scored may be lost
                os.kill(server.pid, signal.SIGKILL)
                server.wait()
                server = _server(tmp_path / "http", port)
                assert _call(port, "/api/status")["scored"] == 7
            due = _call(port, "/api/next")
            if due.get("done"):
                break
            result = rollout(policy, task, [Episode(_source(due, plan.seed), due["episode"])])[0]
            _call(port, "/api/score", {"episode": due["episode"], "success": result.success})
        http_verdict = _call(port, "/api/status")["verdict"]
    finally:
        server.kill()
    automatic = Session.new(tmp_path / "automatic", plan)
    with Engine(POLICY, task) as engine:
        for _ in range(2):  # search phase, then confirm phase: all episodes of a phase batched
            planned = [r for r in automatic.scores() if r["success"] is None]
            dues = [automatic.episode(r["episode"]).to_json() for r in planned]
            results = engine.evaluate([Episode(_source(d, plan.seed), d["episode"]) for d in dues])
            for r, res in zip(planned, results, strict=True):
                automatic.score(r["episode"], res.success)
    assert automatic.verdict() == http_verdict
    assert 0 < sum(r["success"] for r in automatic.scores()) < len(automatic.scores())



def test_the_terminal_scorer_scores_undoes_and_stops(tmp_path, capsys):
    from goldenticket.session.terminal import score_in_terminal

    session = Session.new(tmp_path, _plan(tickets=2, episodes_per_ticket=1, confirm=1))
    answers = iter(["s", "f slipped", "u", "?", "f slipped again", "q"])
    assert score_in_terminal(session, lambda prompt: next(answers)) == 0
    assert [(r["success"], r["note"]) for r in session.scores()[:2]] == [(1, ""), (0, "slipped again")]
    answers = iter(["s"] * 3)
    score_in_terminal(Session(tmp_path), lambda prompt: next(answers))
    out = capsys.readouterr().out
    assert "score of episode 1 removed" in out and "Fisher's exact test" in out and "base" in out


def test_session_commands_refuse_bad_input_in_one_line(tmp_path, capsys):
    from goldenticket.cli import main

    out = tmp_path / "s"
    assert main(["session", "new", "--policy", POLICY, "--out", str(out), "--tickets", "1"]) == 2
    assert main(["session", "new", "--policy", POLICY, "--out", str(out), "--tickets", "2",
                 "--episodes-per-ticket", "1", "--confirm", "1"]) == 0
    assert main(["session", "new", "--policy", POLICY, "--out", str(out)]) == 2
    assert main(["session", "serve", str(out), "--host", "0.0.0.0"]) == 2
    assert main(["session", "score", str(tmp_path / "nothing")]) == 2
    assert main(["session", "serve", str(out), "--port", "70000"]) == 2
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        assert main(["session", "serve", str(out), "--port", str(taken.getsockname()[1])]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 6 and all(line.startswith("goldenticket: error: ") for line in errors)
    assert "--token" in errors[2] and "no session here" in errors[3]
    assert "1..65535" in errors[4] and "cannot listen" in errors[5]


def test_readme_robot_loop_runs_as_written(tmp_path):
    """README's robot loop against a live server; here the 'robot' is Meta-World and it also
    plays the operator, posting each true outcome."""
    from pathlib import Path

    readme = (Path(__file__).parent.parent / "README.md").read_text()
    loop = re.findall(r"```python\n(.*?)```", readme.split("## Searching on a real robot")[1], re.S)[0]
    plan = _plan(policy=POLICY, tickets=2, episodes_per_ticket=2, confirm=2, seed=9)
    Session.new(tmp_path, plan)
    port = _free_port()
    server = _server(tmp_path, port)
    prelude = f"""
from goldenticket.policies import load_policy
from goldenticket.tasks import get_task
policy, env = load_policy({POLICY!r}), get_task({TASK!r}, max_steps=60).make_env()
shape = policy.noise_shape
def run_episode_on_the_robot(noise):
    obs, success, done, steps = env.reset(due["episode"]), False, False, 0
    while not (success or done or steps >= 60):
        for action in policy.act(obs[None], noise()[None])[0]:
            obs, success, done = env.step(action)
            steps += 1
            if success or done or steps >= 60:
                break
    call("/score", {{"episode": due["episode"], "success": bool(success)}})
"""
    try:
        (tmp_path / "robot.py").write_text(loop.replace("8765", str(port)).replace(
            "\n\ndef call", prelude + "\n\ndef call", 1))
        proc = subprocess.run([sys.executable, "robot.py"], cwd=tmp_path, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr
    finally:
        server.kill()
    status = Session(tmp_path).status()
    assert status["scored"] == status["total"] == 10 and "verdict" in status


def test_a_damaged_session_file_is_one_clear_error(tmp_path):
    import sqlite3

    (tmp_path / "session.sqlite").write_bytes(b"not a database at all" * 100)
    with pytest.raises(UserError, match="cannot open the session"):
        Session(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    sqlite3.connect(other / "session.sqlite").execute("CREATE TABLE t (x)").connection.commit()
    with pytest.raises(UserError, match="not a goldenticket session"):
        Session(other)
