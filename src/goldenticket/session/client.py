"""The robot's side of a session served over HTTP (`goldenticket session serve`).

    robot = Client("http://127.0.0.1:8765")
    while (due := robot.next()) is not None:
        noise = due.noise_source()  # call it at every policy call
        ...  # run the episode; then robot.score(due.episode, success), or let the operator score it
        robot.wait_until_scored(due.episode)

The server keeps every score, so a robot process that restarts makes a new Client and goes on
with the episode now due; while the server itself restarts, requests are retried.
"""

from __future__ import annotations

import http.client
import json
import time
import urllib.error
import urllib.request

from goldenticket.errors import UserError
from goldenticket.session.episode import NextEpisode
from goldenticket.session.folder import ScoreConflict


class Client:
    """A session's JSON API for the robot's process. `token`: the server's --token, if any;
    `patience`: seconds to keep retrying while no server answers (a restart)."""

    def __init__(self, url: str = "http://127.0.0.1:8765", token: str | None = None, patience: float = 60.0):
        self.url, self.token, self.patience = url.rstrip("/"), token, patience
        self._retried = False  # whether the last request was sent again

    def next(self) -> NextEpisode | None:
        """The episode to run now, or None when the session is complete."""
        answer = self._call("/api/next")
        return None if answer.get("done") else NextEpisode.from_json(answer)

    def score(self, episode: int, success: bool, note: str | None = None, scene: str | None = None) -> None:
        """Record the due episode's outcome (ScoreConflict, naming the due episode, for another). A
        score sent again after its answer was lost, and found saved, is not an error."""
        try:
            self._call("/api/score", {"episode": episode, "success": bool(success), "note": note,
                                      "scene": scene})
        except ScoreConflict as conflict:
            if not (self._retried and "scored already" in str(conflict)):
                raise

    def status(self) -> dict:
        """Scored and due episodes, what is due in words, and the verdict once complete."""
        return self._call("/api/status")

    def wait_until_scored(self, episode: int, poll: float = 1.0) -> None:
        """Return once `episode` is no longer due: the operator has scored it on the page or in a
        terminal (or the robot did, with `score`)."""
        while self.status()["due"] == episode:
            time.sleep(poll)

    def _call(self, path: str, body: dict | None = None) -> dict:
        data = None if body is None else json.dumps(body).encode()
        headers = {"Content-Type": "application/json"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        deadline, self._retried = time.monotonic() + self.patience, False
        while True:
            try:
                with urllib.request.urlopen(urllib.request.Request(self.url + path, data, headers),
                                            timeout=30) as response:
                    return json.load(response)
            except urllib.error.HTTPError as e:
                raise _refusal(e) from None
            except (OSError, http.client.HTTPException) as e:  # no server (yet), or it died answering
                if time.monotonic() > deadline:
                    why = getattr(e, "reason", e)
                    raise UserError(f"{self.url}: no session server answers ({why})") from None
                time.sleep(0.5)
                self._retried = True


def _refusal(error: urllib.error.HTTPError) -> UserError:
    """The server's JSON error as a ScoreConflict (409) or a UserError naming it."""
    try:
        answer = json.load(error)
    except ValueError:
        answer = {}
    message = answer.pop("error", f"HTTP {error.code} {error.reason}")
    if error.code == 409:
        return ScoreConflict(message, **answer)
    return UserError(f"the session server refused: {message}")
