"""The operator page's terminal twin: score a session's episodes from the keyboard."""

from __future__ import annotations

from collections.abc import Callable

from goldenticket.report import verdict_table
from goldenticket.session.protocol import ScoreConflict, Session

HELP = "s = success, f = failure (a note may follow: `f gripper slipped`), u = undo, q = quit"


def score_in_terminal(session: Session, read: Callable[[str], str] = input) -> int:
    """Ask for each due episode's outcome until the session is complete or the operator quits."""
    print(HELP)
    while (status := session.status()) and (due := session.next()) is not None:
        try:
            answer = read(f"[{status['scored']}/{status['total']}] episode {due.episode}: ").strip()
        except EOFError:  # input closed: stop as with q
            answer = "q"
        key, _, note = answer.partition(" ")
        if key.lower() in ("s", "f"):
            try:
                session.score(due.episode, key.lower() == "s", note)
            except ScoreConflict as e:  # another tab or terminal scored it first
                print(f"not saved: {e}")
        elif key.lower() == "u":
            undone = session.undo()
            print("nothing to undo" if undone is None else f"score of episode {undone} removed")
        elif key.lower() == "q":
            print("stopped; every score entered is saved, run the same command to go on")
            return 0
        else:
            print(HELP)
    verdict = status["verdict"]
    print(verdict_table(verdict["arms"], title="arm"))
    print(verdict["note"])
    return 0
