"""Real-robot sessions: the protocol, its HTTP API, and a whole session with Meta-World as the robot."""

import itertools
import json
import os
import re
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np
import pytest

from goldenticket.errors import UserError
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import Engine, Episode, rollout
from goldenticket.session import Plan, ScoreConflict, Session, store
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket

POLICY, TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"


def _plan(**kw) -> Plan:
    fields = dict(policy="p", policy_fingerprint="fp", noise_shape=(8, 4), tickets=3,
                  episodes_per_ticket=2, confirm=3, seed=0, stopping="fixed") | kw
    return Plan(**fields)


def _client(folder, **kw):
    """A test client of the app, calling it as a page served from 127.0.0.1:8765 would."""
    from starlette.testclient import TestClient

    from goldenticket.session.server import make_app

    return TestClient(make_app(folder, **kw), base_url="http://127.0.0.1:8765")


def test_protocol_scores_once_undoes_and_resumes(tmp_path):
    session = Session.new(tmp_path, _plan())
    assert session.status() == {"scored": 0, "total": 15, "planned": 6, "phase": "search", "due": 0,
                                "last_scored": None, "stopping": "fixed", "stage": "search phase"}
    first = session.next()
    session.score(first.episode, True, "clean grasp")
    with pytest.raises(ScoreConflict, match="scored already"):
        session.score(first.episode, False)
    with pytest.raises(UserError, match="not in the plan"):
        session.score(99, False)
    session.undo(first.episode)
    assert session.next().episode == first.episode
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
    assert set(verdict.arms) == set(confirm)
    assert all(v.test.startswith("Fisher") for a, v in verdict.arms.items() if a != "base")
    saved = {p.stem for p in (tmp_path / "tickets").glob("*.safetensors")}
    assert saved == set(verdict.arms) - {"base"}
    assert Ticket.load(tmp_path / "tickets" / f"{saved.pop()}.safetensors").id in verdict.arms


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
    tests = {v.test for a, v in session.verdict().arms.items() if a != "base"}
    assert tests == {"paired exact McNemar (sign) test on scene ids"}


def test_http_api_answers_and_refuses_clearly(tmp_path):
    Session.new(tmp_path, _plan())
    client = _client(tmp_path)
    due = client.get("/api/next").json()
    assert len(due["noise"]) == 8 and due["gaussian_seed"] is None
    assert client.post("/api/score", json={"episode": due["episode"], "success": True}).status_code == 200
    assert client.post("/api/score", json={"episode": due["episode"], "success": True}).status_code == 409
    for body, message in (({"episode": 1}, "'success'"), ({"episode": "1", "success": True}, "'episode'"),
                          ([1], "JSON object"), ({"episode": 1, "success": True, "note": 3}, "'note'")):
        response = client.post("/api/score", json=body)
        assert response.status_code == 400 and message in response.json()["error"]
    assert client.post("/api/score", content=b"{not json",
                       headers={"Content-Type": "application/json"}).status_code == 400
    status = client.get("/api/status").json()
    assert status["scored"] == 1 and status["due"] == due["episode"] + 1 and "ticket_id" not in status
    assert "Score the episode" in client.get("/").text
    gated = _client(tmp_path, token="s3cret")
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


@pytest.mark.slow
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
    assert automatic.verdict().to_dict() == http_verdict
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
    assert "p vs zero" not in out and (tmp_path / "summary.json").is_file()


def test_session_commands_refuse_bad_input_in_one_line(tmp_path, capsys):
    from goldenticket.cli import main

    out = tmp_path / "s"
    assert main(["session", "new", "--policy", POLICY, "--out", str(out), "--tickets", "1"]) == 2
    assert main(["session", "new", "--policy", POLICY, "--out", str(out), "--tickets", "2",
                 "--episodes-per-ticket", "1", "--confirm", "1", "--stopping", "fixed"]) == 0
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


@pytest.mark.slow
def test_docs_robot_loop_runs_as_written(tmp_path):
    """The docs' robot loop against a live server, for a policy that takes `noise=`; here the
    'robot' is Meta-World and it also plays the operator, posting each true outcome."""
    from pathlib import Path

    page = (Path(__file__).parent.parent / "docs" / "how-to" / "real-robot.md").read_text()
    loop = re.findall(r"```python\n(.*?)```", page.split("## The robot's side")[1], re.S)[0]
    plan = _plan(policy=POLICY, tickets=2, episodes_per_ticket=2, confirm=2, seed=9)
    Session.new(tmp_path, plan)
    port = _free_port()
    server = _server(tmp_path, port)
    prelude = f"""
from goldenticket.policies import load_policy
from goldenticket.tasks import get_task
bundled, env = load_policy({POLICY!r}), get_task({TASK!r}, max_steps=60).make_env()
def policy(obs, noise):
    return bundled.act(obs[None], noise[None])[0]
def run_episode_on_the_robot(act):
    obs, success, done, steps = env.reset(due.episode), False, False, 0
    while not (success or done or steps >= 60):
        for action in act(obs):
            obs, success, done = env.step(action)
            steps += 1
            if success or done or steps >= 60:
                break
    robot.score(due.episode, bool(success))
"""
    try:
        head = "from goldenticket.session import Client\n"
        (tmp_path / "robot.py").write_text(loop.replace("8765", str(port)).replace(head, head + prelude, 1))
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


def test_other_sites_can_neither_score_nor_undo_nor_read_the_arm(tmp_path):
    Session.new(tmp_path, _plan())
    client = _client(tmp_path)
    assert client.post("/api/score", json={"episode": 0, "success": True}).status_code == 200
    evil, text = {"Origin": "http://evil.example"}, {"Content-Type": "text/plain"}
    score = json.dumps({"episode": 1, "success": True})
    attacks = [client.post("/api/score", content=score, headers=evil | text),  # a cross-site fetch
               client.post("/api/score", json={"episode": 1, "success": True}, headers=evil),
               client.post("/api/undo", data={"episode": "0"}, headers=evil),  # a cross-site form
               client.post("/api/score", content=score, headers=text),  # no Origin, not JSON
               client.post("/api/undo", data={"episode": "0"}),
               client.get("/api/next", headers={"Host": "evil.example:8765"})]  # DNS rebinding
    assert [r.status_code for r in attacks] == [403, 403, 403, 415, 415, 403]
    assert all(r.json()["error"] for r in attacks)
    assert client.get("/api/status").json()["scored"] == 1
    same_site = client.post("/api/score", content=score, headers={"Origin": "http://127.0.0.1:8765",
                                                                   "Content-Type": "application/json"})
    assert same_site.status_code == 200 and client.get("/api/status").json()["scored"] == 2
    big = client.post("/api/score", content=b" " * (64 * 1024 + 1),
                      headers={"Content-Type": "application/json"})
    assert big.status_code == 413 and "64 KiB" in big.json()["error"]
    for response in (client.get("/"), client.get("/api/status"), attacks[0]):
        assert response.headers["x-frame-options"] == "DENY"
        assert "frame-ancestors 'none'" in response.headers["content-security-policy"]
        assert response.headers["x-content-type-options"] == "nosniff"


def test_only_the_due_episode_is_scored(tmp_path):
    session = Session.new(tmp_path, _plan())
    with pytest.raises(ScoreConflict, match="not due") as refused:
        session.score(1, True)
    assert refused.value.details == {"due": 0}
    response = _client(tmp_path).post("/api/score", json={"episode": 2, "success": True})
    assert response.status_code == 409 and response.json()["due"] == 0
    assert session.status()["scored"] == 0 and session.next().episode == 0


def test_undo_names_its_episode_and_follows_the_order_of_entry(tmp_path, monkeypatch):
    session = Session.new(tmp_path, _plan())
    clock = iter([100.0, 50.0, 75.0])  # the wall clock steps back between scores
    monkeypatch.setattr(store, "time", SimpleNamespace(time=lambda: next(clock)))
    for episode in range(3):
        session.score(episode, True)
    with pytest.raises(ScoreConflict, match="not the last") as stale:
        session.undo(1)
    assert stale.value.details == {"last_scored": 2}
    stale_http = _client(tmp_path).post("/api/undo", json={"episode": 0})
    assert stale_http.status_code == 409 and stale_http.json()["last_scored"] == 2
    session.undo(2)
    assert _client(tmp_path).post("/api/undo", json={"episode": 1}).json()["undone"] == 1
    assert [r["success"] for r in session.scores()[:3]] == [1, None, None]
    assert session.status()["last_scored"] == 0


def test_concurrent_undos_of_one_episode_remove_one_score(tmp_path):
    session = Session.new(tmp_path, _plan())
    for episode in range(4):
        session.score(episode, True)
    start = threading.Barrier(20)

    def undo(_) -> bool:
        mine = Session(tmp_path)  # its own connection, as another process would have
        start.wait()
        try:
            mine.undo(3)
            return True
        except ScoreConflict:
            return False

    with ThreadPoolExecutor(20) as pool:
        assert sum(pool.map(undo, range(20))) == 1
    assert session.status()["scored"] == 3


def test_finalist_tickets_survive_a_failure_after_the_confirm_plan(tmp_path):
    session = Session.new(tmp_path, _plan())
    tickets = tmp_path / "tickets"
    candidates = {r["arm"] for r in session.scores()}
    for arm in candidates:  # something in the way of every ticket file
        (tickets / f"{arm}.safetensors").mkdir(parents=True)
    for episode in range(6):
        session.score(episode, episode % 2 == 0)
    with pytest.raises((OSError, UserError)):
        session.next()  # plans the confirm phase, then cannot write the finalists
    for arm in candidates:
        (tickets / f"{arm}.safetensors").rmdir()
    finalists = {r["arm"] for r in Session(tmp_path).scores() if r["phase"] == "confirm"} - {"base"}
    assert len(finalists) == 2 and {p.stem for p in tickets.iterdir()} == finalists
    shutil.rmtree(tickets)  # as if killed between the plan's commit and the files
    Session(tmp_path)
    assert {Ticket.load(p).id for p in tickets.iterdir()} == finalists


def test_a_deleted_session_file_refuses_scores(tmp_path):
    Session.new(tmp_path, _plan())
    client = _client(tmp_path)
    assert client.post("/api/score", json={"episode": 0, "success": True}).status_code == 200
    (tmp_path / "session.sqlite").unlink()
    response = client.post("/api/score", json={"episode": 1, "success": True})
    assert response.status_code == 503 and "deleted" in response.json()["error"]


def test_absurd_requests_and_a_full_disk_get_a_json_error(tmp_path):
    Session.new(tmp_path, _plan())
    client = _client(tmp_path)
    huge = client.post("/api/score", json={"episode": 10**23, "success": True})
    assert huge.status_code == 400 and "not in the plan" in huge.json()["error"]
    nested = client.post("/api/score", content=b"[" * 30000 + b"]" * 30000,
                         headers={"Content-Type": "application/json"})
    assert nested.status_code == 400 and "JSON" in nested.json()["error"]
    con = client.app.state.session._store.con  # the store may grow no more: a full disk, for SQLite
    con.execute(f"PRAGMA max_page_count = {con.execute('PRAGMA page_count').fetchone()[0]}")
    full = client.post("/api/score", json={"episode": 0, "success": True, "note": "x" * 60000})
    assert full.status_code == 503 and "full" in full.json()["error"]
    assert client.get("/api/status").json()["scored"] == 0


def test_session_new_bounds_its_plan_in_one_line(tmp_path, capsys):
    from goldenticket.cli import main

    for flag, value in (("--confirm", "300000000"), ("--tickets", "1000000000"),
                        ("--episodes-per-ticket", "1000000000")):
        assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / flag), flag, value]) == 2
        assert not (tmp_path / flag).exists()
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 3 and all("at most 100000 episodes" in line for line in errors)
    with pytest.raises(UserError, match="at most 100000 episodes"):
        _plan(tickets=10**9)


def test_session_new_names_its_own_flags_in_its_errors(tmp_path, capsys):
    from goldenticket.cli import main

    for count in ("1", "100000"):
        assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path), "--tickets", count]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert "--tickets must be at least 2" in errors[0] and "(--tickets x --episodes-per-ticket" in errors[1]
    assert not any("--ticket " in line for line in errors)


def test_a_finished_session_writes_its_verdict_beside_its_store(tmp_path):
    session = Session.new(tmp_path / "cup", _plan())
    while (due := session.next()) is not None:
        session.score(due.episode, due.ticket_id != "base")
    summary = json.loads((tmp_path / "cup" / "summary.json").read_text())
    assert summary["verdict"] == session.verdict().to_dict() and summary["session"] == "cup"
    assert set(summary["tickets"]) == set(session.verdict().arms) - {"base"}
    assert (tmp_path / "cup" / "verdict.png").read_bytes().startswith(b"\x89PNG")
    status = _client(tmp_path / "cup").get("/api/status").json()
    assert status["session"] == "cup" and status["policy"] == "p"
    session.undo(status["last_scored"])
    assert session.status()["due"] is not None
    assert not any((tmp_path / "cup" / name).exists() for name in ("summary.json", "verdict.png"))


def test_the_verdict_plot_shows_every_marker_and_label_whole(tmp_path, monkeypatch):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from goldenticket import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    session = Session.new(tmp_path, _plan())
    while (due := session.next()) is not None:  # the extremes: base 100%, finalists 0%
        session.score(due.episode, due.ticket_id == "base")
    fig = figures[-1]
    fig.tight_layout()
    renderer = FigureCanvasAgg(fig).get_renderer()
    ax = fig.axes[0]
    inside = ax.get_window_extent(renderer)
    for text in ax.texts:
        box = text.get_window_extent(renderer)
        assert inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1), text.get_text()
    for line in ax.lines:
        if line.get_marker() not in ("None", None, ""):
            whole = inside.padded(-line.get_markersize() * fig.dpi / 72 / 2)  # the marker's radius
            assert all(whole.contains(x, y) for x, y in ax.transData.transform(line.get_xydata()))


def test_a_plan_that_is_not_json_is_one_clear_error(tmp_path, capsys):
    import sqlite3

    from goldenticket.cli import main

    Session.new(tmp_path, _plan())
    con = sqlite3.connect(tmp_path / "session.sqlite")
    con.execute("UPDATE plan SET value = '{\"policy\": '")
    con.commit()
    with pytest.raises(UserError, match="not a goldenticket session, or damaged"):
        Session(tmp_path)
    assert main(["session", "score", str(tmp_path)]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 1 and "damaged" in errors[0]


@pytest.mark.slow
def test_input_that_is_not_utf8_stops_the_terminal_scorer_in_one_line(tmp_path):
    Session.new(tmp_path, _plan())
    proc = subprocess.run([sys.executable, "-m", "goldenticket.cli", "session", "score", str(tmp_path)],
                          input=b"s\nf \xff\xfe\n", capture_output=True, timeout=120)
    errors = proc.stderr.decode().splitlines()
    assert proc.returncode == 2 and len(errors) == 1 and "not UTF-8" in errors[0]
    assert [r["success"] for r in Session(tmp_path).scores()[:2]] == [1, None]  # the score before it is saved


def test_a_session_stored_before_entry_numbers_opens_and_undoes_its_last_score(tmp_path):
    session = Session.new(tmp_path, _plan())
    for _ in range(3):
        session.score(session.next().episode, True)
    last = session.status()["last_scored"]
    with sqlite3.connect(tmp_path / "session.sqlite") as con:  # the table as sessions stored it before
        con.executescript("""
            CREATE TABLE old AS SELECT episode, phase, arm, success, note, scene, scored_at FROM episodes;
            DROP TABLE episodes; ALTER TABLE old RENAME TO episodes;""")
    reopened = Session(tmp_path)
    assert reopened.status()["scored"] == 3 and reopened.status()["last_scored"] == last
    reopened.undo(last)
    assert reopened.next().episode == last


def _scene_by_arm(due, runs: dict[str, int]) -> str:
    """A scene id that pairs each arm's k-th confirm episode with the other arms' k-th."""
    runs[due.ticket_id] = runs.get(due.ticket_id, 0) + 1
    return f"layout {runs[due.ticket_id]}"


def _scene_by_pair(due, runs: dict[str, int]) -> str:
    return f"layout {due.episode // 2}"


def _mostly_tickets(due) -> bool:
    return due.ticket_id != "base" or due.episode % 3 == 0


def _mostly_base(due) -> bool:
    return due.ticket_id == "base" or due.episode % 4 == 0


_FIXED_PAIRED = {"session": "cup",
                 "plan": {"policy": "p", "policy_fingerprint": "fp", "noise_shape": [8, 4], "tickets": 3,
                          "episodes_per_ticket": 2, "confirm": 5, "seed": 5, "stopping": "fixed",
                          "alpha": 0.05},
                 "search_successes": {"c30a7c35a742": 2, "6f4d83c10292": 2, "e8177d15f3e8": 2},
                 "search_episodes": {"c30a7c35a742": 2, "6f4d83c10292": 2, "e8177d15f3e8": 2},
                 "tickets": {"6f4d83c10292": "tickets/6f4d83c10292.safetensors",
                             "c30a7c35a742": "tickets/c30a7c35a742.safetensors"},
                 "verdict": {"arms": {"base": {"success_rate": 0.4, "ci_low": 0.11762077423264794,
                                               "ci_high": 0.769275718723987, "n": 5},
                                      "6f4d83c10292": {"success_rate": 1.0, "ci_low": 0.5655175352168251,
                                                       "ci_high": 1.0, "n": 5, "p_vs_base": 0.25,
                                                       "test": ("paired exact McNemar (sign) test on scene "
                                                                "ids"),
                                                       "golden": False, "verdict": "not golden"},
                                      "c30a7c35a742": {"success_rate": 1.0, "ci_low": 0.5655175352168251,
                                                       "ci_high": 1.0, "n": 5, "p_vs_base": 0.25,
                                                       "test": ("paired exact McNemar (sign) test on scene "
                                                                "ids"),
                                                       "golden": False, "verdict": "not golden"}},
                             "stopping": {"rule": "fixed", "alpha": 0.05, "episodes": 21,
                                          "reason": "every planned episode scored",
                                          "why": "the fixed protocol: all 21 planned episodes scored"},
                             "note": ("p-values: paired exact McNemar (sign) test on scene ids; one-sided, "
                                      "finalist better than base, Holm-adjusted over the 2 finalists; "
                                      "'golden' means p < 0.05")}}
_SEQUENTIAL_PAIRED = {"session": "cup",
                      "plan": {"policy": "p", "policy_fingerprint": "fp", "noise_shape": [8, 4],
                               "tickets": 3, "episodes_per_ticket": 4, "confirm": 8, "seed": 2,
                               "stopping": "sequential", "alpha": 0.05},
                      "race": {"first_round": 4, "round": 2, "drop_z": 1.5},
                      "search_successes": {"359ade34fdeb": 4, "4f5e361bc84f": 4, "32bb36b10584": 4},
                      "search_episodes": {"359ade34fdeb": 4, "4f5e361bc84f": 4, "32bb36b10584": 4},
                      "tickets": {"359ade34fdeb": "tickets/359ade34fdeb.safetensors"},
                      "verdict": {"arms": {"base": {"success_rate": 0.375, "ci_low": 0.13684428582359737,
                                                    "ci_high": 0.6942576053973728, "n": 8},
                                           "359ade34fdeb": {"success_rate": 1.0,
                                                            "ci_low": 0.6755924351161198, "ci_high": 1.0,
                                                            "n": 8, "p_vs_base": 0.03125,
                                                            "test": ("sequential sign test, pairs matched "
                                                                     "by scene id"),
                                                            "golden": True, "verdict": "golden"}},
                                  "stopping": {"rule": "sequential",
                                               "test": "sequential sign test, pairs matched by scene id",
                                               "alpha": 0.05, "cap": 8, "threshold": 10.499999999999995,
                                               "e_value": 10.499999999999995,
                                               "futility": {"q1": 0.7, "beta": 0.2}, "pairs": 8,
                                               "ticket_only": 5, "base_only": 0, "episodes": 28,
                                               "stopped_at": 1027.0, "reason": "cap reached",
                                               "why": ("cap reached after 8 of at most 8 pairs (28 episodes "
                                                       "in all): the e-value reached 10.5 (threshold 10.5); "
                                                       "golden")},
                                  "note": ("p-value: the sequential sign test, one-sided, ticket better "
                                           "than base, tested after every pair of the confirm phase; "
                                           "'golden' means its mixture e-value reached 10.5, which under no "
                                           "difference happens within 8 pairs with chance below 0.05 (p < "
                                           "0.05); not golden early once out of reach, or futile (which "
                                           "stops a ticket that wins 70% of the discordant pairs with "
                                           "chance at most 0.2)")}}
_SEQUENTIAL_FUTILE = {"session": "cup",
                      "plan": {"policy": "p", "policy_fingerprint": "fp", "noise_shape": [8, 4],
                               "tickets": 4, "episodes_per_ticket": 12, "confirm": 20, "seed": 1,
                               "stopping": "sequential", "alpha": 0.05},
                      "race": {"first_round": 10, "round": 2, "drop_z": 1.5},
                      "search_successes": {"e33f2ca0c068": 4, "7ba9b1b8e4ff": 1, "6fc347d8eecb": 5,
                                           "1757947ac165": 2},
                      "search_episodes": {"e33f2ca0c068": 12, "7ba9b1b8e4ff": 10, "6fc347d8eecb": 12,
                                          "1757947ac165": 12},
                      "tickets": {"6fc347d8eecb": "tickets/6fc347d8eecb.safetensors"},
                      "verdict": {"arms": {"base": {"success_rate": 1.0, "ci_low": 0.6096657120978346,
                                                    "ci_high": 1.0, "n": 6},
                                           "6fc347d8eecb": {"success_rate": 0.3333333333333333,
                                                            "ci_low": 0.09677141110578047,
                                                            "ci_high": 0.700006684861608, "n": 6,
                                                            "p_vs_base": 1.0,
                                                            "test": ("sequential sign test, unpaired "
                                                                     "episodes"),
                                                            "golden": False, "verdict": "not golden"}},
                                  "stopping": {"rule": "sequential",
                                               "test": "sequential sign test, unpaired episodes",
                                               "alpha": 0.05, "cap": 20, "threshold": 11.255555555555565,
                                               "e_value": 1.0, "futility": {"q1": 0.7, "beta": 0.2},
                                               "pairs": 6, "ticket_only": 0, "base_only": 4, "episodes": 58,
                                               "stopped_at": 1057.0, "reason": "decided early",
                                               "why": ("decided early after 6 of at most 20 pairs (58 "
                                                       "episodes in all): the base won 4 of 4 discordant "
                                                       "pairs: no difference is 5 or more times likelier "
                                                       "than a ticket winning 70% of them; not golden")},
                                  "note": ("p-value: the sequential sign test, one-sided, ticket better "
                                           "than base, tested after every pair of the confirm phase; "
                                           "'golden' means its mixture e-value reached 11.3, which under no "
                                           "difference happens within 20 pairs with chance below 0.05 (p < "
                                           "0.05); not golden early once out of reach, or futile (which "
                                           "stops a ticket that wins 70% of the discordant pairs with "
                                           "chance at most 0.2)")}}
_WRITTEN = {  # a plan, its confirm episodes' scene ids and every outcome, and the summary.json they give
    "fixed, paired": (dict(confirm=5, seed=5), _scene_by_arm, _mostly_tickets, _FIXED_PAIRED),
    "sequential, paired, cap reached": (dict(stopping="sequential", episodes_per_ticket=4, confirm=8, seed=2),
                                        _scene_by_pair, _mostly_tickets, _SEQUENTIAL_PAIRED),
    "sequential, unpaired, futile": (dict(stopping="sequential", tickets=4, episodes_per_ticket=12,
                                          confirm=20, seed=1), None, _mostly_base, _SEQUENTIAL_FUTILE)}


@pytest.mark.parametrize("case", list(_WRITTEN))
def test_the_verdict_files_and_answers_are_the_json_written_before(tmp_path, monkeypatch, case):
    fields, scene, success, written = _WRITTEN[case]
    clock, runs = itertools.count(1000), {}
    monkeypatch.setattr(store, "time", SimpleNamespace(time=lambda: float(next(clock))))
    session = Session.new(tmp_path / "cup", _plan(**fields))
    while (due := session.next()) is not None:
        confirm = session.status()["phase"] == "confirm"
        session.score(due.episode, success(due), scene=scene(due, runs) if scene and confirm else None)
    assert (tmp_path / "cup" / "summary.json").read_text() == json.dumps(written, indent=2) + "\n"
    assert _client(tmp_path / "cup").get("/api/status").json()["verdict"] == written["verdict"]
