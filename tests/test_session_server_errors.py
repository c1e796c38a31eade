"""The session server's answers to paths it does not have and methods a path does not take: JSON
errors, like every other error it sends."""

from test_session import _client, _plan

from goldenticket.session import Session


def test_unknown_paths_and_wrong_methods_get_a_json_error(tmp_path):
    Session.new(tmp_path, _plan())
    client = _client(tmp_path)
    missing = client.get("/api/nothing")
    assert missing.status_code == 404 and "/api/nothing" in missing.json()["error"]
    for method, path, allowed in (("POST", "/api/status", "GET"), ("GET", "/api/score", "POST"),
                                  ("PUT", "/api/undo", "POST")):
        wrong = client.request(method, path, json={"episode": 0})
        assert wrong.status_code == 405 and allowed in wrong.json()["error"], (method, path)
        assert allowed in wrong.headers["allow"]
    for response in (missing, wrong):
        assert response.headers["content-type"] == "application/json"
        assert set(response.json()) == {"error"} and response.headers["x-frame-options"] == "DENY"
    assert client.get("/api/status").json()["scored"] == 0
