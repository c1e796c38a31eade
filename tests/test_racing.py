"""Racing across a whole search (ticket_search.racing): tickets stop where a paired sign test on
the seeds they share with the incumbent says they are worse, or, halved, where the better half of
their batch goes on without them."""

from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from goldenticket.config import SearchConfig
from goldenticket.errors import OptionError, UserError
from goldenticket.ticket_search import EpisodeOutcome, Halved, Query, Raced, make_optimizer, run_search

SEEDS = tuple(range(100, 120))


class Scripted:
    """An optimizer asking the given batches of (1, 1) tickets in turn, recording what it is told."""

    def __init__(self, *batches):
        self.seeds, self.batches, self.told = SEEDS, list(batches), []

    def ask(self) -> list[Query]:
        return [Query(np.full((1, 1), t), self.seeds) for t in self.batches.pop(0)] if self.batches else []

    def tell(self, queries, returns) -> None:
        self.told.append({round(float(q.ticket[0, 0]), 3): r for q, r in zip(queries, returns, strict=True)})


def succeeds_with_probability_ticket(queries: list[Query]) -> list[EpisodeOutcome]:
    """A ticket t succeeds on seed s when (s * 0.618) mod 1 < t: the same seeds for every ticket."""
    outcomes = []
    for q in queries:
        won = (np.array(q.seeds) * 0.618) % 1 < q.ticket[0, 0]
        outcomes.append(EpisodeOutcome(won.astype(float), won))
    return outcomes


def test_a_ticket_worse_than_the_incumbent_stops_and_the_optimizer_hears_what_it_ran():
    inner = Scripted([0.6], [0.05, 0.6, 0.9])
    seen = []

    def evaluate(queries):
        seen.extend((round(float(q.ticket[0, 0]), 3), q.seeds) for q in queries)
        return succeeds_with_probability_ticket(queries)

    result = run_search(Raced(inner, block=5, alpha=0.1), evaluate, budget=10_000)
    runs = {t: sum(len(s) for u, s in seen if u == t) for t in (0.05, 0.6, 0.9)}
    assert runs[0.05] < len(SEEDS) and runs[0.6] == 2 * len(SEEDS) and runs[0.9] == len(SEEDS)
    assert all(s in [SEEDS[i : i + 5] for i in range(0, 20, 5)] for _, s in seen)  # the same blocks, in order
    assert {t: len(r) for t, r in inner.told[1].items()} == {0.05: runs[0.05], 0.6: 20, 0.9: 20}
    assert result.episodes_used == sum(runs.values())


def test_the_incumbent_is_the_best_ticket_that_ran_every_seed():
    raced = Raced(Scripted([0.3, 0.7], [0.5]), block=10, alpha=0.1)
    assert raced.incumbent is None
    while queries := raced.ask():
        raced.tell(queries, [o.returns for o in succeeds_with_probability_ticket(queries)])
    expected = succeeds_with_probability_ticket([Query(np.full((1, 1), 0.7), SEEDS)])[0].returns
    np.testing.assert_array_equal(raced.incumbent, expected)


def test_racing_lets_random_search_score_more_tickets_within_a_budget():
    def tickets_scored(race: bool) -> int:
        opt = make_optimizer("rs", (1, 1), SEEDS, np.random.default_rng(0), batch_size=10)
        opt = Raced(opt, block=5, alpha=0.1) if race else opt
        return len(run_search(opt, succeeds_with_probability_ticket, budget=1_000).candidates)

    assert tickets_scored(True) > 1.3 * tickets_scored(False)


@pytest.mark.parametrize(("block", "alpha", "says"),
                         [(0, 0.1, "block"), (21, 0.1, "block"), (5, 1.0, "level")])
def test_bad_race_settings_are_one_line(block, alpha, says):
    with pytest.raises(UserError, match=says):
        Raced(Scripted(), block, alpha)


@pytest.mark.parametrize(("method", "race", "halving", "says"),
                         [("cma-es", 0.0, False, "level in"), ("cem-racing", 0.1, False, "its own"),
                          ("cem-bounds", None, True, "halving is for"), ("cma-es", 0.1, True, "choose one")])
def test_a_run_races_with_a_level_or_halves_and_not_a_self_racing_method(method, race, halving, says):
    with pytest.raises(OptionError, match=says):
        SearchConfig("metaworld/reach-v3/flow", "metaworld/reach-v3", method=method, race=race,
                     halving=halving).check()


@pytest.mark.parametrize(("options", "halves"),
                         [({}, True), ({"budget": 1100}, True), ({"budget": 1101}, False),
                          ({"budget": 4000, "halving": True}, True), ({"halving": False}, False),
                          ({"race": 0.1}, False), ({"method": "cem-racing"}, False),
                          ({"method": "gp"}, True)])
def test_a_run_halves_by_default_up_to_1100_search_episodes_unless_its_tickets_race(options, halves):
    assert SearchConfig("metaworld/reach-v3/flow", "metaworld/reach-v3", **options).halves() is halves


def test_the_race_and_halving_help_names_the_block_sizes_and_the_budget_rule():
    from dataclasses import fields

    from goldenticket.config import HALVING_UP_TO
    from goldenticket.job.stages import VALIDATION_BLOCK
    from goldenticket.ticket_search.racing import RACE_BLOCK

    helps = {f.name: f.metadata["help"] for f in fields(SearchConfig) if f.name in ("race", "halving")}
    assert f"blocks of {RACE_BLOCK} search seeds" in helps["race"]
    assert f"first {RACE_BLOCK} search seeds, the better half on the next {RACE_BLOCK}" in helps["halving"]
    assert f"first {VALIDATION_BLOCK} validation seeds, the better half on the next {VALIDATION_BLOCK}" \
        in helps["halving"] and f"at most {HALVING_UP_TO} and" in helps["halving"]


def test_halving_runs_the_better_half_on_each_next_block_and_tells_what_each_ran():
    tickets = [round(0.05 * i, 2) for i in range(1, 21)]  # 20 tickets: the higher, the better
    inner, seen = Scripted(tickets), []

    def evaluate(queries):
        seen.append([round(float(q.ticket[0, 0]), 2) for q in queries])
        assert len({q.seeds for q in queries}) == 1  # a block: the same seeds for every ticket
        return succeeds_with_probability_ticket(queries)

    result = run_search(Halved(inner, block=5), evaluate, budget=10_000)
    assert [len(block) for block in seen] == [20, 10, 5, 2]
    assert set(seen[-1]) <= set(tickets[-5:])  # the last ones are among the best
    ran = {t: 5 * sum(t in block for block in seen) for t in tickets}
    assert {t: len(r) for t, r in inner.told[0].items()} == ran and result.episodes_used == 185


def test_halving_gives_cma_es_more_generations_within_a_budget():
    def generations(halve: bool) -> int:
        opt = make_optimizer("cma-es", (1, 1), SEEDS, np.random.default_rng(0), population=20)
        run_search(Halved(opt, block=5) if halve else opt, succeeds_with_probability_ticket, budget=850)
        return opt.iteration

    assert (generations(False), generations(True)) == (2, 4)


def test_a_run_with_halving_halves_its_method(monkeypatch):
    from goldenticket.job import Plan, checked_tasks, stages
    from goldenticket.policies import load_policy

    monkeypatch.syspath_prepend(str(Path(__file__).parent))
    cfg = SearchConfig("byo_example:make_policy", "byo_example:make_env", halving=True, workers=1)
    policy = load_policy(cfg.policy)
    built = stages.optimizer(Plan.of(cfg, policy, checked_tasks(policy, cfg)))
    assert isinstance(built, Halved) and [len(b) for b in built.blocks] == [5, 5, 5, 5]


def test_halving_validates_tickets_stopped_before_the_last_search_seed():
    from goldenticket.job import stages
    from goldenticket.ticket_search import Candidate, SearchResult

    def cand(value, returns):
        return Candidate(np.full((1, 1), value), list(range(len(returns))), returns, [r > 0 for r in returns])

    stopped, finished = cand(0.9, [1.0] * 10), cand(0.5, [1.0] * 12 + [0.0] * 8)
    result = SearchResult([stopped, finished], episodes_used=30, stopped_because="budget")
    plan = SimpleNamespace(keys=tuple(range(20)), seeds=SimpleNamespace(validation=[1]),
                           cfg=SimpleNamespace(top_k=1, halves=lambda: True))
    assert stages.top_candidates(plan, result) == [stopped, finished]
    plan.cfg.halves = lambda: False
    assert stages.top_candidates(plan, result) == [finished]


class Validating:
    """An evaluator for `stages.validate`: ticket t succeeds on seed s as in
    `succeeds_with_probability_ticket`; records each call's (tickets, seeds) and the bar's size."""

    def __init__(self):
        self.calls, self.total = [], None

    @contextmanager
    def progress(self, total, desc):
        self.total = total
        yield

    def run(self, jobs, task):
        self.calls.append(([label for label, _, _ in jobs], tuple(jobs[0][2])))
        queries = [Query(np.asarray(source.noise), tuple(seeds)) for _, source, seeds in jobs]
        outcomes = succeeds_with_probability_ticket(queries)
        return [[SimpleNamespace(ret=r) for r in o.returns] for o in outcomes]


@pytest.mark.parametrize("halving", [False, True])
def test_halved_validation_runs_the_better_half_on_the_next_seeds_while_more_than_top_k(halving):
    from goldenticket.job.stages import validate
    from goldenticket.tickets import Ticket, TicketRecord

    qualities = (0.3, 0.9, 0.5, 0.8, 0.1, 0.7, 0.2, 0.6, 0.4, 0.85)
    tickets = [Ticket(np.full((1, 1), q), TicketRecord()) for q in qualities]
    seeds = list(range(500, 540))
    plan = SimpleNamespace(seeds=SimpleNamespace(validation=seeds), task_names=["t"],
                           cfg=SimpleNamespace(halves=lambda: halving, top_k=3))
    evaluator = Validating()
    validated = validate(plan, evaluator, tickets)
    ids = [t.id for t in tickets]
    if halving:
        assert [(len(labels), s) for labels, s in evaluator.calls] == [(10, tuple(seeds[:10])),
                                                                        (5, tuple(seeds[10:20]))]
        assert evaluator.total == 150
        ran = {t.id: t.record.validation_seeds for t in validated.scored}
        assert sorted(ran.values()).count((500, 519)) == 5 and sorted(ran.values()).count((500, 509)) == 5
    else:
        assert evaluator.calls == [(ids, tuple(seeds))] and evaluator.total == 400
    assert {t.id for t in validated.chosen} == {ids[1], ids[9], ids[3]}  # 0.9, 0.85 and 0.8


@pytest.mark.parametrize(("tickets", "keep", "blocks", "sizes"),
                         [(10, 3, 4, [10, 5]), (20, 3, 4, [20, 10, 5]), (10, 3, 1, [10]), (4, 3, 4, [4])])
def test_halving_sizes_stop_where_the_half_would_not_be_more_than_to_keep(tickets, keep, blocks, sizes):
    from goldenticket.ticket_search.racing import halving_sizes

    assert halving_sizes(tickets, keep, blocks) == sizes


def test_a_race_cuts_after_each_round_but_its_last_and_is_over_once_nobody_is_left():
    from goldenticket.ticket_search.racing import Race, better_half

    race = Race(5, better_half, sum, rounds=3)
    race.record([1, 3, 3, 0, 2])
    assert race.alive == [1, 2] and not race.over  # the better half; of the tied, the earlier first
    race.record([0, 1])
    assert race.alive == [2] and race.ranked() == [2]
    race.record([5])
    assert race.over and race.alive == [2] and race.results == [[1], [3, 0], [3, 1, 5], [0], [2]]
    dropped = Race(3, lambda race: [], sum)  # no last round: over once the cut leaves nobody
    dropped.record([1, 2, 3])
    assert dropped.over and dropped.alive == []
    assert Race(0, better_half, sum).over
