"""The zero ticket and tickets a user gives are candidates beside the search's best."""

import json
from pathlib import Path

import numpy as np
import pytest

import goldenticket
from goldenticket.cli import main
from goldenticket.store import RunStore
from goldenticket.tickets import Ticket, ticket_id, zero_ticket

HERE = Path(__file__).parent
EXACT = ["--policy", "byo_example:make_exact_policy", "--task", "byo_example:make_env"]
SMALL = ["--method", "rs", "--budget", "40", "--search-seeds", "4", "--heldout", "30", "--top-k", "1",
         "--validation-seeds", "10", "--workers", "1", "--max-steps", "40"]


@pytest.fixture(autouse=True)
def _byo(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))


def test_where_any_noise_hurts_the_zero_ticket_is_delivered(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["search", *EXACT, *SMALL, "--out", str(out)]) == 0
    said = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    best = summary["best"]
    assert best["source"] == "zero ticket" and best["success_rate"] == summary["zero"]["success_rate"]
    assert best["success_rate"] > summary["base"]["success_rate"]
    assert "(the zero ticket, w = 0)" in said
    assert f"zero ticket = ticket {best['ticket_id']}, judged as " in said
    assert said.count("zero ticket  ") == 1 and f"ticket {best['ticket_id']}  " not in said  # its row, once
    delivered = Ticket.load(best["ticket_path"])
    assert not delivered.noise.any() and delivered.metadata["source"] == "zero ticket"
    with RunStore(out / "run.sqlite") as store:  # the zero arm's held-out episodes serve it: none rerun
        judged = {r.ticket_id for r in store.episodes(seed_set="heldout")}
    assert best["ticket_id"] not in judged and {"base", "zero"} <= judged
    assert delivered.id == ticket_id(zero_ticket((4, 2)).noise, delivered.record.policy_fingerprint)


@pytest.mark.slow
def test_a_given_ticket_is_validated_beside_the_search(tmp_path):
    given = Ticket(np.full((4, 2), 0.01, np.float32)).save(tmp_path / "earlier.safetensors")
    summary = goldenticket.search("byo_example:make_exact_policy", "byo_example:make_env", tmp_path / "run",
                                  method="rs", budget=40, search_seeds=4, heldout=30, top_k=2,
                                  validation_seeds=10, workers=1, max_steps=40, tickets=[str(given)])
    with RunStore(tmp_path / "run" / "run.sqlite") as store:
        rows = store.episodes(seed_set="validation")
    scores = {t: np.mean([r.ret for r in rows if r.ticket_id == t]) for t in {r.ticket_id for r in rows}}
    judged = {t.id for t in summary.tickets}
    zero = next(t.id for t in summary.tickets if t.source == "zero ticket")  # judged whatever its score
    assert len(scores) == 3 * 2 + 2  # the search's 3 x top-k, the zero ticket and the given one
    fingerprint = Ticket.load(summary.best.path).record.policy_fingerprint
    assert ticket_id(Ticket.load(given).noise, fingerprint) in scores
    assert 2 <= len(judged) <= 3  # the top 2 on validation, and the zero ticket if not among them
    assert min(scores[t] for t in judged - {zero}) >= max(scores[t] for t in set(scores) - judged)


def test_given_tickets_need_validation_seeds(tmp_path, capsys):
    given = str(Ticket(np.zeros((4, 2), np.float32)).save(tmp_path / "t.safetensors"))
    options = [a if a != "10" else "0" for a in SMALL]  # --validation-seeds 0
    assert main(["search", *EXACT, *options, "--ticket", given, "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == ("goldenticket: error: --ticket: a given ticket runs on the validation "
                                       "seeds beside the search's best, so it needs --validation-seeds > 0\n")
    assert not (tmp_path / "o").exists()


def test_the_zero_ticket_ranks_before_a_ticket_it_ties(tmp_path):
    from goldenticket.evaluation import Arm, VerdictRow
    from goldenticket.job.folder import save_ranked
    from goldenticket.stats import Rate
    from goldenticket.tickets import ZERO_SOURCE, TicketRecord

    def judged(successes: str, p: float) -> VerdictRow:
        return VerdictRow(Rate.of([c == "1" for c in successes]), p_vs_base=p)

    zero = Ticket(zero_ticket((4, 2)).noise, TicketRecord(source=ZERO_SOURCE))
    tie, worse = (Ticket(np.full((4, 2), w, np.float32), TicketRecord(search_score=1.0)) for w in (0.5, -0.5))
    rows = {Arm.ticket(zero.id): judged("1100", 0.3), Arm.ticket(tie.id): judged("1010", 0.1),
            Arm.ticket(worse.id): judged("1000", 0.6)}
    ranked = save_ranked([tie, worse, zero], rows, tmp_path, (0, 3), {})
    assert [t.id for t in ranked] == [zero.id, tie.id, worse.id]  # a lower p does not break the tie
    rows[Arm.ticket(tie.id)] = judged("1110", 0.1)
    assert save_ranked([tie, worse, zero], rows, tmp_path, (0, 3), {})[0].id == tie.id
