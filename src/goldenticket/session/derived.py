"""The files beside a session's store, derived from it: the finalists' ticket files, and once the
session is complete summary.json and verdict.png."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from goldenticket.files import write_atomic
from goldenticket.session.race import DROP_Z, ROUND, Plan
from goldenticket.session.verdict import SessionVerdict
from goldenticket.tickets import Ticket

SUMMARY, PLOT = "summary.json", "verdict.png"


def save_tickets(folder: Path, finalists: list[str], ticket: Callable[[str], Ticket]) -> None:
    """The finalists as ticket files in `folder` (`ticket(arm)` makes one), ready to deploy once the
    verdict is in; a missing one is written again, one no longer a finalist (after an undo) removed."""
    for old in folder.glob("*.safetensors"):
        if old.stem not in finalists and old.is_file():
            old.unlink()
    for arm in finalists:
        if not (folder / f"{arm}.safetensors").is_file():
            ticket(arm).save(folder / f"{arm}.safetensors")


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
