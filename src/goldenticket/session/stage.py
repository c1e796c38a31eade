"""What is due, in words for the operator: the phase, the search round or the confirm pair, and
never the arm (the operator scores blind)."""

from __future__ import annotations

from collections.abc import Callable

from goldenticket.session.race import Plan


def stage(plan: Plan, due: int | None, confirm: int | None,
          search_round: Callable[[int], tuple[int, int]]) -> str:
    """The due episode's stage: `confirm` is the first confirm episode (None before the confirm
    phase is planned), `search_round(due)` the due search round's number and how many tickets run
    in it."""
    if due is None:
        return "complete"
    if confirm is None and plan.stopping == "fixed":
        return "search phase"
    if confirm is None:
        round_, left = search_round(due)
        return f"search phase, round {round_}, {left} tickets left"
    if plan.stopping == "fixed":
        return "confirm phase"
    pair, run = divmod(due - confirm, 2)
    scene = "the same scene as run 1" if run else "set up a new scene"
    return f"confirm phase, pair {pair + 1} of at most {plan.confirm}, run {run + 1} of 2: {scene}"
