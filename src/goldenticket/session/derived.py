"""The files beside a session's store, derived from it: the finalists' ticket files, and once the
session is complete summary.json and verdict.png. Nothing else in the folder is written or removed,
and nothing through a symbolic link in place of tickets/."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Collection
from dataclasses import asdict
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.files import write_atomic
from goldenticket.session.race import DROP_Z, ROUND, Plan
from goldenticket.session.verdict import SessionVerdict
from goldenticket.tickets import Ticket

SUMMARY, PLOT, TICKETS = "summary.json", "verdict.png", "tickets"
RUN_STORE = "run.sqlite"  # a search's run folder


def check_free(folder: Path) -> None:
    """UserError unless `folder` can take a new session: it holds no search run (run.sqlite) and no
    summary.json, verdict.png or tickets of another run, which the session would replace or remove."""
    tickets = tickets_folder(folder)
    taken = [name for name in (RUN_STORE, SUMMARY, PLOT) if os.path.lexists(folder / name)]
    if tickets.exists() and (not tickets.is_dir() or any(tickets.iterdir())):
        taken.append(TICKETS)
    if taken:
        raise UserError(f"{folder} holds another run ({', '.join(taken)}); choose a new folder for the "
                        "session")


def tickets_folder(folder: Path) -> Path:
    """The session's tickets/ in `folder`; UserError if it is a symbolic link, which would have the
    session write and remove files elsewhere."""
    tickets = folder / TICKETS
    if tickets.is_symlink():
        raise UserError(f"{tickets} is a symbolic link; a session keeps its tickets in a folder of its own "
                        "(replace the link with a folder)")
    return tickets


def save_tickets(folder: Path, candidates: Collection[str], finalists: list[str],
                 ticket: Callable[[str], Ticket]) -> None:
    """The finalists as ticket files in `folder`/tickets (`ticket(arm)` makes one), ready to deploy
    once the verdict is in; a missing one is written again, and a candidate's that is no longer a
    finalist (after an undo) removed. Any other file there is left alone."""
    tickets = tickets_folder(folder)
    for old in tickets.glob("*.safetensors"):
        if old.stem in candidates and old.stem not in finalists and old.is_file():
            old.unlink()
    for arm in finalists:
        if not (tickets / f"{arm}.safetensors").is_file():
            ticket(arm).save(tickets / f"{arm}.safetensors")


def save_verdict(folder: Path, name: str, plan: Plan, verdict: SessionVerdict,
                 record: dict[str, tuple[int, int]], finalists: list[str]) -> None:
    """summary.json and verdict.png in `folder` for the complete session `name`, whose candidates
    had `record` (search successes, episodes); neither is written again while summary.json holds
    the same text."""
    summary, png = folder / SUMMARY, folder / PLOT
    race = {} if plan.stopping == "fixed" else {
        "race": {"first_round": plan.first_round, "round": ROUND, "drop_z": DROP_Z}}
    text = json.dumps({"session": name, "plan": asdict(plan), **race,
                       "search_successes": {arm: won for arm, (won, _) in record.items()},
                       "search_episodes": {arm: n for arm, (_, n) in record.items()},
                       "tickets": {a: f"tickets/{a}.safetensors" for a in finalists},
                       "verdict": verdict.to_dict()}, indent=2) + "\n"
    if png.is_file() and summary.is_file() and summary.read_text() == text:
        return
    from goldenticket.plots import arms_png

    stopped = "" if plan.stopping == "fixed" else f" ({verdict.stopping.reason})"
    arms_png(verdict.arms, png, f"Session {name}: {plan.policy}{stopped}", what="confirm-phase success",
             unit="episodes per arm")
    write_atomic(summary, text)  # last: a summary.json that matches says verdict.png is written


def remove_verdict(folder: Path) -> None:
    """No summary.json nor verdict.png: the session is not complete (again, after an undo)."""
    (folder / SUMMARY).unlink(missing_ok=True)
    (folder / PLOT).unlink(missing_ok=True)
