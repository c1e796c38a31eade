"""The job's results are typed; summary.json, ticket metadata and `evaluate --json` are their dicts."""

import json
from dataclasses import FrozenInstanceError, replace
from pathlib import Path

import pytest

from goldenticket.config import SearchConfig
from goldenticket.evaluation import BASE, ZERO, Arm, VerdictRow, judged_arms
from goldenticket.job import find_golden_tickets
from goldenticket.results import Summary, VerdictTable, to_run
from goldenticket.rollout import NONFINITE, EpisodeResult
from goldenticket.stats import Rate, holm_adjust, paired_exact_test
from goldenticket.tickets import Ticket

HERE = Path(__file__).parent


def _episodes(successes: str, nonfinite: int = 0) -> list[EpisodeResult]:
    return [EpisodeResult(seed, s == "1", float(s == "1"), 5, 0.0,
                          cause=NONFINITE if seed < nonfinite else None) for seed, s in enumerate(successes)]


def test_a_verdict_row_writes_the_keys_of_its_tests_in_order():
    rows = judged_arms({BASE: _episodes("0000011111"), ZERO: _episodes("0001111111"),
                        Arm.ticket("t"): _episodes("1111111111")}).rows
    base, zero, ticket = rows.values()
    rate = ["success_rate", "ci_low", "ci_high", "n", "nonfinite_episodes"]
    assert list(base.to_dict()) == rate
    assert list(zero.to_dict()) == [*rate, "p_vs_base", "golden", "verdict"]
    assert list(ticket.to_dict()) == [*rate, "p_vs_base", "golden", "verdict", "p_vs_zero"]
    assert ticket.golden and ticket.to_dict()["verdict"] == "golden" and ticket.to_dict()["golden"] is True
    assert not zero.golden and zero.to_dict()["verdict"] == "not golden"
    assert list(replace(ticket, diversity=0.5).to_dict())[-1] == "diversity"
    assert judged_arms({BASE: _episodes("0011", nonfinite=3)}).rows[BASE].nonfinite == 3


@pytest.mark.slow
def test_the_job_returns_its_summary_typed_and_writes_it_as_summary_json(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    cfg = SearchConfig("byo_example:make_policy", "byo_example:make_env", method="rs", budget=40,
                       search_seeds=4, validation_seeds=6, heldout=20, top_k=2, workers=1, max_steps=30,
                       front_objective="speed")
    summary = find_golden_tickets(cfg, tmp_path)
    assert isinstance(summary, Summary)
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written == summary.to_dict()
    assert list(written) == ["task", "policy", "method", "seed", "search_episodes", "stopped_because",
                             "heldout_seeds", "base", "zero", "best", "deliver", "tickets", "p_value_note",
                             "front"]
    assert summary.best == summary.tickets[0] and written["best"] == summary.best.to_dict()
    assert list(summary.best.to_dict())[-3:] == ["ticket_id", "ticket_path", "search_score"]
    for found in summary.tickets:
        ticket = Ticket.load(found.path)
        assert ticket.id == found.id and found.validation_score is not None
        seeds = list(summary.run.heldout_seeds)
        assert ticket.metadata["heldout"] == found.heldout.to_dict() | {"seeds": seeds}
    assert set(summary.front.tickets) <= {p.stem for p in (tmp_path / "tickets").iterdir()}
    assert summary.base.rate.n == summary.zero.rate.n == 20
    assert summary.run.policy == "byo_example:make_policy"


def test_without_a_golden_ticket_the_verdict_says_what_to_run_instead():
    from goldenticket.report import verdict_text

    def row(k, p=None):
        return VerdictRow(Rate.counted(k, 100), p_vs_base=p)

    weak = row(48, 0.7)
    for zero, said in ((row(80, 1e-6), "The zero ticket (w = 0) is: 80.0%, p = 1e-06; deploy it"),
                       (row(53, 0.3), "The zero ticket (w = 0, 53.0%) is ahead of the base on these seeds"),
                       (row(49, 0.7), "Keep the base policy (fresh Gaussian noise)")):
        text = verdict_text(VerdictTable(row(50), zero, {"ticket t": weak}), weak, "t", "")
        assert "No golden ticket: the best ticket (t, 48.0%)" in text and said in text
    ahead = row(55, 0.2)
    text = verdict_text(VerdictTable(row(50), row(49, 0.7), {"ticket t": ahead}), ahead, "t", "")
    assert "It is ahead of the base on these seeds: run it rather than the base, though not proven" in text
    judged_zero = VerdictTable(row(50), row(60, 0.06), {}, "z", 0.01)  # the zero ticket, best, judged as z
    assert "ahead of the base on these seeds" in verdict_text(judged_zero, judged_zero.zero, "z", "")


@pytest.mark.parametrize(("best", "zero", "golden", "run"), [
    (0.6, 0.7, True, "best"),  # golden: the best ticket, whatever the zero ticket did
    (0.55, 0.52, False, "best"), (0.55, 0.55, False, "best"), (0.48, 0.53, False, "zero"),
    (0.5, 0.49, False, "base"), (0.3, 0.2, False, "base")])
def test_the_job_runs_an_arm_ahead_of_the_base_or_else_the_base(best, zero, golden, run):
    assert to_run(best, zero, 0.5, golden) == run


@pytest.mark.parametrize(("best", "source", "delivered"), [
    ((60, 0.2), None, "ticket"), ((60, 0.2), "zero", "zero ticket"), ((50, 0.6), None, "base"),
    ((70, 0.01), "zero", "zero ticket")])
def test_summary_json_says_what_the_job_delivers(best, source, delivered):
    from goldenticket.results import FoundTicket, SearchRun
    from goldenticket.tickets import ZERO_SOURCE

    def row(k, p=None):
        return VerdictRow(Rate.counted(k, 100), p_vs_base=p)

    found = FoundTicket("t", "t.safetensors", 0.5, row(*best), source=ZERO_SOURCE if source else None)
    run = SearchRun("p", "cma-es", 0, 840, "budget", (1000000, 1000099))
    summary = Summary("task", run, row(50), row(best[0] if source else 40, 0.5), (found,))
    assert summary.deliver == delivered == summary.to_dict()["deliver"]


def test_the_verdict_table_shows_the_zero_ticket_once_and_says_what_holm_made_of_it():
    """Where the job judged w = 0 as one of its tickets, its table has one zero-ticket row: the p-values it
    was judged with among the tickets, and a line under the table naming the ticket, the adjustment and the
    p-value before it (summary.json's `zero` row)."""
    from goldenticket.report import verdict_text
    from goldenticket.results import FoundTicket, SearchRun
    from goldenticket.tickets import ZERO_SOURCE

    def row(k, p_base=None, p_zero=None):
        return VerdictRow(Rate.counted(k, 200), p_vs_base=p_base, p_vs_zero=p_zero)

    tickets = (FoundTicket("635cab4edbe4", "a", 0.6, row(134, 0.0107, 0.0351)),
               FoundTicket("81bed810a464", "z", None, row(116, 0.755, 1.0), source=ZERO_SOURCE),
               FoundTicket("ec7d021b8955", "b", 0.6, row(110, 1.0, 1.0)))
    run = SearchRun("p", "cma-es", 0, 1100, "budget", (1000000, 1000199))
    summary = Summary("task", run, row(112), row(116, 0.252), tickets)
    text = verdict_text(summary.table(), summary.best.heldout, summary.best.name, summary.p_value_note)
    table = text.split("\n\n")[0].splitlines()
    assert [line.split("  ")[0] for line in table[1:4]] == ["base", "zero ticket", "ticket 635cab4edbe4"]
    assert len(table) == 6 and "81bed810a464" not in "\n".join(table[:5])  # the zero ticket: one row
    assert table[2].split()[-5:] == ["200", "0.755", "-", "not", "golden"]  # as judged among the tickets
    assert table[5] == ("zero ticket = ticket 81bed810a464, judged as one of the 3 tickets: its p vs base is "
                        "Holm-adjusted over them (0.252 unadjusted)")
    assert summary.to_dict()["zero"]["p_vs_base"] == 0.252  # summary.json keeps the zero arm's own row
    alone = Summary("task", run, row(112), row(116, 0.252), tickets[::2])
    text = verdict_text(alone.table(), alone.best.heldout, alone.best.name, alone.p_value_note)
    assert "zero ticket = " not in text and " 0.252 " in text.splitlines()[2]  # not judged as a ticket


def test_a_verdict_holm_adjusts_its_candidates_once_from_their_episodes():
    episodes = {BASE: "0000011111" * 3, ZERO: "0001111111" * 3, Arm.ticket("a"): "1111111111" * 3,
                Arm.ticket("b"): "0000111111" * 3}
    verdict = judged_arms({arm: _episodes(successes) for arm, successes in episodes.items()})
    raw = {arm: paired_exact_test([s == "1" for s in episodes[arm]], [s == "1" for s in episodes[BASE]])
           for arm in (ZERO, Arm.ticket("a"), Arm.ticket("b"))}
    rows = verdict.rows
    assert rows[ZERO].p_vs_base == raw[ZERO]  # what the tickets are tested against: not adjusted
    tickets = verdict.candidates
    assert [rows[t].p_vs_base for t in tickets] == holm_adjust([raw[t] for t in tickets])
    assert rows[Arm.ticket("a")].p_vs_base == 2 * raw[Arm.ticket("a")]
    again = judged_arms({arm: judged.results for arm, judged in verdict.arms.items()})
    assert again.rows == rows and verdict.rows is rows  # computed from the episodes, once
    with pytest.raises(FrozenInstanceError):
        verdict.arms[BASE].results = ()
    with pytest.raises(FrozenInstanceError):
        verdict.arms = {}
    with pytest.raises(TypeError):  # neither the arms nor the rows change in place
        verdict.arms[BASE] = verdict.arms[ZERO]
    with pytest.raises(TypeError):
        verdict.rows[BASE] = rows[ZERO]
