"""The operator page's terminal twin: score a session's episodes from the keyboard."""

from __future__ import annotations

from collections.abc import Callable

from goldenticket.errors import UserError
from goldenticket.report import verdict_table
from goldenticket.session.folder import ScoreConflict, Session

HELP = "s = success, f = failure (a note may follow: `f gripper slipped`), u = undo the last score, q = quit"


def score_in_terminal(session: Session, read: Callable[[str], str] = input) -> int:
    """Ask for each due episode's outcome until the session is complete or the operator quits."""
    print(HELP)
    most = "at most " if session.plan.stopping == "sequential" else ""
    while (status := session.status())["due"] is not None:
        due = status["due"]
        try:
            answer = read(f"[{status['scored']}/{most}{status['total']}] episode {due} ({status['stage']}): ")
            answer.encode()  # bytes that are not UTF-8 arrive as surrogates, which nothing can store
        except EOFError:  # input closed: stop as with q
            answer = "q"
        except UnicodeError:
            raise UserError("the input is not UTF-8 text; every score entered is saved, run the same "
                            "command to go on") from None
        answer = answer.strip()
        key, _, note = answer.partition(" ")
        if key.lower() in ("s", "f"):
            try:
                session.score(due, key.lower() == "s", note)
            except ScoreConflict as e:  # another tab or terminal scored it first
                print(f"not saved: {e}")
        elif key.lower() == "u":
            _undo(session, status["last_scored"])
        elif key.lower() == "q":
            print("stopped; every score entered is saved, run the same command to go on")
            return 0
        else:
            print(HELP)
    verdict = status["verdict"]
    print(verdict_table(verdict.rows(), title="arm"))
    print(verdict.note)
    print(f"Stopped: {verdict.stopping.why}")
    print(f"Wrote summary.json and verdict.png in {session.path.parent}")
    return 0


def _undo(session: Session, episode: int | None) -> None:
    if episode is None:
        print("nothing to undo")
        return
    try:
        session.undo(episode)
        print(f"score of episode {episode} removed")
    except ScoreConflict as e:  # another tab or terminal scored or undid meanwhile
        print(f"not undone: {e}")
